"""Real-time factor of a fast scenario with and without the live view (one client subscribed).

The scanner_threshold graph (device at 40 kHz, threshold detector + hybrid EKF, recorder)
run as fast as its consumers take the frames, once alone and once with the live view
(``run_scenario --live-view``: the ``live_view`` process on the graph's domain) and a
Foxglove WebSocket client subscribed to every channel it advertises. Real-time factor:
simulated seconds per wall second from the first frame to the last frame delivered (set-up
excluded); medians of interleaved runs after a warm-up. Ratios measured in one run on this
machine.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import statistics
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_scenarios import scanner_threshold
from mems_scenarios.base import Progress, ScenarioOptions

DURATION_S = 2.0
REPEATS = 3
SUBPROTOCOL = "foxglove.sdk.v1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Client(threading.Thread):
    """A Foxglove WebSocket client that subscribes to every advertised channel and counts
    the Message Data frames and bytes it receives, until :attr:`stop` is set."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.stop = threading.Event()
        self.messages = 0
        self.bytes = 0
        self.channels: set[str] = set()

    def run(self) -> None:
        asyncio.run(self._run())

    async def _run(self) -> None:
        import websockets

        while not self.stop.is_set():  # the server starts with the graph
            try:
                ws = await websockets.connect(
                    f"ws://127.0.0.1:{self.port}",
                    subprotocols=[SUBPROTOCOL],
                    max_size=None,
                    proxy=None,
                )
                break
            except OSError:
                await asyncio.sleep(0.1)
        else:
            return
        async with ws:
            sub = 0
            while not self.stop.is_set():
                try:
                    raw = await asyncio.wait_for(ws.recv(), 0.1)
                except (asyncio.TimeoutError, websockets.ConnectionClosed):
                    continue
                if isinstance(raw, str):
                    msg = json.loads(raw)
                    if msg["op"] == "advertise":
                        subs = []
                        for ch in msg["channels"]:
                            sub += 1
                            subs.append({"id": sub, "channelId": ch["id"]})
                            self.channels.add(ch["topic"])
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif raw[0] == 1:
                    struct.unpack_from("<IQ", raw, 1)
                    self.messages += 1
                    self.bytes += len(raw) - 13


def rtf(live: bool, tmp: Path) -> tuple[float, Client | None]:
    """Simulated s / wall s of DURATION_S of the scanner_threshold graph."""
    options = ScenarioOptions(duration_s=DURATION_S, seed=1, plots=False, progress=False)
    client = None
    if live:
        port = free_port()
        options.live_view = port
        client = Client(port)
        client.start()
    try:
        result = scanner_threshold.run_graph(
            options, tmp / "bench.mcap", DURATION_S, Progress(DURATION_S, False, "")
        )
    finally:
        if client is not None:
            client.stop.set()
            client.join(5.0)
    return DURATION_S / result["wall_s"], client


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        rtf(False, Path(d))  # warm-up: compilation and first-import costs
        runs = {False: [], True: []}
        for _ in range(REPEATS):  # interleaved, so that a drift of the machine hits both
            for live in (False, True):
                factor, client = rtf(live, Path(d))
                runs[live].append(factor)
        without, with_live = statistics.median(runs[False]), statistics.median(runs[True])
        total = time.perf_counter() - t0
    print(
        f"scanner_threshold fast mode, {DURATION_S:g} s simulated, median of {REPEATS}: "
        f"real-time factor {without:.2f}x without the live view, {with_live:.2f}x with it and one client "
        f"subscribed to all {len(client.channels)} channels (ratio {with_live / without:.2f}); "
        f"the last client received {client.messages} messages ({client.bytes / 1e6:.1f} MB); "
        f"bench {total:.0f} s"
    )


if __name__ == "__main__":
    main()

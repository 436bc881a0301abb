"""The ``live_view`` process under hostile clients: 30 clients that subscribe to a fast
topic of large messages and never read keep its resident memory under 500 MB (their oldest
messages are dropped, counted, while a client that reads keeps receiving), and its sockets
are all on loopback."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from proc_sockets import inet_sockets, is_loopback

BIN = Path(sys.executable).parent
SUBPROTOCOL = "foxglove.sdk.v1"
TOPIC = "/bulk"
LISTENING = re.compile(r"live_view: Foxglove WebSocket server on ws://127\.0\.0\.1:(\d+)")
DROPPED = re.compile(r"(\d+) messages dropped for clients that did not read")
MESSAGE_DATA = 1
#: The hostile load: payload of each message [bytes], publishing period [s], clients that
#: never read, seconds they hold on.
PAYLOAD_BYTES = 128 * 1024
PERIOD_S = 0.01
NON_READERS = 30
HOLD_S = 6.0
MEMORY_LIMIT_BYTES = 500 * 1024 * 1024


def _status_kib(pid: int, field: str) -> int:
    """A ``/proc/PID/status`` memory field (VmRSS, VmHWM) [KiB]."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise AssertionError(f"no {field} in /proc/{pid}/status")


class LiveViewProcess:
    """``live_view --ros-args -p port:=0 -p NAME:=VALUE ...`` with its output collected."""

    def __init__(self, env: dict, **params) -> None:
        args = ["--ros-args", "-p", "port:=0"]
        for name, value in params.items():
            args += ["-p", f"{name}:={value}"]
        self.proc = subprocess.Popen(
            [str(BIN / "live_view"), *args],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._listening = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)
            if LISTENING.search(line):
                self._listening.set()

    def port(self, timeout_s: float = 60.0) -> int:
        assert self._listening.wait(timeout_s), "live_view did not listen:\n" + self.output()
        return int(next(m for m in map(LISTENING.search, self.lines) if m).group(1))

    def output(self) -> str:
        return "".join(self.lines)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        time.sleep(0.1)  # the reader thread takes the last lines
        return self.proc.returncode


def _publish_bulk(node, stop: threading.Event) -> None:
    """Publish ``sensor_msgs/Image`` of :data:`PAYLOAD_BYTES` every :data:`PERIOD_S` until
    ``stop``."""
    from sensor_msgs.msg import Image

    pub = node.create_publisher(Image, TOPIC, 10)
    msg = Image(height=1, width=PAYLOAD_BYTES, encoding="mono8", step=PAYLOAD_BYTES)
    msg.data = bytes(PAYLOAD_BYTES)
    k = 0
    while not stop.is_set():
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 10_000_000, 1_000_000_000)
        pub.publish(msg)
        k += 1
        time.sleep(PERIOD_S)


async def _subscribed_client(port: int):
    """A connection subscribed to :data:`TOPIC` that has received one message of it."""
    import websockets

    ws = await websockets.connect(
        f"ws://127.0.0.1:{port}",
        subprotocols=[SUBPROTOCOL],
        max_size=None,
        max_queue=1,
        ping_interval=None,
        proxy=None,
    )
    channel = None
    while True:
        raw = await asyncio.wait_for(ws.recv(), 60)
        if isinstance(raw, bytes):
            if raw[0] == MESSAGE_DATA:
                return ws
            continue
        msg = json.loads(raw)
        found = msg["op"] == "advertise" and channel is None
        channel = next((c for c in msg.get("channels", []) if c["topic"] == TOPIC), channel)
        if (found and channel is not None) or (
            msg["op"] == "status" and "Unknown channel" in msg.get("message", "")
        ):
            await asyncio.sleep(0.05 * (msg["op"] == "status"))
            sub = {"id": 1, "channelId": channel["id"]}
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [sub]}))


async def _hostile_load(port: int, pid: int) -> dict:
    """30 clients subscribe and stop reading; one reads on; the figures after HOLD_S."""
    silent = await asyncio.gather(*(_subscribed_client(port) for _ in range(NON_READERS)))
    reader = await _subscribed_client(port)
    received, peak_rss_kib = 0, 0
    deadline = time.monotonic() + HOLD_S
    while time.monotonic() < deadline:
        try:
            raw = await asyncio.wait_for(reader.recv(), 0.25)
        except TimeoutError:
            raw = b""
        received += raw[:1] == bytes([MESSAGE_DATA])
        peak_rss_kib = max(peak_rss_kib, _status_kib(pid, "VmRSS"))
    figures = dict(received=received, rss_kib=peak_rss_kib, hwm_kib=_status_kib(pid, "VmHWM"))
    for ws in (*silent, reader):
        ws.transport.abort()
    return figures


def test_thirty_clients_that_never_read_keep_live_view_under_500_mb(graph, subprocess_env):
    _, _, probe = graph
    view = LiveViewProcess(subprocess_env, topics=TOPIC, max_rate_hz=0.0, max_clients=40)
    stop = threading.Event()
    publisher = threading.Thread(target=_publish_bulk, args=(probe, stop), daemon=True)
    publisher.start()
    try:
        figures = asyncio.run(_hostile_load(view.port(), view.proc.pid))
    finally:
        stop.set()
        publisher.join(5)
        code = view.stop()
    out = view.output()
    print(f"live_view under {NON_READERS} silent clients: {figures}")  # the measured figures
    assert code == 0, out
    assert figures["hwm_kib"] * 1024 < MEMORY_LIMIT_BYTES, (figures, out)
    dropped = DROPPED.search(out)
    assert dropped and int(dropped.group(1)) > 0, out
    assert "does not keep up: dropping its oldest messages" in out
    # the client that reads is served all along (100 Hz published, no rate limit)
    assert figures["received"] >= 2 * HOLD_S, figures


def test_live_view_sockets_are_all_on_loopback(subprocess_env):
    view = LiveViewProcess(subprocess_env)
    try:
        port = view.port()
        sockets = inet_sockets(view.proc.pid)
        assert any(address.endswith(f":{port}") for proto, address in sockets), sockets
        assert len([s for s in sockets if s[0].startswith("tcp")]) >= 2, sockets  # + the SDK
        assert all(is_loopback(address) for _, address in sockets), sockets
    finally:
        assert view.stop() == 0, view.output()

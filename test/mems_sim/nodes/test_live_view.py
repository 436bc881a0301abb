"""The live view: a Foxglove WebSocket client connected during a scenario run subscribes to
the estimate channel and decodes a message with the schema the server advertised; no
process of the run has a socket beyond loopback.

The client side of the Foxglove WebSocket protocol (JSON ``serverInfo``/``advertise`` from
the server, ``subscribe`` from the client, binary Message Data frames: opcode 1, u32
subscription id, u64 log time, payload; all little-endian) is written here on the
``websockets`` library from the Foxglove WebSocket protocol specification, not from
the server's code, and asks for the spec's subprotocol ``foxglove.websocket.v1``, which
ws-protocol clients and older Foxglove and Lichtblick versions send; the live view's front end
serves it beside the SDK's ``foxglove.sdk.v1`` (the handshake of both: test_foxglove_front).
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from proc_sockets import non_loopback_sockets, process_tree

BIN = Path(sys.executable).parent
SUBPROTOCOL = "foxglove.websocket.v1"
ESTIMATE = "/scanner/estimate"
URL_LINE = re.compile(r"live view: ws://127\.0\.0\.1:(\d+)")
MESSAGE_DATA = 1


def _lines_until(stream, pattern, timeout_s: float, seen: list[str]):
    """Read ``stream`` in a thread; return the first match of ``pattern`` (None on timeout
    or at the end of the stream). Every line goes to ``seen``; the thread keeps draining the
    stream afterwards."""
    found = threading.Event()
    match = []

    def read():
        for line in stream:
            seen.append(line)
            m = pattern.search(line)
            if m and not match:
                match.append(m)
                found.set()
        found.set()  # end of the stream: the process ended

    threading.Thread(target=read, daemon=True).start()
    found.wait(timeout_s)
    return match[0] if match else None


async def _subscribe_and_take(port: int, topic: str, timeout_s: float) -> dict:
    """Connect, wait for ``topic``'s advertisement, subscribe, return the channel and the
    first Message Data frame's (log time, payload)."""
    import websockets

    deadline = time.monotonic() + timeout_s
    async with websockets.connect(
        f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None, proxy=None
    ) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channel, sub_id, info = None, 7, None

        def subscribe(ch: dict) -> str:
            return json.dumps(
                {"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": ch["id"]}]}
            )

        while time.monotonic() < deadline:
            raw = await asyncio.wait_for(ws.recv(), max(0.01, deadline - time.monotonic()))
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg["op"] == "serverInfo":
                    info = msg
                elif msg["op"] == "advertise" and channel is None:
                    channel = next((c for c in msg["channels"] if c["topic"] == topic), None)
                    if channel is not None:
                        await ws.send(subscribe(channel))
                elif (
                    msg["op"] == "status"
                    and channel is not None
                    and msg["message"] == f"Unknown channel ID: {channel['id']}"
                ):
                    # the SDK's server sends an advertisement before it registers the
                    # channel for that client; a subscription sent at once can fall in
                    # between and be refused: subscribe again
                    await asyncio.sleep(0.05)
                    await ws.send(subscribe(channel))
                continue
            if raw[0] == MESSAGE_DATA:
                got_id, log_time = struct.unpack_from("<IQ", raw, 1)
                assert got_id == sub_id
                return dict(info=info, channel=channel, log_time=log_time, payload=raw[13:])
        raise AssertionError(f"no message on {topic} within {timeout_s} s (channel {channel})")


def test_foxglove_client_decodes_the_estimate_during_a_scenario(tmp_path, subprocess_env):
    from rclpy.serialization import deserialize_message

    from mems_sim.bag.schema import message_class, schema_text

    out = tmp_path / "live.mcap"
    run = subprocess.Popen(
        [
            str(BIN / "run_scenario"),
            "scanner_threshold",
            "--duration",
            "2",  # the longest this scenario allows: the view closes with the scenario
            "--realtime",
            # paced at a quarter of real time (8 s of graph), so that a loaded machine's
            # slow discovery by the client does not outlast the run
            "--set",
            "scanner.realtime_factor=0.25",
            "--live-view",
            "0",
            "--out",
            str(out),
            "--no-plots",
            "--no-progress",
        ],
        env=subprocess_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen: list[str] = []
    try:
        m = _lines_until(run.stderr, URL_LINE, 60.0, seen)
        assert m, "run_scenario printed no live view URL:\n" + "".join(seen)
        # what `ss -ltnp` would show: nothing of the run's processes beyond loopback
        tree = process_tree(run.pid)
        assert len(tree) >= 2, tree  # run_scenario and its live_view process at least
        assert non_loopback_sockets(run.pid) == []
        got = asyncio.run(_subscribe_and_take(int(m.group(1)), ESTIMATE, 30.0))
        stdout, _ = run.communicate(timeout=90)
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
            run.wait(30)
    assert run.returncode == 0, stdout + "".join(seen)
    assert "scenario scanner_threshold" in stdout
    assert out.exists()

    ch = got["channel"]
    assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg"
    assert ch["schemaName"] == "mems_msgs/msg/StateEstimate"
    assert ch["schema"] == schema_text(ch["schemaName"])
    msg = deserialize_message(got["payload"], message_class(ch["schemaName"]))
    k = len(msg.state_names)
    assert k >= 1 and msg.num_samples >= 1 and msg.sample_rate_hz > 0
    assert len(msg.states) == len(msg.variances) == k * msg.num_samples
    assert all(math.isfinite(x) for x in msg.states)
    assert all(v >= 0 for v in msg.variances)
    # the log time is the message's sensor time (its header stamp)
    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    assert got["log_time"] == stamp


def _refusal(env: dict, executable: str, *args: str) -> str:
    """The one line ``executable args...`` prints on stderr as it exits with 2."""
    run = subprocess.run(
        [str(BIN / executable), *args], env=env, capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 2, run.stderr
    assert len(run.stderr.strip().splitlines()) == 1, run.stderr
    return run.stderr


def _live_view_refusal(env: dict, parameter: str) -> str:
    """The one line ``live_view --ros-args -p PARAMETER`` prints as it exits with 2."""
    return _refusal(env, "live_view", "--ros-args", "-p", parameter)


@pytest.mark.parametrize("port", ["-1", "70000"])
def test_run_scenario_refuses_a_bad_live_view_port(port, subprocess_env):
    err = _refusal(subprocess_env, "run_scenario", "scanner_threshold", "--live-view", port)
    assert "--live-view" in err


def test_live_view_refuses_a_port_in_use(subprocess_env):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        err = _live_view_refusal(subprocess_env, f"port:={port}")
    assert "port" in err and str(port) in err


@pytest.mark.parametrize("origins", ["viewer.example", "https://viewer.example/page"])
def test_live_view_refuses_an_allowed_origin_that_is_no_origin(origins, subprocess_env):
    err = _live_view_refusal(subprocess_env, f"allowed_origins:={origins}")
    assert "allowed_origins" in err and origins in err


def test_foxglove_layouts_are_generated_and_name_recorded_topics():
    """config/foxglove/<device>.json are what tools/foxglove_layouts.py writes, each panel
    of the layout tree is configured, and every plotted topic is in the device's reference
    bag."""
    import importlib.util

    from mcap.reader import make_reader

    repo = Path(__file__).resolve().parents[3]
    spec = importlib.util.spec_from_file_location(
        "foxglove_layouts", repo / "tools" / "foxglove_layouts.py"
    )
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    files = sorted((repo / "config" / "foxglove").glob("*.json"))
    assert [f.stem for f in files] == sorted(gen.DEVICES)
    for path in files:
        text = path.read_text()
        assert text == gen.render(path.stem), f"{path.name}: run tools/foxglove_layouts.py"
        layout = json.loads(text)

        def leaves(node):
            return (
                [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])
            )

        assert sorted(leaves(layout["layout"])) == sorted(layout["configById"])
        with open(repo / "bags" / f"{path.stem}.mcap", "rb") as f:
            topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
        for panel, config in layout["configById"].items():
            for series in config.get("paths", []):
                topic = series["value"].split(".", 1)[0]
                assert topic in topics, f"{path.name}: {panel} plots {topic}, not in the bag"


def test_a_layout_moved_to_a_scenario_namespace_names_its_recorded_topics():
    """``tools/foxglove_layouts.py --namespace /stage_t1 stage``: every plotted topic is one
    gyro_calibration records under that namespace; a bad namespace is refused (exit 2)."""
    from mems_scenarios import gyro_calibration

    repo = Path(__file__).resolve().parents[3]
    tool = [sys.executable, str(repo / "tools" / "foxglove_layouts.py")]
    for ns in gyro_calibration.INSTANCES:
        run = subprocess.run(
            [*tool, "--namespace", f"/{ns}", "stage"], capture_output=True, text=True
        )
        assert run.returncode == 0, run.stderr
        layout = json.loads(run.stdout)
        paths = [s["value"] for c in layout["configById"].values() for s in c.get("paths", [])]
        recorded = {f"/{ns}/{t}" for t in gyro_calibration.RECORDED}
        assert paths and all(p.split(".", 1)[0] in recorded for p in paths), paths
    bad = subprocess.run([*tool, "--namespace", "a b", "stage"], capture_output=True, text=True)
    assert bad.returncode == 2 and "not a ROS namespace" in bad.stderr

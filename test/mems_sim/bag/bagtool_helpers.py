"""Helpers of the bag-tool tests: measured subprocess runs, a live publisher, MCAP crafting."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent
REPO = Path(__file__).resolve().parents[3]


@dataclass
class Run:
    """Result of :func:`run_measured`."""

    returncode: int
    stdout: str
    stderr: str
    max_rss_mb: float
    wall_s: float

    @property
    def err_lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]


#: Runs a program in a fork of a small interpreter and reports the child's peak RSS:
#: ``ru_maxrss`` of a child counts the memory of the process it was forked from before
#: ``exec``, so forking the tool straight from pytest would report pytest's size.
_MEASURE = """
import os, sys
pid = os.fork()
if pid == 0:
    try:
        os.execv(sys.argv[2], sys.argv[2:])
    finally:
        os._exit(127)
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as out:
    out.write(f"{os.waitstatus_to_exitcode(status)} {usage.ru_maxrss}")
"""


def run_measured(args, env=None, timeout: float = 60.0) -> Run:
    """Run a console script of the venv; return its exit code, output and peak RSS [MB]
    (of the tool's process alone, see ``_MEASURE``)."""
    with (
        tempfile.TemporaryFile() as out,
        tempfile.TemporaryFile() as err,
        tempfile.NamedTemporaryFile("r") as report,
    ):
        t0 = time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, "-S", "-c", _MEASURE, report.name, str(BIN / args[0])]
            + [str(a) for a in args[1:]],
            env=env,
            stdout=out,
            stderr=err,
            start_new_session=True,
        )
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
        wall = time.monotonic() - t0
        code, rss_kb = (int(v) for v in open(report.name).read().split())
        out.seek(0)
        err.seek(0)
        return Run(
            code,
            out.read().decode(errors="replace"),
            err.read().decode(errors="replace"),
            rss_kb / 1024.0,
            wall,
        )


PUBLISHER = r"""
import sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy, DurabilityPolicy
from mems_msgs.msg import AdcFrame

rclpy.init()
node = rclpy.create_node("live_publisher")
qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
pub = node.create_publisher(AdcFrame, sys.argv[1], qos)
period = float(sys.argv[2])
num = int(sys.argv[3])
msg = AdcFrame()
msg.header.frame_id = "live"
msg.sample_rate_hz = 1000.0
msg.num_samples = num
msg.bits = 16
msg.channel_names = ["a", "b", "c"]
msg.channel_units = ["V"] * 3
msg.lsb = [1e-3] * 3
msg.offset = [0.0] * 3
msg.full_scale = [32.767] * 3
msg.codes = [(7 * i) % 30000 - 15000 for i in range(3 * num)]
print("publishing", flush=True)
k = 0
t_next = time.monotonic()
while True:
    msg.first_sample_index = k * num
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * num * 1_000_000, 1_000_000_000)
    pub.publish(msg)
    k += 1
    t_next += period
    delay = t_next - time.monotonic()
    if delay > 0:
        time.sleep(delay)
"""


def start_publisher(env, topic: str, period_s: float = 0.002, num: int = 100):
    """A separate process publishing AdcFrames on ``topic`` continuously (until killed)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", PUBLISHER, topic, str(period_s), str(num)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()
    assert "publishing" in line, proc.stderr.read() if proc.poll() is not None else line
    return proc


def stop_process(proc) -> None:
    """Kill a helper process of the test and reap it."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)


class Collector:
    """Collects the lines of a text stream in a thread (so the child never blocks on a pipe)."""

    def __init__(self, stream):
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._run, args=(stream,), daemon=True)
        self._thread.start()

    def _run(self, stream) -> None:
        for line in stream:
            self.lines.append(line)

    def wait_for(self, text: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in self.lines):
                return True
            time.sleep(0.02)
        return False

    def text(self, timeout: float = 5.0) -> str:
        self._thread.join(timeout)
        return "".join(self.lines)


def reference_frames(count: int | None = None):
    """``(schema_text, qos_yaml, [cdr bytes])`` of the /imu/adc AdcFrames of bags/imu.mcap."""
    from mems_sim.bag.player import iter_messages, recorded_topics
    from mems_sim.bag.schema import schema_text

    path = str(REPO / "bags" / "imu.mcap")
    _, qos = recorded_topics(path)["/imu/adc"]
    data = [m.data for m in iter_messages(path, ["/imu/adc"])]
    return schema_text("mems_msgs/msg/AdcFrame"), qos, data[:count]

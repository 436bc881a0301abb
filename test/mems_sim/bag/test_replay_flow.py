"""Bags on the data's timeline, paced replay, and lossless replay into other processes.

* A fast simulated run records log times = sensor time (frames: epoch 0 + index / fs;
  /clock: its value) and ``mcap_info`` gives the data's duration; ``mcap_play --rate 1``
  replays it in as long as the data lasts, its /clock carries the stamps' time (to one
  clock period) and a recording of the replay has the same log times.
* ``mcap_play --as-fast-as-possible`` into a slow consumer in this process: without flow
  control frames are lost (and the player cannot tell); with ``--wait-for-consumer`` every
  frame arrives, the report says so, and a loss the consumer reports is counted (exit 3).
* Into ``imu_noise_identifier_node`` in another process: the final model equals the one
  the identifier gave live, field by field.
"""

from __future__ import annotations

import math
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from conftest import spin_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import UInt64

from mems_msgs.msg import AdcFrame, NoiseModel
from mems_sim.bag.info import bag_info
from mems_sim.bag.player import iter_messages, read_messages
from mems_sim.bag.recorder import RecorderNode
from mems_sim.bag.schema import peek_header_stamp_ns, schema_text
from mems_sim.bag.writer import McapBagWriter
from mems_sim.ros.frames import index_to_ns, time_to_ns
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS
from mems_sim.ros.qos_yaml import profiles_yaml as qos_profiles_yaml

BIN = Path(sys.executable).parent
FS = 100.0


def _fast_run(path: Path, domain_id: int, duration_s: float, frame: int = 10) -> None:
    """An IMU emulator stepped as fast as the recorder takes its frames (the scenario
    runner's machinery), /clock recorded too."""
    from mems_scenarios.base import Graph
    from mems_scenarios.delivery import drive_fast
    from mems_sim.nodes.imu_node import ImuNode

    graph = Graph(domain_id)
    try:
        emu = graph.add_device(
            ImuNode,
            dict(seed=5, duration_s=duration_s, frame_size=frame, publish_imu=False),
            realtime=False,
        )
        rec = graph.add(
            RecorderNode(str(path), topics=["/imu/adc", "/clock"], context=graph.context)
        )
        graph.spin_until(
            lambda: emu.pub_adc.get_subscription_count() >= 1 and len(rec.recorded_topics()) == 2,
            20.0,
            "the recorder",
        )
        drive_fast(graph, [emu], lambda d: rec.received("/imu/adc") * d.p["frame_size"])
        graph.spin_until(
            lambda: rec.received("/imu/adc") >= emu.frames_published, 20.0, "the last frames"
        )
        rec.close()
    finally:
        graph.close()


def test_fast_run_bag_is_on_the_data_timeline_and_replays_in_data_time(
    graph, subprocess_env, tmp_path
):
    ctx, ex, probe = graph
    duration = 2.0
    src = tmp_path / "fast.mcap"
    _fast_run(src, next_domain(), duration)
    clocks = []
    for m in iter_messages(str(src)):
        if m.topic == "/imu/adc":
            frame = rclpy.serialization.deserialize_message(m.data, AdcFrame)
            assert m.log_time_ns == time_to_ns(frame.header.stamp)
            assert m.log_time_ns == index_to_ns(frame.first_sample_index, FS, 0)
        else:
            assert m.log_time_ns == peek_header_stamp_ns(m.data)  # /clock: its value
            clocks.append(m.log_time_ns)
    assert clocks[-1] == index_to_ns(int(duration * FS), FS, 0)
    info = bag_info(str(src))
    assert info["start_ns"] == 0 and abs(info["duration_s"] - duration) <= 1 / FS

    out = tmp_path / "replay.mcap"
    rec = RecorderNode(str(out), topics=["/imu/adc", "/clock"], context=ctx)
    ex.add_node(rec)
    proc = subprocess.Popen(
        [str(BIN / "mcap_play"), str(src), "--topics", "/imu/adc", "--rate", "1"]
        + ["--clock", "20", "--wait-for-subscribers", "1"],
        env=subprocess_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert spin_until(ex, lambda: proc.poll() is not None, timeout=30)
        stdout, stderr = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    spin_until(ex, lambda: rec.received("/imu/adc") >= 20, timeout=5)
    rec.close()
    ex.remove_node(rec)
    rec.destroy_node()
    # paced on log time: the 1.9 s from the first to the last frame take 1.9 s of wall time
    found = re.search(r"([\d.]+) s of log time in ([\d.]+) s", stdout)
    log_s, wall_s = float(found[1]), float(found[2])
    assert log_s == pytest.approx(duration - 10 / FS)
    assert 0.97 <= wall_s / log_s <= 1.15, stdout
    replayed = list(iter_messages(str(out)))
    frames = [m.log_time_ns for m in replayed if m.topic == "/imu/adc"]
    assert frames == [index_to_ns(10 * k, FS, 0) for k in range(20)]
    values = [m.log_time_ns for m in replayed if m.topic == "/clock"]
    assert values == sorted(values) and values[-1] == frames[-1]
    # /clock carries the stamps' time (not the wall clock's) at 20 Hz of that time: its values
    # lie on the frames' timeline, 50 ms apart (median; a timer late on a loaded machine
    # stretches one gap, not the time the values carry)
    assert frames[0] - 0.05e9 <= values[0] and values[-1] == frames[-1]
    assert np.median(np.diff(values)) == pytest.approx(0.05e9, rel=0.2)
    assert abs(bag_info(str(out))["duration_s"] - duration) <= 1 / FS


def next_domain() -> int:
    from conftest import next_domain_id

    return next_domain_id()


# ---------------------------------------------------------------------- flow control

CONSUMER_NS, CONSUMER = "/x", "slow_consumer"
PROGRESS_QOS = QoSProfile(  # as the estimator nodes publish it
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
)


def _frame_bag(path: Path, frames: int, num: int = 10) -> None:
    writer = McapBagWriter(str(path))
    writer.add_topic(
        "/x/adc",
        "mems_msgs/msg/AdcFrame",
        schema_text("mems_msgs/msg/AdcFrame"),
        qos_profiles_yaml([FRAME_QOS]),
    )
    for k in range(frames):
        msg = AdcFrame()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * num * 10**7, 10**9)
        msg.first_sample_index, msg.sample_rate_hz, msg.num_samples = k * num, FS, num
        msg.bits, msg.channel_names, msg.channel_units = 16, ["a"], ["V"]
        msg.lsb, msg.offset, msg.full_scale = [1e-3], [0.0], [32.0]
        msg.codes = list(range(num))
        stamp = time_to_ns(msg.header.stamp)
        writer.write("/x/adc", serialize_message(msg), stamp, stamp)
    writer.close()


class SlowConsumer:
    """A consumer node in this process: takes ``delay_s`` per frame from a shallow history,
    publishes ``~/progress`` after every frame as the estimator nodes do, counts gaps, and
    reports them on /diagnostics. ``skip``: frame indices it pretends never arrived."""

    def __init__(self, ctx, delay_s: float, depth: int = 5, skip=()):
        self.node = rclpy.create_node(CONSUMER, namespace=CONSUMER_NS, context=ctx)
        self.delay_s, self.skip = delay_s, set(skip)
        self.firsts: list[int] = []
        self.gaps = 0
        self.expected = 0
        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, depth=depth)
        self.node.create_subscription(AdcFrame, "/x/adc", self.on_frame, qos)
        self.progress = self.node.create_publisher(UInt64, "~/progress", PROGRESS_QOS)
        self.diag = self.node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.node.create_timer(0.2, self.publish_diagnostics)

    def on_frame(self, msg: AdcFrame) -> None:
        first = int(msg.first_sample_index)
        if first in self.skip:
            return
        time.sleep(self.delay_s)
        if first != self.expected:
            self.gaps += 1
        self.expected = first + msg.num_samples
        self.firsts.append(first)
        self.progress.publish(UInt64(data=self.expected))

    def publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name=f"{CONSUMER}: test consumer")
        status.values = [KeyValue(key="gaps", value=str(self.gaps))]
        self.diag.publish(DiagnosticArray(status=[status]))


def _play(ex, env, bag: Path, *extra: str, timeout: float = 60.0):
    proc = subprocess.Popen(
        [str(BIN / "mcap_play"), str(bag), "--as-fast-as-possible", *extra],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert spin_until(ex, lambda: proc.poll() is not None, timeout=timeout)
        stdout, stderr = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, stdout, stderr


def test_flow_control_replays_every_frame_into_a_slow_consumer(graph, subprocess_env, tmp_path):
    ctx, ex, probe = graph
    n = 300
    bag = tmp_path / "frames.mcap"
    _frame_bag(bag, n)
    consumer = SlowConsumer(ctx, delay_s=0.002)
    ex.add_node(consumer.node)
    # the middleware alone: the player publishes everything, the consumer loses frames
    code, stdout, stderr = _play(ex, subprocess_env, bag, "--wait-for-subscribers", "1")
    spin_until(ex, lambda: False, timeout=1.0)
    assert code == 0 and f"published {n} messages" in stdout, stderr
    assert len(consumer.firsts) < n and consumer.gaps > 0
    # application-level flow control: every frame, reported as acknowledged
    consumer.firsts.clear()
    consumer.expected = 0
    consumer.gaps = 0
    code, stdout, stderr = _play(
        ex,
        subprocess_env,
        bag,
        "--wait-for-consumer",
        f"{CONSUMER_NS}/{CONSUMER}",
        "--credit",
        "3f",
    )
    assert code == 0, stdout + stderr
    assert consumer.firsts == [10 * k for k in range(n)] and consumer.gaps == 0
    assert f"/x/adc: published {n}, acknowledged {n} by /x/slow_consumer" in stdout
    assert "loss: none" in stdout
    # a credit in samples works the same
    consumer.firsts.clear()
    consumer.expected = 0
    code, stdout, stderr = _play(
        ex,
        subprocess_env,
        bag,
        "--wait-for-consumer",
        f"{CONSUMER_NS}/{CONSUMER}",
        "--credit",
        "25",
    )
    assert code == 0 and len(consumer.firsts) == n, stdout + stderr
    ex.remove_node(consumer.node)
    consumer.node.destroy_node()


def test_flow_control_reports_a_loss_the_consumer_reports(graph, subprocess_env, tmp_path):
    ctx, ex, probe = graph
    bag = tmp_path / "frames.mcap"
    _frame_bag(bag, 100)
    consumer = SlowConsumer(ctx, delay_s=0.0, depth=1000, skip={500})
    ex.add_node(consumer.node)
    code, stdout, stderr = _play(
        ex, subprocess_env, bag, "--wait-for-consumer", f"{CONSUMER_NS}/{CONSUMER}"
    )
    assert code == 3, stdout + stderr
    assert consumer.gaps == 1 and len(consumer.firsts) == 99
    assert "gaps it reported 1" in stdout and "loss: 1 frames" in stdout
    # a consumer that is not there: exit 3 after the wait, one line
    code, stdout, stderr = _play(
        ex, subprocess_env, bag, "--wait-for-consumer", "/x/nobody", "--wait-timeout", "1"
    )
    assert code == 3 and "consumer not ready: /x/nobody" in stderr
    ex.remove_node(consumer.node)
    consumer.node.destroy_node()


# ---------------------------------------------------------------------- the identifier


def _differences(a, b, path: str = "") -> list[str]:
    """Fields of two messages that differ (NaN equals NaN)."""
    if hasattr(a, "get_fields_and_field_types"):
        out = []
        for name in a.get_fields_and_field_types():
            out += _differences(getattr(a, name), getattr(b, name), f"{path}.{name}")
        return out
    if isinstance(a, float):
        same = a == b or (math.isnan(a) and math.isnan(b))
        return [] if same else [f"{path}: {a!r} vs {b!r}"]
    if isinstance(a, (str, int, bool, bytes)):
        return [] if a == b else [f"{path}: {a!r} vs {b!r}"]
    if len(a) != len(b):
        return [f"{path}: {len(a)} vs {len(b)} elements"]
    if len(a) and hasattr(a[0], "get_fields_and_field_types"):
        return [d for k, (x, y) in enumerate(zip(a, b)) for d in _differences(x, y, f"{path}[{k}]")]
    x, y = np.asarray(a), np.asarray(b)
    return [] if np.array_equal(x, y, equal_nan=x.dtype.kind == "f") else [f"{path}: arrays differ"]


def test_fast_replay_into_the_identifier_process_gives_the_live_model(
    graph, subprocess_env, tmp_path
):
    from mems_scenarios import imu_noise
    from mems_scenarios.base import ScenarioOptions

    ctx, ex, probe = graph
    bag = tmp_path / "imu.mcap"
    live = imu_noise.run(
        ScenarioOptions(
            duration_s=70.0, seed=3, out=bag, domain_id=next_domain(), progress=False, plots=False
        )
    )["model"]
    assert live.final
    models = []
    probe.create_subscription(NoiseModel, "/imu/noise_model", models.append, RESULT_QOS)
    ident = subprocess.Popen(
        [str(BIN / "imu_noise_identifier_node"), "--ros-args", "-r", "__ns:=/imu"]
        + ["-p", "publish_period_s:=0.0"],
        env=subprocess_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        code, stdout, stderr = _play(
            ex,
            subprocess_env,
            bag,
            "--topics",
            "/imu/adc",
            "--wait-for-consumer",
            "/imu/imu_noise_identifier",
            "--wait-timeout",
            "30",
        )
        assert code == 0, stdout + stderr
        assert "/imu/adc: published 70, acknowledged 70" in stdout and "loss: none" in stdout
        ident.send_signal(signal.SIGINT)  # it publishes its final model at shutdown
        assert spin_until(ex, lambda: any(m.final for m in models), timeout=30), models
        ident.wait(timeout=10)
    finally:
        if ident.poll() is None:
            ident.kill()
            ident.wait()
    (replayed,) = [m for m in models if m.final]
    assert _differences(replayed, live) == []
    # the recorded live bag has the same model in it, also on the data's timeline
    (_, _, log_time, recorded) = [
        x for x in read_messages(str(bag), ["/imu/noise_model"]) if x[3].final
    ][0]
    assert log_time == time_to_ns(recorded.header.stamp) == index_to_ns(7000 - 1, FS, 0)

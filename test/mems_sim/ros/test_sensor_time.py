"""Sensor time: one epoch per run, stamps epoch + k / fs, /clock, use_sim_time.

* A node that paces itself (as its executable does) stamps from the wall clock at start;
  its frames' stamps are epoch + first_sample_index / fs exactly, and with
  ``publish_clock`` its /clock carries the same timeline to one clock period, ending at the
  end of its data.
* Under use_sim_time (at start or set at runtime) an emulator publishes nothing before the
  first /clock, then paces on /clock (one simulated second per /clock second), stamps from
  /clock's time at start, and goes back to the wall clock when use_sim_time is cleared.
* Executables under use_sim_time with nobody publishing /clock still stop on SIGINT and
  SIGTERM at once.
* The scenario runner's graph (fast and real-time runs): frames, diagnostics and the
  recording's log times are all on the epoch-0 timeline, and ``mcap_info``'s duration is
  the data's.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from conftest import params, spin_until
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
from mems_msgs.msg import AdcFrame
from mems_sim.bag.info import bag_info
from mems_sim.bag.player import read_messages
from mems_sim.devices import imu
from mems_sim.nodes.imu_node import ImuNode
from mems_sim.ros.frames import index_to_ns, time_to_ns
from mems_sim.ros.qos import FRAME_QOS

BIN = Path(sys.executable).parent
FS = 100.0


def _clock(ns: int) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(ns, 10**9)
    return msg


def test_self_paced_emulator_stamps_from_wall_and_publishes_clock(graph):
    ctx, ex, probe = graph
    frames, clocks = [], []
    probe.create_subscription(AdcFrame, "/imu/adc", frames.append, FRAME_QOS)
    probe.create_subscription(Clock, "/clock", clocks.append, 10)
    imu.ImuNoiseModel(seed=0).generate(10)  # compile the kernels before pacing starts
    before = time.time_ns()
    emu = ImuNode(
        context=ctx,
        parameter_overrides=params(
            publish_imu=False, frame_size=10, duration_s=1.0, publish_clock=20.0
        ),
    )
    ex.add_node(emu)
    assert spin_until(ex, lambda: emu.finished and len(frames) == 10, timeout=10)
    t0 = emu.t0_ns
    assert emu.stamp_origin == "wall" and before <= t0 <= time.time_ns()
    for m in frames:
        assert time_to_ns(m.header.stamp) == index_to_ns(m.first_sample_index, FS, t0)
    end = index_to_ns(100, FS, t0)
    assert spin_until(ex, lambda: time_to_ns(clocks[-1].clock) == end, timeout=5)
    values = [time_to_ns(c.clock) for c in clocks]
    assert values == sorted(values) and t0 <= values[0] <= end
    # 20 Hz of wall clock at realtime_factor 1: about 20 messages over the second of data
    assert 12 <= len(values) <= 30, len(values)
    # /clock is on the frames' timeline: within one clock period (50 ms) of every frame's
    # end (a frame goes out when its last sample is due); the host may delay a message
    for m in frames:
        frame_end = time_to_ns(m.header.stamp) + 0.1e9
        assert min(abs(v - frame_end) for v in values) <= 0.05e9 + 0.02e9, frame_end - t0
    ex.remove_node(emu)
    emu.destroy_node()


def test_emulator_follows_clock_under_use_sim_time(graph):
    ctx, ex, probe = graph
    frames = []
    probe.create_subscription(AdcFrame, "/imu/adc", frames.append, FRAME_QOS)
    clock_pub = probe.create_publisher(Clock, "/clock", 10)
    emu = ImuNode(
        context=ctx,
        parameter_overrides=[
            *params(publish_imu=False, frame_size=10),
            Parameter("use_sim_time", value=True),
        ],
    )
    ex.add_node(emu)
    assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() == 1)
    spin_until(ex, lambda: False, timeout=0.3)
    assert frames == [] and emu.t0_ns is None  # no /clock yet: nothing, epoch still open
    start = 100 * 10**9
    clock_pub.publish(_clock(start))
    assert spin_until(ex, lambda: emu.t0_ns is not None, timeout=5)
    assert emu.t0_ns == start  # 'auto' -> the graph's time at start: /clock's
    clock_pub.publish(_clock(start + 500_000_000))  # half a second of /clock: 50 samples
    assert spin_until(ex, lambda: len(frames) == 5, timeout=5)
    spin_until(ex, lambda: False, timeout=0.3)  # and no more, whatever the wall clock does
    assert len(frames) == 5 and emu.next_index == 50
    assert [time_to_ns(m.header.stamp) for m in frames] == [
        index_to_ns(10 * k, FS, start) for k in range(5)
    ]
    # /clock going backwards (a replay that loops) restarts the pacing from there
    clock_pub.publish(_clock(start))
    spin_until(ex, lambda: False, timeout=0.2)
    clock_pub.publish(_clock(start + 200_000_000))
    assert spin_until(ex, lambda: len(frames) == 7, timeout=5)
    # use_sim_time cleared at runtime: the wall clock paces again, stamps continue
    (result,) = emu.set_parameters([Parameter("use_sim_time", value=False)])
    assert result.successful
    assert spin_until(ex, lambda: len(frames) >= 12, timeout=5)
    assert [m.first_sample_index for m in frames] == list(range(0, 10 * len(frames), 10))
    assert time_to_ns(frames[-1].header.stamp) == index_to_ns(
        frames[-1].first_sample_index, FS, start
    )
    # and set again at runtime: /clock paces again (it stands still: nothing more)
    (result,) = emu.set_parameters([Parameter("use_sim_time", value=True)])
    assert result.successful
    spin_until(ex, lambda: False, timeout=0.2)
    n = len(frames)
    spin_until(ex, lambda: False, timeout=0.5)
    assert len(frames) == n
    ex.remove_node(emu)
    emu.destroy_node()


def test_executables_stop_under_use_sim_time_without_clock(graph, subprocess_env):
    """Nobody publishes /clock: the nodes wait, and SIGINT / SIGTERM stop them at once."""
    _, ex, probe = graph
    procs = [
        subprocess.Popen(
            [str(BIN / exe), "--ros-args", "-p", "use_sim_time:=true", *extra],
            env=subprocess_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for exe, extra in (
            ("imu_node", ["-p", "publish_imu:=false"]),
            ("imu_noise_identifier_node", ["-r", "__ns:=/imu"]),
        )
    ]
    try:
        wanted = {("imu", "/imu"), ("imu_noise_identifier", "/imu")}
        assert spin_until(
            ex, lambda: wanted <= set(probe.get_node_names_and_namespaces()), timeout=30
        )
        spin_until(ex, lambda: False, timeout=1.0)  # both up, waiting for /clock
        assert all(p.poll() is None for p in procs)
        for p, sig in zip(procs, (signal.SIGINT, signal.SIGTERM)):
            p.send_signal(sig)
        t0 = time.monotonic()
        for p in procs:
            p.wait(timeout=10)
        assert time.monotonic() - t0 < 3.0
        for p in procs:
            assert p.returncode == 0, p.stderr.read()
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def _check_timeline(path: Path, duration_s: float, device_topics: list[str]) -> None:
    """Frames' stamps and log times = index / fs (epoch 0); every other stamped message and
    /clock within the data; mcap_info's duration is the data's."""
    info = bag_info(str(path))
    for topic, _, log_time, msg in read_messages(str(path)):
        if topic in device_topics:
            want = index_to_ns(msg.first_sample_index, msg.sample_rate_hz, 0)
            assert time_to_ns(msg.header.stamp) == want == log_time, topic
        else:
            assert 0 <= log_time <= duration_s * 1e9, (topic, log_time)
    assert info["start_ns"] == 0
    assert abs(info["duration_s"] - duration_s) <= 1 / FS


@pytest.mark.parametrize("realtime", [False, True], ids=["fast", "realtime"])
def test_scenario_graph_is_on_one_timeline(realtime, tmp_path, domain_id):
    from diagnostic_msgs.msg import DiagnosticArray

    from mems_scenarios.base import Graph
    from mems_scenarios.delivery import publish_all
    from mems_sim.bag.recorder import RecorderNode

    duration = 1.5
    out = tmp_path / "run.mcap"
    graph = Graph(domain_id)
    diags = []
    try:
        emu = graph.add_device(
            ImuNode,
            dict(duration_s=duration, frame_size=10, publish_imu=False),
            realtime=realtime,
        )
        rec = graph.add(
            RecorderNode(
                str(out), topics=["/imu/adc", "/imu/truth", "/diagnostics"], context=graph.context
            )
        )
        ident = graph.add(
            ImuNoiseIdentifierNode(
                context=graph.context, parameter_overrides=params(publish_period_s=0.0)
            )
        )
        listener = graph.add(rclpy.create_node("listener", context=graph.context))
        listener.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        graph.spin_until(
            lambda: (
                emu.pub_adc.get_subscription_count() >= 1
                and emu.pub_truth.get_subscription_count() >= 1
            ),
            20.0,
            "the recorder",
        )
        publish_all(
            graph,
            [emu],
            lambda d: min(rec.received("/imu/adc"), rec.received("/imu/truth")) * d.p["frame_size"],
            None,
            realtime=realtime,
            realtime_timeout_s=30.0,
        )

        def names() -> set[str]:
            return {s.name.split(":")[0] for d in diags for s in d.status}

        graph.spin_until(lambda: {"imu", "imu_noise_identifier"} <= names(), 5.0, "diagnostics")
        assert ident.frames_received > 0
        rec.close()
    finally:
        graph.close()
    for d in diags:  # emulator and identifier (use_sim_time): the run's timeline
        assert 0 <= time_to_ns(d.header.stamp) <= duration * 1e9
    _check_timeline(out, duration, ["/imu/adc", "/imu/truth"])

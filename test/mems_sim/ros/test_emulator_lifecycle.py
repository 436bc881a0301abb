"""An emulator executable in a graph of processes: ``start_when_matched`` (it publishes only
once its subscribers are matched) and ``exit_when_acknowledged`` (it exits with status 0
once its duration is published and acknowledged)."""

from __future__ import annotations

import subprocess
import sys
import time

from conftest import spin_until

NS = "/accelerometer"
TOPICS = ("adc", "drive", "truth")
#: 20 frames of 500 samples (0.01 s at 1 MHz), paced at 1/20 of real time (0.2 s wall).
PARAMS = dict(
    seed=3,
    frame_size=500,
    duration_s=0.01,
    realtime_factor=0.05,
    start_when_matched=True,
    exit_when_acknowledged=True,
)
FRAMES = 20


def _device(env: dict, node: str = "accelerometer_node", **params) -> subprocess.Popen:
    args = [a for k, v in params.items() for a in ("-p", f"{k}:={str(v).lower()}")]
    return subprocess.Popen(
        [sys.executable, "-m", f"mems_sim.nodes.{node}", "--ros-args", *args],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_emulator_starts_when_matched_and_exits_when_acknowledged(graph, subprocess_env):
    from mems_msgs.msg import AdcFrame, SignalFrame
    from mems_sim.ros.qos import FRAME_QOS

    _, ex, probe = graph
    proc = _device(subprocess_env, **PARAMS)
    try:
        seen = spin_until(ex, lambda: probe.count_publishers(f"{NS}/adc") > 0, timeout=30.0)
        assert seen, "the device's publishers never appeared"
        spin_until(ex, lambda: False, timeout=1.0)
        assert proc.poll() is None, "the device ended before anybody subscribed"
        # subscribe one topic after the other: it must wait for all three
        got: dict[str, list] = {t: [] for t in TOPICS}
        subscribed_ns = time.time_ns()
        for t in TOPICS:
            kind = AdcFrame if t == "adc" else SignalFrame
            probe.create_subscription(kind, f"{NS}/{t}", got[t].append, FRAME_QOS)
            spin_until(ex, lambda: False, timeout=0.3)
        assert spin_until(ex, lambda: proc.poll() is not None, timeout=60.0)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err[-2000:]
        spin_until(ex, lambda: all(len(got[t]) >= FRAMES for t in TOPICS), timeout=5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    for t in TOPICS:
        first = [m.first_sample_index for m in got[t]]
        assert first == [500 * k for k in range(FRAMES)], f"{t}: {first}"
    # the epoch (stamp of sample 0) is fixed when the pacing starts: after the match
    stamp = got["adc"][0].header.stamp
    assert stamp.sec * 1_000_000_000 + stamp.nanosec >= subscribed_ns


def test_exit_when_acknowledged_needs_an_end(subprocess_env):
    proc = _device(subprocess_env, exit_when_acknowledged=True)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "exit_when_acknowledged" in err and "duration_s" in err


def test_wait_for_subscribers_is_checked(subprocess_env):
    proc = _device(subprocess_env, wait_for_subscribers="adc:two", duration_s=0.01)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "wait_for_subscribers" in err


def test_a_node_with_a_duration_exits_on_its_own(subprocess_env):
    """``accelerometer_node -p duration_s:=...`` publishes its duration and exits with
    status 0 (nobody subscribed: nothing to wait for); it idled until SIGINT before."""
    proc = _device(subprocess_env, seed=7, duration_s=0.01, realtime_factor=0.05)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-2000:]


def test_exit_when_acknowledged_false_keeps_the_node_until_shut_down(subprocess_env):
    proc = _device(
        subprocess_env, duration_s=0.01, realtime_factor=0.05, exit_when_acknowledged=False
    )
    try:
        time.sleep(6.0)
        assert proc.poll() is None, "the node exited although exit_when_acknowledged is false"
        proc.send_signal(2)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_consumers_progress_gates_the_frames(graph, subprocess_env):
    """With ``consumers``, the node publishes at most CONSUMER_CREDIT_FRAMES frames beyond
    the consumer's progress (from sample 0 before its first report), however fast it is
    paced; a progress report lets exactly that many more out."""
    from std_msgs.msg import UInt64

    from mems_msgs.msg import AdcFrame
    from mems_sim.ros.node_base import CONSUMER_CREDIT_FRAMES
    from mems_sim.ros.qos import FRAME_QOS, PROGRESS_QOS

    _, ex, probe = graph
    got: list = []
    probe.create_subscription(AdcFrame, "/imu/adc", got.append, FRAME_QOS)
    progress = probe.create_publisher(UInt64, "/imu/fake_consumer/progress", PROGRESS_QOS)
    proc = _device(
        subprocess_env,
        "imu_node",
        frame_size=1,
        realtime_factor=1000.0,
        duration_s=100.0,
        consumers="fake_consumer",
        start_when_matched=True,
        wait_for_subscribers="adc:1",
        min_subscribers=0,
    )
    try:
        credit = CONSUMER_CREDIT_FRAMES
        assert spin_until(ex, lambda: len(got) >= credit, timeout=60.0), len(got)
        spin_until(ex, lambda: False, timeout=2.0)  # 2 s at 1000x: 200,000 samples due
        assert len(got) == credit
        progress.publish(UInt64(data=100))
        assert spin_until(ex, lambda: len(got) >= credit + 100, timeout=30.0), len(got)
        spin_until(ex, lambda: False, timeout=1.0)
        assert [m.first_sample_index for m in got] == list(range(credit + 100))
    finally:
        proc.kill()
        proc.wait()

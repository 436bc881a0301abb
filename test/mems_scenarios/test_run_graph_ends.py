"""Process graphs that end and never hide loss: the shipped IMU graph with a duration ends
on its own (emulator and identifier exit, status 0) without a gap, flow-controlled by the
identifier's ``~/progress``; a recorder that joins after the stream started reports the
missing head in its summary and ``mcap_info`` does too."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import spin_until

ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = Path(sys.executable).parent
IMU_GRAPH = str(ROOT / "launch" / "imu.launch.yaml")
#: The documented command (docs/graphs.md) with its duration argument.
DOCUMENTED = [
    IMU_GRAPH,
    "realtime_factor:=100.0",
    "min_duration_s:=10.0",
    "publish_period_s:=10.0",
    "duration_s:=60.0",
]


def _run_graph(args, env, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(VENV_BIN / "run_graph"), *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _gap_lines(run: subprocess.CompletedProcess) -> list[str]:
    return [line for line in (run.stdout + run.stderr).splitlines() if "gap of" in line]


def test_imu_graph_with_a_duration_ends_on_its_own_without_loss(tmp_path, subprocess_env):
    """5 s of data at 100x: both nodes exit on their own, run_graph with status 0; the
    recorded adc (the identifier's input, recorder started before the emulator) has every
    sample from 0, and the identifier logged no gap."""
    out = tmp_path / "imu.mcap"
    args = [
        IMU_GRAPH,
        "realtime_factor:=100.0",
        "min_duration_s:=1.0",
        "publish_period_s:=1.0",
        "duration_s:=5.0",
        "wait_for_subscribers:=adc:2",
        "--record",
        str(out),
        "--record-regex",
        "/imu/adc",
    ]
    run = _run_graph(args, subprocess_env)
    assert run.returncode == 0, run.stderr[-3000:]
    assert _gap_lines(run) == []
    summary = [line for line in run.stdout.splitlines() if "/imu/adc [" in line]
    assert summary and "500 samples, 0 gaps" in summary[-1], run.stdout[-3000:]
    assert "missing head" not in run.stdout


@pytest.mark.slow
def test_documented_imu_graph_ends_without_loss_5_of_5(subprocess_env):
    """The documented command (60 s of data at 100x): 5 of 5 runs end with status 0 and
    no gap warning of the identifier."""
    for k in range(5):
        run = _run_graph(DOCUMENTED, subprocess_env, timeout=300)
        assert run.returncode == 0, f"run {k}: {run.stderr[-3000:]}"
        assert _gap_lines(run) == [], f"run {k}"


#: The device waits for the test's subscription, then for the progress of ``held``.
HELD = (
    "consumers:=held",
    "start_when_matched:=true",
    "min_subscribers:=0",
    "wait_for_subscribers:=adc:1",
)


def test_a_late_recorder_reports_the_missing_head(tmp_path, subprocess_env, graph):
    """The accelerometer publishes its first CONSUMER_CREDIT_FRAMES frames before the
    recorder starts (held there by a consumer of the test that reports no progress until
    the recorder subscribed): the recorder's summary and mcap_info name the missing head of
    exactly those samples, and the recorder exits with its loss status."""
    from std_msgs.msg import UInt64

    from mems_msgs.msg import AdcFrame
    from mems_sim.ros.node_base import CONSUMER_CREDIT_FRAMES
    from mems_sim.ros.qos import FRAME_QOS, PROGRESS_QOS

    _, ex, probe = graph
    ns, frame = "/acc_a", 100
    head = CONSUMER_CREDIT_FRAMES * frame
    progress = probe.create_publisher(UInt64, f"{ns}/held/progress", PROGRESS_QOS)
    got: list = []
    probe.create_subscription(AdcFrame, f"{ns}/adc", got.append, FRAME_QOS)
    params = ("seed:=3", "duration_s:=0.1", "realtime_factor:=0.05", f"frame_size:={frame}")
    device = subprocess.Popen(
        [str(VENV_BIN / "accelerometer_node"), "--ros-args", "-r", f"__ns:={ns}"]
        + [a for p in (*params, *HELD) for a in ("-p", p)],
        env=subprocess_env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    out = tmp_path / "late.mcap"
    recorder = None
    try:
        assert spin_until(ex, lambda: len(got) >= CONSUMER_CREDIT_FRAMES, timeout=60.0)
        recorder = subprocess.Popen(
            [str(VENV_BIN / "mcap_record"), "-o", str(out), "-e", f"{ns}/adc", "--fail-on-loss"],
            env=subprocess_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        joined = spin_until(ex, lambda: probe.count_subscribers(f"{ns}/adc") >= 2, timeout=60.0)
        assert joined, "the recorder never subscribed"
        spin_until(ex, lambda: False, timeout=1.0)
        progress.publish(UInt64(data=100_000))  # the whole duration may go out now
        assert device.wait(timeout=60) == 0, device.stderr.read()[-2000:]
        time.sleep(0.5)
        recorder.send_signal(signal.SIGINT)
        stdout, stderr = recorder.communicate(timeout=30)
    finally:
        for proc in (device, recorder):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert recorder.returncode == 3, stderr[-2000:]
    phrase = f"missing head ({head} samples before the first frame)"
    lost = [line for line in stdout.splitlines() if "lost:" in line]
    assert lost == [f"  lost: {ns}/adc: {phrase}"], stdout
    info = subprocess.run(
        [str(VENV_BIN / "mcap_info"), str(out)], capture_output=True, text=True, timeout=60
    )
    assert phrase in info.stdout, info.stdout
    assert f"lost data: {ns}/adc: {phrase}" in info.stderr, info.stderr

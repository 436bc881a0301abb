"""run_scenario stopped by a signal: SIGINT, SIGTERM and SIGHUP (a closed terminal) all
unwind the graph and finalise the recording (a Summary the mcap library and rosbags read),
and the exit status names the signal (128 + N)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from mcap.reader import make_reader


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_stop_signal_finalises_the_recording(name, tmp_path, subprocess_env):
    out = tmp_path / "stopped.mcap"
    cmd = [sys.executable, "-m", "mems_scenarios.cli", "imu_noise", "--duration", "100000"]
    cmd += ["--out", str(out), "--no-plots", "--no-progress"]
    proc = subprocess.Popen(
        cmd, env=subprocess_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        # the recording has started: chunks written (the graph is running, not starting up)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if out.exists() and out.stat().st_size > 200_000:
                break
            time.sleep(0.1)
        assert proc.poll() is None and out.stat().st_size > 200_000, proc.communicate()[1]
        sig = getattr(signal, name)
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + sig, stderr[-2000:]
    assert f"interrupted by {name}; the MCAP file was finalised" in stderr, stderr[-2000:]
    assert "Traceback" not in stderr, stderr[-2000:]
    with open(out, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    from rosbags.highlevel import AnyReader

    with AnyReader([out]) as reader:
        adc = [c for c in reader.connections if c.topic == "/imu/adc"]
        assert adc and reader.message_count > 0

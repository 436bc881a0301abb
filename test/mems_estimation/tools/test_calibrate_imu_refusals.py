"""``calibrate_imu`` refuses data that do not follow the profile it is given, instead of a
confident wrong calibration (exit 0 with an accelerometer matrix ~0 and a z bias ~g)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent
STATIC_BAG = Path(__file__).resolve().parents[3] / "bags" / "imu.mcap"  # the IMU at rest


def test_static_bag_with_a_multi_position_profile_is_one_line_and_exit_2(tmp_path, subprocess_env):
    out = tmp_path / "cal.yaml"
    cmd = [str(BIN / "calibrate_imu"), str(STATIC_BAG), "--profile", "multi_position"]
    run = subprocess.run(
        cmd + ["--out", str(out)], capture_output=True, text=True, env=subprocess_env
    )
    lines = run.stderr.splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stdout + run.stderr
    assert lines[0].startswith("calibrate_imu: error: the data do not follow the profile:")
    assert "accel mean" in lines[0] and run.stdout == "" and not out.exists()

"""``identify_noise --kalibr`` on a 900 s white-noise recording (no bias instability, no
random walk): Kalibr rejects a noise value <= 0, so the random walks the record cannot see
are written as their upper 95 % bounds (and said so), and ``rostopic`` names the
``sensor_msgs/Imu`` topic Kalibr reads, not the AdcFrame topic that was identified."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys

import yaml

from mems_estimation.tools.identify_noise import main as identify_main

WHITE_ONLY = [
    f"imu.{sensor}_{term}=0"
    for sensor in ("gyro", "accel")
    for term in ("bias_instability", "random_walk")
]


def test_kalibr_file_of_a_white_noise_bag_is_positive_and_names_imu_data(
    tmp_path, subprocess_env, domain_id
):
    bag = tmp_path / "white.mcap"
    cmd = [sys.executable, "-m", "mems_scenarios.cli", "imu_noise", "--duration", "900"]
    cmd += ["--no-plots", "--no-progress", "--out", str(bag), "--domain-id", str(domain_id)]
    cmd += ["--set", "imu.publish_imu=true"] + [a for s in WHITE_ONLY for a in ("--set", s)]
    run = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    kalibr = tmp_path / "imu.yaml"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert identify_main([str(bag), "--kalibr", str(kalibr)]) == 0
    k = yaml.safe_load(kalibr.read_text())
    noise = {key: v for key, v in k.items() if key.endswith(("noise_density", "random_walk"))}
    assert len(noise) == 4 and all(v > 0 for v in noise.values()), k
    assert k["rostopic"] == "/imu/data" and k["update_rate"] == 100.0
    # a random walk of 0 on every axis was replaced by its bound, and the output says so
    assert "upper 95 % bound" in printed.getvalue(), printed.getvalue()

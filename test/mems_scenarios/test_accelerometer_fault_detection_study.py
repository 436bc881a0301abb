"""``python -m mems_scenarios.accelerometer_fault_detection``: a small run prints its
results and writes its figure; bad input is one line and exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

PROG = [sys.executable, "-m", "mems_scenarios.accelerometer_fault_detection"]


def _run(args, env):
    return subprocess.run(
        [*PROG, *args], capture_output=True, text=True, env=env, timeout=300, check=False
    )


def test_small_run_prints_the_results_and_writes_the_figure(tmp_path, subprocess_env):
    r = _run(
        [
            *("--seeds", "5", "--kinds", "bias_step,stuck_at", "--calibration", "table"),
            *("--out", str(tmp_path), "--json"),
        ],
        subprocess_env,
    )
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    b = res["kinds"]["bias_step"]
    assert b["magnitudes"] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert b["probability"][4] >= 0.95 and b["probability"][0] < 0.5
    assert res["kinds"]["stuck_at"]["probability_two_sided"][0] >= 0.95
    png = tmp_path / "accelerometer_fault_detection.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(png) in r.stderr


def test_the_table_names_every_kind_and_the_false_alarms(tmp_path, subprocess_env):
    r = _run(
        ["--seeds", "6", "--kinds", "sign_flip", "--no-plots"],
        subprocess_env,
    )
    assert r.returncode == 0, r.stderr
    assert "sign_flip" in r.stdout and "alarm episodes outside faults" in r.stdout
    assert "monitor calibration: bench" in r.stdout


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--seeds", "x"], "--seeds"),
        (["--devices", "nominal,-3"], "--devices"),
        (["--kinds", "wobble"], "magnitude grid"),
        (["--seeds", "1"], "training seeds"),
        (["--fault-free-samples", "-1"], "--fault-free-samples"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, words, subprocess_env):
    r = _run([*argv, "--no-plots"], subprocess_env)
    assert r.returncode == 2
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and words in err, err

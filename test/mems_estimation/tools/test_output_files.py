"""Outputs of ``identify_noise`` and ``calibrate_imu`` when the write itself fails after the
analysis: the process runs with ``RLIMIT_FSIZE`` (SIGXFSZ ignored, so a write past the limit
fails with EFBIG, as on a full disk; no mount rights needed). One line naming the path,
exit 2, no traceback, and nothing left at the path (no half file).

The up-front checks (a link, an existing file, a missing directory) are in
test/mems_scenarios/test_imu_noise_scenario.py.
"""

from __future__ import annotations

import resource
import signal
import subprocess
import sys
from pathlib import Path

BAG = Path(__file__).resolve().parents[3] / "bags" / "imu.mcap"
BIN = Path(sys.executable).parent


def _small_files(limit_bytes: int):
    """preexec_fn: files of the child end at ``limit_bytes``; a write past it is EFBIG."""

    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return apply


def _run(args, env, limit_bytes: int | None = None) -> subprocess.CompletedProcess:
    """A console script of the venv; with ``limit_bytes``, under that RLIMIT_FSIZE."""
    return subprocess.run(
        [str(BIN / args[0]), *map(str, args[1:])],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        preexec_fn=None if limit_bytes is None else _small_files(limit_bytes),
    )


def test_identify_noise_plot_on_a_full_disk(tmp_path, subprocess_env):
    figure = tmp_path / "allan.png"
    run = _run(["identify_noise", BAG, "--plot", figure], subprocess_env, 4096)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2, run.stderr
    assert lines == [f"identify_noise: error: {figure}: File too large"], run.stderr
    assert sorted(tmp_path.iterdir()) == []  # no half figure, no temporary file


def test_calibrate_imu_out_refused_before_the_calibration(tmp_path, subprocess_env):
    """A link (target untouched, also with --overwrite), an existing file without
    --overwrite, a directory: one line and exit 2 before the bag is read."""
    target = tmp_path / "target.yaml"
    target.write_text("keep me\n")
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    existing = tmp_path / "cal.yaml"
    existing.write_text("old\n")
    for path, extra, needle in (
        (link, [], "is a symbolic link; refusing to write through it"),
        (link, ["--overwrite"], "is a symbolic link; refusing to write through it"),
        (existing, [], "exists (give --overwrite to replace it)"),
        (tmp_path, ["--overwrite"], "is a directory"),
    ):
        args = ["calibrate_imu", "/nonexistent.mcap", "--profile", "six_position", "--out"]
        run = _run([*args, path, *extra], subprocess_env)
        assert run.returncode == 2, run.stderr
        lines = run.stderr.strip().splitlines()
        assert lines == [f"calibrate_imu: error: --out {path}: {needle}"], run.stderr
    assert target.read_text() == "keep me\n" and existing.read_text() == "old\n"

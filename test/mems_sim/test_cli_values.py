"""Command-line values checked at parse time (mems_sim.cli_values): NaN, infinities,
negative times, malformed names and addresses are one line and exit status 2, before any
work starts; a reader that stops early ends a listing quietly."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from mems_sim.cli_values import number

BIN = Path(sys.executable).parent
BAG = Path(__file__).resolve().parents[2] / "bags" / "imu.mcap"


def test_number_ranges():
    parse = number(0.0, 10.0, lo_open=True)
    assert parse("2.5") == 2.5 and parse("10") == 10.0
    for bad in ("nan", "inf", "-inf", "0", "-1", "10.5", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(bad)
    assert number(1, integer=True)("3") == 3
    with pytest.raises(argparse.ArgumentTypeError):
        number(1, integer=True)("2.5")


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["mcap_play", str(BAG), "--start-offset", "nan"], "--start-offset"),
        (["mcap_play", str(BAG), "--start-offset", "-1"], "--start-offset"),
        (["mcap_play", str(BAG), "--duration", "-1"], "--duration"),
        (["mcap_play", str(BAG), "--clock", "nan"], "--clock"),
        (["mcap_play", str(BAG), "--wait-timeout", "nan"], "--wait-timeout"),
        (["mcap_play", str(BAG), "--delay", "1e308"], "--delay"),
        (["mcap_play", str(BAG), "--wait-for-consumer", "not a fqn"], "consumer"),
        (["mcap_record", "-o", "x", "-b", "1", "/t"], "--max-bag-size"),
        (["mcap_record", "-o", "x", "-d", "nan", "/t"], "--max-bag-duration"),
        (["run_campaign", "imu_noise", "--seeds", "1", "--out", "o", "--scheduler", "x"], "x"),
        (
            ["run_campaign", "imu_noise", "--seeds", "1", "--out", "o", "--run-timeout", "nan"],
            "--run-timeout",
        ),
        (
            ["run_campaign", "imu_noise", "--seeds", "1", "--out", "o", "--run-timeout", "-1"],
            "--run-timeout",
        ),
    ],
)
def test_bad_values_are_one_line_and_exit_2(argv, needle, tmp_path, subprocess_env):
    run = subprocess.run(
        [str(BIN / argv[0]), *argv[1:]],
        capture_output=True,
        text=True,
        env=subprocess_env,
        cwd=tmp_path,
        timeout=60,
    )
    assert run.returncode == 2, (run.returncode, run.stderr[-1000:])
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "error" in lines[0], run.stderr[-1000:]
    assert not list(tmp_path.iterdir())  # nothing written


def test_a_listing_read_in_part_ends_quietly(subprocess_env):
    run = subprocess.run(
        f"{BIN / 'run_scenario'} --list | head -1",
        shell=True,
        capture_output=True,
        text=True,
        env=subprocess_env,
        timeout=60,
    )
    assert run.returncode == 0 and len(run.stdout.splitlines()) == 1
    assert "Traceback" not in run.stderr and "BrokenPipe" not in run.stderr, run.stderr

"""Outputs of ``run_scenario``: default outputs under ``runs/`` replaced only after the run
succeeded (:mod:`mems_scenarios.staged_outputs`), and ``--out`` with the files beside it refused
when they are symbolic links or exist without ``--overwrite`` (before the run)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mems_scenarios.cli import main as run_scenario
from mems_scenarios.staged_outputs import INCOMPLETE, StagedOutputs

OLD = b"the previous run's output\n"


def test_staged_outputs_replace_only_on_success(tmp_path):
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "a.mcap").write_bytes(OLD)
    target = tmp_path / "elsewhere.png"
    target.write_bytes(OLD)
    (runs / "a-seed0.png").symlink_to(target)

    failed = StagedOutputs(runs)
    failed.path("a.mcap").write_bytes(b"failed run\n")
    moved = failed.publish(succeeded=False)
    assert moved == {failed.path("a.mcap"): runs / INCOMPLETE / "a.mcap"}
    assert (runs / "a.mcap").read_bytes() == OLD
    assert (runs / INCOMPLETE / "a.mcap").read_bytes() == b"failed run\n"

    ok = StagedOutputs(runs)
    ok.path("a.mcap").write_bytes(b"new\n")
    ok.path("a-seed0.png").write_bytes(b"png\n")
    ok.publish(succeeded=True)
    assert (runs / "a.mcap").read_bytes() == b"new\n"
    # the link itself is replaced, its target never written
    assert not (runs / "a-seed0.png").is_symlink() and target.read_bytes() == OLD
    assert sorted(os.listdir(runs)) == ["a-seed0.png", "a.mcap", INCOMPLETE]

    nothing = StagedOutputs(runs)
    nothing.discard()
    assert sorted(os.listdir(runs)) == ["a-seed0.png", "a.mcap", INCOMPLETE]


def _argv(*extra):
    return ["imu_noise", "--duration", "120", "--seed", "2", "--no-progress", *extra]


def test_failed_run_leaves_previous_runs_output(tmp_path, monkeypatch, capsys, domain_id):
    monkeypatch.chdir(tmp_path)
    # the test's own domain: a leased free one may be another xdist worker's next domain
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id))
    mcap, figure = Path("runs/imu_noise-2.mcap"), Path("runs/imu_noise-seed2-allan.png")
    assert run_scenario(_argv()) == 0
    first = mcap.read_bytes(), figure.read_bytes()
    out = capsys.readouterr().out
    assert f"recorded {mcap}:" in out and f"figure: {figure}" in out, out

    # a run that loses data (fault injection: only 20 truth messages reach the middleware)
    assert run_scenario(_argv("--cut", "/imu/truth:20")) != 0
    captured = capsys.readouterr()
    assert "/imu/truth" in captured.err
    assert (mcap.read_bytes(), figure.read_bytes()) == first
    assert f"outputs are in runs/{INCOMPLETE}/" in captured.out, captured.out
    assert (Path("runs") / INCOMPLETE / mcap.name).stat().st_size > 0

    # a run stopped by bad input before recording: nothing changes, nothing is left
    assert run_scenario(_argv("--set", "imu.frame_size=0")) == 2
    assert (mcap.read_bytes(), figure.read_bytes()) == first
    names = sorted(os.listdir("runs"))
    assert names == sorted([INCOMPLETE, mcap.name, figure.name]), names  # no staging directory left

    # the same command again (a second `make demo`): replaced
    assert run_scenario(_argv("--duration", "60")) == 0
    assert mcap.read_bytes() != first[0] and figure.read_bytes() != first[1]
    assert sorted(os.listdir("runs")) == names


@pytest.mark.parametrize("overwrite", [False, True])
def test_out_and_files_beside_it_refused_before_the_run(tmp_path, capsys, overwrite):
    out = tmp_path / "run.mcap"
    target = tmp_path / "target.png"
    target.write_bytes(OLD)
    beside = tmp_path / "run-seed2-allan.png"  # the figure this run would write
    beside.symlink_to(target)
    other_seed = tmp_path / "run-seed20-allan.png"  # another seed's: not this run's
    other_seed.write_bytes(OLD)
    extra = ["--out", str(out)] + (["--overwrite"] if overwrite else [])
    assert run_scenario(_argv(*extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"run_scenario: error: --out: {beside}: is a symbolic link; refusing to write through it"
    ], err
    assert target.read_bytes() == OLD and not out.exists()

    beside.unlink()
    out.write_bytes(OLD)
    if not overwrite:
        assert run_scenario(_argv(*extra)) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [
            f"run_scenario: error: --out: {out}: exists (give --overwrite to replace it)"
        ], err
        assert out.read_bytes() == OLD


def test_write_launch_refuses_links_and_existing_files(tmp_path, capsys):
    launch = tmp_path / "g.launch.yaml"
    record = tmp_path / "g.run_record.json"
    target = tmp_path / "target.json"
    target.write_bytes(OLD)
    record.symlink_to(target)
    argv = ["imu_noise", "--seed", "1", "--write-launch", str(launch)]
    assert run_scenario(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"run_scenario: error: --write-launch: {record}: is a symbolic link; refusing to "
        "write through it"
    ], err
    assert target.read_bytes() == OLD and not launch.exists()
    record.unlink()
    assert run_scenario(argv) == 0
    assert "imu_node" in launch.read_text() and record.stat().st_size > 0
    assert run_scenario(argv) == 2 and "--overwrite" in capsys.readouterr().err
    assert run_scenario(argv + ["--overwrite"]) == 0


def test_printed_paths_name_the_final_place():
    """The paths a scenario returns (a Path, a text listing paths, a tuple of them) are
    printed where the outputs end up, not in the staging directory."""
    from mems_scenarios.cli import _relocated

    staging, dest = Path("runs/.partial-x"), Path("runs")
    assert _relocated(staging / "a.mcap", staging, dest) == Path("runs/a.mcap")
    text = f"{staging}/a-seed1-period.png, {staging}/a-seed1-peak_to_peak.png"
    assert (
        _relocated(text, staging, dest) == "runs/a-seed1-period.png, runs/a-seed1-peak_to_peak.png"
    )
    assert _relocated((staging / "b.png",), staging, dest / "incomplete") == (
        Path("runs/incomplete/b.png"),
    )
    assert _relocated(None, staging, dest) is None

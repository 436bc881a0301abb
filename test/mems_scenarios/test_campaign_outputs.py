"""run_campaign's directory: symbolic links refused before any run, the report written
whole through :func:`~mems_sim.bag.output_paths.write_output` (never through a link)."""

from __future__ import annotations

import os

from mems_scenarios.campaign import RunResult, RunSpec, main, write_report

PRECIOUS = "precious, must survive\n"


def test_links_in_the_campaign_directory_refused_up_front(tmp_path, capsys):
    target = tmp_path / "target.txt"
    target.write_text(PRECIOUS)
    real = tmp_path / "real"
    real.mkdir()
    linked_dir = tmp_path / "linked"
    linked_dir.symlink_to(real)
    camp = tmp_path / "camp"
    camp.mkdir()
    (camp / "report.txt").symlink_to(target)
    (tmp_path / "pages").mkdir()
    (tmp_path / "pages" / "report-1.png").symlink_to(target)
    for out, bad in (
        (linked_dir, linked_dir),
        (camp, camp / "report.txt"),
        (tmp_path / "pages", tmp_path / "pages" / "report-1.png"),
    ):
        assert main(["imu_noise", "--seeds", "1", "--workers", "0", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [
            f"run_campaign: error: --out: {bad}: is a symbolic link; refusing to write through it"
        ], err
    assert target.read_text() == PRECIOUS and os.listdir(real) == []
    assert sorted(os.listdir(camp)) == ["report.txt"]  # nothing written, nothing run


def test_report_replaced_whole(tmp_path):
    figs = [{"name": "a", "value": 0.5, "unit": "m", "target": "<= 1", "pass": True}]
    results = [RunResult(RunSpec("imu_noise", s), "ok", 0, "", 1.0, figs) for s in (1, 2)]
    (tmp_path / "report.txt").write_text("old\n")
    table, rep, pages = write_report(tmp_path, results)
    assert rep["runs"] == 2 and "old" not in (tmp_path / "report.txt").read_text()
    assert [p.name for p in pages] == ["report-1.png"]
    names = sorted(os.listdir(tmp_path))
    assert names == ["report-1.png", "report.json", "report.txt", "results.parquet"], names

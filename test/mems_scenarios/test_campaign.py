"""run_campaign: planning, storage, report (ROS-free), and campaigns of real runs.

The quick tier runs one small campaign of ``imu_noise`` on a local Dask cluster of two
workers with one failing run injected (an out-of-range parameter on one grid point); the
slow tier checks the resume after a SIGKILL of the driver and that a cluster of separate
processes talking TCP (``--scheduler``), a local cluster and a serial run give the same
table row for row.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mems_scenarios.campaign import (
    CampaignError,
    RunResult,
    RunSpec,
    bootstrap_ci,
    load_results,
    main,
    parameter_points,
    parse_ints,
    report,
    save_result,
    write_table,
)

BIN = Path(sys.executable).parent
#: columns that differ between equal campaigns (time taken)
WALL = ["wall_s"]


def _result(seed: int, value: float) -> RunResult:
    figs = [
        {"name": "a", "value": value, "unit": "m", "target": "<= 1", "pass": value <= 1},
        {"name": "b", "value": None, "unit": "-", "target": None, "pass": None},
    ]
    return RunResult(RunSpec("imu_noise", seed), "ok", 0, "", 1.0, figs)


def test_plan_parsing_and_points():
    assert parse_ints("1-3,7", "--seeds") == [1, 2, 3, 7]
    for bad in ("3-1", "a", "-1", ""):
        with pytest.raises(CampaignError, match="--seeds"):
            parse_ints(bad, "--seeds")
    pts = parameter_points(["imu.a=1,2"], ["imu.b=0:1"], 3, draw_seed=5)
    assert len(pts) == 6 and pts == parameter_points(["imu.a=1,2"], ["imu.b=0:1"], 3, 5)
    assert all(0 <= float(p[1].split("=")[1]) <= 1 for p in pts)
    with pytest.raises(CampaignError, match="--draw"):
        parameter_points([], ["imu.b=1:0"], 1, 0)
    ids = {RunSpec("x", s, d, t).run_id for s in range(3) for d in (None, 1) for t in (None, 25.0)}
    assert len(ids) == 12  # unique, and stable (derived from the spec only)
    assert RunSpec("x", 1, sets=("a.b=1",)).run_id == RunSpec("x", 1, sets=("a.b=1",)).run_id
    assert RunSpec("x", 1, sets=("a.b=1",)).run_id != RunSpec("x", 1, sets=("a.b=2",)).run_id


def test_report_statistics_and_table(tmp_path):
    rng = np.random.default_rng(1)
    values = rng.normal(0.8, 0.3, 40)
    results = [_result(i, float(v)) for i, v in enumerate(values)]
    results.append(RunResult(RunSpec("imu_noise", 99), "failed", 2, "bad parameter", 0.5, []))
    rep = report(results)
    assert rep["runs"] == 41 and rep["failed"] == 1 and rep["failures"][0]["error"]
    a = next(f for f in rep["figures"] if f["name"] == "a")
    assert a["mean"] == pytest.approx(values.mean()) and a["median"] == pytest.approx(
        np.median(values)
    )
    assert a["mean_ci_low"] < values.mean() < a["mean_ci_high"]
    assert a["pass_rate"] == pytest.approx(np.mean(values <= 1))
    b = next(f for f in rep["figures"] if f["name"] == "b")
    assert b["non_finite"] == 40 and "mean" not in b
    lo, hi = bootstrap_ci(values)
    half = 1.96 * values.std(ddof=1) / np.sqrt(values.size)
    assert hi - lo == pytest.approx(2 * half, rel=0.2)  # the normal-theory width
    path = write_table(tmp_path, results)
    df = pd.read_parquet(path)
    assert len(df) == 40 * 2 + 1
    failed = df[df.status == "failed"]
    assert len(failed) == 1 and failed.error.iloc[0] == "bad parameter"
    assert failed.name.isna().all()


def test_results_survive_a_round_trip(tmp_path):
    r = _result(3, 0.5)
    save_result(tmp_path, r)
    assert load_results(tmp_path, [r.spec]) == {r.spec.run_id: r}
    (tmp_path / "runs" / f"{r.spec.run_id}.json").write_text("{truncated")
    assert load_results(tmp_path, [r.spec]) == {}  # unreadable: run again


def test_bad_input_one_line(capsys, tmp_path):
    for argv, what in (
        (["nope", "--seeds", "1", "--out", str(tmp_path)], "unknown scenario"),
        (["imu_noise", "--seeds", "x", "--out", str(tmp_path)], "--seeds"),
        (["imu_noise", "--seeds", "1", "--workers", "-1", "--out", str(tmp_path)], "--workers"),
        (["imu_noise", "--seeds", "1", "--set", "nodot=1", "--out", str(tmp_path)], "--set"),
        # sizes checked before anything is built (this took 2.45 GB in 40 s)
        (["imu_noise", "--seeds", "0-30000000", "--out", str(tmp_path)], "at most 100000"),
        (
            ["imu_noise", "--seeds", "0-999", "--device-seeds", "0-999", "--out", str(tmp_path)],
            "the plan",
        ),
        (
            [
                "imu_noise",
                "--seeds",
                "1",
                "--grid",
                "a.b=" + ",".join(["1"] * 400),
                "--grid",
                "a.c=" + ",".join(["1"] * 400),
                "--out",
                str(tmp_path),
            ],
            "--grid",
        ),
    ):
        t0 = time.monotonic()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert what in err and len(err.splitlines()) == 1, err
        assert time.monotonic() - t0 < 5


def _campaign(args: list[str], env: dict, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / "run_campaign"), *args, "--no-progress"],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        check=False,
    )


def _table(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "results.parquet").drop(columns=WALL)


SMALL = ["imu_noise", "--duration", "300"]
#: the quick tier's run: just above the identifier's 60 s minimum
QUICK = ["imu_noise", "--duration", "70"]


def test_small_campaign_with_a_failed_run(tmp_path, subprocess_env):
    """One seed x two grid points on two local workers; one grid point is out of range:
    its run is in the table with its error, counted in the report, exit 1."""
    out = tmp_path / "c"
    run = _campaign(
        QUICK
        + ["--seeds", "1", "--grid", "imu.gyro_noise_density=1.01437e-3,-1", "--workers", "2"]
        + ["--out", str(out), "--json"],
        subprocess_env,
    )
    assert run.returncode == 1, run.stderr
    rep = json.loads(run.stdout)
    assert rep["runs"] == 2 and rep["ok"] == 1 and rep["failed"] == 1, rep
    assert all("gyro_noise_density" in f["error"] for f in rep["failures"]), rep["failures"]
    df = _table(out)
    ok = df[df.status == "ok"]
    assert set(ok.seed) == {1} and ok.name.notna().all() and ok["value"].notna().any()
    assert (df.status == "failed").sum() == 1
    assert {p.name for p in out.glob("report*")} >= {"report.txt", "report.json", "report-1.png"}


@pytest.mark.slow
def test_resume_after_sigkill_redoes_no_finished_run(tmp_path, subprocess_env):
    args = SMALL + ["--seeds", "1-4", "--workers", "1"]
    ref = tmp_path / "ref"
    assert _campaign(args + ["--out", str(ref)], subprocess_env).returncode == 0
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [str(BIN / "run_campaign"), *args, "--out", str(out), "--no-progress"],
        env=subprocess_env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    runs = out / "runs"
    deadline = time.monotonic() + 200
    while time.monotonic() < deadline and len(list(runs.glob("*.json"))) < 2:
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = {p.name: p.stat().st_mtime_ns for p in runs.glob("*.json")}
    assert 2 <= len(finished) < 4, finished
    time.sleep(5)  # orphaned workers, if any, finish what they ran
    finished = {p.name: p.stat().st_mtime_ns for p in runs.glob("*.json")}
    again = _campaign(args + ["--out", str(out)], subprocess_env)
    assert again.returncode == 0, again.stderr
    for name, mtime in finished.items():  # not redone
        assert (runs / name).stat().st_mtime_ns == mtime, name
    pd.testing.assert_frame_equal(_table(out), _table(ref))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_scheduler_over_tcp_equals_local_and_serial(tmp_path, subprocess_env):
    """A scheduler and two workers as separate processes talking TCP, as on separate
    hosts (bound to 127.0.0.1 here), run the campaign; the table equals a local cluster's
    and a serial run's, row for row."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [
        subprocess.Popen(
            [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port)]
            + ["--no-dashboard"],
            env=subprocess_env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        time.sleep(2)
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [str(BIN / "dask"), "worker", address, "--nworkers", "1", "--nthreads", "1"]
                    + ["--host", "127.0.0.1", "--no-dashboard"],
                    env=subprocess_env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        args = SMALL + ["--seeds", "1-4"]
        tables = {}
        for label, how in (
            ("tcp", ["--scheduler", address]),
            ("local", ["--workers", "2"]),
            ("serial", ["--workers", "0"]),
        ):
            out = tmp_path / label
            run = _campaign(args + how + ["--out", str(out)], subprocess_env)
            assert run.returncode == 0, (label, run.stderr)
            tables[label] = _table(out)
        pd.testing.assert_frame_equal(tables["tcp"], tables["serial"])
        pd.testing.assert_frame_equal(tables["local"], tables["serial"])
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()


def test_local_cluster_listens_on_loopback_only():
    """--workers N: Dask's scheduler and worker HTTP servers (which it starts whatever the
    dashboard setting) are bound to 127.0.0.1 and serve no route; nothing listens beyond."""
    import urllib.error
    import urllib.request
    from types import SimpleNamespace

    from proc_sockets import inet_sockets, is_loopback

    from mems_scenarios.campaign import _client

    before = set(inet_sockets(os.getpid()))
    client, cluster = _client(SimpleNamespace(scheduler=None, workers=2))
    try:
        assert client.submit(int, "41").result() == 41
        new = set(inet_sockets(os.getpid())) - before
        assert len(new) >= 3, new  # the scheduler's server and one per worker
        assert all(is_loopback(address) for _, address in new), new
        port = cluster.scheduler.http_server.port
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/json/identity.json", timeout=5)
        assert refused.value.code == 404
    finally:
        client.close()
        cluster.close()

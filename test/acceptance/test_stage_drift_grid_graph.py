"""Acceptance (slow tier): the drift grid of the gyro_calibration scenario's drifting
micro-stage through the node graph, recorded and evaluated with the campaign machinery
(Chen 2018 ch. 3, Table 3.6 form).

One ``run_campaign gyro_calibration --seeds 2-6`` over the 8 corners of the drift grid
(resonance-frequency tempco -30 / -100 ppm/K x actuator-gain tempco +0.05 / +0.3 %/K x
damping ratio 0.9 / 1.1 x 0.005, ``--grid stage.freq_tempco_per_k=...`` etc.): each run is
one ``run_scenario ... --json`` process whose stage overrides reach the drifting device's
three stage nodes, its identification and its context rows alike (the drift-free stage
keeps its own). Per corner, from ``results.parquet``: the scale-factor error [ppm] of
row 1 (sensor parameters of 22.9 C only) and row 2 (D_n, eta re-identified at 35.7 C with
the LDV-like reference), RMS over the two temperatures and the 5 seeds,
RMS = sqrt(mean over seeds and T of ppm^2); the criterion applies to row 2: <= 600 ppm at
every corner (goal <= 100 ppm, reported), with the in-situ EKF's omega RMSE <= 0.114 rad/s
and |alpha - 1| <= 8e-4 in every run of row 2. Row 1 cannot meet it (a drift of D_n is not
observable from the channels without a reference). The ROS-free version of the same grid
is the companion acceptance test on the cores.

``MEMS_DRIFT_GRID_DIR``: keep the campaign there (a second run with it set only
re-evaluates: the campaign redoes only runs without a result file)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import print_drift_rows

from mems_estimation.identification.stage_gyro_calibration import DRIFT_GRID

SEEDS = "2-6"
TARGET_PPM = 600.0
GOAL_PPM = 100.0
#: the nominal damping ratio the grid's ratios multiply
ZETA = 0.005
#: ``--grid`` node parameter of each axis of the drift grid (fn tempco, b_c tempco, zeta)
AXES = ("stage.freq_tempco_per_k", "stage.b_c_tempco_per_k", "stage.damping_ratio")


def grid_arguments() -> list[str]:
    """``--grid`` arguments of the drift grid (the corners of ``DRIFT_GRID``)."""
    fc = sorted({c[0] for c in DRIFT_GRID}, reverse=True)
    bc = sorted({c[1] for c in DRIFT_GRID})
    z = sorted({c[2] for c in DRIFT_GRID})
    values = (fc, bc, [ZETA * r for r in z])
    out = []
    for axis, vals in zip(AXES, values):
        out += ["--grid", f"{axis}=" + ",".join(f"{v:g}" for v in vals)]
    return out


def corner_of(sets: str) -> tuple[float, float, float]:
    """(fn tempco [1/K], b_c tempco [1/K], damping ratio / 0.005) of a run's ``--set`` text."""
    values = dict(s.split("=", 1) for s in sets.split())
    fc, bc, zeta = (float(values[a]) for a in AXES)
    return fc, bc, round(zeta / ZETA, 6)


def corner_table(results: Path) -> list[dict]:
    """Per corner from ``results.parquet``: RMS over T1/T2 and seeds of each row [ppm], the
    per-run row-2 RMS values, the worst omega RMSE [rad/s] and |alpha - 1| of row 2, the
    runs and failed runs."""
    import pandas as pd

    df = pd.read_parquet(results)
    out = []
    for sets, g in df.groupby("sets", sort=False):
        ok = g[g["status"] == "ok"]
        runs = g["run_id"].nunique()

        def values(name):
            return ok.loc[ok["name"] == name, "value"].to_numpy(float)

        r2 = values("drifting.scale_factor_error_rms")
        r1 = values("drifting.scale_factor_error_rms.ref_t1_only")
        rmse = np.concatenate(
            [values(f"drifting.{k}.omega_rmse") for k in ("stage_t1", "stage_t2.ref_t2")]
        )
        alpha = np.concatenate(
            [values(f"drifting.{k}.alpha") for k in ("stage_t1", "stage_t2.ref_t2")]
        )
        out.append(
            {
                "corner": corner_of(sets),
                "runs": runs,
                "ok": ok["run_id"].nunique(),
                # each run's figure is the RMS over T1/T2: the mean of squares over runs
                "rms_ref_t1": math.sqrt(np.mean(r1**2)) if r1.size else math.nan,
                "rms_ref_t2": math.sqrt(np.mean(r2**2)) if r2.size else math.nan,
                "ppm_ref_t2": r2.tolist(),
                "max_rmse": float(rmse.max()) if rmse.size else math.nan,
                "max_dalpha": float(np.abs(alpha - 1).max()) if alpha.size else math.nan,
            }
        )
    return out


def test_grid_arguments_cover_the_corners():
    args = grid_arguments()
    assert args[1::2] == [
        "stage.freq_tempco_per_k=-3e-05,-0.0001",
        "stage.b_c_tempco_per_k=0.0005,0.003",
        "stage.damping_ratio=0.0045,0.0055",
    ]
    sets = "stage.freq_tempco_per_k=-0.0001 stage.b_c_tempco_per_k=0.003 stage.damping_ratio=0.0045"
    assert corner_of(sets) == (-100e-6, 3e-3, 0.9) and corner_of(sets) in DRIFT_GRID


@pytest.mark.slow
def test_drift_grid_every_corner_through_graph(tmp_path):
    out = Path(os.environ.get("MEMS_DRIFT_GRID_DIR") or tmp_path / "drift_grid")
    cmd = [sys.executable, "-m", "mems_scenarios.campaign", "gyro_calibration"]
    cmd += ["--seeds", SEEDS, *grid_arguments(), "--workers", "2", "--out", str(out)]
    wall = time.monotonic()
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=3 * 3600)
    wall = time.monotonic() - wall
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    rows = corner_table(out / "results.parquet")
    assert sorted(r["corner"] for r in rows) == sorted(DRIFT_GRID)
    print(f"\ncampaign: {sum(r['runs'] for r in rows)} graph runs in {wall:.0f} s wall")
    print_drift_rows(rows)
    worst = max(r["rms_ref_t2"] for r in rows)
    goal = sum(r["rms_ref_t2"] <= GOAL_PPM for r in rows)
    print(
        f"worst corner, row 2: {worst:.0f} ppm (target <= {TARGET_PPM:g}); "
        f"goal <= {GOAL_PPM:g} ppm met at {goal} of {len(rows)} corners"
    )
    for r in rows:
        assert r["ok"] == r["runs"] == 5, r["corner"]
        assert r["rms_ref_t2"] <= TARGET_PPM, r["corner"]
        assert r["max_rmse"] <= 0.114 and r["max_dalpha"] <= 8e-4, r["corner"]

"""Acceptance (``make acceptance``): gyro scale-factor error of the in-situ calibration on the
drifting micro-stage at every corner of the drift grid (Chen 2018 ch. 3, Table 3.6 form):
resonance-frequency tempco -30 / -100 ppm/K x actuator-gain tempco +0.05 / +0.3 %/K x
damping ratio 0.9 / 1.1 x 0.005, on the ROS-free cores of scenario ``gyro_calibration``
(:func:`mems_estimation.identification.stage_gyro_calibration.drift_corner`, the same seeds
as its drifting rows).

Evaluation seeds 2-6 (the design was tuned on seed 1 at the default corner; the grid was
never used for tuning). Both rows are reported per corner: "ref. at 22.9 C only" (sensor
parameters of the training temperature) and "D_n, eta re-identified at 35.7 C" with the
LDV-like reference. The first cannot meet the target (a drift of D_n is not observable
from the channels without a reference: (theta, D_n, eta) -> s (theta, D_n, eta) leaves every
channel unchanged), so the criterion applies to the second: RMS over the two
temperatures and the 5 seeds <= 600 ppm at every corner (goal <= 100 ppm, reported)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from campaign_helpers import print_drift_rows

from mems_estimation.identification.stage_gyro_calibration import DRIFT_GRID, Plan, drift_corner

SEEDS = (2, 3, 4, 5, 6)
TARGET_PPM = 600.0
GOAL_PPM = 100.0


def grid_table(seeds=SEEDS, plan: Plan | None = None) -> list[dict]:
    """Per corner: RMS over T1/T2 and seeds of each row [ppm], the per-seed values, and the
    worst omega RMSE / |alpha - 1| of the re-identified row."""
    plan = plan or Plan()
    models: dict = {}
    out = []
    for fc, bc, z in DRIFT_GRID:
        r1, r2, rmse, dalpha = [], [], [], []
        for seed in seeds:
            r = drift_corner(seed, plan, fc, bc, z, model=models.get((seed, z)))
            models[(seed, z)] = r["model"]
            r1 += [r["ppm_t1"], r["ppm_t2_ref_t1"]]
            r2 += [r["ppm_t1"], r["ppm_t2_ref_t2"]]
            for k in ("t1", "t2_ref_t2"):
                rmse.append(r["eval"][k]["rmse"])
                dalpha.append(abs(r["eval"][k]["alpha"] - 1))
        out.append(
            {
                "corner": (fc, bc, z),
                "rms_ref_t1": math.sqrt(np.mean(np.square(r1))),
                "rms_ref_t2": math.sqrt(np.mean(np.square(r2))),
                "ppm_ref_t2": r2,
                "max_rmse": max(rmse),
                "max_dalpha": max(dalpha),
            }
        )
    return out


@pytest.mark.slow
def test_drift_grid_every_corner():
    rows = grid_table()
    print()
    print_drift_rows(rows)
    worst = max(r["rms_ref_t2"] for r in rows)
    print(f"worst corner, row 2: {worst:.0f} ppm (target <= {TARGET_PPM:g}, goal <= {GOAL_PPM:g})")
    for r in rows:
        assert r["rms_ref_t2"] <= TARGET_PPM, r["corner"]
        assert r["max_rmse"] <= 0.114 and r["max_dalpha"] <= 8e-4, r["corner"]

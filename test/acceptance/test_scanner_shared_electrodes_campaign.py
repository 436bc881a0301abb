"""Acceptance (``make acceptance``): the shared-electrode micro-scanner's EKF and UKF over noise
seeds (Chen 2018 ch. 5, restated criteria): on every seed of a 10-seed campaign of
``scanner_shared_electrodes`` both filters reach phase RMSE <= 0.18 deg (eq. (79)) and
amplitude RMSE <= 0.63 deg, their NEES of theta is within 0.5-2 (Bar-Shalom, Li &
Kirubarajan 2001, Sec. 5.4), the UKF/EKF RMSE ratio is within +-1 % (Julier & Uhlmann 2004:
at this noise level the unscented transform and the linearisation agree), and both acquire
from 0.25 theta_0 and 0.1 rad initial errors.  Prints each item's distribution (median,
5-95 %, pass rate), as the scanner documentation gives them.  Reproduce:
``run_campaign scanner_shared_electrodes --seeds 1-10 --workers 2 --out DIR``.
The seeds are not the tuning seeds of the filters' chain curve and inflation (1001-1005)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

SEEDS = "1-10"
#: figure -> (lower, upper) bound every run must meet (None: reported only)
ITEMS = {
    "ekf.phase_rmse": (None, 0.18),
    "ukf.phase_rmse": (None, 0.18),
    "ekf.amplitude_rmse": (None, 0.63),
    "ukf.amplitude_rmse": (None, 0.63),
    "ekf.nees": (0.5, 2.0),
    "ukf.nees": (0.5, 2.0),
    "ukf_ekf.amplitude_rmse_ratio": (0.99, 1.01),
    "ukf_ekf.phase_rmse_ratio": (0.99, 1.01),
    "ekf.phase_bias": None,
    "ukf.phase_bias": None,
    "stress.ekf.acquired": (1.0, 1.0),
    "stress.ukf.acquired": (1.0, 1.0),
    "acquire_0p1rad.ekf.acquired": (1.0, 1.0),
    "acquire_0p1rad.ukf.acquired": (1.0, 1.0),
    "stress.ekf.acquire_time_median": None,
    "stress.ukf.acquire_time_median": None,
    "stress.ekf.acquire_time_max": None,
    "stress.ukf.acquire_time_max": None,
    "stress.ukf_ekf.theta_rmse_ratio": None,
    "acquire_0p1rad.ekf.acquire_time_median": None,
    "acquire_0p1rad.ukf.acquire_time_median": None,
    "acquire_0p1rad.ekf.acquire_time_max": None,
    "acquire_0p1rad.ukf.acquire_time_max": None,
    "acquire_0p1rad.ukf_ekf.theta_rmse_ratio": None,
    "off.final_theta_true": (None, 1e-3),
}


def campaign(out: Path, env) -> pd.DataFrame:
    """run_campaign scanner_shared_electrodes: one row per seed, one column per figure."""
    cmd = [str(Path(sys.executable).parent / "run_campaign"), "scanner_shared_electrodes"]
    cmd += ["--seeds", SEEDS, "--workers", "2", "--out", str(out), "--no-progress"]
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
    assert run.returncode == 0, run.stderr[-3000:]
    df = pd.read_parquet(out / "results.parquet")
    assert (df.status == "ok").all()
    return df.pivot(index="seed", columns="name", values="value")


@pytest.mark.slow
def test_restated_criteria_on_every_seed(tmp_path, subprocess_env):
    wide = campaign(tmp_path / "c", subprocess_env)
    assert len(wide) >= 5
    lines, missed = [], []
    for name, bounds in ITEMS.items():
        v = wide[name].astype(float).to_numpy()
        lo, med, hi = np.percentile(v, [5, 50, 95])
        if bounds is None:
            lines.append(f"{name}: median {med:.4g}, 5-95 % {lo:.4g}..{hi:.4g}")
            continue
        ok = np.isfinite(v)
        if bounds[0] is not None:
            ok &= v >= bounds[0]
        if bounds[1] is not None:
            ok &= v <= bounds[1]
        lines.append(
            f"{name}: median {med:.4g}, 5-95 % {lo:.4g}..{hi:.4g}, pass {ok.mean():.0%} of {v.size}"
        )
        if not ok.all():
            missed.append((name, v[~ok].tolist()))
    print("\n" + "\n".join(lines))
    assert not missed, missed


#: Device draws and noise seeds of the identified-vs-oracle campaign (the filters'
#: inflation was chosen on draws 5, 12 and 101, seed 1).
DRAWS, DRAW_SEEDS = "1-10", "1-2"


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> pd.DataFrame:
    """run_campaign over 10 drawn devices x 2 noise seeds: one row per run (every run's
    status kept: a device whose resonance search finds no onset fails its run)."""
    import os

    from conftest import next_domain_id

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env["ROS_DOMAIN_ID"] = str(next_domain_id())
    out = tmp_path_factory.mktemp("drawn")
    cmd = [str(Path(sys.executable).parent / "run_campaign"), "scanner_shared_electrodes"]
    cmd += ["--seeds", DRAW_SEEDS, "--device-seeds", DRAWS, "--workers", "2"]
    cmd += ["--out", str(out), "--no-progress"]
    subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    df = pd.read_parquet(out / "results.parquet")
    return df


def _wide(df: pd.DataFrame) -> pd.DataFrame:
    ok = df[df.status == "ok"]
    return ok.pivot(index=["device_seed", "seed"], columns="name", values="value")


def _spread(v: np.ndarray) -> str:
    lo, med, hi = np.nanpercentile(v, [5, 50, 95])
    return f"median {med:.4g}, 5-95 % {lo:.4g}..{hi:.4g}"


@pytest.mark.slow
def test_drawn_devices_identified_on_the_bench(drawn):
    """The resonance search acquires motion on >= 19 of the 20 runs (a run whose bench finds
    no onset fails); the identified and the oracle filters' distributions, the pass counts
    of Table 5.3's accuracy and of the NEES, and the bench's errors are printed side by
    side."""
    runs = drawn.groupby(["device_seed", "seed"]).status.first()
    wide = _wide(drawn)
    lines = [f"runs ok: {int((runs == 'ok').sum())} of {runs.size}"]
    for k in ("ekf", "ukf"):
        for q in ("amplitude", "phase"):
            ident = wide[f"{k}.{q}_rmse"].to_numpy(float)
            orc = wide[f"oracle.{k}.{q}_rmse"].to_numpy(float)
            lines.append(f"{k}.{q}_rmse identified: {_spread(ident)} deg")
            lines.append(f"{k}.{q}_rmse oracle:     {_spread(orc)} deg")
        nees = wide[f"{k}.nees"]
        lines.append(
            f"{k}.nees identified: {_spread(nees.to_numpy(float))}, within 0.5-2 on "
            f"{int(nees.between(0.5, 2.0).sum())}; phase <= 0.18 deg on "
            f"{int((wide[f'{k}.phase_rmse'] <= 0.18).sum())}, amplitude <= 0.63 deg on "
            f"{int((wide[f'{k}.amplitude_rmse'] <= 0.63).sum())}"
        )
    for name in ("omega_n", "zeta", "cap_c0", "cap_theta0"):
        e = np.abs(wide[f"device.identified_{name}_error"].to_numpy(float))
        lines.append(f"|identification error| {name}: {_spread(e)}")
    print("\n" + "\n".join(lines))
    assert (runs == "ok").sum() >= 19


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="NEES of the bench-model filters within 0.5-2 on 15 of 20 runs (inflation 20, "
    "chosen on draws 5, 12, 101): draw 2's inertia is 1.8 % off the design value the bench "
    "keeps (NEES 5.2-5.6), draw 7 is driven 20 % harder near its threshold, draw 6 seed 1 "
    "is hard for the oracle too. strict: a pass would flag a change to revisit",
)
def test_bench_model_nees_on_18_of_20_runs(drawn):
    wide = _wide(drawn)
    for k in ("ekf", "ukf"):
        assert wide[f"{k}.nees"].between(0.5, 2.0).sum() >= 18


@pytest.mark.slow
def test_identified_within_the_oracle_spread(drawn):
    """Per headline figure, the identified filters' RMSE within max(10 %, the oracle's 5-95 %
    spread over the campaign) of the oracle's of the same run, on >= 18 of the 20 runs (a
    failed run counts as a miss). Per run the ratio is context: within 10 % needs the
    inertia to 0.1 % and w_n to 5 ppm (docs/scanner.md)."""
    wide = _wide(drawn)
    for k in ("ekf", "ukf"):
        for q in ("amplitude", "phase"):
            ident = wide[f"{k}.{q}_rmse"].to_numpy(float)
            orc = wide[f"oracle.{k}.{q}_rmse"].to_numpy(float)
            lo, hi = np.percentile(orc, [5, 95])
            tol = np.maximum(0.10 * orc, hi - lo)
            within = np.abs(ident - orc) <= tol
            print(f"{k}.{q}: identified within max(10 %, spread) of oracle: {within.sum()}")
            assert within.sum() >= 18

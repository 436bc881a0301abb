"""Helpers shared by the campaign tests (test/mems_scenarios, test/acceptance): running
``run_campaign`` and printing the drifting stage's per-corner table."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def spread_campaign(out: Path, seeds: str, device_seeds: str, env, workers: str = "0"):
    """run_campaign accelerometer_spread over noise seeds x device seeds: the per-run rows
    (gain at 0.1 g and 1 g, the device's mismatch against the filter's nominal model), one
    column per figure (a pandas DataFrame indexed by seed and device_seed)."""
    import pandas as pd

    cmd = [str(Path(sys.executable).parent / "run_campaign"), "accelerometer_spread"]
    cmd += ["--seeds", seeds, "--device-seeds", device_seeds, "--workers", workers]
    cmd += ["--out", str(out), "--no-progress"]
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    assert run.returncode == 0, run.stderr[-3000:]
    df = pd.read_parquet(out / "results.parquet")
    assert (df.status == "ok").all()
    return df.pivot(index=["seed", "device_seed"], columns="name", values="value")


def print_drift_rows(rows: list[dict]) -> None:
    """One line per drift corner: the tempcos and damping factor, the row-1 and row-2 scale
    factor RMS [ppm], the worst EKF RMSE and |alpha - 1| (Chen 2018 eq. (27) rows)."""
    print(
        "fn tempco | gain tempco | zeta | row 1 ref. 22.9 C only | row 2 D_n/eta re-id. "
        "| max RMSE | max |alpha-1|"
    )
    for r in rows:
        fc, bc, z = r["corner"]
        print(
            f"{1e6 * fc:+.0f} ppm/K | {100 * bc:+.2f} %/K | {z:.1f} x | {r['rms_ref_t1']:.0f} ppm "
            f"| {r['rms_ref_t2']:.0f} ppm | {r['max_rmse']:.4f} | {r['max_dalpha']:.1e}"
        )

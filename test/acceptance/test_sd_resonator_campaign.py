"""Acceptance (``make acceptance``): the sigma-delta resonator over drawn devices, every
observer's model identified on the bench (Colinet et al., Sec. 6): 10 device draws (f0
+-2 %, Q +-20 %) x 2 noise seeds of ``sd_resonator``. The identified-model observer's
error std within 10 % of the oracle observer's on the same stream (the device's own table)
in >= 18 of 20 runs; its measured / predicted error variance within 0.5-2 in >= 18 of 20;
the bench's f0 within 150 ppm and Q within 3 % of the device's in every run. Prints the
distributions side by side."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


@pytest.mark.slow
def test_identified_observer_against_the_oracle_over_drawn_devices(tmp_path, subprocess_env):
    import pandas as pd

    out = tmp_path / "c"
    cmd = [str(Path(sys.executable).parent / "run_campaign"), "sd_resonator"]
    cmd += ["--seeds", "1-2", "--device-seeds", "1-10", "--workers", "2"]
    cmd += ["--out", str(out), "--no-progress"]
    run = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env, timeout=3600)
    assert run.returncode == 0, run.stderr[-3000:]
    df = pd.read_parquet(out / "results.parquet")
    assert (df.status == "ok").all()
    wide = df.pivot(index=["seed", "device_seed"], columns="name", values="value")
    assert len(wide) == 20

    def col(name):
        return wide[name].astype(float)

    ratio = col("identified_vs_oracle.error_ratio")
    ident, exact = (
        col("identified_noisy.error_variance_ratio"),
        col("exact_noisy.error_variance_ratio"),
    )
    f0, q = col("device.identified_f0_error"), col("device.identified_q_error")
    for label, v in (
        ("identified / oracle error std", ratio),
        ("identified model: measured / predicted variance", ident),
        ("oracle model: measured / predicted variance", exact),
        ("identified f0 error [ppm]", f0 * 1e6),
        ("identified Q error [%]", q * 100),
    ):
        lo, med, hi = np.percentile(v, [5, 50, 95])
        print(
            f"\n{label}: median {med:.3f}, 5-95 % {lo:.3f}..{hi:.3f}, min {v.min():.3f}, max {v.max():.3f}"
        )
    assert int((ratio <= 1.1).sum()) >= 18, ratio
    assert int(((ident >= 0.5) & (ident <= 2.0)).sum()) >= 18, ident
    assert (f0.abs() <= 150e-6).all() and (q.abs() <= 0.03).all()

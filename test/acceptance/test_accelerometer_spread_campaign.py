"""Acceptance (``make acceptance``): the force-rebalance accelerometer's EKF loop over its PI
loop on a manufacturing batch (Zhang 2010 Table III, restated): 20 device draws (k +-10 %,
d0 +-5 %, m +-2 %, damping +-20 %, uniform) x 5 noise seeds, the rebalance bias and the
in-loop EKF designed from the nominal values; >= +6 dB at 0.1 g and at 1 g in >= 95 % of
the runs. Prints the distributions and the gain against the model mismatch."""

from __future__ import annotations

import numpy as np
import pytest
from campaign_helpers import spread_campaign


@pytest.mark.slow
def test_ekf_gain_over_pi_across_the_batch(tmp_path, subprocess_env):
    wide = spread_campaign(tmp_path / "c", "1-5", "1-20", subprocess_env, workers="2")
    assert len(wide) == 100
    mism = wide["device.k_eff_mismatch"].astype(float)
    for a in ("0g1", "1g"):
        g = wide[f"ekf_minus_pi_snr_{a}"].astype(float)
        rate = float((g >= 6.0).mean())
        lo, med, hi = np.percentile(g, [5, 50, 95])
        print(
            f"\nEKF - PI at {a}: median {med:.2f} dB, 5-95 % {lo:.2f}..{hi:.2f} dB, "
            f"min {g.min():.2f} dB, pass rate {rate:.0%}"
        )
        bins = np.digitize(mism.abs(), [0.1, 0.3])
        for b, label in enumerate(("|dk_eff| < 10 %", "10-30 %", ">= 30 %")):
            sel = g[bins == b]
            if len(sel):
                print(
                    f"  {label}: {len(sel)} runs, median {np.median(sel):.2f} dB, "
                    f"min {sel.min():.2f} dB"
                )
        print(f"  corr(gain, k_eff mismatch) = {np.corrcoef(g, mism)[0, 1]:+.2f}")
        assert rate >= 0.95, (a, rate)

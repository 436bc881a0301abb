"""Acceptance (``make acceptance``): the force-rebalance accelerometer's EKF loop over its PI
loop on a manufacturing batch (Zhang 2010 Table III, restated): 20 device draws (k +-10 %,
d0 +-5 %, m +-2 %, damping +-20 %, uniform) x 5 noise seeds, the rebalance bias designed
from the nominal values and the in-loop EKF's model identified on the bench for each
draw; >= +6 dB at 0.1 g and at 1 g in >= 95 % of the runs. The identified-model loop
against the oracle loop (the device's own table, same noise): within max(0.41 dB, the
oracle's 5-95 % spread) in >= 90 % of the runs (18 of 20), and the x NEES (one state)
within 0.5-2 in >= 90 %. Prints the distributions side by side and the identification
errors."""

from __future__ import annotations

import numpy as np
import pytest
from campaign_helpers import spread_campaign


@pytest.mark.slow
def test_ekf_gain_over_pi_across_the_batch(tmp_path, subprocess_env):
    wide = spread_campaign(tmp_path / "c", "1-5", "1-20", subprocess_env, workers="2")
    assert len(wide) == 100
    mism = wide["device.k_eff_mismatch"].astype(float)
    for k in ("mass", "stiffness", "damping", "gap", "electronic_accel_std"):
        e = wide[f"device.identified_{k}_error"].astype(float).abs()
        print(
            f"\nidentified {k}: |error| median {e.median():.2%}, 95 % {e.quantile(0.95):.2%}, "
            f"max {e.max():.2%}"
        )
        # measured: 95 % quantiles 0.38-1.35 %, the largest error 2.9 % (k and b0 of draw 18)
        assert e.quantile(0.95) < 0.02, (k, e.quantile(0.95))
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
        ident = wide[f"acc_ekf_{a}.output_snr"].astype(float)
        orac = wide[f"acc_oracle_ekf_{a}.output_snr"].astype(float)
        o5, o50, o95 = np.percentile(orac, [5, 50, 95])
        i5, i50, i95 = np.percentile(ident, [5, 50, 95])
        diff = ident - orac
        tol = max(0.41, o95 - o5)
        within = float((diff.abs() <= tol).mean())
        print(
            f"  output SNR identified {i50:.2f} dB ({i5:.2f}..{i95:.2f}), oracle {o50:.2f} dB "
            f"({o5:.2f}..{o95:.2f}); identified - oracle median {diff.median():+.3f} dB, "
            f"max |.| {diff.abs().max():.3f} dB, within {tol:.2f} dB: {within:.0%}"
        )
        assert within >= 0.9, (a, within)
        for who in ("ekf", "oracle_ekf"):
            nees = wide[f"acc_{who}_{a}.x_nees"].astype(float)
            n5, n50, n95 = np.percentile(nees, [5, 50, 95])
            inside = float(((nees >= 0.5) & (nees <= 2.0)).mean())
            print(f"  {who} x NEES median {n50:.2f} ({n5:.2f}..{n95:.2f}), in 0.5-2: {inside:.0%}")
            if who == "ekf":
                assert inside >= 0.9, (a, inside)

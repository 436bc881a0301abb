"""Acceptance (``make acceptance``): fault detection on the force-rebalance accelerometer
(study ``python -m mems_scenarios.accelerometer_fault_detection``, its ROS-free core): the
downstream EKF's windowed NIS monitor, calibrated on each device's own fault-free bench
runs (noise seeds 1, 2), evaluated on noise seeds 3-6 over the nominal device and four
drawn devices (11-14), every fault kind of the readout over its magnitude grid, 20 faults
per run.

Criteria (faults on demand): a bias step of 5 innovation standard deviations detected in
>= 95 % of the trials; fault-free alarm windows within [0.5, 2]x the designed count at
1e-2 and 1e-3 with >= 30 expected at each; no non-finite estimate and no filter reset
under any fault; the RMS error 5-15 ms after each fault within 1.5x the fault-free run's
(the sign flip on drawn devices: over 100 ms from 1 s after the fault, its stated settling
below)."""

from __future__ import annotations

import numpy as np
import pytest

from mems_estimation.studies import accelerometer_fault_detection as study

SEEDS = (3, 4, 5, 6)
DEVICES = (None, 11, 12, 13, 14)
FAULT_FREE_SAMPLES = 15_000_000

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def campaigns():
    out = {}
    for ds in DEVICES:
        out[ds] = study.campaign(tuple(study.GRID), SEEDS, (ds,), calibration="bench")
    return out


def _print(res, label):
    for kind, k in res["kinds"].items():
        print(
            f"{label} {kind}: P {np.round(k['probability'], 2).tolist()} two-sided "
            f"{np.round(k['probability_two_sided'], 2).tolist()} at {k['magnitudes']}; "
            f"95 % at {k['magnitude_95']} / {k['magnitude_95_two_sided']}; "
            f"after max {k['recovery_max']:.3g}, median {k['recovery_median']:.3g}"
        )


def test_five_sigma_bias_step_detected_and_estimates_stay_finite(campaigns):
    for ds, res in campaigns.items():
        _print(res, f"\ndevice {ds}:")
        b = res["kinds"]["bias_step"]
        p5 = b["probability"][b["magnitudes"].index(5.0)]
        d5 = b["delays_s"][b["magnitudes"].index(5.0)]
        print(f"device {ds}: 5 sigma bias step P {p5:.3f}, delay median/p95 {d5} s")
        assert p5 >= 0.95, (ds, p5)
        for kind, k in res["kinds"].items():
            assert k["non_finite_runs"] == 0 and k["resets"] == 0, (ds, kind)


def test_error_recovers_after_every_fault_but_the_sign_flip(campaigns):
    for ds, res in campaigns.items():
        for kind, k in res["kinds"].items():
            if kind == "sign_flip" and ds is not None:
                continue
            assert k["recovery_max"] <= 1.5, (ds, kind, k["recovery_max"])


#: The sign flip's stated settling: it drives the loop to its rail, and the PI integrator
#: keeps a wound-up offset (about 0.3 mV on v_f) that decays with the loop's slowest time
#: constant (about 0.6 s); the EKF's nominal model turns it into acceleration error on a
#: drawn device (up to 7.8x the fault-free RMS 5-15 ms after the fault). Measured instead
#: over 100 ms starting 1 s after each fault's end.
SIGN_FLIP = study.TrialConfig(faults_per_run=4, spacing_s=1.2, settle_s=1.0, recovery_s=0.1)


def test_sign_flip_recovers_after_its_stated_settling_on_drawn_devices():
    worst = 0.0
    for ds in DEVICES[1:]:
        for ns in SEEDS:
            t = study.run_trial("sign_flip", 0.0, ns, ds, SIGN_FLIP)
            assert t.finite and t.resets == 0, (ds, ns)
            worst = max(worst, float(t.recovery.max()))
    print(f"\nsign flip, drawn devices, 1 s after: worst error ratio {worst:.3g}")
    assert worst <= 1.5


def test_fault_free_alarms_at_two_designed_rates(campaigns):
    totals = {1e-2: [0, 0.0], 1e-3: [0, 0.0]}
    for ds, res in campaigns.items():
        rates = study.false_alarm_rates(
            SEEDS, FAULT_FREE_SAMPLES, device_seed=ds, moments=tuple(res["moments"][str(ds)])
        )
        for a, r in rates.items():
            print(
                f"\ndevice {ds}, alpha {a:g}: {r['alarm_windows']} of {r['windows']} windows, "
                f"designed {r['designed']:.1f}, ratio {r['ratio']:.2f}"
            )
            totals[a][0] += r["alarm_windows"]
            totals[a][1] += r["designed"]
            assert r["designed"] >= 30 and 0.5 <= r["ratio"] <= 2.0, (ds, a, r)
    for a, (n, designed) in totals.items():
        print(f"all devices, alpha {a:g}: {n} alarms, designed {designed:.1f}")
        assert designed >= 30

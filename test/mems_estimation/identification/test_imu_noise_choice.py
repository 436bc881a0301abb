"""Tests of the flicker / Gauss-Markov model choice (mems_estimation.identification.imu_noise_choice), no ROS.

Independent data: allantools' Kasdin & Walter (1992) generator ``allantools.noise_kasdin.Noise``,
whose series x has the one-sided PSD S_x(f) = g_b f^b, g_b = 2 qd (2 pi)^b tau0^(b+1) (Kasdin &
Walter eq. (39), ``Noise.phase_psd_from_qd``).  The generated series is used as the RATE
itself, so b = 0 is white rate noise, b = -1 flicker (1/f) rate noise and b = -2 a rate random
walk (in the library's oscillator terms the rate is a fractional frequency: these are white FM,
flicker FM and random-walk FM, the library's phase exponents -2, -3, -4).  This module's
conventions use the two-sided PSD: white N^2, flicker B^2/(2 pi f), random walk
K^2/(4 pi^2 f^2) (IEEE Std 952-1997, Annex C), i.e. one-sided h_0 = 2 N^2, h_-1 = B^2/pi,
h_-2 = K^2/(2 pi^2).  With tau0 = 1/fs that gives the generator's discrete variances

    white:   2 qd tau0 = 2 N^2                   ->  qd = N^2 fs
    flicker: 2 qd / (2 pi) = B^2 / pi            ->  qd = B^2
    walk:    2 qd / (4 pi^2 tau0) = K^2 / (2 pi^2)  ->  qd = K^2 / fs

and the library's closed-form Allan variances of white, flicker and random-walk FM
(``Noise.adev``: h_0/(2 tau), 2 ln 2 h_-1, (2 pi^2/3) h_-2 tau) become N^2/tau,
(2 ln 2/pi) B^2 and K^2 tau/3, the terms of the identified model
(:func:`test_kasdin_closed_form_matches_model_terms` checks this conversion against the
library).  The discrete flicker series exceeds the continuous floor by 44 % at tau = tau0,
decaying as ~ln(m)/m^2 (0.5 % at m = 8): the levels put the white noise 200 x above the
floor at tau0, so that excess is a 0.1 % bias of N, inside its interval.

Seeds: the flicker inflation was calibrated on seeds 1000-1099 (module doc); the quick tests
use seeds 1-8 (flicker) and 1-2 (Gauss-Markov), the acceptance campaign 3000-3019.
"""

import math
import os
import sys

import numpy as np
import pytest
from allantools.noise_kasdin import Noise
from kasdin_records import kasdin_rate

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "..")))

from mems_estimation.identification.allan import allan_analysis
from mems_estimation.identification.allan_stream import StreamingAllan
from mems_estimation.identification.imu_noise_choice import (
    FLICKER_AVAR,
    avar_model_flicker,
    choose_model,
    fit_flicker,
    identify_axes_choice,
    identify_choice,
    identify_stream_choice,
)
from mems_estimation.identification.imu_noise_fit import fit_allan, identify
from mems_sim.devices.imu import ImuNoiseModel

FS = 200.0
PARAMS = ("N", "B", "K")


def levels(B: float, tau_white: float, tau_walk: float) -> dict:
    """N, B, K (SI) of a flicker floor (2 ln 2/pi) B^2 that the white term meets at
    tau_white (s) and the random walk at tau_walk (s)."""
    floor = FLICKER_AVAR * B**2
    return {"N": math.sqrt(floor * tau_white), "B": B, "K": math.sqrt(3.0 * floor / tau_walk)}


def flicker_runs(seeds, n: int, truth: dict) -> list[dict]:
    """One identification with model choice per seed: the choice and the truth."""
    out = []
    for seed in seeds:
        rate = kasdin_rate(n, FS, truth["N"], truth["B"], truth["K"], seed)
        choice, _ = identify_choice(rate, FS)
        out.append({"seed": seed, "choice": choice, "truth": truth})
    return out


def _inside(run: dict, p: str) -> bool:
    lo, hi = run["choice"].fits["flicker"].ci95[p]
    return lo <= run["truth"][p] <= hi


def campaign_summary(runs: list[dict]) -> dict:
    """Coverage of the flicker model's N, B, K intervals and the rate of choosing it."""
    out = {f"coverage_{p}": float(np.mean([_inside(r, p) for r in runs])) for p in PARAMS}
    out["flicker_rate"] = float(np.mean([r["choice"].model == "flicker" for r in runs]))
    out["n"] = len(runs)
    return out


QUICK = levels(1e-4, 1.0, 100.0)


@pytest.fixture(scope="module")
def quick_runs():
    return flicker_runs(range(1, 9), 2**20, QUICK)


def test_kasdin_closed_form_matches_model_terms():
    """The conversion of the module doc against the library's own closed forms: the rate
    series of exponent b is the fractional frequency of the library's phase exponent b - 2
    with qd scaled by tau0^2 (the phase is the rate integrated with step tau0), so the
    library's Allan variance of that frequency is the Allan variance of our rate."""
    tau0, taus = 1.0 / FS, np.array([0.1, 1.0, 10.0, 100.0])
    t = QUICK
    want = {
        0: t["N"] ** 2 / taus,
        -1: np.full(taus.shape, FLICKER_AVAR * t["B"] ** 2),
        -2: t["K"] ** 2 * taus / 3.0,
    }
    for b, qd in ((0, t["N"] ** 2 * FS), (-1, t["B"] ** 2), (-2, t["K"] ** 2 / FS)):
        lib = Noise(nr=2, qd=qd * tau0**2, b=b - 2)
        # the fractional-frequency PSD h_a of the library's series is our rate's PSD g_b
        assert lib.frequency_psd_from_qd(tau0) == pytest.approx(
            Noise(nr=2, qd=qd, b=b).phase_psd_from_qd(tau0), rel=1e-12
        )
        np.testing.assert_allclose(lib.adev(tau0, taus) ** 2, want[b], rtol=1e-12)
    total = avar_model_flicker(taus, t["N"], t["B"], t["K"])
    np.testing.assert_allclose(total, want[0] + want[-1] + want[-2], rtol=1e-12)


def test_kasdin_flicker_intervals_and_choice(quick_runs):
    """8 seeds x 2^20 samples at 200 Hz (floor from 1 s to 100 s): the flicker model is
    chosen every time, by a margin, and N, B, K lie inside their 95 % intervals in at least
    7 of 8 runs each (P(2 or more misses) = 5.7 % for exact 95 % intervals)."""
    s = campaign_summary(quick_runs)
    print(s)
    assert s["flicker_rate"] == 1.0
    for p in PARAMS:
        assert s[f"coverage_{p}"] >= 7 / 8, (p, s)
    for r in quick_runs:
        c = r["choice"]
        assert c.bic["gm"] - c.bic["flicker"] > 20.0, (r["seed"], c.bic)
        assert c.fit is c.fits["flicker"] and math.isnan(c.fit.T)
        for p in PARAMS:  # the point estimates are close, not only covered
            assert abs(getattr(c.fit, p) / r["truth"][p] - 1.0) < 0.3, (r["seed"], p)


def test_kasdin_intervals_not_vacuous(quick_runs):
    """The intervals are informative: median relative half-width of B below 5 %, of N
    below 1 %, of K below 40 %."""
    for p, most in (("N", 0.01), ("B", 0.05), ("K", 0.40)):
        fits = [r["choice"].fit for r in quick_runs]
        w = [(f.ci95[p][1] - f.ci95[p][0]) / (2.0 * getattr(f, p)) for f in fits]
        assert float(np.median(w)) < most, (p, w)


#: A Gauss-Markov bump well above the white and random-walk terms: the project's device
#: model with T = 10 s (Allan deviation peak 0.617 B at 18.9 s).
GM_PARAMS = {
    "gyro_bias_instability": 1e-3,
    "gyro_correlation_time": 10.0,
    "accel_bias_instability": 1.5e-2,
    "accel_correlation_time": 10.0,
}


def test_gauss_markov_data_choose_gm():
    """mems_sim's ImuNoiseModel (white + Gauss-Markov + random walk + ADC), 2^18 samples at
    100 Hz, seeds 1-2, 6 axes each: the Gauss-Markov model is chosen on all 12, with T and
    B within a factor 1.5 of the truth."""
    fs = 100.0
    for seed in (1, 2):
        model = ImuNoiseModel(GM_PARAMS, seed=seed)
        frame = model.generate(2**18)
        stream = StreamingAllan(6, fs, "octave")
        stream.add(np.hstack([frame.gyro_si, frame.accel_si]))
        for ax, (choice, allan) in enumerate(identify_stream_choice(stream)):
            sensor = model.sensors["gyro" if ax < 3 else "accel"]
            assert choice.model == "gm", (seed, ax, choice.bic)
            assert choice.bic["flicker"] - choice.bic["gm"] > 10.0, (seed, ax, choice.bic)
            assert abs(math.log(choice.fit.T / sensor.T)) < math.log(1.5), (seed, ax)
            assert abs(math.log(choice.fit.B / sensor.B)) < math.log(1.5), (seed, ax)
            assert allan.ci_low.shape == allan.adev.shape


def test_ar1_choose_gm_by_both_criteria():
    """A plain AR(1) (Gauss-Markov, T = 5 s, B = 1) plus white noise (N = 0.05), 2^18 samples
    at 200 Hz: the Gauss-Markov model wins by AIC and BIC."""
    rng = np.random.default_rng(7)
    n, T, B, N = 2**18, 5.0, 1.0, 0.05
    a = math.exp(-1.0 / (FS * T))
    drive = rng.standard_normal(n) * B * math.sqrt(1.0 - a * a)
    from scipy.signal import lfilter

    x = lfilter([1.0], [1.0, -a], drive) + rng.standard_normal(n) * N * math.sqrt(FS)
    for criterion in ("aic", "bic"):
        choice, _ = identify_choice(x, FS, criterion=criterion)
        assert choice.model == "gm" and choice.criterion == criterion
        assert choice.fit.T == pytest.approx(T, rel=0.3)


def test_flicker_fit_recovers_exact_curve():
    """Noise-free flicker-model AVAR points give back N, B, K; the choice is flicker."""
    import dataclasses

    rng = np.random.default_rng(0)
    al = allan_analysis(rng.standard_normal(400_000), FS)
    t = QUICK
    al = dataclasses.replace(al, adev=np.sqrt(avar_model_flicker(al.taus, t["N"], t["B"], t["K"])))
    fit = fit_flicker(al)
    for p in PARAMS:
        assert getattr(fit, p) == pytest.approx(t[p], rel=1e-6), p
    assert math.isnan(fit.T) and fit.dof == fit.n_points - 4
    assert choose_model(al).model == "flicker"


def test_existing_fit_unchanged_by_choice():
    """The Gauss-Markov fit inside the choice is fit_allan's, bit for bit, and identify()
    does not depend on whether a choice was made."""
    rate = ImuNoiseModel({}, seed=3).generate(100_000).accel_si[:, 0]
    before, _ = identify(rate, 100.0)
    choice, _ = identify_choice(rate, 100.0)
    after, _ = identify(rate, 100.0)
    assert repr(before) == repr(after) == repr(choice.fits["gm"])
    assert repr(choice.fits["gm"]) == repr(fit_allan(allan_analysis(rate, 100.0)))
    d = choice.as_dict()
    assert d["model"] == choice.model and {"aic_gm", "bic_flicker", "nll_gm"} <= set(d)
    assert d["bic_gm"] - d["bic_flicker"] == pytest.approx(choice.bic["gm"] - choice.bic["flicker"])


def test_axes_and_criterion_validation():
    rates = kasdin_rate(2**16, FS, QUICK["N"], QUICK["B"], QUICK["K"], 11)
    out = identify_axes_choice(np.column_stack([rates, rates]), FS)
    assert len(out) == 2 and repr(out[0][0]) == repr(out[1][0])
    with pytest.raises(ValueError, match="criterion"):
        identify_choice(rates, FS, criterion="hqc")
    with pytest.raises(ValueError, match="shape"):
        identify_axes_choice(rates, FS)


# --- acceptance campaign (make acceptance) ----------------------------------------------

#: Six axes: gyro-like (B = 3.5 deg/h) and accelerometer-like (B = 40 ug) floors, white
#: meeting the floor at 2-20 s, the random walk at 500-3000 s.
ACCEPTANCE_AXES = (
    levels(1.7e-5, 5.0, 1000.0),
    levels(1.7e-5, 10.0, 2000.0),
    levels(1.7e-5, 20.0, 3000.0),
    levels(3.9e-4, 2.0, 500.0),
    levels(3.9e-4, 5.0, 1000.0),
    levels(3.9e-4, 10.0, 2000.0),
)
ACCEPTANCE_SEEDS = tuple(range(3000, 3020))
ACCEPTANCE_SAMPLES = int(8 * 3600 * FS)


@pytest.mark.slow
def test_acceptance_kasdin_8h_coverage_and_choice():
    """6 axes x 20 seeds x 8 h at 200 Hz: the flicker model chosen in >= 97 % of the 120
    runs, the 95 % intervals of N, B and K covering the truth in 88-99 % each (measured:
    flicker 100 %, coverage N 93.3 %, B 96.7 %, K 95.8 %; about 10 minutes)."""
    runs = []
    for i, truth in enumerate(ACCEPTANCE_AXES):
        seeds = [s * 10 + i for s in ACCEPTANCE_SEEDS]
        runs += flicker_runs(seeds, ACCEPTANCE_SAMPLES, truth)
    s = campaign_summary(runs)
    print(s)
    assert s["flicker_rate"] >= 0.97, s
    for p in PARAMS:
        assert 0.88 <= s[f"coverage_{p}"] <= 0.99, (p, s)


if __name__ == "__main__":
    print("quick", campaign_summary(flicker_runs(range(1, 9), 2**20, QUICK)))

"""Tests of Allan-variance noise identification (mems_estimation.identification.imu_noise_fit), no ROS.

The acceptance campaigns (``@pytest.mark.slow``, ``make acceptance``) run the device model
(mems_sim.devices.imu.ImuNoiseModel, Petkov defaults, 100 Hz) and the identifier's own code
path (StreamingAllan + identify_stream, as imu_noise_identifier_node and identify_noise run
it) without ROS: the numbers are the same as through a node graph (frames carry the same
samples) and a run costs seconds instead of minutes.  Tuning seeds (fit design, interval
calibration): 10-29; the campaigns use seeds 100-199 (10,000 s) and 200-219 (40,000 s).
Print the campaign figures:  ``.venv/bin/python test/mems_estimation/identification/test_imu_noise_fit.py``.
"""

import dataclasses
import functools
import math
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "..")))

from mems_estimation.identification.allan import allan_analysis
from mems_estimation.identification.allan_stream import StreamingAllan
from mems_estimation.identification.imu_noise_fit import (
    avar_gm,
    avar_model,
    crb_relative_se,
    discrete_model,
    fit_allan,
    fit_whittle,
    identify,
    identify_axes,
    identify_stream,
)
from mems_sim.devices.imu import ImuNoiseModel

FS = 100.0
PARAMS = ("N", "B", "K", "T")
AXES = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")


def _truth(model: ImuNoiseModel, sensor: str) -> dict:
    """Configured N, B, K, T; N as the white density the output carries (the ADC's
    quantisation noise lsb^2/12 per sample is white and adds to it)."""
    s = model.sensors[sensor]
    n_eff = math.sqrt(s.N**2 + s.lsb**2 / (12.0 * FS))
    return {"N": n_eff, "B": s.B, "K": s.K, "T": s.T}


def run_identification(seed: int, duration_s: float, ml_axis: int | None = None) -> list[dict]:
    """One run: the device model at rest, streamed into the identifier's accumulator.

    Returns one record per axis: identified value, interval and CRB s.e. of each parameter
    and the truth; with ``ml_axis`` also the reference Whittle ML fit of that axis."""
    model = ImuNoiseModel({}, seed=seed)
    stream = StreamingAllan(6, FS, "octave")
    n, raw = int(duration_s * FS), []
    while n > 0:
        k = min(n, 500_000)
        f = model.generate(k)
        block = np.hstack([f.gyro_si, f.accel_si])
        stream.add(block)
        if ml_axis is not None:
            raw.append(block[:, ml_axis].copy())
        n -= k
    out = []
    for ax, (fit, _) in enumerate(identify_stream(stream)):
        truth = _truth(model, "gyro" if ax < 3 else "accel")
        rec = {"seed": seed, "axis": AXES[ax], "truth": truth, "fit": fit}
        if ax == ml_axis:
            rec["ml"] = fit_whittle(np.concatenate(raw), FS, fit)
        out.append(rec)
    return out


@functools.cache
def campaign(duration_s: float, seeds: tuple, ml_axis: int | None = None) -> list[dict]:
    return [r for s in seeds for r in run_identification(s, duration_s, ml_axis)]


def _err(rec, p):
    return getattr(rec["fit"], p) / rec["truth"][p] - 1.0


def _median_abs(recs, p, log=False):
    e = np.array([_err(r, p) for r in recs])
    return float(np.median(np.abs(np.log1p(e)) if log else np.abs(e)))


def summary(recs) -> dict:
    """Campaign figures: median |err| per sensor and parameter, coverage, CRB, ML reference."""
    out = {}
    for sensor in ("gyro", "accel"):
        sel = [r for r in recs if r["axis"].startswith(sensor)]
        for p in PARAMS:
            out[f"{sensor}_{p}_median_abs"] = _median_abs(sel, p)
            out[f"{sensor}_{p}_median_abs_log"] = _median_abs(sel, p, log=True)
        out[f"{sensor}_B_max"] = max(_err(r, "B") for r in sel)
        ml = [r for r in sel if "ml" in r]
        if ml:
            for p in ("K", "T"):
                e = np.array([r["ml"][p] / r["truth"][p] for r in ml])
                out[f"{sensor}_{p}_ml_median_abs_log"] = float(np.median(np.abs(np.log(e))))
                out[f"{sensor}_{p}_fit_same_axes_median_abs_log"] = _median_abs(ml, p, log=True)
            out[f"{sensor}_B_ml_median_abs"] = float(
                np.median([abs(r["ml"]["B"] / r["truth"]["B"] - 1) for r in ml])
            )
            out[f"{sensor}_B_ml_max"] = float(max(r["ml"]["B"] / r["truth"]["B"] - 1 for r in ml))
    for p in PARAMS:
        inside = [
            r["fit"].ci95[p][0] <= r["truth"][p] <= r["fit"].ci95[p][1]
            for r in recs
            if np.isfinite(getattr(r["fit"], p))
        ]
        out[f"coverage_{p}"] = float(np.mean(inside))
        out[f"coverage_{p}_n"] = len(inside)
    return out


def predicted_median_B(sensor: str, duration_s: float) -> float:
    """0.674 x the Cramer-Rao relative s.e. of B at the truth (the median |error| of an
    efficient unbiased Gaussian estimator)."""
    t = _truth(ImuNoiseModel({}, seed=0), sensor)
    return 0.674 * crb_relative_se(t["N"], t["B"], t["K"], t["T"], FS, int(duration_s * FS))["B"]


SEEDS_10K = tuple(range(100, 200))
SEEDS_40K = tuple(range(200, 220))


def _camp10k():
    return summary(campaign(10_000.0, SEEDS_10K, 3))


@pytest.mark.slow
def test_acceptance_40000s_bias_instability():
    """20 seeds x 40,000 s: median |err B| <= 15 % (accelerometer), <= 13 % (gyro)."""
    s = summary(campaign(40_000.0, SEEDS_40K))
    print({k: round(v, 4) for k, v in s.items() if "_B_" in k})
    assert s["accel_B_median_abs"] <= 0.15, s["accel_B_median_abs"]
    assert s["gyro_B_median_abs"] <= 0.13, s["gyro_B_median_abs"]


@pytest.mark.slow
def test_acceptance_10000s_B_within_cramer_rao():
    """100 seeds x 10,000 s: median |err B| <= 1.5 x 0.674 x CRB relative s.e.; N within 3 %."""
    s = _camp10k()
    for sensor in ("gyro", "accel"):
        pred = predicted_median_B(sensor, 10_000.0)
        print(sensor, "B median", s[f"{sensor}_B_median_abs"], "predicted", pred)
        assert s[f"{sensor}_B_median_abs"] <= 1.5 * pred, (sensor, s[f"{sensor}_B_median_abs"])
        assert s[f"{sensor}_N_median_abs"] <= 0.03


@pytest.mark.slow
def test_acceptance_10000s_K_T_against_ml():
    """Median |log error| of K and T no worse than 1.5 x a Whittle ML fit's on the same runs
    (accelerometer x axis, seeds 100-199)."""
    s = _camp10k()
    for p in ("K", "T"):
        fit, ml = s[f"accel_{p}_fit_same_axes_median_abs_log"], s[f"accel_{p}_ml_median_abs_log"]
        print(p, "fit", fit, "ML", ml)
        assert fit <= 1.5 * ml, (p, fit, ml)


@pytest.mark.slow
def test_acceptance_10000s_interval_coverage():
    """95 % intervals of N, B, K, T pooled over 6 axes x 100 runs cover the truth in 88-99 %."""
    s = _camp10k()
    cov = {p: s[f"coverage_{p}"] for p in PARAMS}
    print(cov)
    assert all(0.88 <= c <= 0.99 for c in cov.values()), cov


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason=(
        "no run's B error above 100 % over 100 seeds x 10,000 s: measured max +236 % (accel) and "
        "+176 % (gyro) on seeds 100-199. The likelihood of B, T, K is bimodal there: a "
        "Gauss-Markov term with several times the true T and B fits the random walk as well, "
        "and the reference Whittle ML fit of the raw data picks that mode too (+170 % on the "
        "same runs), so no estimator of these records meets it; with a CRB s.e. of 0.33 in "
        "ln B even an efficient Gaussian estimator exceeds ln 2 in ~1.8 % of runs (P(any of "
        "100) ~ 84 %). strict: a pass would flag a change to revisit"
    ),
)
def test_acceptance_10000s_no_B_error_above_100_percent():
    s = _camp10k()
    assert max(s["accel_B_max"], s["gyro_B_max"]) <= 1.0, (s["accel_B_max"], s["gyro_B_max"])


# --- quick tests (make test) -------------------------------------------------------------


def test_cramer_rao_accelerometer_b():
    """CRB relative s.e. of the accelerometer's B: 0.33 at 10,000 s, 0.16 at 40,000 s, 0.10
    at 100,000 s (scales as 1/sqrt(record))."""
    t = _truth(ImuNoiseModel({}, seed=0), "accel")
    for dur, want in ((1e4, 0.33), (4e4, 0.16), (1e5, 0.10)):
        got = crb_relative_se(t["N"], t["B"], t["K"], t["T"], FS, int(dur * FS))["B"]
        assert got == pytest.approx(want, abs=0.006), dur
    assert predicted_median_B("accel", 1e4) == pytest.approx(0.674 * 0.33, rel=0.02)


def test_quick_campaign_and_streaming_path():
    """One 1,500 s run through the identifier's path: N within 3 %, intervals and CRB
    s.e. reported for every parameter, T's interval may be wide on a short record."""
    recs = campaign(1_500.0, (10,))
    for r in recs:
        fit = r["fit"]
        assert abs(fit.N / r["truth"]["N"] - 1) < 0.03, r["axis"]
        for p in PARAMS:
            lo, hi = fit.ci95[p]
            assert lo <= getattr(fit, p) <= hi or not np.isfinite(getattr(fit, p))
        assert set(fit.crb) == set(PARAMS) and fit.crb["N"] < 0.01


def test_stream_identification_equals_batch():
    rng = np.random.default_rng(5)
    y = ImuNoiseModel({}, seed=3).generate(120_000).accel_si
    st = StreamingAllan(3, FS, "octave")
    i = 0
    while i < y.shape[0]:
        k = int(rng.integers(1, 30_000))
        st.add(y[i : i + k])
        i += k
    taus, adev, _ = st.adev()
    for c in range(3):
        ref = allan_analysis(y[:, c], FS)
        assert np.array_equal(taus, ref.taus)
        assert np.allclose(adev[c], ref.adev, rtol=1e-12, atol=0)
    (f1, _), (f2, _) = identify_stream(st)[2], identify(y[:, 2], FS)
    for p in ("N", "B", "K"):
        assert getattr(f1, p) == pytest.approx(getattr(f2, p), rel=1e-6, abs=1e-12)
    assert np.allclose(st.mean(), y.mean(axis=0), rtol=1e-12)


def test_gm_avar_limits():
    """AVAR_GM -> 2 B^2 tau/(3T) for tau << T (RW-like) and 2 B^2 T / tau for tau >> T."""
    B, T = 2.0, 50.0
    assert avar_gm(np.array([1e-3]), B, T)[0] == pytest.approx(2 * B**2 * 1e-3 / (3 * T), rel=1e-4)
    assert avar_gm(np.array([1e6]), B, T)[0] == pytest.approx(2 * B**2 * T / 1e6, rel=1e-3)
    x = np.array([0.0099, 0.0101]) * T  # continuity across the series switch
    v = avar_gm(x, B, T)
    assert v[1] / v[0] == pytest.approx((0.0101 / 0.0099), rel=1e-2)


def test_fit_recovers_exact_curve():
    """Noise-free AVAR points give back the generating parameters."""
    rng = np.random.default_rng(0)
    al = allan_analysis(rng.standard_normal(200_000), 100.0)
    truth = dict(N=1e-3, B=3e-4, K=2e-5, T=60.0, Q=0.0)
    al = dataclasses.replace(al, adev=np.sqrt(avar_model(al.taus, **truth)))
    fit = fit_allan(al)
    for p in ("N", "B", "K", "T"):
        assert getattr(fit, p) == pytest.approx(truth[p], rel=1e-3), p
    assert fit.ci95["B"][0] <= fit.B <= fit.ci95["B"][1]


def test_white_only_identification():
    fs, N = 100.0, 5e-3
    y = np.random.default_rng(4).standard_normal(500_000) * N * math.sqrt(fs)
    fit, allan = identify(y, fs)
    assert fit.N == pytest.approx(N, rel=0.02)
    assert abs(fit.N - N) < 4.0 * fit.se["N"]
    assert fit.B < 0.2 * N * math.sqrt(fs) and fit.K < 1e-4
    assert allan.ci_low.shape == allan.adev.shape


def test_identify_axes_and_discrete_model():
    frame = ImuNoiseModel({}, seed=9).generate(200_000)
    results = identify_axes(frame.gyro_si, FS)
    assert len(results) == 3
    fit = results[0][0]
    d = discrete_model(fit, FS)
    assert d.sigma_white == pytest.approx(fit.N * 10.0)
    assert d.sigma_rw_increment == pytest.approx(fit.K * 0.1)
    assert d.sigma_omega == pytest.approx(10.0)
    if fit.B > 0:
        assert d.a_d == pytest.approx(math.exp(-0.01 / fit.T))
        assert (1 - d.a_d**2) * fit.B**2 == pytest.approx(d.b_d**2 * d.sigma_eta**2)


def test_discrete_model_paper_numbers():
    """Petkov Sec. 3 with B in deg/s: a_d = 0.999917, b_d = 8.33299e-5, sigma_eta = 2.40125."""
    from mems_estimation.identification.imu_noise_fit import NoiseModelFit

    fit = NoiseModelFit(N=0.0581188, B=1.55e-2, K=9e-4, T=120.0, Q=0.0)
    d = discrete_model(fit, 100.0)
    assert d.a_d == pytest.approx(0.999917, abs=5e-7)
    assert d.b_d == pytest.approx(8.33299e-5, rel=1e-5)
    assert d.sigma_eta == pytest.approx(2.40125, rel=1e-5)
    assert d.sigma_white == pytest.approx(0.581188)


if __name__ == "__main__":
    import json

    for label, recs in (
        ("40,000 s x seeds 200-219", campaign(40_000.0, SEEDS_40K)),
        ("10,000 s x seeds 100-199", campaign(10_000.0, SEEDS_10K, 3)),
    ):
        print(label, json.dumps({k: round(v, 4) for k, v in summary(recs).items()}, indent=1))
    for sensor in ("gyro", "accel"):
        print(sensor, "predicted median |err B| at 10,000 s:", predicted_median_B(sensor, 1e4))

"""Core tests of the 6-state Kalman observer and the adaptive (EKF) observer (Colinet et al.).

Acceptance figures: exact model without state noise (figure 1), consistency with state
noise (figure 2), f0 model error, adaptive recovery and f0 step tracking (figure 4) and
bit-stream validation (figure 5).  Seeded; measured
figures are printed.  Where a figure is not met, a strict xfail documents it
with the measured value and the reason.
"""

import math

import numpy as np
import pytest
from scipy import stats

from mems_estimation.filters.resonator_adaptive_observer import AdaptiveObserver
from mems_sim.devices.resonator import SdResonatorDevice, default_pulse_amplitude
from mems_sim.kernels.resonator_observer import KalmanObserver, observer_model, steady_state_gains

FS, F0, Q = 1e6, 5e4, 100.0
N = 300_000
SKIP = 50_000


def _amp(y):
    return math.sqrt(2.0) * float(np.std(y))


def _io(fr):
    """Observer inputs of a device frame: bits, pulse heights, firing offsets, widths."""
    return fr.bits, fr.pulses, fr.pulse_start, fr.pulse_width


def _acf(x, lags=20):
    x = x - x.mean()
    return np.array([np.dot(x[:-k], x[k:]) / np.dot(x, x) for k in range(1, lags + 1)])


def _run(amp, sb, sf, seed, n=N, **extra):
    p = {
        "output_noise_std": sb,
        "state_noise_std": sf,
        "observer_state_noise_std": sf,
        "fast": False,
        "pulse_amplitude": default_pulse_amplitude(amp),
    }
    p.update(extra)
    return SdResonatorDevice(p, seed=seed).step(n)


def test_fig1_exact_model_no_state_noise():
    """Figure 1: RMS error <= 1e-9 A (paper ~1e-10) with output noise std = amplitude."""
    fr = SdResonatorDevice({"output_noise_std": 0.5}, seed=3).step(200_000)
    a = _amp(fr.position[100_000:])
    in_loop = np.sqrt(np.mean((fr.estimate - fr.position)[100_000:] ** 2)) / a
    # same stream, observer started with a wrong, uncertain resonator state
    ko = KalmanObserver(
        F0,
        Q,
        FS,
        0.5,
        0.0,
        initial_state=[0.3, -0.2, 0, 0, 0, 0],
        initial_cov=np.diag([0.25, 0.25, 1, 1, 1, 1]),
    )
    p, _ = ko.step(*_io(fr))
    off = np.sqrt(np.mean((p - fr.position)[100_000:] ** 2)) / a
    print(
        f"\nA = {a:.4f} V; RMS error / A: in-loop (known rest start, fast) {in_loop:.2e}, "
        f"offline from a wrong start {off:.2e}"
    )
    assert in_loop <= 1e-9
    assert off <= 1e-9


def test_steady_state_gain_matches_time_varying():
    m = observer_model(F0, Q, FS, 0.25, 5e-4)
    ss = steady_state_gains(m)
    fr = _run(0.25, 0.25, 5e-4, seed=2, n=60_000)
    full = KalmanObserver(F0, Q, FS, 0.25, 5e-4)
    fast = KalmanObserver(F0, Q, FS, 0.25, 5e-4, steady_state=True)
    pf, vf = full.step(*_io(fr))
    ps, vs = fast.step(*_io(fr))
    print(
        f"\nDARE method {ss['method']}, steady pos var {ss['pos_var']:.3e}, "
        f"time-varying at end {vf[-1]:.3e}, "
        f"max |diff| last half {np.abs(pf - ps)[30_000:].max():.2e}"
    )
    assert vf[-1] == pytest.approx(ss["pos_var"], rel=1e-6)
    assert np.abs(pf - ps)[30_000:].max() < 1e-6


def test_fig2_consistency_with_state_noise():
    """Figure 2 (modulator within range): amplitude 0.25 V, output noise std 0.25 V (the
    paper's "noise of the order of the signal", scaled into the modulator's input range)."""
    sb, sf = 0.25, 5e-4
    ratios = []
    for seed in (4, 5):
        fr = _run(0.25, sb, sf, seed)
        err = (fr.estimate - fr.position)[SKIP:]
        pred = float(np.mean(fr.estimate_var[SKIP:]))
        a = _amp(fr.position[SKIP:])
        ratio = err.var() / pred
        ratios.append(ratio)
        ko = KalmanObserver(F0, Q, FS, sb, sf)
        ko.step(*_io(fr))
        inn = ko.last_innovations[SKIP:]
        print(
            f"\nseed {seed}: A = {a:.3f} V, error std {err.std():.2e} V "
            f"({err.std() / a:.2%} of A, {err.std() / sb:.2%} of the output noise), "
            f"mean {err.mean():.1e} V; "
            f"measured/predicted variance {ratio:.3f}; error acf lags 1..3 "
            f"{np.round(_acf(err)[:3], 3)}; innovations var {inn.var():.3f}, "
            f"max |acf 1..20| {np.abs(_acf(inn)).max():.3f}"
        )
        assert 0.8 <= ratio <= 1.2
        assert err.std() < 0.05 * sb


def _ljung_box(x, lags=20):
    """Ljung-Box statistic Q = n (n+2) sum r_k^2/(n-k) and its chi^2(lags) p-value."""
    n = x.size
    r = _acf(x, lags)
    q = n * (n + 2) * float(np.sum(r**2 / (n - np.arange(1, lags + 1))))
    return q, float(stats.chi2.sf(q, lags))


@pytest.mark.xfail(
    strict=True,
    reason=(
        "Colinet Sec. 7 says that with state noise 'the residual error will be a white noise with "
        "non-zero variance P'. Measured (amplitude 0.25 V, output noise 0.25 V, state noise "
        "5e-4 V, seed 4): the error x - x(k|k) has lag-1 autocorrelation 0.951, Ljung-Box "
        "(20 lags) p = 0: it is narrow-band around f0, as the a-posteriori error of any Kalman "
        "filter of a Q = 100 resonator driven by white force noise is (its correlation decays "
        "with the resonator's ~Q/(pi f0) time constant, not in one sample). Only the "
        "innovations are white in theory, and even they fail here (acf(1) = -0.22, Ljung-Box "
        "Q = 14,600, p = 0) because the one-bit quantisation error is not white. The paper's "
        "statement is wrong as written, so this item cannot be met"
    ),
)
def test_fig2_error_whiteness():
    """The paper's claim, tested literally: the estimation error is white (Ljung-Box, 20 lags,
    5 % level).  The innovations' statistic is printed alongside."""
    fr = _run(0.25, 0.25, 5e-4, seed=4)
    err = (fr.estimate - fr.position)[SKIP:]
    ko = KalmanObserver(F0, Q, FS, 0.25, 5e-4)
    ko.step(*_io(fr))
    inn = ko.last_innovations[SKIP:]
    q_e, p_e = _ljung_box(err)
    q_i, p_i = _ljung_box(inn)
    print(
        f"\nerror: acf(1) {_acf(err)[0]:.3f}, Ljung-Box Q {q_e:.0f} p {p_e:.2g}; "
        f"innovations: acf(1..3) {np.round(_acf(inn)[:3], 3)}, Ljung-Box Q {q_i:.0f} p {p_i:.2g}"
    )
    assert p_e > 0.05


def test_fig2_error_small_and_uncorrelated_with_state():
    """What the paper contrasts (Sec. 7, Figs. 5-6): with an exact model and state noise the
    residual error is small and unrelated to the resonator's motion, whereas a model error
    leaves "a residual non-white error strongly correlated with the real resonator state
    position".  Tested: exact model -> error std <= 5 % of the output-noise std and
    |corr(error, true position)| < 0.25; 5 % f0 error -> |corr| > 0.9 and >= 10x larger.
    This does not replace the whiteness item (strict xfail above)."""
    sb, sf = 0.25, 5e-4
    for seed in (4, 5):
        fr = _run(0.25, sb, sf, seed)
        x = fr.position[SKIP:]
        err = (fr.estimate - fr.position)[SKIP:]
        wrong, _ = KalmanObserver(F0 * 1.05, Q, FS, sb, sf).step(*_io(fr))
        err_w = wrong[SKIP:] - x
        c, c_w = np.corrcoef(err, x)[0, 1], np.corrcoef(err_w, x)[0, 1]
        print(
            f"\nseed {seed}: exact model: error std {err.std():.2e} V "
            f"({err.std() / sb:.2%} of the output noise), corr(error, x) {c:+.3f}; "
            f"5 % f0 error: std {err_w.std():.2e} V, corr {c_w:+.3f}"
        )
        assert err.std() <= 0.05 * sb
        assert abs(c) < 0.25
        assert abs(c_w) > 0.9 and err_w.std() >= 10 * err.std()


def test_fig2_consistency_default_amplitude():
    """Consistency at the device's default amplitude (0.5 V) and default output noise (0),
    state noise on: the modulator input stays within its +-1 V range."""
    for seed in (4, 5):
        fr = _run(0.5, 0.0, 1e-3, seed)
        err = (fr.estimate - fr.position)[SKIP:]
        ratio = err.var() / float(np.mean(fr.estimate_var[SKIP:]))
        print(
            f"\nseed {seed}: A = {_amp(fr.position[SKIP:]):.3f} V, max |x| "
            f"{np.abs(fr.position).max():.3f} V; measured/predicted variance {ratio:.3f}"
        )
        assert np.abs(fr.position).max() < 1.0
        assert 0.8 <= ratio <= 1.2


@pytest.mark.xfail(
    strict=True,
    reason=(
        "amplitude 0.5 V with output noise std 0.5 V drives the +-1 V one-bit second-order "
        "modulator beyond its reference on 10 % of the samples (peaks ~2 V): it overloads "
        "(comparator-input std 2.5-2.6 V instead of 0.63-0.68 V in range) and no additive "
        "linear quantiser model holds. Measured/predicted error variance 2.9-3.3 (seeds 4, 5) "
        "with the paper's unit-gain model; a Bussgang gain does not help: 3.2-3.5 with the "
        "in-range gain 1.247, 3.4 with a self-consistent Gaussian gain, 2.9-3.1 even with the "
        "gain from the measured comparator-input std. The same SNR inside the input range "
        "(0.25 V + 0.25 V) is consistent: 0.91-1.00"
    ),
)
def test_fig2_consistency_default_amplitude_overloaded():
    fr = _run(0.5, 0.5, 1e-3, seed=4)
    err = (fr.estimate - fr.position)[SKIP:]
    ratio = err.var() / float(np.mean(fr.estimate_var[SKIP:]))
    print(f"\nA = 0.5 V, sb = 0.5 V: measured/predicted variance {ratio:.3f}")
    assert 0.8 <= ratio <= 1.2


def test_fig4_f0_error_and_adaptive_recovery():
    """Figure 4a/b: 5 % f0 error >= 10x error; adaptive EKF from 5 % back within 2x exact.

    Exact-model figure: same stream, same conditions (amplitude 0.25 V, output
    noise 0.25 V, state noise 5e-4 V so that it is not ~0), exact KalmanObserver.
    """
    sb, sf = 0.25, 5e-4
    fr = _run(0.25, sb, sf, seed=5)
    a = _amp(fr.position[SKIP:])
    exact, _ = KalmanObserver(F0, Q, FS, sb, sf).step(*_io(fr))
    wrong, _ = KalmanObserver(F0 * 1.05, Q, FS, sb, sf).step(*_io(fr))
    e_exact = np.std((exact - fr.position)[N // 2 :])
    e_wrong = np.std((wrong - fr.position)[N // 2 :])
    ao = AdaptiveObserver(F0 * 1.05, Q, FS, sb, sf, f0_random_walk_ppm=0.2)
    pa, _, fa, fva = ao.step(*_io(fr))
    e_adapt = np.std((pa - fr.position)[N // 2 :])
    print(
        f"\nA = {a:.3f} V; RMS error / A: exact {e_exact / a:.3e}, 5 % f0 error "
        f"{e_wrong / a:.3e} (x{e_wrong / e_exact:.1f}), adaptive from 5 % {e_adapt / a:.3e} "
        f"(x{e_adapt / e_exact:.2f} of exact); adaptive f0 error at end "
        f"{(fa[-1] / F0 - 1) * 1e6:.0f} ppm (std {math.sqrt(fva[-1]) / F0 * 1e6:.0f} ppm)"
    )
    assert e_wrong >= 10 * e_exact
    assert e_adapt <= 2 * e_exact


def _step_run(**kw):
    sb, sf = 0.05, 5e-4
    t_step = 0.2
    fr = SdResonatorDevice(
        {
            "mode": "comparator",
            "output_noise_std": sb,
            "state_noise_std": sf,
            "f0_step_fraction": 0.02,
            "f0_step_time_s": t_step,
        },
        seed=kw.pop("seed", 6),
    ).step(600_000)
    ao = AdaptiveObserver(F0, Q, FS, sb, sf, f0_random_walk_ppm=0.2, **kw)
    _, _, f, fv = ao.step(*_io(fr))
    rel = f / fr.f0 - 1.0
    k0 = int(t_step * FS)
    return fr, rel, k0, ao


def _settling(rel, k0, tol):
    """Samples after k0 until |rel| stays <= tol to the end (None: never)."""
    bad = np.flatnonzero(np.abs(rel[k0:]) > tol)
    if bad.size and bad[-1] == rel.size - k0 - 1:
        return None
    return int(bad[-1] + 1) if bad.size else 0


@pytest.mark.parametrize("seed", [6, 7])
def test_fig4_f0_step_tracking(seed):
    """Figure 4c: +2 % f0 step; the adaptive f0 settles within 100 ppm (settling time in periods).

    The stream comes from the Fig.-1 comparator loop with low output noise
    (0.05 V), which keeps oscillating through the step (the fixed in-loop Kalman
    observer, built for the old f0, lets the amplitude collapse to ~0.06 V after it).
    """
    fr, rel, k0, ao = _step_run(seed=seed)
    s = _settling(rel, k0, 100e-6)
    per = fr.f0[-1] / FS
    tail = rel[-100_000:]
    pre = rel[100_000:k0]
    print(
        f"\nseed {seed}: +2 % step: settled within 100 ppm after "
        f"{'never' if s is None else f'{s} samples = {s * per:.0f} periods'}; last 100k "
        f"samples: mean {tail.mean() * 1e6:.0f} ppm, std {tail.std() * 1e6:.0f} ppm; before "
        f"the step: mean {pre.mean() * 1e6:.0f} ppm, max |err| {np.abs(pre).max() * 1e6:.0f} ppm;"
        f" covariance resets {ao.resets}"
    )
    assert s is not None
    assert np.abs(pre).max() <= 100e-6


def test_fig4_unit_gain_quantiser_model_is_biased():
    """Documents why the adaptive observer defaults to the Bussgang quantiser model."""
    fr, rel, k0, ao = _step_run(quantizer_gain=1.0)
    bias = rel[100_000:k0].mean()
    print(
        f"\nunit-gain (paper) quantiser model: f0 bias before the step {bias * 1e6:.0f} ppm, "
        f"after {rel[-100_000:].mean() * 1e6:.0f} ppm; settling to 100 ppm: "
        f"{_settling(rel, k0, 100e-6)}"
    )
    assert bias > 50e-6


@pytest.mark.parametrize("bits", [[1, 0, -1], [1, 2, -1], [1.0, -1.0, 0.5], [1, -1, np.nan]])
def test_bad_bits_rejected(bits):
    ko = KalmanObserver(F0, Q, FS, 0.5, 0.0)
    with pytest.raises(ValueError, match=r"\+1/-1") as ei:
        ko.step(np.array(bits), np.zeros(3))
    print("\n", ei.value)
    ao = AdaptiveObserver(F0, Q, FS, 0.5, 0.0)
    with pytest.raises(ValueError, match=r"\+1/-1"):
        ao.step(np.array(bits), np.zeros(3))


def test_shape_mismatch_and_model_refusals():
    ko = KalmanObserver(F0, Q, FS, 0.5, 0.0)
    with pytest.raises(ValueError, match="equal length"):
        ko.step(np.ones(3), np.zeros(4))
    for f0, q, fs in ((6e5, Q, FS), (F0, 0.0, FS), (F0, Q, -1.0)):
        with pytest.raises(ValueError):
            KalmanObserver(f0, q, fs, 0.5, 0.0)
        with pytest.raises(ValueError):
            AdaptiveObserver(f0, q, fs, 0.5, 0.0)


def test_carried_state_observers():
    fr = _run(0.25, 0.25, 5e-4, seed=9, n=20_000)
    for make in (
        lambda: KalmanObserver(F0, Q, FS, 0.25, 5e-4),
        lambda: KalmanObserver(F0, Q, FS, 0.25, 5e-4, steady_state=True),
        lambda: AdaptiveObserver(F0 * 1.01, Q, FS, 0.25, 5e-4, estimate_q=True),
    ):
        whole = make().step(*_io(fr))
        o = make()
        parts = [
            o.step(*(x[a:b] for x in _io(fr)))
            for a, b in ((0, 1), (1, 777), (777, 777), (777, 20_000))
        ]
        for i, w in enumerate(whole):
            assert np.array_equal(w, np.concatenate([p[i] for p in parts]))

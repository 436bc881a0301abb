"""Core tests of the 6-state Kalman observer and the adaptive (EKF) observer (issue 6).

Acceptance figures 1, 2, 4 and 5 (bit-stream validation).  Seeded; measured
figures are printed.  Where a figure is not met, a strict xfail documents it
with the measured value (see the report / module docs for why).
"""
import math

import numpy as np
import pytest

from mems_estimation.adaptive_observer import AdaptiveObserver
from mems_estimation.kalman_observer import KalmanObserver, observer_model, steady_state_gains
from mems_sim.sd_resonator import SdResonatorDevice, default_pulse_amplitude

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
    p = {"output_noise_std": sb, "state_noise_std": sf, "observer_state_noise_std": sf,
         "fast": False, "pulse_amplitude": default_pulse_amplitude(amp)}
    p.update(extra)
    return SdResonatorDevice(p, seed=seed).step(n)


def test_fig1_exact_model_no_state_noise():
    """Figure 1: RMS error <= 1e-9 A (paper ~1e-10) with output noise std = amplitude."""
    fr = SdResonatorDevice({"output_noise_std": 0.5}, seed=3).step(200_000)
    a = _amp(fr.position[100_000:])
    in_loop = np.sqrt(np.mean((fr.estimate - fr.position)[100_000:] ** 2)) / a
    # same stream, observer started with a wrong, uncertain resonator state
    ko = KalmanObserver(F0, Q, FS, 0.5, 0.0, initial_state=[0.3, -0.2, 0, 0, 0, 0],
                        initial_cov=np.diag([0.25, 0.25, 1, 1, 1, 1]))
    p, _ = ko.step(*_io(fr))
    off = np.sqrt(np.mean((p - fr.position)[100_000:] ** 2)) / a
    print(f"\nA = {a:.4f} V; RMS error / A: in-loop (known rest start, fast) {in_loop:.2e}, "
          f"offline from a wrong start {off:.2e}")
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
    print(f"\nDARE method {ss['method']}, steady pos var {ss['pos_var']:.3e}, "
          f"time-varying at end {vf[-1]:.3e}, "
          f"max |diff| last half {np.abs(pf - ps)[30_000:].max():.2e}")
    assert vf[-1] == pytest.approx(ss["pos_var"], rel=1e-6)
    assert np.abs(pf - ps)[30_000:].max() < 1e-6


def test_fig2_consistency_with_state_noise():
    """Figure 2 (modulator within range): amplitude 0.25 V, output noise std 0.25 V."""
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
        print(f"\nseed {seed}: A = {a:.3f} V, error std {err.std():.2e} V "
              f"({err.std() / a:.2%} of A, {err.std() / sb:.2%} of the output noise), "
              f"mean {err.mean():.1e} V; "
              f"measured/predicted variance {ratio:.3f}; error acf lags 1..3 "
              f"{np.round(_acf(err)[:3], 3)}; innovations var {inn.var():.3f}, "
              f"max |acf 1..20| {np.abs(_acf(inn)).max():.3f}")
        assert 0.8 <= ratio <= 1.2
        assert err.std() < 0.05 * sb


@pytest.mark.xfail(strict=True, reason="the estimation error x - x(k|k) of a Q = 100 resonator "
                   "is narrow-band around f0 (acf(1) ~ 0.95); the paper's 'white residual' holds "
                   "for the innovations only, and even these show acf up to ~0.2 because the "
                   "one-bit quantisation error is not white")
def test_fig2_error_whiteness():
    fr = _run(0.25, 0.25, 5e-4, seed=4)
    err = (fr.estimate - fr.position)[SKIP:]
    acf = _acf(err)
    bound = 3.0 / math.sqrt(err.size)
    print(f"\nerror acf lags 1..20: {np.round(acf, 3)}; bound {bound:.4f}")
    assert np.all(np.abs(acf) < bound)


@pytest.mark.xfail(strict=True, reason="amplitude 0.5 V + output noise std 0.5 V overloads the "
                   "+-1 V second-order one-bit modulator (comparator input std ~2 V, var(e) ~3.3 "
                   "V^2 vs 1/3 assumed): measured/predicted error variance ~2.1-2.3")
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
    e_exact = np.std((exact - fr.position)[N // 2:])
    e_wrong = np.std((wrong - fr.position)[N // 2:])
    ao = AdaptiveObserver(F0 * 1.05, Q, FS, sb, sf, f0_random_walk_ppm=0.2)
    pa, _, fa, fva = ao.step(*_io(fr))
    e_adapt = np.std((pa - fr.position)[N // 2:])
    print(f"\nA = {a:.3f} V; RMS error / A: exact {e_exact / a:.3e}, 5 % f0 error "
          f"{e_wrong / a:.3e} (x{e_wrong / e_exact:.1f}), adaptive from 5 % {e_adapt / a:.3e} "
          f"(x{e_adapt / e_exact:.2f} of exact); adaptive f0 error at end "
          f"{(fa[-1] / F0 - 1) * 1e6:.0f} ppm (std {math.sqrt(fva[-1]) / F0 * 1e6:.0f} ppm)")
    assert e_wrong >= 10 * e_exact
    assert e_adapt <= 2 * e_exact


def _step_run(**kw):
    sb, sf = 0.05, 5e-4
    t_step = 0.2
    fr = SdResonatorDevice({"mode": "comparator", "output_noise_std": sb, "state_noise_std": sf,
                            "f0_step_fraction": 0.02, "f0_step_time_s": t_step},
                           seed=kw.pop("seed", 6)).step(600_000)
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
    print(f"\nseed {seed}: +2 % step: settled within 100 ppm after "
          f"{'never' if s is None else f'{s} samples = {s * per:.0f} periods'}; last 100k "
          f"samples: mean {tail.mean() * 1e6:.0f} ppm, std {tail.std() * 1e6:.0f} ppm; before "
          f"the step: mean {pre.mean() * 1e6:.0f} ppm, max |err| {np.abs(pre).max() * 1e6:.0f} ppm;"
          f" covariance resets {ao.resets}")
    assert s is not None
    assert np.abs(pre).max() <= 100e-6


def test_fig4_unit_gain_quantiser_model_is_biased():
    """Documents why the adaptive observer defaults to the Bussgang quantiser model."""
    fr, rel, k0, ao = _step_run(quantizer_gain=1.0)
    bias = rel[100_000:k0].mean()
    print(f"\nunit-gain (paper) quantiser model: f0 bias before the step {bias * 1e6:.0f} ppm, "
          f"after {rel[-100_000:].mean() * 1e6:.0f} ppm; settling to 100 ppm: "
          f"{_settling(rel, k0, 100e-6)}")
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
    for make in (lambda: KalmanObserver(F0, Q, FS, 0.25, 5e-4),
                 lambda: KalmanObserver(F0, Q, FS, 0.25, 5e-4, steady_state=True),
                 lambda: AdaptiveObserver(F0 * 1.01, Q, FS, 0.25, 5e-4, estimate_q=True)):
        whole = make().step(*_io(fr))
        o = make()
        parts = [o.step(*(x[a:b] for x in _io(fr))) for a, b in
                 ((0, 1), (1, 777), (777, 777), (777, 20_000))]
        for i, w in enumerate(whole):
            assert np.array_equal(w, np.concatenate([p[i] for p in parts]))

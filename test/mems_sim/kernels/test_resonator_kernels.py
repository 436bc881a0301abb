"""The structured kernels of the resonator observers against the generic loops, bit for bit.

:mod:`mems_sim.kernels.resonator_observer` keeps the generic n x n loops of the Kalman
recursion of Colinet et al. eq. (2) (``predicted_output``, ``kf_update``, ``kf_predict``,
``cov_predict``) next to the structured kernels the observers and the device run
(``predicted_output_sd``, ``kf_update6``, ``kf_predict6``, ``predictor_gain_sd``,
``cov_predict_sd``, ``cov_predict6``), which skip the exact zeros of the model's matrices; the two must give
equal floats (same bits) for finite inputs, so recordings and reference tables do not
move.  Checked here on the 6-state model and on the adaptive observer's Jacobian pattern
(7 and 8 states), with a covariance that starts with exact zeros (the device's prior) and
with random positive-definite ones; the frame checks keep their results and messages.
The whole kernels (device, observers) against the old ones kept by the resonator oracles:
``bench/bench_sd_resonator.py --check-only``, and the slow test below.
"""

import numpy as np
import pytest

from mems_sim.kernels.resonator_kf_steps import (
    cov_predict,
    cov_predict6,
    cov_predict_sd,
    kf_predict,
    kf_predict6,
    kf_update,
    kf_update6,
    predicted_output,
    predicted_output_sd,
    predictor_gain_sd,
)
from mems_sim.kernels.resonator_observer import check_bits, check_pulse_timing
from mems_sim.kernels.resonator_observer_model import _sd_blocks, observer_model

FS, F0, Q = 1e6, 5e4, 100.0


def _bits(x):
    return np.asarray(x, dtype=float).view(np.int64)


def _same(a, b):
    return np.array_equal(_bits(a), _bits(b))


def _spd(rng, n, scale=1.0):
    a = rng.standard_normal((n, n))
    p = a @ a.T * scale + np.eye(n) * 1e-3 * scale
    return 0.5 * (p + p.T)


def _trial_cov(rng, n, trial):
    """Covariance of trial ``trial``: random SPD (:func:`_spd`, scale 1e-8..10), its
    parameter rows and columns 6.. zero on every 4th trial (the warm-up's held parameters),
    all zero on the next."""
    P = _spd(rng, n, 10.0 ** rng.uniform(-8, 1))
    if trial % 4 == 0:
        P[6:, :] = 0.0
        P[:, 6:] = 0.0
    if trial % 4 == 1:
        P[:, :] = 0.0
    return P


def _models():
    yield observer_model(F0, Q, FS, 0.25, 5e-4)
    yield observer_model(1.05 * F0, 80.0, FS, 0.5, 0.0, quantizer_gain=1.247)
    yield observer_model(0.2 * FS, 3.0, FS, 0.0, 1e-3, sd_feedforward=0.0)


def _jacobian(rng, n, kappa=1.247):
    """The adaptive observer's J (rows 0-1 resonator and parameter columns, STF/NTF blocks,
    random-walk rows), F and M as its kernel builds them."""
    Ad, _, _ = _sd_blocks(0.5, kappa)
    J = np.zeros((n, n))
    J[0:2, 0:2] = rng.standard_normal((2, 2)) * 0.5 + np.eye(2) * 0.5
    J[0:2, 6:] = rng.standard_normal((2, n - 6)) * 3.0
    J[2, 0] = 1.0
    J[2:4, 2:4] = Ad
    J[4:6, 4:6] = Ad
    for a in range(6, n):
        J[a, a] = 1.0
    g = np.abs(rng.standard_normal(2))
    F = np.zeros((n, n))
    F[0:2, 0:2] = np.outer(g, g) * 1e-6
    F[2, 2] = 0.0625
    F[4, 4] = 1.0 - 2.0 / np.pi
    for a in range(6, n):
        F[a, a] = 4e-14
    M = np.zeros(n)
    M[4] = 1.0 - 2.0 / np.pi
    return J, F, M


@pytest.mark.parametrize("start", ["zeros", "random"])
def test_kf6_steps_equal_generic(start):
    """kf_update6 / kf_predict6 (with u = 0, as the filters call them) against kf_update /
    kf_predict over 500 steps of one-bit measurements: x, P, nu, S, position, variance."""
    rng = np.random.default_rng(7)
    for m in _models():
        P0 = np.diag([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]) if start == "zeros" else _spd(rng, 6)
        x0 = np.zeros(6) if start == "zeros" else rng.standard_normal(6)
        xa, Pa, xb, Pb = x0.copy(), P0.copy(), x0.copy(), P0.copy()
        xf, PC, L, AP, tmp = (np.empty(6), np.empty(6), np.empty(6), np.empty((6, 6)), np.empty(6))
        PCb, Lb = np.empty(6), np.empty(6)
        for v in np.sign(rng.standard_normal(500)):
            ra = kf_update(xa, Pa, m.C, m.G, m.C_pos, v, xf, PC)
            rb = kf_update6(xb, Pb, m.C, m.G, v, PCb)
            assert _same(ra, rb[:4]) and _same(xf[1], rb[4]) and _same(PC, PCb)
            kf_predict(xa, Pa, m.A, m.B, m.F, m.M, 0.0, ra[0], ra[1], PC, L, AP, tmp)
            kf_predict6(xb, Pb, m.A, m.F, m.M, rb[0], rb[1], PCb, Lb)
            assert _same(L, Lb) and _same(xa, xb) and _same(Pa, Pb)


def test_cov_predict6_equal_structured_loop_for_any_covariance():
    """cov_predict6 (the 6-state covariance step on scalars) gives the floats of
    cov_predict_sd, bit for bit, also for a covariance that is not exactly symmetric (it
    reads every entry that loop reads), with exact zeros, and with the gain of a zero
    or negative innovation variance's sign."""
    rng = np.random.default_rng(66)
    for m in _models():
        for trial in range(60):
            P = _spd(rng, 6, 10.0 ** rng.uniform(-8, 2))
            if trial % 3 == 0:
                P = P + rng.standard_normal((6, 6)) * 1e-9  # not symmetric
            if trial % 5 == 0:
                P[rng.integers(6), :] = 0.0
            L = rng.standard_normal(6)
            S = float(rng.uniform(-1.0, 3.0))
            Pa, Pb = P.copy(), P.copy()
            cov_predict_sd(Pa, m.A, m.F, L, S, np.empty((6, 6)))
            cov_predict6(Pb, m.A, m.F, L, S)
            assert _same(Pa, Pb), trial


@pytest.mark.parametrize("n", [6, 7, 8, 9])
def test_structured_covariance_equal_generic(n):
    """predicted_output_sd, predictor_gain_sd and cov_predict_sd on the Jacobian pattern
    of the adaptive observer (n = 7: f0, n = 8: f0 and Q, n = 9: any number of parameter
    states) against the generic loops, on
    covariances with exact zeros (the warm-up's held parameter rows) and random ones."""
    rng = np.random.default_rng(n)
    _, c_stf, c_ntf = _sd_blocks(0.5, 1.247)
    C = np.zeros(n)
    C[2:4] = c_stf
    C[4:6] = c_ntf
    G = 1.0 - 2.0 / np.pi
    for trial in range(40):
        J, F, M = _jacobian(rng, n)
        P = _trial_cov(rng, n, trial)
        xp = rng.standard_normal(n)
        PCa, PCb = np.empty(n), np.empty(n)
        yhat, S = predicted_output(xp, P, C, G, PCa)
        assert _same((yhat, S), predicted_output_sd(xp, P, C, G, PCb))
        assert _same(PCa, PCb)
        La = np.empty(n)  # L = (J P C' + M)/S as the generic loop of the EKF formed it
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += J[i, j] * PCa[j]
            La[i] = (acc + M[i]) / S
        Lb = np.empty(n)
        predictor_gain_sd(J, M, PCa, S, Lb)
        assert _same(La, Lb)
        Pa, Pb = P.copy(), P.copy()
        cov_predict(Pa, J, F, La, S, np.empty((n, n)))
        cov_predict_sd(Pb, J, F, Lb, S, np.empty((n, n)))
        assert _same(Pa, Pb)


@pytest.mark.parametrize(
    "bits, pulses, starts, widths",
    [
        ([1, -1, 0, 2], [0.0] * 4, None, None),
        ([1, -1, 1.0, np.nan], [0.0] * 4, None, None),
        ([1, -1, 1, 1], [0, np.inf, 0, 0], None, None),
        ([1, -1, 1, 1], [0, 1, 0, 0], [0, 2e-6, 0, 0], None),
        ([1, -1, 1, 1], [0, 1, 0, 0], [0, np.nan, 0, 0], None),
        ([1, -1, 1, 1], [0, 0, 0, 0], [0, -np.inf, 0, 0], None),
        ([1, -1, 1, 1], [0, 1, 0, 0], None, [0, 0, 0, 0.0]),
        ([1, -1, 1, 1], [0, 1, 0, 0], [0, -1e-9, 0, 0], [0, 1e-7, 0, 0.0]),
        ([1, -1, 1, 1], [0, 1, 0, 0], [0, 0.5e-6, 0, 0], [0, 1.1e-6, 0, 0.0]),
    ],
)
def test_frame_checks_reject(bits, pulses, starts, widths):
    """The frame checks name the fault as before (bad bit with its index and count,
    non-finite pulses, non-finite or out-of-range timing where a pulse is fired)."""
    with pytest.raises(ValueError) as err:
        b, u = check_bits(np.array(bits), np.array(pulses, dtype=float))
        check_pulse_timing(
            u,
            None if starts is None else np.array(starts),
            None if widths is None else np.array(widths),
            FS,
        )
    msg = str(err.value)
    if any(v not in (1, -1) for v in bits):
        assert "one-bit convention" in msg and "at index" in msg
    elif not np.all(np.isfinite(pulses)):
        assert msg == "pulses must be finite (V)"
    elif starts is not None and not np.all(np.isfinite(starts)):
        assert msg.startswith("pulse starts/widths must be finite")
    else:
        assert msg.startswith("pulse start must be in [0, T)")


def test_frame_checks_accept():
    """Valid frames pass unchanged: float64 contiguous bits, pulses, starts and widths in T
    (strided inputs included); timing outside the window is allowed where no pulse fires."""
    bits = np.array([1, -1, 1, 1, -1, 1], dtype=np.int8)[::2]
    pulses = np.array([0.0, 0.2, -0.3, 0.0, 0.0, 0.0])[::2]
    starts = np.array([5e-6, 0.0, 0.4e-6, 0.0, 0.0, 0.0])[::2]
    b, u = check_bits(bits, pulses)
    s, w = check_pulse_timing(u, starts, None, FS)
    assert b.dtype == u.dtype == s.dtype == w.dtype == np.float64
    assert all(a.flags.c_contiguous for a in (b, u, s, w))
    assert _same(b, [1, 1, -1]) and _same(u, [0.0, -0.3, 0.0]) and _same(w, [1.0, 1.0, 1.0])
    assert _same(s, np.array([5e-6, 0.4e-6, 0.0]) * FS)


@pytest.mark.slow
def test_kernels_equal_old_reference():
    """Device frames and Kalman observer outputs (with their carried states) equal bit for
    bit to the old generic-loop kernels kept in test/resonator_oracles.py, the adaptive
    observer's (analytic f0 Jacobian column against the old central difference) within
    1e-6 of each output's scale with the same monitor resets (one seed, 50,000 samples per
    case)."""
    from resonator_oracles import check_equal

    assert check_equal(seeds=(5,), n=50_000, frame=1000)


# ------------------------------------------------ adaptive observer: analytic f0 Jacobian
def _richardson(fun, f0, h=1e-3):
    """f0 d/df0 of fun by a Richardson-extrapolated central difference (relative steps h and
    h/2; truncation error O(h^4), ~1e-12 here)."""

    def cd(hh):
        return (np.array(fun(f0 * (1 + hh))) - np.array(fun(f0 * (1 - hh)))) / (2 * hh)

    return (4 * cd(h / 2) - cd(h)) / 3


@pytest.mark.parametrize(
    "f0, q, dt",
    [
        (F0, Q, 1 / FS),
        (1.05 * F0, Q, 1 / FS),
        (0.2 * FS, 3.0, 1 / FS),
        (F0, 0.6, 1 / FS),
        (1e3, 1e4, 1 / FS),
        (F0, Q, 0.05 / FS),
        (1.3 * F0, 10.0, 0.97 / FS),
        (F0, Q, 0.0),
    ],
)
def test_zoh_f0_derivative_analytic(f0, q, dt):
    """The adaptive observer's closed-form ZOH with its analytic f0 derivative: the values are
    resonator_zoh_t's bit for bit, the derivative (f0 d/df0 of Phi and Gam, eqs. (7)-(9) of
    Colinet et al.) matches a fine central difference (1e-8 of each block's largest entry,
    in the observer's velocity scaling; the old step-1e-7 difference was ~1e-9)."""
    from mems_estimation.filters.resonator_adaptive_jacobian import _zoh_dlog_t
    from mems_sim.kernels.resonator_models import resonator_zoh_t

    z = _zoh_dlog_t(f0, q, FS, dt)
    assert _same(z[:6], resonator_zoh_t(f0, q, FS, dt))
    w0 = 2 * np.pi * f0
    scale = np.array([1.0, w0, 1.0 / w0, 1.0, 1.0, 1.0 / w0])
    ana = np.array(z[6:]) * scale
    num = _richardson(lambda x: resonator_zoh_t(x, q, FS, dt), f0) * scale
    if dt == 0.0:
        assert np.all(ana == 0.0)
        return
    for blk in (slice(0, 4), slice(4, 6)):
        err = np.abs(ana[blk] - num[blk]).max() / np.abs(num[blk]).max()
        print(f"\nf0 {f0:.0f} Hz, Q {q}, dt {dt * FS:.2f} T: block {blk}: rel. error {err:.1e}")
        assert err <= 1e-8


@pytest.mark.parametrize(
    "spill_u, spill_end, u, s, w",
    [
        (0.0, 0.0, 0.3, 0.0, 1.0),  # one-sample pulse of eq. (8): Gam(T) u
        (0.0, 0.0, 0.3, 0.2, 0.05),  # whole pulse inside the interval
        (0.0, 0.0, -0.3, 0.97, 0.05),  # pulse outlasting the interval
        (0.0, 0.0, 0.3, 1e-9, 0.9),
        (0.2, 0.4, 0.0, 0.0, 0.0),  # previous pulse's tail only
        (0.2, 0.4, 0.3, 0.1, 0.05),
        (-0.2, 0.03, 0.3, 0.0, 1.0),
    ],
)
def test_pulse_f0_derivative_analytic(spill_u, spill_end, u, s, w):
    """The exact sub-sample pulse term as the adaptive observer forms it (_pulse_dlog): its
    value equal bit for bit to interval_input's, its f0 derivative against a fine central
    difference of interval_input itself."""
    from mems_estimation.filters.resonator_adaptive_jacobian import _pulse_dlog, _zoh_dlog_t
    from mems_sim.kernels.resonator_models import interval_input

    def pulse_term(f0, q):
        gam = np.array(_zoh_dlog_t(f0, q, FS, 1 / FS)[4:6])
        out = np.empty(2)
        interval_input(
            f0, q, FS, gam, spill_u, spill_end, u, s, w, out, np.empty(6), np.full(3, -1.0)
        )
        return out

    for f0, q in ((F0, Q), (1.05 * F0, Q), (0.2 * FS, 3.0)):
        z = _zoh_dlog_t(f0, q, FS, 1 / FS)
        got = np.empty(4)
        _pulse_dlog(f0, q, FS, z[4], z[5], z[10], z[11], spill_u, spill_end, u, s, w, got)
        assert _same(got[:2], pulse_term(f0, q))
        num = _richardson(lambda x: pulse_term(x, q), f0)
        w0 = 2 * np.pi * f0
        err = np.abs((got[2:] - num) * [1.0, 1.0 / w0]).max() / np.abs(num * [1.0, 1.0 / w0]).max()
        print(f"\nf0 {f0:.0f} Hz, Q {q}: rel. error {err:.1e}")
        assert err <= 1e-8


@pytest.mark.parametrize("n", [7, 8])
def test_ekf_covariance_prediction_equal_structured(n):
    """The adaptive observer's written-out covariance prediction (_cov_predict_ekf) against
    cov_predict_sd bit for bit (symmetric covariances with exact zeros and random ones)."""
    from mems_estimation.filters.resonator_adaptive_observer import _cov_predict_ekf

    rng = np.random.default_rng(100 + n)
    for trial in range(200):
        J, F, _ = _jacobian(rng, n)
        P = _trial_cov(rng, n, trial)
        L = rng.standard_normal(n)
        S = rng.uniform(0.1, 3.0)
        Pa, Pb = P.copy(), P.copy()
        cov_predict_sd(Pa, J, F, L, S, np.empty((n, n)))
        _cov_predict_ekf(Pb, J, F, L, S)
        assert _same(Pa, Pb)

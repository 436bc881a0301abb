"""Adaptive (joint state-parameter) Kalman observer of the sigma-delta resonator.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using digital
Kalman observer", Sec. 7-8: "a non-linear adaptive Kalman observer: the unknown state
variables are the system coefficients together with the original state variables" (their
announced future work).  This module implements it as an extended Kalman filter (EKF) over
the 6 states of :mod:`mems_sim.kernels.resonator_observer` augmented with

    d = f0/f0_init - 1                  (random walk, std f0_random_walk_ppm*1e-6 per sample)
    r = Q/Q_init - 1   (estimate_q)     (random walk, std q_random_walk_ppm*1e-6 per sample)

The resonator block is re-discretised every sample at the current estimate
(closed-form ZOH, :func:`mems_sim.kernels.resonator_models.resonator_zoh`).  Its Jacobian
column with respect to d is the analytic f0 derivative of that closed form at fixed Q and T
(``_zoh_dlog_t`` of :mod:`mems_estimation.filters.resonator_adaptive_jacobian`: Phi and Gam
differentiated in closed form; agrees with a Richardson-extrapolated central difference
to ~1e-11), computed from the same exp/sin/cos as the transition itself, so one set per
sample instead of the three of a central difference.  The column with respect to r
(estimate_q) is a central difference of the closed form (step 1e-7, relative error ~1e-9).
The modulator part and the noise model
(F, G, M with the cross-covariance of eq. (2)) are those of the linear observer;
the velocity state is scaled by the fixed w_ref = 2 pi f0_init.  By default the
quantiser is linearised statistically (Bussgang gain, see
:func:`mems_sim.kernels.resonator_observer.bussgang_quantizer`): with the paper's
unit-gain model the f0 estimate is biased by ~+100 ppm because the one-bit
error is correlated with the signal (measured; ~+13 ppm on a truly linear
white-noise model of the same loop).

Start-up and steps: the parameters are held for ``warmup_periods`` while the
states converge, and an innovation monitor re-opens the parameter covariance
when the normalised innovation power stays high (a step of f0), see the
constructor arguments.

Why an EKF and not a UKF: the only nonlinearity is the dependence of the
one-sample transition on f0 (and Q), smooth and nearly bilinear over a sample
(the per-sample phase 2 pi f0/fs changes by 5e-4 rad for a 1e-3 error at
f0 = 0.05 fs), and the measurement is linear; the EKF costs one Jacobian column
per parameter, while a UKF would need 2n+1 = 15-17 sigma points, each with its
own exp/sin/cos discretisation, per sample at MHz rates.

Recursion per sample (a-priori form with the cross term, J = df/dX at X(k|k)):

    S = C P C' + G,  nu = v(k) - C Xp,  X(k|k) = Xp + P C'/S nu
    Xp <- f(X(k|k), u(k)) + M nu / S,   L = (J P C' + M)/S,   P <- J P J' + F(k) - L L' S

f includes the exact pulse term of sub-sample pulses (fired at s T, width w T) at the
current f0 estimate, the term of :func:`mems_sim.kernels.resonator_models.interval_input`
(the same floats); it is formed together with its f0 derivative (``_pulse_dlog``, the
product rule on the two sub-sample discretisations of each pulse segment), and its Q
derivative (estimate_q) by the same central difference as the transition's.  The
covariance prediction is :func:`_cov_predict_ekf`, the floats of the structured kernel
:func:`mems_sim.kernels.resonator_kf_steps.cov_predict_sd` written out for n = 7 and 8.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mems_estimation.filters.resonator_adaptive_jacobian import (
    _H,
    _pulse_dlog,
    _pulse_scaled,
    _res_scaled,
    _res_scaled_dlog,
)
from mems_sim.kernels.divergence import covariance_ok, state_ok
from mems_sim.kernels.resonator_kf_steps import (
    head6,
    ntf_entry,
    predicted_output_sd,
    predictor_gain_sd,
    put_sym,
    row6,
    sd_coefficients,
    stf_entry,
)
from mems_sim.kernels.resonator_models import next_spill
from mems_sim.kernels.resonator_observer import KalmanObserver, check_bits, check_pulse_timing
from mems_sim.kernels.resonator_observer_model import (
    BUSSGANG_GAIN,
    BUSSGANG_VAR,
    DEFAULT_QUANTIZATION_VAR,
    _sd_blocks,
)

__all__ = ["AdaptiveObserver"]


@numba.njit(cache=True, inline="always")
def _row_r(b0, b1, b6, b7, q, x0, x1, x6, x7):
    """One entry of a resonator row of J P: b0 x0 + b1 x1 + b6 x6 (+ b7 x7 if q), in that order."""
    s = b0 * x0 + b1 * x1
    s += b6 * x6
    if q:
        s += b7 * x7
    return s


@numba.njit(cache=True, inline="always")
def _acc_r(x0, x1, x6, x7, b0, b1, b6, b7, q):
    """One entry of (J P) J' by a resonator row of J: 0 + x0 b0 + x1 b1 + x6 b6 (+ x7 b7)."""
    acc = 0.0 + x0 * b0 + x1 * b1
    acc += x6 * b6
    if q:
        acc += x7 * b7
    return acc


@numba.njit(cache=True, inline="always")
def _cov_predict_ekf(P, J, F, L, S):
    """Covariance prediction of the EKF, P <- J P J' + F - L L' S in place (Colinet, Galayko
    & Juillard, eq. (2), the predictor form with the cross term; L = (J P C' + M)/S), for
    this observer's Jacobian pattern and n = 7 (d) or 8 (d, r) states.

    The same floating-point operations in the same order as
    :func:`mems_sim.kernels.resonator_kf_steps.cov_predict_sd` (so the same floats, for a
    P that is exactly symmetric, as this recursion keeps it), written out for the two
    sizes: the old P is held in scalars (its upper triangle) instead of the scratch J P
    array with its copied rows, and the loops over the parameter states are unrolled
    (measured: about 2/3 of cov_predict_sd's time inside the kernel).  Units: V^2 for the
    voltage states (the velocity is scaled to V by 1/wref), 1 for the parameters d, r.
    """
    n = P.shape[0]
    q = n == 8
    a00, a01, a10, a11, a22, a23, a44, a45 = sd_coefficients(J)
    j06 = J[0, 6]
    j16 = J[1, 6]
    j07 = J[0, 7] if q else 0.0
    j17 = J[1, 7] if q else 0.0
    # old P, upper triangle
    p00, p01, p02, p03, p04, p05 = row6(P, 0)
    p06 = P[0, 6]
    p11 = P[1, 1]
    p12 = P[1, 2]
    p13 = P[1, 3]
    p14 = P[1, 4]
    p15 = P[1, 5]
    p16 = P[1, 6]
    p22 = P[2, 2]
    p23 = P[2, 3]
    p24 = P[2, 4]
    p25 = P[2, 5]
    p26 = P[2, 6]
    p33 = P[3, 3]
    p34 = P[3, 4]
    p35 = P[3, 5]
    p36 = P[3, 6]
    p44 = P[4, 4]
    p45 = P[4, 5]
    p46 = P[4, 6]
    p55 = P[5, 5]
    p56 = P[5, 6]
    p66 = P[6, 6]
    if q:
        p07 = P[0, 7]
        p17 = P[1, 7]
        p27 = P[2, 7]
        p37 = P[3, 7]
        p47 = P[4, 7]
        p57 = P[5, 7]
        p67 = P[6, 7]
        p77 = P[7, 7]
    else:
        p07 = 0.0
        p17 = 0.0
        p27 = 0.0
        p37 = 0.0
        p47 = 0.0
        p57 = 0.0
        p67 = 0.0
        p77 = 0.0
    # rows of J P that are not copies of rows of P: 0, 1 (resonator), 2 (STF), 4 (NTF)
    u0 = _row_r(a00, a01, j06, j07, q, p00, p01, p06, p07)
    u1 = _row_r(a00, a01, j06, j07, q, p01, p11, p16, p17)
    u2 = _row_r(a00, a01, j06, j07, q, p02, p12, p26, p27)
    u3 = _row_r(a00, a01, j06, j07, q, p03, p13, p36, p37)
    u4 = _row_r(a00, a01, j06, j07, q, p04, p14, p46, p47)
    u5 = _row_r(a00, a01, j06, j07, q, p05, p15, p56, p57)
    u6 = _row_r(a00, a01, j06, j07, q, p06, p16, p66, p67)
    u7 = _row_r(a00, a01, j06, j07, q, p07, p17, p67, p77)
    v0 = _row_r(a10, a11, j16, j17, q, p00, p01, p06, p07)
    v1 = _row_r(a10, a11, j16, j17, q, p01, p11, p16, p17)
    v2 = _row_r(a10, a11, j16, j17, q, p02, p12, p26, p27)
    v3 = _row_r(a10, a11, j16, j17, q, p03, p13, p36, p37)
    v4 = _row_r(a10, a11, j16, j17, q, p04, p14, p46, p47)
    v5 = _row_r(a10, a11, j16, j17, q, p05, p15, p56, p57)
    v6 = _row_r(a10, a11, j16, j17, q, p06, p16, p66, p67)
    v7 = _row_r(a10, a11, j16, j17, q, p07, p17, p67, p77)
    w0 = stf_entry(a22, a23, p00, p02, p03)
    w2 = stf_entry(a22, a23, p02, p22, p23)
    w3 = stf_entry(a22, a23, p03, p23, p33)
    w4 = stf_entry(a22, a23, p04, p24, p34)
    w5 = stf_entry(a22, a23, p05, p25, p35)
    w6 = stf_entry(a22, a23, p06, p26, p36)
    w7 = stf_entry(a22, a23, p07, p27, p37)
    x4 = ntf_entry(a44, a45, p44, p45)
    x5 = ntf_entry(a44, a45, p45, p55)
    x6 = ntf_entry(a44, a45, p46, p56)
    x7 = ntf_entry(a44, a45, p47, p57)
    L0, L1, L2, L3, L4, L5 = head6(L)
    L6 = L[6]
    # (J P) J' + F - L L' S, upper triangle mirrored; resonator rows
    P[0, 0] = _acc_r(u0, u1, u6, u7, a00, a01, j06, j07, q) + F[0, 0] - L0 * L0 * S
    put_sym(P, 0, 1, _acc_r(u0, u1, u6, u7, a10, a11, j16, j17, q) + F[0, 1] - L0 * L1 * S)
    P[1, 1] = _acc_r(v0, v1, v6, v7, a10, a11, j16, j17, q) + F[1, 1] - L1 * L1 * S
    # STF state, J[2] = [1, 0, a22, a23, 0, ...]
    put_sym(P, 0, 2, (0.0 + u0 + u2 * a22 + u3 * a23) + F[0, 2] - L0 * L2 * S)
    put_sym(P, 1, 2, (0.0 + v0 + v2 * a22 + v3 * a23) + F[1, 2] - L1 * L2 * S)
    P[2, 2] = (0.0 + w0 + w2 * a22 + w3 * a23) + F[2, 2] - L2 * L2 * S
    # STF delay, J[3] = e_2; F[:, 3] = 0
    put_sym(P, 0, 3, (0.0 + u2) - L0 * L3 * S)
    put_sym(P, 1, 3, (0.0 + v2) - L1 * L3 * S)
    put_sym(P, 2, 3, (0.0 + w2) - L2 * L3 * S)
    P[3, 3] = (0.0 + p22) - L3 * L3 * S
    # NTF state, J[4] = [0, 0, 0, 0, a44, a45, 0, ...]
    put_sym(P, 0, 4, (0.0 + u4 * a44 + u5 * a45) + F[0, 4] - L0 * L4 * S)
    put_sym(P, 1, 4, (0.0 + v4 * a44 + v5 * a45) + F[1, 4] - L1 * L4 * S)
    put_sym(P, 2, 4, (0.0 + w4 * a44 + w5 * a45) + F[2, 4] - L2 * L4 * S)
    put_sym(P, 3, 4, (0.0 + p24 * a44 + p25 * a45) + F[3, 4] - L3 * L4 * S)
    P[4, 4] = (0.0 + x4 * a44 + x5 * a45) + F[4, 4] - L4 * L4 * S
    # NTF delay, J[5] = e_4; F[:, 5] = 0
    put_sym(P, 0, 5, (0.0 + u4) - L0 * L5 * S)
    put_sym(P, 1, 5, (0.0 + v4) - L1 * L5 * S)
    put_sym(P, 2, 5, (0.0 + w4) - L2 * L5 * S)
    put_sym(P, 3, 5, (0.0 + p24) - L3 * L5 * S)
    put_sym(P, 4, 5, (0.0 + x4) - L4 * L5 * S)
    P[5, 5] = (0.0 + p44) - L5 * L5 * S
    # parameters (random walks), J[j] = e_j
    put_sym(P, 0, 6, (0.0 + u6) + F[0, 6] - L0 * L6 * S)
    put_sym(P, 1, 6, (0.0 + v6) + F[1, 6] - L1 * L6 * S)
    put_sym(P, 2, 6, (0.0 + w6) + F[2, 6] - L2 * L6 * S)
    put_sym(P, 3, 6, (0.0 + p26) + F[3, 6] - L3 * L6 * S)
    put_sym(P, 4, 6, (0.0 + x6) + F[4, 6] - L4 * L6 * S)
    put_sym(P, 5, 6, (0.0 + p46) + F[5, 6] - L5 * L6 * S)
    P[6, 6] = (0.0 + p66) + F[6, 6] - L6 * L6 * S
    if q:
        L7 = L[7]
        put_sym(P, 0, 7, (0.0 + u7) + F[0, 7] - L0 * L7 * S)
        put_sym(P, 1, 7, (0.0 + v7) + F[1, 7] - L1 * L7 * S)
        put_sym(P, 2, 7, (0.0 + w7) + F[2, 7] - L2 * L7 * S)
        put_sym(P, 3, 7, (0.0 + p27) + F[3, 7] - L3 * L7 * S)
        put_sym(P, 4, 7, (0.0 + x7) + F[4, 7] - L4 * L7 * S)
        put_sym(P, 5, 7, (0.0 + p47) + F[5, 7] - L5 * L7 * S)
        put_sym(P, 6, 7, (0.0 + p67) + F[6, 7] - L6 * L7 * S)
        P[7, 7] = (0.0 + p77) + F[7, 7] - L7 * L7 * S


# nogil: in a one-process graph the recorder's writer thread runs meanwhile
@numba.njit(cache=True, nogil=True)
def _ekf_run(
    bits,
    pulses,
    starts,
    widths,
    spill,
    xp,
    P,
    f0i,
    Qi,
    fs,
    wref,
    Asd,
    C,
    G,
    qv,
    sb2,
    sf2,
    rw2,
    rq2,
    est_q,
    k0,
    warm,
    aux,
    alpha,
    thresh,
    reset_var,
    pos,
    pvar,
    f0o,
    f0v,
):
    n = xp.shape[0]
    PC = np.empty(n)
    xf = np.empty(n)
    J = np.zeros((n, n))
    F = np.zeros((n, n))
    Mv = np.zeros(n)
    Mv[4] = qv
    L = np.empty(n)
    r0 = np.empty(6)
    rp = np.empty(6)
    rm = np.empty(6)
    dr = np.empty(6)
    de = np.empty(4)
    z = np.empty(6)
    # constant parts of J
    for i in range(2, 6):
        for j in range(n):
            J[i, j] = 0.0
    J[2, 2] = Asd[0, 0]
    J[2, 3] = Asd[0, 1]
    J[3, 2] = Asd[1, 0]
    J[3, 3] = Asd[1, 1]
    J[4, 4] = Asd[0, 0]
    J[4, 5] = Asd[0, 1]
    J[5, 4] = Asd[1, 0]
    J[5, 5] = Asd[1, 1]
    J[2, 0] = 1.0
    for i in range(6, n):
        J[i, i] = 1.0
    saved = np.zeros(2)
    e0 = np.zeros(2)
    ep = np.zeros(2)
    em = np.zeros(2)
    g = np.empty(5)
    for k in range(bits.shape[0]):
        frozen = k0 + k < warm
        if frozen:
            # warm-up: parameters held (treated as known) while the states converge
            for a in range(6, n):
                saved[a - 6] = P[a, a]
                for j in range(n):
                    P[a, j] = 0.0
                    P[j, a] = 0.0
        # ---- update
        yhat, S = predicted_output_sd(xp, P, C, G, PC)
        nu = bits[k] - yhat
        # innovation monitor: exponential mean of nu^2/S; a jump of f0 (or Q) shows up as
        # a sustained excess -> re-open the parameter covariance (once per window)
        aux[0] += alpha * (nu * nu / S - aux[0])
        if aux[1] > 0.0:
            aux[1] -= 1.0
        elif thresh > 0.0 and not frozen and aux[0] > thresh:
            for a in range(6, n):
                if P[a, a] < reset_var[a - 6]:
                    P[a, a] = reset_var[a - 6]
            aux[0] = 1.0
            aux[1] = 1.0 / alpha
            aux[2] += 1.0
            _, S = predicted_output_sd(xp, P, C, G, PC)
        for i in range(n):
            xf[i] = xp[i] + PC[i] / S * nu
        pos[k] = xf[0]
        pvar[k] = P[0, 0] - PC[0] * PC[0] / S
        f0o[k] = f0i * (1.0 + xf[6])
        f0v[k] = f0i * f0i * (P[6, 6] - PC[6] * PC[6] / S)
        # ---- Jacobian and mean at X(k|k)
        d = xf[6]
        r = xf[7] if est_q else 0.0
        f0 = f0i * (1.0 + d)
        Qc = Qi * (1.0 + r)
        if f0 <= 0.0:
            f0 = 1e-6 * f0i
        if f0 >= 0.5 * fs:
            f0 = 0.4999 * fs
        if Qc <= 0.5:
            Qc = 0.5000001
        u = pulses[k]
        pulse = u != 0.0 or spill[0] != 0.0
        if not pulse:
            for i in range(2):
                e0[i] = 0.0
                ep[i] = 0.0
                em[i] = 0.0
        # transition at f0 and f0 d/df0 of it (analytic: one exp/sin/cos set); the
        # Jacobian column of d is f0_init d/df0 = (f0_init/f0) f0 d/df0
        _res_scaled_dlog(f0, Qc, fs, wref, r0, dr)
        y0 = xf[0]
        y1 = xf[1]
        j0 = dr[0] * y0 + dr[1] * y1
        j1 = dr[2] * y0 + dr[3] * y1
        if pulse:
            # pulse term (interval_input's floats) and f0 d/df0 of it, one pass
            _pulse_dlog(
                f0,
                Qc,
                fs,
                r0[4],
                r0[5] * wref,
                dr[4],
                dr[5] * wref,
                spill[0],
                spill[1],
                u,
                starts[k],
                widths[k],
                de,
            )
            e0[0] = de[0]
            e0[1] = de[1] / wref
            j0 += de[2]
            j1 += de[3] / wref
        m = f0i / f0
        J[0, 6] = m * j0
        J[1, 6] = m * j1
        if est_q:
            _res_scaled(f0, Qc + Qi * _H, fs, wref, rp)
            if pulse:
                _pulse_scaled(
                    f0, Qc + Qi * _H, fs, wref, rp, spill, u, starts[k], widths[k], ep, z, g
                )
            _res_scaled(f0, Qc - Qi * _H, fs, wref, rm)
            if pulse:
                _pulse_scaled(
                    f0, Qc - Qi * _H, fs, wref, rm, spill, u, starts[k], widths[k], em, z, g
                )
            J[0, 7] = ((rp[0] - rm[0]) * y0 + (rp[1] - rm[1]) * y1 + (ep[0] - em[0])) / (2 * _H)
            J[1, 7] = ((rp[2] - rm[2]) * y0 + (rp[3] - rm[3]) * y1 + (ep[1] - em[1])) / (2 * _H)
        if pulse:
            next_spill(u, starts[k], widths[k], spill)
        J[0, 0] = r0[0]
        J[0, 1] = r0[1]
        J[1, 0] = r0[2]
        J[1, 1] = r0[3]
        # process covariance F(k)
        F[0, 0] = r0[4] * r0[4] * sf2
        F[0, 1] = r0[4] * r0[5] * sf2
        F[1, 0] = F[0, 1]
        F[1, 1] = r0[5] * r0[5] * sf2
        F[2, 2] = sb2
        F[4, 4] = qv
        F[6, 6] = rw2
        if est_q:
            F[7, 7] = rq2
        # ---- mean prediction
        xp[0] = r0[0] * y0 + r0[1] * y1 + e0[0]
        xp[1] = r0[2] * y0 + r0[3] * y1 + e0[1]
        t2 = xf[2]
        t4 = xf[4]
        xp[2] = Asd[0, 0] * t2 + Asd[0, 1] * xf[3] + y0
        xp[3] = t2
        xp[4] = Asd[0, 0] * t4 + Asd[0, 1] * xf[5] + qv * nu / S
        xp[5] = t4
        for i in range(6, n):
            xp[i] = xf[i]
        # ---- covariance prediction (predictor form with the cross term; J has the
        # pattern of the 6-state model's A plus the parameter columns J[0:2, 6:] and the
        # random-walk rows, which the structured kernels use)
        predictor_gain_sd(J, Mv, PC, S, L)
        _cov_predict_ekf(P, J, F, L, S)
        if frozen:
            for a in range(6, n):
                for j in range(n):
                    P[a, j] = 0.0
                    P[j, a] = 0.0
                P[a, a] = saved[a - 6]


class AdaptiveObserver:
    """EKF over [resonator (2), STF (2), NTF (2), d = f0/f0_init - 1 (, r = Q/Q_init - 1)].

    Args:
        f0_init: initial f0 estimate, Hz (0 < f0_init < fs/2).
        Q: quality factor (initial value when estimate_q), > 0.5.
        fs: sample rate, Hz.
        output_noise_std: std of b at the modulator input, V.
        state_noise_std: thermomechanical force-noise std (per sample, on u), V.
        f0_random_walk_ppm: std of the per-sample random walk of f0, ppm of f0_init.
        estimate_q: also estimate Q (8th state).
        f0_init_std: initial std of f0/f0_init - 1 (fraction).
        q_init_std: initial std of Q/Q_init - 1 (fraction), estimate_q only.
        q_random_walk_ppm: per-sample random walk std of Q, ppm of Q_init.
        sd_feedforward: modulator STF feed-in c (0.5: eq. (11)).
        quantizer_gain: kappa of the quantiser model v = kappa q + w.  Default: the
            Bussgang gain sqrt(2/pi)/0.64 = 1.247 (comparator-input std 0.64 V measured in
            the non-overloaded loops); 1 is the paper's unit-gain model, which leaves a
            steady f0 bias of ~+70..125 ppm (the quantisation error is correlated with the
            signal).
        quantization_var: variance of w, V^2 (None: 1 - 2/pi = 0.363 for the Bussgang
            model, 1/3 for quantizer_gain = 1).
        initial_position_std: initial std of the resonator position/velocity states, V.
        warmup_periods: the parameters are held (not updated) for this many periods of
            f0_init at the start, while the state estimate converges; adapting them from
            an unconverged state makes the EKF jump by several % (measured).
        reset_threshold: innovation monitor: when the exponential mean (time constant
            reset_window_periods periods) of nu^2/S exceeds this, the parameter variances
            are raised to reset_std^2 (fraction^2) so that a step of f0 is re-acquired in
            a few hundred periods instead of the random walk's ~10^4; 0 disables it.
        reset_window_periods: time constant of the monitor, periods of f0_init.
        reset_std: parameter std (fraction) after a reset.
    """

    def __init__(
        self,
        f0_init: float,
        Q: float,
        fs: float,
        output_noise_std: float,
        state_noise_std: float,
        f0_random_walk_ppm: float = 0.2,
        estimate_q: bool = False,
        *,
        f0_init_std: float = 0.05,
        q_init_std: float = 0.1,
        q_random_walk_ppm: float = 0.0,
        quantization_var: float | None = None,
        sd_feedforward: float = 0.5,
        quantizer_gain: float = BUSSGANG_GAIN,
        initial_position_std: float = 1.0,
        warmup_periods: float = 50.0,
        reset_threshold: float = 1.5,
        reset_window_periods: float = 20.0,
        reset_std: float = 0.01,
    ) -> None:
        if not (fs > 0 and 0 < f0_init < fs / 2 and Q > 0.5):
            raise ValueError(
                f"need fs > 0, 0 < f0_init < fs/2 and Q > 0.5; got fs = {fs!r} Hz, "
                f"f0_init = {f0_init!r} Hz, Q = {Q!r}"
            )
        for name, val in (
            ("output_noise_std", output_noise_std),
            ("state_noise_std", state_noise_std),
            ("f0_random_walk_ppm", f0_random_walk_ppm),
            ("q_random_walk_ppm", q_random_walk_ppm),
            ("f0_init_std", f0_init_std),
            ("q_init_std", q_init_std),
        ):
            if not (val >= 0 and math.isfinite(val)):
                raise ValueError(f"{name} = {val!r} must be finite and >= 0")
        self.f0_init, self.Q, self.fs = float(f0_init), float(Q), float(fs)
        self.estimate_q = bool(estimate_q)
        if quantization_var is None:
            quantization_var = DEFAULT_QUANTIZATION_VAR if quantizer_gain == 1.0 else BUSSGANG_VAR
        self.qv = float(quantization_var)
        self.wref = 2.0 * math.pi * self.f0_init
        Ad, c_stf, c_ntf = _sd_blocks(sd_feedforward, quantizer_gain)
        self.Asd = np.ascontiguousarray(Ad)
        n = 8 if self.estimate_q else 7
        self.C = np.zeros(n)
        self.C[2:4] = c_stf
        self.C[4:6] = c_ntf
        self.x = np.zeros(n)
        self.P = np.zeros((n, n))
        self.P[0, 0] = self.P[1, 1] = initial_position_std**2
        for i in range(2, 6):
            self.P[i, i] = 1.0  # modulator states unknown (may join a running stream)
        self.P[6, 6] = f0_init_std**2
        if self.estimate_q:
            self.P[7, 7] = q_init_std**2
        self.sb2 = float(output_noise_std) ** 2
        self.sf2 = float(state_noise_std) ** 2
        self.rw2 = (f0_random_walk_ppm * 1e-6) ** 2
        self.rq2 = (q_random_walk_ppm * 1e-6) ** 2
        self.warm = int(round(warmup_periods * self.fs / self.f0_init))
        self._warm_end = self.warm  # sample index until which the parameters are held
        self.alpha = 1.0 / max(1.0, reset_window_periods * self.fs / self.f0_init)
        self.thresh = float(reset_threshold)
        self.reset_var = np.full(2, float(reset_std) ** 2)
        self._aux = np.array([1.0, 0.0, 0.0])
        self._spill = np.zeros(2)  # tail of a pulse outlasting its sample interval
        self.next_index = 0
        self.x0 = self.x.copy()
        self.P0 = self.P.copy()
        self.divergence_resets = 0

    def reset(self) -> None:
        """Re-initialise from the prior: state (f0 = f0_init) and covariance of the
        constructor, innovation monitor and pulse tail cleared; the parameters are held
        again for the warm-up (the sample count goes on)."""
        self._warm_end = self.next_index + self.warm
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        self._aux = np.array([1.0, 0.0, self._aux[2]])
        self._spill = np.zeros(2)
        self.divergence_resets += 1

    def diverged(self) -> bool:
        """True if the state is not finite, a voltage state is beyond
        :attr:`KalmanObserver.STATE_LIMIT`, the covariance is not positive definite
        (:func:`~mems_sim.kernels.divergence.covariance_ok`) or f0 is not inside (0, fs/2)."""
        f0 = self.f0_init * (1.0 + self.x[6])
        return not (
            state_ok(self.x, self._spill, self._aux)
            and float(np.max(np.abs(self.x[:6]))) <= KalmanObserver.STATE_LIMIT
            and covariance_ok(self.P)
            and 0.0 < f0 < self.fs / 2
        )

    @property
    def resets(self) -> int:
        """Number of parameter-covariance resets by the innovation monitor so far."""
        return int(self._aux[2])

    @property
    def f0(self) -> float:
        """Current (a-priori) f0 estimate, Hz."""
        return self.f0_init * (1.0 + self.x[6])

    @property
    def quality_factor(self) -> float:
        """Current Q estimate (the fixed Q unless estimate_q)."""
        return self.Q * (1.0 + self.x[7]) if self.estimate_q else self.Q

    def step(self, bits, pulses, starts=None, widths=None):
        """Process n samples.

        Args:
            bits: (n,) +1/-1 bit stream. pulses: (n,) heights of the pulses fired in
            [k T, (k+1) T), V.  starts, widths: (n,) their firing offsets and widths, s
            (None: 0 and T, the one-sample ZOH pulses of eq. (8)); the pulse term is exact
            at the current f0 estimate (:func:`mems_sim.kernels.resonator_models.interval_input`).
        Returns:
            (position (n,) V, position variance (n,) V^2, f0 (n,) Hz, f0 variance (n,) Hz^2),
            all a-posteriori at k.
        Raises:
            ValueError: bits not in {+1, -1} (message names the convention) or bad shape.
        """
        b, u = check_bits(bits, pulses)
        s, w = check_pulse_timing(u, starts, widths, self.fs)
        n = b.shape[0]
        pos, pv, f0, f0v = (np.empty(n) for _ in range(4))
        _ekf_run(
            b,
            u,
            s,
            w,
            self._spill,
            self.x,
            self.P,
            self.f0_init,
            self.Q,
            self.fs,
            self.wref,
            self.Asd,
            self.C,
            self.qv,
            self.qv,
            self.sb2,
            self.sf2,
            self.rw2,
            self.rq2,
            self.estimate_q,
            self.next_index,
            self._warm_end,
            self._aux,
            self.alpha,
            self.thresh,
            self.reset_var,
            pos,
            pv,
            f0,
            f0v,
        )
        self.next_index += n
        return pos, pv, f0, f0v

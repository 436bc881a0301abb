"""Per-sample Kalman steps of the resonator's sigma-delta observer (numba kernels).

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using digital
Kalman observer", eq. (2) with the joint covariance M of process and measurement noise; the
model is :mod:`mems_sim.kernels.resonator_observer_model`, docs/resonator.md.  Recursion
(predictor form with the cross term, per sample k):

    S = C P C^T + G,  nu = v(k) - C Xp
    X(k|k) = Xp + P C^T / S nu,          P(k|k) = P - P C^T C P / S
    L = (A P C^T + M) / S
    Xp <- A Xp + B u(k) + L nu,          P <- A P A^T + F - L L^T S

with B u(k) generalised to the exact term of sub-sample pulses (height u, fired at s T,
width w T; :func:`mems_sim.kernels.resonator_models.interval_input`), the same function the
device uses (:func:`add_pulse_input`).  Generic n x n loops first, then the structured
kernels of the 6-state model (and the adaptive observer's Jacobian), equal bit for bit.
"""

from __future__ import annotations

import numba

from mems_sim.kernels.resonator_models import interval_input, next_spill

__all__ = [
    "add_pulse_input",
    "predicted_output",
    "state_predict",
    "kf_update",
    "kf_predict",
    "cov_predict",
    "predicted_output_sd",
    "kf_update6",
    "predictor_gain_sd",
    "kf_predict6",
    "cov_predict_sd",
    "cov_predict6",
    "sd_coefficients",
    "head6",
    "row6",
    "stf_entry",
    "ntf_entry",
    "put_sym",
    "ss_step",
    "ss_step6",
]


@numba.njit(cache=True)
def add_pulse_input(xp, f0, Q, fs, w0s, gam, spill, u, s, w, eff, z, wc):
    """Add the exact sub-sample pulse term to the predicted resonator states, in place.

    xp[0:2] += [e0, e1/w0s] with e = :func:`mems_sim.kernels.resonator_models.interval_input` (the
    tail of the previous pulse carried in ``spill`` plus the pulse u fired at s T,
    width w T); ``spill`` is then advanced.  w0s: velocity scale of the state, rad/s.
    wc: (3,) width cache of ``interval_input`` (wc[0] = -1 initially).
    """
    if u == 0.0 and spill[0] == 0.0:
        return
    interval_input(f0, Q, fs, gam, spill[0], spill[1], u, s, w, eff, z, wc)
    xp[0] += eff[0]
    xp[1] += eff[1] / w0s
    next_spill(u, s, w, spill)


@numba.njit(cache=True)
def predicted_output(xp, P, C, G, PC):
    """Predicted bit yhat = C X(k|k-1) and innovation variance S = C P C' + G; fills PC = P C'."""
    n = xp.shape[0]
    S = G
    yhat = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * C[j]
        PC[i] = acc
        yhat += C[i] * xp[i]
    for i in range(n):
        S += C[i] * PC[i]
    return yhat, S


@numba.njit(cache=True)
def state_predict(xp, A, B, L, u, nu, tmp):
    """Predictor-form state update in place: X <- A X + B u + L nu (tmp is scratch (n,))."""
    n = xp.shape[0]
    for i in range(n):
        acc = B[i] * u + L[i] * nu
        for j in range(n):
            acc += A[i, j] * xp[j]
        tmp[i] = acc
    for i in range(n):
        xp[i] = tmp[i]


@numba.njit(cache=True)
def kf_update(xp, P, C, G, Cp, v, xf, PC):
    """Measurement update at k; fills xf = X(k|k), PC = P C^T; returns (nu, S, pos, pos_var)."""
    n = xp.shape[0]
    yhat, S = predicted_output(xp, P, C, G, PC)
    nu = v - yhat
    pos = 0.0
    cpc = 0.0
    cpp = 0.0
    for i in range(n):
        xf[i] = xp[i] + PC[i] / S * nu
        pos += Cp[i] * xf[i]
        cpc += Cp[i] * PC[i]
        for j in range(n):
            cpp += Cp[i] * P[i, j] * Cp[j]
    return nu, S, pos, cpp - cpc * cpc / S


@numba.njit(cache=True)
def kf_predict(xp, P, A, B, F, M, u, nu, S, PC, L, AP, tmp):
    """Time update with the cross term: Xp <- A Xp + B u + L nu, P <- A P A' + F - L L' S."""
    n = xp.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * PC[j]
        L[i] = (acc + M[i]) / S
    state_predict(xp, A, B, L, u, nu, tmp)
    cov_predict(P, A, F, L, S, AP)


@numba.njit(cache=True)
def cov_predict(P, A, F, L, S, AP):
    """Covariance time update with the process/measurement cross term, in place:
    P <- A P A' + F - L L' S (predictor form of the Kalman filter with correlated noises,
    Colinet et al. eq. 2 with joint covariance M; L = (A P C' + M)/S). AP is scratch (n, n)."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for m in range(n):
                acc += A[i, m] * P[m, j]
            AP[i, j] = acc
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for m in range(n):
                acc += AP[i, m] * A[j, m]
            val = acc + F[i, j] - L[i] * L[j] * S
            P[i, j] = val
            P[j, i] = val


# ------------------------------------------------- structured kernels (6-state model, EKF)
# The matrices of eq. (2) for the model of eq. (13), and the Jacobian of the adaptive
# observer (:mod:`mems_estimation.filters.resonator_adaptive_observer`, states 6.. its
# parameters), have a fixed pattern of exact zeros and ones:
#
#   rows 0-1  resonator:   A[r, 0], A[r, 1] (Phi_s) and the parameter columns A[r, 6:]
#   row 2     STF state:   A[2, 0] = 1 (input y), A[2, 2], A[2, 3]   (Ad row 0)
#   row 3     STF delay:   A[3, 2] = 1
#   row 4     NTF state:   A[4, 4], A[4, 5]                          (Ad row 0)
#   row 5     NTF delay:   A[5, 4] = 1
#   rows 6..  parameters:  A[a, a] = 1 (random walks)
#   C non-zero on states 2-5 only, M on state 4 only, C_pos = [1, 0, ...];
#   F zero outside F[0:2, 0:2], F[2, 2], F[4, 4] and F[a, a], a >= 6; B >= 0.
#
# The kernels below are the generic loops above (:func:`predicted_output`, :func:`kf_update`,
# :func:`kf_predict`, :func:`cov_predict`) without the terms these zeros contribute and with
# the unit products written as the factor itself.  The remaining terms are added in the
# generic loops' order from the same initial value (+0.0, or G): a sum started at +0.0 is
# never -0.0 (round to nearest), so adding an omitted term, an exact +-0 for finite operands,
# leaves it unchanged, and 1.0 * x == x.  The results are therefore equal bit for bit to
# the generic loops' for finite values (the core tests of these kernels check it; once a
# filter has diverged to inf/NaN the non-finite values may differ).  A P, an intermediate,
# is formed without the leading +0.0: it differs at most in the sign of a zero, which the
# sums of (A P) A' (started at +0.0) do not see.  They are inlined into the per-sample
# loops (a call with array arguments costs more than the arithmetic).  Numba invalidates a
# cached kernel only when the text of its own source file changes, not when a function it
# inlines or calls from another file does: after editing these, clear the cached kernels
# of mems_sim/kernels/resonator_observer.py, resonator_observer_model.py,
# mems_sim/devices/resonator.py and mems_estimation/filters/resonator_adaptive_observer.py
# (their files under NUMBA_CACHE_DIR), or the old code stays in use.


@numba.njit(cache=True, inline="always")
def sd_coefficients(A):
    """The free entries of the structured A (or the adaptive observer's Jacobian J) in the
    pattern above: (a00, a01, a10, a11, a22, a23, a44, a45) = Phi_s, STF row, NTF row."""
    return A[0, 0], A[0, 1], A[1, 0], A[1, 1], A[2, 2], A[2, 3], A[4, 4], A[4, 5]


@numba.njit(cache=True, inline="always")
def head6(v):
    """(v[0], ..., v[5]): the six model states of a vector held in scalars (the kernels
    below read them before writing the array, so the compiler need not reload them)."""
    return v[0], v[1], v[2], v[3], v[4], v[5]


@numba.njit(cache=True, inline="always")
def row6(P, i):
    """(P[i, 0], ..., P[i, 5]): the model-state entries of row i of a covariance, in scalars."""
    return P[i, 0], P[i, 1], P[i, 2], P[i, 3], P[i, 4], P[i, 5]


@numba.njit(cache=True, inline="always")
def stf_entry(a22, a23, p0, p2, p3):
    """One entry of the STF row of A P, A[2] = [1, 0, a22, a23, 0, ...]: p0 + a22 p2 + a23 p3
    (p0, p2, p3 the entries of rows 0, 2, 3 of P in one column)."""
    return p0 + a22 * p2 + a23 * p3


@numba.njit(cache=True, inline="always")
def ntf_entry(a44, a45, p4, p5):
    """One entry of the NTF row of A P, A[4] = [0, 0, 0, 0, a44, a45, 0, ...]: a44 p4 + a45 p5."""
    return a44 * p4 + a45 * p5


@numba.njit(cache=True, inline="always")
def put_sym(P, i, j, val):
    """P[i, j] = P[j, i] = val (a symmetric covariance entry, units of P)."""
    P[i, j] = val
    P[j, i] = val


@numba.njit(cache=True, inline="always")
def predicted_output_sd(xp, P, C, G, PC):
    """:func:`predicted_output` for C non-zero on the modulator states 2-5 only (any number
    of states >= 6): yhat = C X(k|k-1), S = C P C' + G (eq. (2)); fills PC = P C'."""
    c2 = C[2]
    c3 = C[3]
    c4 = C[4]
    c5 = C[5]
    for i in range(xp.shape[0]):
        PC[i] = 0.0 + P[i, 2] * c2 + P[i, 3] * c3 + P[i, 4] * c4 + P[i, 5] * c5
    yhat = 0.0 + c2 * xp[2] + c3 * xp[3] + c4 * xp[4] + c5 * xp[5]
    S = G + c2 * PC[2] + c3 * PC[3] + c4 * PC[4] + c5 * PC[5]
    return yhat, S


@numba.njit(cache=True, inline="always")
def kf_update6(xp, P, C, G, v, PC):
    """:func:`kf_update` for the 6-state model (C_pos = [1, 0, 0, 0, 0, 0]): measurement
    update at k, X(k|k) = Xp + P C'/S nu; fills PC = P C'.

    Returns:
        (nu, S, position y(k|k), its variance C_pos P(k|k) C_pos', X(k|k)[1] the scaled
        velocity).
    """
    yhat, S = predicted_output_sd(xp, P, C, G, PC)
    nu = v - yhat
    xf0 = xp[0] + PC[0] / S * nu
    xf1 = xp[1] + PC[1] / S * nu
    cpc = 0.0 + PC[0]
    return nu, S, 0.0 + xf0, (0.0 + P[0, 0]) - cpc * cpc / S, xf1


@numba.njit(cache=True, inline="always")
def predictor_gain_sd(A, M, PC, S, L):
    """Predictor gain L = (A P C' + M)/S of the cross-term filter (Colinet et al. eq. (2))
    for the structured A (any number of states >= 6; M non-zero on state 4 only);
    PC = P C'."""
    pc0 = PC[0]
    pc1 = PC[1]
    pc2 = PC[2]
    pc4 = PC[4]
    n = PC.shape[0]
    s0 = 0.0 + A[0, 0] * pc0 + A[0, 1] * pc1
    s1 = 0.0 + A[1, 0] * pc0 + A[1, 1] * pc1
    for a in range(6, n):
        s0 += A[0, a] * PC[a]
        s1 += A[1, a] * PC[a]
    L[0] = s0 / S
    L[1] = s1 / S
    L[2] = (0.0 + pc0 + A[2, 2] * pc2 + A[2, 3] * PC[3]) / S
    L[3] = (0.0 + pc2) / S
    L[4] = (0.0 + A[4, 4] * pc4 + A[4, 5] * PC[5] + M[4]) / S
    L[5] = (0.0 + pc4) / S
    for a in range(6, n):
        L[a] = (0.0 + PC[a]) / S


@numba.njit(cache=True, inline="always")
def kf_predict6(xp, P, A, F, M, nu, S, PC, L):
    """:func:`kf_predict` for the 6-state model with u = 0 (the pulses enter through
    :func:`add_pulse_input`; B >= 0, so B u = +0): Xp <- A Xp + L nu,
    P <- A P A' + F - L L' S (Colinet et al. eq. (2) with the cross term M,
    L = (A P C' + M)/S; :func:`cov_predict6`).  L (6,) is scratch."""
    predictor_gain_sd(A, M, PC, S, L)
    x0, x1, x2, x3, x4, x5 = head6(xp)
    xp[0] = 0.0 + L[0] * nu + A[0, 0] * x0 + A[0, 1] * x1
    xp[1] = 0.0 + L[1] * nu + A[1, 0] * x0 + A[1, 1] * x1
    xp[2] = 0.0 + L[2] * nu + x0 + A[2, 2] * x2 + A[2, 3] * x3
    xp[3] = 0.0 + L[3] * nu + x2
    xp[4] = 0.0 + L[4] * nu + A[4, 4] * x4 + A[4, 5] * x5
    xp[5] = 0.0 + L[5] * nu + x4
    cov_predict6(P, A, F, L, S)


@numba.njit(cache=True, inline="always")
def cov_predict_sd(P, A, F, L, S, AP):
    """:func:`cov_predict` for the structured A: the 6-state model (n = 6) or the adaptive
    observer's Jacobian with its parameter states 6.. (f0, Q): P <- A P A' + F - L L' S in
    place (Colinet et al. eq. (2) with the cross term; L = (A P C' + M)/S).  AP (n, n) is
    scratch."""
    n = P.shape[0]
    a00, a01, a10, a11, a22, a23, a44, a45 = sd_coefficients(A)
    # A P; rows 3, 5 and 6.. of A pick rows 2, 4 and 6.. of P
    for m in range(n):
        p0 = P[0, m]
        p1 = P[1, m]
        p2 = P[2, m]
        p4 = P[4, m]
        s0 = a00 * p0 + a01 * p1
        s1 = a10 * p0 + a11 * p1
        for a in range(6, n):
            s0 += A[0, a] * P[a, m]
            s1 += A[1, a] * P[a, m]
        AP[0, m] = s0
        AP[1, m] = s1
        AP[2, m] = stf_entry(a22, a23, p0, p2, P[3, m])
        AP[3, m] = p2
        AP[4, m] = ntf_entry(a44, a45, p4, P[5, m])
        AP[5, m] = p4
        for a in range(6, n):
            AP[a, m] = P[a, m]
    # (A P) A' + F - L L' S: upper triangle (i <= j) by the rows j of A, mirrored
    for j in range(2):  # resonator rows (and their parameter columns)
        aj0 = A[j, 0]
        aj1 = A[j, 1]
        for i in range(j + 1):
            acc = 0.0 + AP[i, 0] * aj0 + AP[i, 1] * aj1
            for a in range(6, n):
                acc += AP[i, a] * A[j, a]
            val = acc + F[i, j] - L[i] * L[j] * S
            put_sym(P, i, j, val)
    for i in range(3):  # STF state, A[2] = [1, 0, a22, a23, 0, ...]
        val = (0.0 + AP[i, 0] + AP[i, 2] * a22 + AP[i, 3] * a23) + F[i, 2] - L[i] * L[2] * S
        put_sym(P, i, 2, val)
    for i in range(4):  # STF delay, A[3] = e_2; F[:, 3] = 0
        val = (0.0 + AP[i, 2]) - L[i] * L[3] * S
        put_sym(P, i, 3, val)
    for i in range(5):  # NTF state, A[4] = [0, 0, 0, 0, a44, a45, 0, ...]
        val = (0.0 + AP[i, 4] * a44 + AP[i, 5] * a45) + F[i, 4] - L[i] * L[4] * S
        put_sym(P, i, 4, val)
    for i in range(6):  # NTF delay, A[5] = e_4; F[:, 5] = 0
        val = (0.0 + AP[i, 4]) - L[i] * L[5] * S
        put_sym(P, i, 5, val)
    for j in range(6, n):  # parameters (random walks), A[j] = e_j
        for i in range(j + 1):
            val = (0.0 + AP[i, j]) + F[i, j] - L[i] * L[j] * S
            put_sym(P, i, j, val)


@numba.njit(cache=True, inline="always")
def cov_predict6(P, A, F, L, S):
    """:func:`cov_predict_sd` for the 6-state model (n = 6): P <- A P A' + F - L L' S in
    place (Colinet et al. eq. (2) with the cross term; L = (A P C' + M)/S), units V^2 (the
    velocity scaled to V).

    The same floating-point operations in the same order as :func:`cov_predict_sd`, so the
    same floats for any P (symmetric or not): the entries of the old P that the result
    depends on are held in scalars (``p<row><column>``), and so are the entries of A P
    that it uses (``u``, ``v``, ``w``, ``x``: rows 0, 1, 2 and 4; rows 3 and 5 of A P are
    rows 2 and 4 of P), instead of the scratch array that the compiler had to store and
    reload around every write of P.
    """
    a00, a01, a10, a11, a22, a23, a44, a45 = sd_coefficients(A)
    p00, p01, p02, p03, p04, p05 = row6(P, 0)
    p10, p11, p12, p13, p14, p15 = row6(P, 1)
    p20 = P[2, 0]
    p22 = P[2, 2]
    p23 = P[2, 3]
    p24 = P[2, 4]
    p25 = P[2, 5]
    p30 = P[3, 0]
    p32 = P[3, 2]
    p33 = P[3, 3]
    p34 = P[3, 4]
    p35 = P[3, 5]
    p44 = P[4, 4]
    p45 = P[4, 5]
    p54 = P[5, 4]
    p55 = P[5, 5]
    # rows of A P that are not copies of rows of P (those entries only that the
    # products below use)
    u0 = a00 * p00 + a01 * p10
    u1 = a00 * p01 + a01 * p11
    u2 = a00 * p02 + a01 * p12
    u3 = a00 * p03 + a01 * p13
    u4 = a00 * p04 + a01 * p14
    u5 = a00 * p05 + a01 * p15
    v0 = a10 * p00 + a11 * p10
    v1 = a10 * p01 + a11 * p11
    v2 = a10 * p02 + a11 * p12
    v3 = a10 * p03 + a11 * p13
    v4 = a10 * p04 + a11 * p14
    v5 = a10 * p05 + a11 * p15
    w0 = stf_entry(a22, a23, p00, p20, p30)
    w2 = stf_entry(a22, a23, p02, p22, p32)
    w3 = stf_entry(a22, a23, p03, p23, p33)
    w4 = stf_entry(a22, a23, p04, p24, p34)
    w5 = stf_entry(a22, a23, p05, p25, p35)
    x4 = ntf_entry(a44, a45, p44, p54)
    x5 = ntf_entry(a44, a45, p45, p55)
    L0, L1, L2, L3, L4, L5 = head6(L)
    # (A P) A' + F - L L' S, upper triangle mirrored
    put_sym(P, 0, 0, (0.0 + u0 * a00 + u1 * a01) + F[0, 0] - L0 * L0 * S)
    put_sym(P, 0, 1, (0.0 + u0 * a10 + u1 * a11) + F[0, 1] - L0 * L1 * S)
    put_sym(P, 1, 1, (0.0 + v0 * a10 + v1 * a11) + F[1, 1] - L1 * L1 * S)
    put_sym(P, 0, 2, (0.0 + u0 + u2 * a22 + u3 * a23) + F[0, 2] - L0 * L2 * S)
    put_sym(P, 1, 2, (0.0 + v0 + v2 * a22 + v3 * a23) + F[1, 2] - L1 * L2 * S)
    put_sym(P, 2, 2, (0.0 + w0 + w2 * a22 + w3 * a23) + F[2, 2] - L2 * L2 * S)
    put_sym(P, 0, 3, (0.0 + u2) - L0 * L3 * S)
    put_sym(P, 1, 3, (0.0 + v2) - L1 * L3 * S)
    put_sym(P, 2, 3, (0.0 + w2) - L2 * L3 * S)
    put_sym(P, 3, 3, (0.0 + p22) - L3 * L3 * S)
    put_sym(P, 0, 4, (0.0 + u4 * a44 + u5 * a45) + F[0, 4] - L0 * L4 * S)
    put_sym(P, 1, 4, (0.0 + v4 * a44 + v5 * a45) + F[1, 4] - L1 * L4 * S)
    put_sym(P, 2, 4, (0.0 + w4 * a44 + w5 * a45) + F[2, 4] - L2 * L4 * S)
    put_sym(P, 3, 4, (0.0 + p24 * a44 + p25 * a45) + F[3, 4] - L3 * L4 * S)
    put_sym(P, 4, 4, (0.0 + x4 * a44 + x5 * a45) + F[4, 4] - L4 * L4 * S)
    put_sym(P, 0, 5, (0.0 + u4) - L0 * L5 * S)
    put_sym(P, 1, 5, (0.0 + v4) - L1 * L5 * S)
    put_sym(P, 2, 5, (0.0 + w4) - L2 * L5 * S)
    put_sym(P, 3, 5, (0.0 + p24) - L3 * L5 * S)
    put_sym(P, 4, 5, (0.0 + x4) - L4 * L5 * S)
    put_sym(P, 5, 5, (0.0 + p44) - L5 * L5 * S)


@numba.njit(cache=True)
def ss_step(xp, A, B, C, L, cpk, v, u, tmp):
    """Steady-state step: returns position estimate Cp X(k|k); advances xp with u."""
    n = xp.shape[0]
    yhat = 0.0
    pos0 = xp[0]
    for i in range(n):
        yhat += C[i] * xp[i]
    nu = v - yhat
    state_predict(xp, A, B, L, u, nu, tmp)
    return pos0 + cpk * nu


@numba.njit(cache=True)
def ss_step6(xp, A, B, C, L, cpk, v, u):
    """:func:`ss_step` for the 6-state model, using its sparsity (res 2x2 block, STF and
    NTF companion blocks, A[2,0] = 1 coupling, B only on the resonator, C only on the
    modulator states)."""
    x0, x1, x2, x3, x4, x5 = head6(xp)
    nu = v - (C[2] * x2 + C[3] * x3 + C[4] * x4 + C[5] * x5)
    xp[0] = A[0, 0] * x0 + A[0, 1] * x1 + B[0] * u + L[0] * nu
    xp[1] = A[1, 0] * x0 + A[1, 1] * x1 + B[1] * u + L[1] * nu
    xp[2] = x0 + A[2, 2] * x2 + A[2, 3] * x3 + L[2] * nu
    xp[3] = x2 + L[3] * nu
    xp[4] = A[4, 4] * x4 + A[4, 5] * x5 + L[4] * nu
    xp[5] = x4 + L[5] * nu
    return x0 + cpk * nu

"""UKF of the shared-electrode micro-scanner (Chen 2018, "High-accuracy Motion Estimation for
MEMS Devices with Capacitive Sensors", chapter 5, Algorithm 2), as a numba kernel over a block of
AMDM samples. Model: :mod:`mems_estimation.filters.scanner_amdm_model`.

UKF (Algorithm 2, with the misprints corrected): scaled sigma points (2n+1 = 5, additive
noise), sigma points re-drawn from the a-priori (x-, P-) for the measurement step,
P_xy = sum W_c dX dy (the thesis adds R: wrong), P = P- - K P_y K^T (the thesis prints +).
EKF (Algorithm 1) in Joseph form.  Both per-sample recursions are numba kernels.  h is eq. (104)
plus the AMDM chain's identified square-law curve (meas of 8 entries); numba caches this kernel
with h inlined, keyed on this file: a change of h must touch this file too.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mems_estimation.filters.scanner_amdm_model import _h, _store_state, _torque_u
from mems_sim.params import ParameterError


def ukf_weights(n: int, alpha: float, beta: float, kappa: float):
    """Scaled unscented-transform weights: (wm (2n+1,), wc (2n+1,), gamma = sqrt(n + lambda)).

    lambda = alpha^2 (n + kappa) - n; wm0 = lambda/(n+lambda), wc0 = wm0 + 1 - alpha^2 + beta,
    wm_i = wc_i = 1/(2(n+lambda)).
    """
    lam = alpha * alpha * (n + kappa) - n
    if not n + lam > 0:
        raise ParameterError(
            f"UKF scaling gives n + lambda = {n + lam!r} <= 0 (alpha={alpha}, kappa={kappa})"
        )
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1.0 - alpha * alpha + beta
    return wm, wc, math.sqrt(n + lam)


@numba.njit(cache=True, inline="always")
def _sigma(x, P, gamma, S):
    """Sigma points S (5,2) of (x, P): x, x +- gamma chol(P)[:, j]; False if P is not PD."""
    if not P[0, 0] > 0.0:
        return False
    l00 = math.sqrt(P[0, 0])
    l10 = P[1, 0] / l00
    d = P[1, 1] - l10 * l10
    if not d > 0.0:
        return False
    l11 = math.sqrt(d)
    S[0, 0] = x[0]
    S[0, 1] = x[1]
    S[1, 0] = x[0] + gamma * l00
    S[1, 1] = x[1] + gamma * l10
    S[2, 0] = x[0] - gamma * l00
    S[2, 1] = x[1] - gamma * l10
    S[3, 0] = x[0]
    S[3, 1] = x[1] + gamma * l11
    S[4, 0] = x[0]
    S[4, 1] = x[1] - gamma * l11
    return True


@numba.njit(cache=True, inline="always")
def _chol(p00, p01, p11):
    """(ok, l00, l10, l11): Cholesky factor of [[p00, p01], [p01, p11]] as :func:`_sigma`
    computes it; ok False if not positive definite (then the factor is not to be used)."""
    if not p00 > 0.0:
        return False, 0.0, 0.0, 0.0
    l00 = math.sqrt(p00)
    l10 = p01 / l00
    d = p11 - l10 * l10
    if not d > 0.0:
        return False, 0.0, 0.0, 0.0
    return True, l00, l10, math.sqrt(d)


@numba.njit(cache=True, inline="always")
def _sigma_repaired(x0, x1, p00, p01, p11, q00, q11, gamma, S):
    """Sigma points of (x, P) on scalars, as :func:`_sigma` (rows flattened: S = (s00, s01,
    s10, ..., s41)), after repairing a P that is not positive definite (p01 = 0, diagonal
    at least Q's). Returns (repaired 0/1, p00, p01, p11, S); S unchanged if P stays not PD."""
    bad = 0
    ok, l00, l10, l11 = _chol(p00, p01, p11)
    if not ok:
        bad = 1
        p01 = 0.0
        p00 = max(p00, q00)
        p11 = max(p11, q11)
        ok, l00, l10, l11 = _chol(p00, p01, p11)
    if ok:
        S = (
            x0,
            x1,
            x0 + gamma * l00,
            x1 + gamma * l10,
            x0 - gamma * l00,
            x1 - gamma * l10,
            x0,
            x1 + gamma * l11,
            x0,
            x1 - gamma * l11,
        )
    return bad, p00, p01, p11, S


@numba.njit(cache=True, inline="always")
def _propagate(s0, s1, v2, m, J, T, f00, f01, f10, f11, g0, g1):
    """Process model of one sigma point (s0, s1) [rad, rad/s]: Phi s + Gam u, u the
    torque term at mid-step theta (:func:`_torque_u`, <V^2> = v2). Returns the new point."""
    u = _torque_u(s0 + 0.5 * T * s1, v2, m, J)
    return f00 * s0 + f01 * s1 + g0 * u, f10 * s0 + f11 * s1 + g1 * u


@numba.njit(cache=True, inline="always")
def _add_outer(p00, p01, p11, w, d0, d1):
    """(p00, p01, p11) + w d d^T for d = (d0, d1): one sigma point's term of P = sum W_c
    dX dX^T + Q (Algorithm 2)."""
    return p00 + w * d0 * d0, p01 + w * d0 * d1, p11 + w * d1 * d1


@numba.njit(cache=True)
def ukf_run(
    y, v2, x, P, Phi, Gam, Q, m, J, R, T, wm, wc, gamma, predict_first, out_x, out_p, out_nis
):
    """UKF (Algorithm 2, corrected; module doc) over a frame; x, P carried in place.

    Arguments and outputs as :func:`ekf_run`; wm, wc (5,) weights, gamma = sqrt(n + lambda).

    The arithmetic of :func:`_sigma` and the loops over the five sigma points, written out
    on scalars (state, covariance and sigma points stay in registers: 2x faster than on
    arrays, results bit for bit the same). A covariance that is not positive definite even
    after the repair leaves the sigma points as they were, as :func:`_sigma` does.

    Returns:
        number of steps whose covariance was not positive definite (repaired).
    """
    x0, x1 = x[0], x[1]
    p00, p01, p11 = P[0, 0], P[0, 1], P[1, 1]
    f00, f01, f10, f11, g0, g1 = Phi[0, 0], Phi[0, 1], Phi[1, 0], Phi[1, 1], Gam[0], Gam[1]
    q00, q01, q11 = Q[0, 0], Q[0, 1], Q[1, 1]
    wm0, wm1, wm2, wm3, wm4 = wm[0], wm[1], wm[2], wm[3], wm[4]
    wc0, wc1, wc2, wc3, wc4 = wc[0], wc[1], wc[2], wc[3], wc[4]
    # sigma points (rows 0..4 of _sigma's S), kept between steps like S
    S = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    bad = 0
    for k in range(y.shape[0]):
        if k > 0 or predict_first:
            r, p00, p01, p11, S = _sigma_repaired(x0, x1, p00, p01, p11, q00, q11, gamma, S)
            bad += r
            s00, s01, s10, s11, s20, s21, s30, s31, s40, s41 = S
            vk = v2[k]
            a0, a1 = _propagate(s00, s01, vk, m, J, T, f00, f01, f10, f11, g0, g1)
            b0, b1 = _propagate(s10, s11, vk, m, J, T, f00, f01, f10, f11, g0, g1)
            c0, c1 = _propagate(s20, s21, vk, m, J, T, f00, f01, f10, f11, g0, g1)
            d0, d1 = _propagate(s30, s31, vk, m, J, T, f00, f01, f10, f11, g0, g1)
            e0, e1 = _propagate(s40, s41, vk, m, J, T, f00, f01, f10, f11, g0, g1)
            m0 = 0.0 + wm0 * a0 + wm1 * b0 + wm2 * c0 + wm3 * d0 + wm4 * e0
            m1 = 0.0 + wm0 * a1 + wm1 * b1 + wm2 * c1 + wm3 * d1 + wm4 * e1
            p00, p01, p11 = _add_outer(q00, q01, q11, wc0, a0 - m0, a1 - m1)
            p00, p01, p11 = _add_outer(p00, p01, p11, wc1, b0 - m0, b1 - m1)
            p00, p01, p11 = _add_outer(p00, p01, p11, wc2, c0 - m0, c1 - m1)
            p00, p01, p11 = _add_outer(p00, p01, p11, wc3, d0 - m0, d1 - m1)
            p00, p01, p11 = _add_outer(p00, p01, p11, wc4, e0 - m0, e1 - m1)
            x0, x1 = m0, m1
        r, p00, p01, p11, S = _sigma_repaired(x0, x1, p00, p01, p11, q00, q11, gamma, S)
        bad += r
        s00, s01, s10, s11, s20, s21, s30, s31, s40, s41 = S
        h0 = _h(s00, m)
        h1 = _h(s10, m)
        h2 = _h(s20, m)
        h3 = _h(s30, m)
        h4 = _h(s40, m)
        ym = 0.0 + wm0 * h0 + wm1 * h1 + wm2 * h2 + wm3 * h3 + wm4 * h4
        dy0, dy1, dy2, dy3, dy4 = h0 - ym, h1 - ym, h2 - ym, h3 - ym, h4 - ym
        py = R + wc0 * dy0 * dy0 + wc1 * dy1 * dy1 + wc2 * dy2 * dy2
        py = py + wc3 * dy3 * dy3 + wc4 * dy4 * dy4
        cx = 0.0 + wc0 * (s00 - x0) * dy0 + wc1 * (s10 - x0) * dy1 + wc2 * (s20 - x0) * dy2
        cx = cx + wc3 * (s30 - x0) * dy3 + wc4 * (s40 - x0) * dy4
        cw = 0.0 + wc0 * (s01 - x1) * dy0 + wc1 * (s11 - x1) * dy1 + wc2 * (s21 - x1) * dy2
        cw = cw + wc3 * (s31 - x1) * dy3 + wc4 * (s41 - x1) * dy4
        k0 = cx / py
        k1 = cw / py
        nu = y[k] - ym
        x0 += k0 * nu
        x1 += k1 * nu
        p00 = p00 - k0 * k0 * py
        p01 = p01 - k0 * k1 * py
        p11 = p11 - k1 * k1 * py
        # a posteriori covariance (_store_posterior): repaired if not positive definite
        if not (p00 > 0.0 and p11 > 0.0 and p00 * p11 - p01 * p01 > 0.0):
            bad += 1
            p01 = 0.0
            p00 = max(p00, q00)
            p11 = max(p11, q11)
        out_x[k, 0] = x0
        out_x[k, 1] = x1
        out_p[k, 0] = p00
        out_p[k, 1] = p11
        out_p[k, 2] = p01
        out_nis[k] = nu * nu / py
    _store_state(x, P, x0, x1, p00, p01, p11)
    return bad

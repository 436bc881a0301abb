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

from mems_estimation.filters.scanner_amdm_model import _h, _store_posterior, _torque_u
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


@numba.njit(cache=True)
def ukf_run(
    y, v2, x, P, Phi, Gam, Q, m, J, R, T, wm, wc, gamma, predict_first, out_x, out_p, out_nis
):
    """UKF (Algorithm 2, corrected; module doc) over a frame; x, P carried in place.

    Arguments and outputs as :func:`ekf_run`; wm, wc (5,) weights, gamma = sqrt(n + lambda).

    Returns:
        number of steps whose covariance was not positive definite (repaired).
    """
    S = np.empty((5, 2))
    Xp = np.empty((5, 2))
    Y = np.empty(5)
    bad = 0
    for k in range(y.shape[0]):
        if k > 0 or predict_first:
            if not _sigma(x, P, gamma, S):
                bad += 1
                P[0, 1] = 0.0
                P[1, 0] = 0.0
                P[0, 0] = max(P[0, 0], Q[0, 0])
                P[1, 1] = max(P[1, 1], Q[1, 1])
                _sigma(x, P, gamma, S)
            m0 = 0.0
            m1 = 0.0
            for i in range(5):
                u = _torque_u(S[i, 0] + 0.5 * T * S[i, 1], v2[k], m, J)
                Xp[i, 0] = Phi[0, 0] * S[i, 0] + Phi[0, 1] * S[i, 1] + Gam[0] * u
                Xp[i, 1] = Phi[1, 0] * S[i, 0] + Phi[1, 1] * S[i, 1] + Gam[1] * u
                m0 += wm[i] * Xp[i, 0]
                m1 += wm[i] * Xp[i, 1]
            p00 = Q[0, 0]
            p01 = Q[0, 1]
            p11 = Q[1, 1]
            for i in range(5):
                d0 = Xp[i, 0] - m0
                d1 = Xp[i, 1] - m1
                p00 += wc[i] * d0 * d0
                p01 += wc[i] * d0 * d1
                p11 += wc[i] * d1 * d1
            x[0] = m0
            x[1] = m1
            P[0, 0] = p00
            P[0, 1] = p01
            P[1, 0] = p01
            P[1, 1] = p11
        if not _sigma(x, P, gamma, S):
            bad += 1
            P[0, 1] = 0.0
            P[1, 0] = 0.0
            P[0, 0] = max(P[0, 0], Q[0, 0])
            P[1, 1] = max(P[1, 1], Q[1, 1])
            _sigma(x, P, gamma, S)
        ym = 0.0
        for i in range(5):
            Y[i] = _h(S[i, 0], m)
            ym += wm[i] * Y[i]
        py = R
        c0 = 0.0
        c1 = 0.0
        for i in range(5):
            dy = Y[i] - ym
            py += wc[i] * dy * dy
            c0 += wc[i] * (S[i, 0] - x[0]) * dy
            c1 += wc[i] * (S[i, 1] - x[1]) * dy
        k0 = c0 / py
        k1 = c1 / py
        nu = y[k] - ym
        x[0] += k0 * nu
        x[1] += k1 * nu
        p00 = P[0, 0] - k0 * k0 * py
        p01 = P[0, 1] - k0 * k1 * py
        p11 = P[1, 1] - k1 * k1 * py
        bad += _store_posterior(P, Q, p00, p01, p11, x, k, out_x, out_p)
        out_nis[k] = nu * nu / py
    return bad

"""EKF of the shared-electrode micro-scanner (Chen 2018, "High-accuracy Motion Estimation for
MEMS Devices with Capacitive Sensors", chapter 5, Algorithm 1), in Joseph form, as a numba
kernel over a block of AMDM samples. Model: :mod:`mems_estimation.filters.scanner_amdm_model`
(h: eq. (104) plus the AMDM chain's identified square-law curve, meas of 8 entries; numba caches
this kernel with h inlined, keyed on this file: a change of h must touch this file too).
"""

from __future__ import annotations

import numba

from mems_estimation.filters.scanner_amdm_model import (
    _dh,
    _dtorque_u,
    _h,
    _store_posterior,
    _store_state,
    _torque_u,
)


@numba.njit(cache=True)
def ekf_run(y, v2, x, P, Phi, Gam, Q, m, J, R, T, predict_first, out_x, out_p, out_nis):
    """EKF (Algorithm 1, Joseph-form update) over a frame; x (2,), P (2,2) carried in place.

    Args:
        y: (n,) AMDM samples [V]. v2: (n,) <V^2> over the step ending at sample k [V^2].
        predict_first: False on the very first sample (x, P already describe sample 0).
        out_x (n,2), out_p (n,3) = (P_tt, P_ww, P_tw), out_nis (n,): a-posteriori outputs.

    Returns:
        number of steps whose covariance was not positive definite (repaired).
    """
    bad = 0
    for k in range(y.shape[0]):
        if k > 0 or predict_first:
            tm = x[0] + 0.5 * T * x[1]
            u = _torque_u(tm, v2[k], m, J)
            du = _dtorque_u(tm, v2[k], m, J)
            x0 = Phi[0, 0] * x[0] + Phi[0, 1] * x[1] + Gam[0] * u
            x1 = Phi[1, 0] * x[0] + Phi[1, 1] * x[1] + Gam[1] * u
            g00 = Phi[0, 0] + Gam[0] * du
            g01 = Phi[0, 1] + Gam[0] * du * 0.5 * T
            g10 = Phi[1, 0] + Gam[1] * du
            g11 = Phi[1, 1] + Gam[1] * du * 0.5 * T
            a00 = g00 * P[0, 0] + g01 * P[1, 0]
            a01 = g00 * P[0, 1] + g01 * P[1, 1]
            a10 = g10 * P[0, 0] + g11 * P[1, 0]
            a11 = g10 * P[0, 1] + g11 * P[1, 1]
            p00 = a00 * g00 + a01 * g01 + Q[0, 0]
            p01 = a00 * g10 + a01 * g11 + Q[0, 1]
            p11 = a10 * g10 + a11 * g11 + Q[1, 1]
            _store_state(x, P, x0, x1, p00, p01, p11)
        hk = _dh(x[0], m)
        nu = y[k] - _h(x[0], m)
        s = hk * hk * P[0, 0] + R
        k0 = P[0, 0] * hk / s
        k1 = P[1, 0] * hk / s
        x[0] += k0 * nu
        x[1] += k1 * nu
        # Joseph form: (I - K H) P (I - K H)^T + K R K^T, H = [hk, 0]
        i00 = 1.0 - k0 * hk
        i10 = -k1 * hk
        p00 = i00 * i00 * P[0, 0] + k0 * k0 * R
        p01 = i00 * (i10 * P[0, 0] + P[1, 0]) + k0 * k1 * R
        p11 = i10 * i10 * P[0, 0] + 2.0 * i10 * P[1, 0] + P[1, 1] + k1 * k1 * R
        bad += _store_posterior(P, Q, p00, p01, p11, x, k, out_x, out_p)
        out_nis[k] = nu * nu / s
    return bad

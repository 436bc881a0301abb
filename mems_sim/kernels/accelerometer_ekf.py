"""Hybrid (continuous-discrete) extended Kalman filter of the force-rebalance accelerometer
(Zhang 2010, section 4.2.6, eqs. 4-48 .. 4-57, and chapter 5).

State ``[x, v, a]``: proof-mass displacement [m], velocity [m/s] and the input
acceleration [m/s^2]. The thesis's filter has the state ``[x, v]`` with the
matrices (5-1)-(5-3); the input acceleration is what the sensor must measure, so
it is not a known input here: it is an augmented state driven by white noise
(a random walk of intensity ``q_a``), which makes the estimate of the acceleration
a filter output.

Continuous model (nonlinear, eq. 4-48 with the plant 2-1, 2-14, 2-15)::

    x' = v
    v' = a - (k x + b(x) v) / m + F_el(x, v_F, V_B) / m + w_F / m,   w_F ~ (0, q_F)
    a' = w_a,                                                           w_a ~ (0, q_a)
    y_k = h(x_k) + n_k,  h(x) = -2 eps A V1 x / (C4 (d0^2 - x^2)),      n_k ~ (0, R)

Time update (4-51)-(4-53): ``x_hat' = f(x_hat, v_F)`` and
``P' = F P + P F^T + L Q L^T`` integrated together over one sample period with the
classical 4th-order Runge-Kutta method (``steps`` per sample, default 1), the
Jacobian ``F`` re-evaluated at every stage's state (4-51 takes it at the start of the
interval; evaluating it along the path is the usual continuous EKF and costs the
same). Measurement update (4-54)-(4-57) in Joseph form
``P = (I - K H) P (I - K H)^T + K R K^T``, algebraically equal to (4-57) and
positive semi-definite in floating point.

The feedback voltage ``v_F`` is known to the filter (it is the controller's output),
held constant over each sample period (ZOH), as in the device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

N_STATES = 3
STATE_NAMES = ("displacement", "velocity", "acceleration")
STATE_UNITS = ("m", "m/s", "m/s^2")


def model_vector(
    *,
    mass: float,
    stiffness: float,
    damping: float,
    squeeze_film: bool,
    eps_area: float,
    gap: float,
    carrier: float,
    c4: float,
    v_b: float,
) -> np.ndarray:
    """Packed model constants ``[m, k, b0, squeeze, eps*A, d0, V1, C4, V_B]`` (SI units)."""
    return np.array(
        [mass, stiffness, damping, 1.0 if squeeze_film else 0.0, eps_area, gap, carrier, c4, v_b],
        dtype=np.float64,
    )


@numba.njit(cache=True)
def _dynamics(x, v, a, v_f, mv):
    """f(s) of the model above and its Jacobian entries (eq. 4-51) [SI units].

    Returns (x', v', f10, f11): the Jacobian is [[0, 1, 0], [f10, f11, 1], [0, 0, 0]].
    """
    k, b0, sq, ea, d0, v1, v_b = mv[1], mv[2], mv[3], mv[4], mv[5], mv[6], mv[8]
    im = 1.0 / mv[0]
    ilo = 1.0 / (d0 - x)  # reciprocals once: divisions dominate the cost
    ihi = 1.0 / (d0 + x)
    ilo2, ihi2 = ilo * ilo, ihi * ihi
    b, db = b0, 0.0
    if sq > 0.5:
        # b(x) = b0/2 [(d0/(d0 - x))^3 + (d0/(d0 + x))^3] (2-14 corrected) and db/dx
        d3 = d0 * d0 * d0
        b = b0 * 0.5 * d3 * (ilo2 * ilo + ihi2 * ihi)
        db = b0 * 1.5 * d3 * (ilo2 * ilo2 - ihi2 * ihi2)
    c2 = 0.5 * v1 * v1
    lo = c2 + (v_f - v_b) ** 2
    hi = c2 + (v_f + v_b) ** 2
    f_el = 0.5 * ea * (lo * ilo2 - hi * ihi2)
    df_el = ea * (lo * ilo2 * ilo + hi * ihi2 * ihi)
    return v, a - (k * x + b * v - f_el) * im, (-k - db * v + df_el) * im, -b * im


@numba.njit(cache=True)
def _pdot(p00, p01, p02, p11, p12, p22, f10, f11, qv, qa):
    """Riccati right-hand side F P + P F^T + L Q L^T (eq. 4-52), symmetric entries."""
    return (
        2.0 * p01,
        p11 + f10 * p00 + f11 * p01 + p02,
        p12,
        2.0 * (f10 * p01 + f11 * p11 + p12) + qv,
        f10 * p02 + f11 * p12 + p22,
        qa,
    )


@numba.njit(cache=True)
def _pdot_stage(p00, p01, p02, p11, p12, p22, h, k00, k01, k02, k11, k12, k22, f10, f11, qv, qa):
    """:func:`_pdot` at P + h K, an RK4 stage (K: the previous stage's derivative)."""
    return _pdot(
        p00 + h * k00,
        p01 + h * k01,
        p02 + h * k02,
        p11 + h * k11,
        p12 + h * k12,
        p22 + h * k22,
        f10,
        f11,
        qv,
        qa,
    )


@numba.njit(cache=True)
def ekf_predict(s, pm, v_f, dt, q, mv, steps=1):
    """Time update over dt [s] (eqs. 4-52, 4-53), RK4; s, pm updated in place.

    q = (q_F [N^2 s], q_a [(m/s^2)^2/s]) are the continuous noise intensities.
    The state and the six distinct entries of P are integrated together, the
    Jacobian evaluated at each stage's state.
    """
    qv = q[0] / (mv[0] * mv[0])
    qa = q[1]
    h = dt / steps
    x, v, a = s[0], s[1], s[2]
    p00, p01, p02, p11, p12, p22 = pm[0, 0], pm[0, 1], pm[0, 2], pm[1, 1], pm[1, 2], pm[2, 2]
    for _ in range(steps):
        x1, v1, f10, f11 = _dynamics(x, v, a, v_f, mv)
        a00, a01, a02, a11, a12, a22 = _pdot(p00, p01, p02, p11, p12, p22, f10, f11, qv, qa)
        hh = 0.5 * h
        x2, v2, f10, f11 = _dynamics(x + hh * x1, v + hh * v1, a, v_f, mv)
        b00, b01, b02, b11, b12, b22 = _pdot_stage(
            p00, p01, p02, p11, p12, p22, hh, a00, a01, a02, a11, a12, a22, f10, f11, qv, qa
        )
        x3, v3, f10, f11 = _dynamics(x + hh * x2, v + hh * v2, a, v_f, mv)
        c00, c01, c02, c11, c12, c22 = _pdot_stage(
            p00, p01, p02, p11, p12, p22, hh, b00, b01, b02, b11, b12, b22, f10, f11, qv, qa
        )
        x4, v4, f10, f11 = _dynamics(x + h * x3, v + h * v3, a, v_f, mv)
        d00, d01, d02, d11, d12, d22 = _pdot_stage(
            p00, p01, p02, p11, p12, p22, h, c00, c01, c02, c11, c12, c22, f10, f11, qv, qa
        )
        w = h / 6.0
        x += w * (x1 + 2.0 * x2 + 2.0 * x3 + x4)
        v += w * (v1 + 2.0 * v2 + 2.0 * v3 + v4)
        p00 += w * (a00 + 2.0 * b00 + 2.0 * c00 + d00)
        p01 += w * (a01 + 2.0 * b01 + 2.0 * c01 + d01)
        p02 += w * (a02 + 2.0 * b02 + 2.0 * c02 + d02)
        p11 += w * (a11 + 2.0 * b11 + 2.0 * c11 + d11)
        p12 += w * (a12 + 2.0 * b12 + 2.0 * c12 + d12)
        p22 += w * (a22 + 2.0 * b22 + 2.0 * c22 + d22)
    s[0], s[1] = x, v
    pm[0, 0], pm[1, 1], pm[2, 2] = p00, p11, p22
    pm[0, 1] = pm[1, 0] = p01
    pm[0, 2] = pm[2, 0] = p02
    pm[1, 2] = pm[2, 1] = p12


@numba.njit(cache=True)
def measurement(x, mv):
    """(h(x), dh/dx): readout (eq. 2-9) and its derivative (eq. 4-54) [V, V/m]."""
    ea, d0, v1, c4 = mv[4], mv[5], mv[6], mv[7]
    den = d0 * d0 - x * x
    return (-2.0 * ea * v1 * x / (c4 * den), -2.0 * ea * v1 / c4 * (d0 * d0 + x * x) / (den * den))


@numba.njit(cache=True)
def ekf_update(s, pm, y, r, mv):
    """Measurement update with y [V] (eqs. 4-54 .. 4-57, Joseph form); returns the innovation
    ``y - h(x_hat)`` [V] (:func:`ekf_update_innovation`, the same floats)."""
    return ekf_update_innovation(s, pm, y, r, mv)[0]


@numba.njit(cache=True)
def ekf_update_innovation(s, pm, y, r, mv):
    """Measurement update with y [V] (eqs. 4-54 .. 4-57, Joseph form); returns the innovation
    ``nu = y - h(x_hat)`` [V] and its predicted variance ``S = H P H^T + R = h'^2 P00 + R``
    [V^2], the denominator of the gain (4-55), from the a-priori P.

    With ``H = [h', 0, 0]``: ``K = P[:, 0] h' / S`` (4-55) and
    ``P+ = (I - K H) P (I - K H)^T + K R K^T`` (4-57 in Joseph form). ``nu^2 / S`` is the
    normalised innovation squared of a consistency test.
    """
    hx, hd = measurement(s[0], mv)
    innov = y - hx
    sv = hd * hd * pm[0, 0] + r
    k0 = pm[0, 0] * hd / sv
    k1 = pm[1, 0] * hd / sv
    k2 = pm[2, 0] * hd / sv
    s[0] += k0 * innov
    s[1] += k1 * innov
    s[2] += k2 * innov
    # B = (I - K H) P: B[i, j] = P[i, j] - K_i h' P[0, j];
    # P+ = B (I - K H)^T + K R K^T: P+[i, j] = B[i, j] - B[i, 0] K_j h' + K_i K_j R.
    g0, g1, g2 = k0 * hd, k1 * hd, k2 * hd
    r00, r01, r02 = pm[0, 0], pm[0, 1], pm[0, 2]
    b00, b01, b02 = r00 - g0 * r00, r01 - g0 * r01, r02 - g0 * r02
    b10, b11, b12 = pm[1, 0] - g1 * r00, pm[1, 1] - g1 * r01, pm[1, 2] - g1 * r02
    b20, b22 = pm[2, 0] - g2 * r00, pm[2, 2] - g2 * r02
    p00 = b00 - b00 * g0 + k0 * k0 * r
    p01 = b01 - b00 * g1 + k0 * k1 * r
    p02 = b02 - b00 * g2 + k0 * k2 * r
    p11 = b11 - b10 * g1 + k1 * k1 * r
    p12 = b12 - b10 * g2 + k1 * k2 * r
    p22 = b22 - b20 * g2 + k2 * k2 * r
    pm[0, 0], pm[1, 1], pm[2, 2] = p00, p11, p22
    pm[0, 1] = pm[1, 0] = p01
    pm[0, 2] = pm[2, 0] = p02
    pm[1, 2] = pm[2, 1] = p12
    return innov, sv


@numba.njit(cache=True)
def is_positive_definite(pm) -> bool:
    """Sylvester's criterion on the 3x3 covariance: all leading minors > 0."""
    m1 = pm[0, 0]
    m2 = pm[0, 0] * pm[1, 1] - pm[0, 1] * pm[1, 0]
    m3 = (
        pm[0, 0] * (pm[1, 1] * pm[2, 2] - pm[1, 2] * pm[2, 1])
        - pm[0, 1] * (pm[1, 0] * pm[2, 2] - pm[1, 2] * pm[2, 0])
        + pm[0, 2] * (pm[1, 0] * pm[2, 1] - pm[1, 1] * pm[2, 0])
    )
    return m1 > 0.0 and m2 > 0.0 and m3 > 0.0


def ekf_init(p0_diag=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Initial state x0 = 0 (Table II) and covariance diag(p0_diag) (eq. 4-50)."""
    return np.zeros(N_STATES), np.diag(np.asarray(p0_diag, dtype=np.float64))


@dataclass
class HybridEkfConfig:
    """Everything the filter needs: model constants, noise intensities, R.

    Attributes:
        model: :func:`model_vector` of the filter's model.
        q: (q_F [N^2 s], q_a [(m/s^2)^2/s]) continuous process-noise intensities.
        r: measurement-noise variance [V^2].
        dt: sample period [s].
    """

    model: np.ndarray
    q: np.ndarray
    r: float
    dt: float
    p0_diag: tuple = (0.0, 0.0, 0.0)

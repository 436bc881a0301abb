"""Capacitance geometry of the piezo tilt micro-stage's rotational parallel-plate sensing
(Y. Chen, PhD thesis, U. Michigan 2018, chapter 3: eqs. (35)-(47), Tables A.1/A.2).

Shared by the emulator (:mod:`mems_sim.devices.stage`), the stage EKF and the stage
identification. Corrections to the source (Table A.1 channel 2A; eqs. (41), (42), (46))
are documented in :mod:`mems_sim.devices.stage`: eq. (40) is evaluated by Gauss-Legendre
quadrature, its derivatives with the w_Y integral in closed form (a cancellation-free
series) and Gauss-Legendre in w_X.

Angles in rad, lengths in m, capacitances in F, gradients in F/rad.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numba
import numpy as np

EPS0 = 8.8541878128e-12  # F/m, electric constant (eq. 35: 8.8542e-12)

# 5x5 Gauss-Legendre nodes: < 1e-12 relative error vs 16x16 for |tilt| <= 5 mrad (tested)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)


def channel_limits(p: Mapping[str, Any], design: bool = False) -> np.ndarray:
    """Integration limits (w1, w2, w3, w4) per channel 1A, 1B, 2A, 2B [m] (Table A.1).

    2A corrected (misprint, see module doc): outer right stator [0.5W - W_SA, 0.5W].
    ``stator_offset_y_m`` (if in ``p``; 0 when ``design``) shifts every stator along Y
    (w3, w4): a misregistration of the stator layer against the rotor. With the
    symmetric layout of Table A.2 the off-axis leakage is second order in the off-axis
    angle; the offset makes it first order (the rotor's dC/dtheta_X no longer vanishes
    at theta_X = 0).
    """
    W, sa, sb, dw = p["w_m"], p["w_sa_m"], p["w_sb_m"], p["d_w_m"]
    dy = 0.0 if design else float(p.get("stator_offset_y_m", 0.0))
    lo, hi = -0.5 * sa + dy, 0.5 * sa + dy
    return np.array(
        [
            [-0.5 * W, -0.5 * W + sa, lo, hi],
            [0.5 * W - sa - dw - sb, 0.5 * W - sa - dw, lo, hi],
            [0.5 * W - sa, 0.5 * W, lo, hi],
            [-0.5 * W + sa + dw, -0.5 * W + sa + dw + sb, lo, hi],
        ]
    )


# 2k/(2k+1), k = 1..30: series of the inner w_Y integral (see _grad_channel)
_SERIES_C = np.array([2.0 * k / (2.0 * k + 1.0) for k in range(1, 31)])
_C1, _C2, _C3 = 2.0 / 3.0, 4.0 / 5.0, 6.0 / 7.0


@numba.njit(cache=True, inline="always")
def _half_widths(w1, w2, w3, w4):
    """(half-width, centre) along w_X, then (centre, half-width) along w_Y of the channel
    rectangle [w1, w2] x [w3, w4] [m]."""
    return 0.5 * (w2 - w1), 0.5 * (w2 + w1), 0.5 * (w3 + w4), 0.5 * (w4 - w3)


@numba.njit(cache=True, inline="always")
def _grad_channel(tx, ty, dn, w1, w2, w3, w4, glx, glw):
    """(int int w_Y/D^2, int int w_X/D^2) over one channel's rectangle of eq. (40),
    D = D_n - w_X tan(theta_Y) + w_Y tan(theta_X); tx, ty = tan(theta_X), tan(theta_Y).

    Inner integral over w_Y in closed form, outer over w_X by Gauss-Legendre (glx, glw).
    With a = D_n - w_X ty + tx c, c = (w3 + w4)/2, h = (w4 - w3)/2, e = tx h / a:
        int dw_Y / D^2     = 2h / (a^2 (1 - e^2))                      = 2h/a^2 sum e^2k
        int w_Y dw_Y / D^2 = c int dw_Y/D^2 - 2h^2/a^2 sum_k>=1 2k/(2k+1) e^(2k-1)
    (series of the exact antiderivatives, free of the 1/tan^2 cancellation of eq. 41;
    |e| < 0.1 for every admissible tilt; the closed form is used beyond 0.5).
    One division per outer node. Returns (Iy, Ix) = (int int w_X/D^2, int int w_Y/D^2) [m]:
    dC/dtheta_Y = eps sec^2(theta_Y) Iy, dC/dtheta_X = -eps sec^2(theta_X) Ix.
    """
    hx, mx, c, h = _half_widths(w1, w2, w3, w4)
    iy = 0.0
    ix = 0.0
    for q in range(glx.shape[0]):
        wx = mx + hx * glx[q]
        a = dn - wx * ty + tx * c
        inv = 1.0 / a
        e = tx * h * inv
        e2 = e * e
        if e2 < 0.25:
            # terms so that e2^nt < 1e-17 (Horner, coefficients 2k/(2k+1))
            if e2 < 1e-6:
                nt = 3
            elif e2 < 1e-3:
                nt = 6
            elif e2 < 1e-2:
                nt = 9
            else:
                nt = 30
            s0 = 1.0
            s1 = _SERIES_C[nt - 1]
            for k in range(nt - 2, -1, -1):
                s0 = 1.0 + e2 * s0
                s1 = _SERIES_C[k] + e2 * s1
            j0 = 2.0 * h * inv * inv * s0
            k1 = -2.0 * h * h * inv * inv * e * s1
        else:
            j0 = 2.0 * h / (a * a * (1.0 - e2))
            th_ = tx * h
            k1 = (math.log((a + th_) / (a - th_)) - 2.0 * a * th_ / (a * a - th_ * th_)) / (tx * tx)
        wq = glw[q] * hx
        iy += wq * wx * j0
        ix += wq * (c * j0 + k1)
    return iy, ix


@numba.njit(cache=True, inline="always")
def _grad_channel_small(tx, ty, dn, w1, w2, w3, w4, glx, glw):
    """:func:`_grad_channel` when |e| < 1e-3 at every node (caller checks with
    :func:`_small_offaxis`): three series terms (e^6 < 1e-18), straight-line code."""
    hx, mx, c, h = _half_widths(w1, w2, w3, w4)
    iy = 0.0
    ix = 0.0
    for q in range(glx.shape[0]):
        wx = mx + hx * glx[q]
        inv = 1.0 / (dn - wx * ty + tx * c)
        e = tx * h * inv
        e2 = e * e
        j0 = 2.0 * h * inv * inv * (1.0 + e2 * (1.0 + e2))
        k1 = -2.0 * h * h * inv * inv * e * (_C1 + e2 * (_C2 + e2 * _C3))
        wq = glw[q] * hx
        iy += wq * wx * j0
        ix += wq * (c * j0 + k1)
    return iy, ix


@numba.njit(cache=True, inline="always")
def _small_offaxis(tx, ty, dn, wxmax, wymax):
    """True when |tan(theta_X)| w_Y / D < 1e-3 for every point of every electrode
    (wxmax, wymax: largest |w_X|, |w_Y| of the layout): the fast path of the gradient."""
    dmin = dn - wxmax * abs(ty) - wymax * abs(tx)
    return dmin > 0.0 and abs(tx) * wymax < 1e-3 * dmin


@numba.njit(cache=True, inline="always")
def _layout_extent(lim):
    """(largest |w_X|, largest |w_Y|) of the electrode layout lim (nch, 4) [m], the bounds
    :func:`_small_offaxis` takes."""
    wxmax = max(np.abs(lim[:, 0]).max(), np.abs(lim[:, 1]).max())
    wymax = max(np.abs(lim[:, 2]).max(), np.abs(lim[:, 3]).max())
    return wxmax, wymax


@numba.njit(cache=True, inline="always")
def _tilt_terms(thx, thy, dn, wxmax, wymax):
    """(tan(theta_X), tan(theta_Y), sec^2(theta_X), sec^2(theta_Y), fast path?) of one
    sample for :func:`_grad_xy` (the flag from :func:`_small_offaxis`)."""
    tx = math.tan(thx)
    ty = math.tan(thy)
    sx = 1.0 + tx * tx
    sy = 1.0 + ty * ty
    return tx, ty, sx, sy, _small_offaxis(tx, ty, dn, wxmax, wymax)


@numba.njit(cache=True, inline="always")
def _grad_xy(tx, ty, sx, sy, small, dn, lim, c, eps, glx, glw):
    """(dC_c/dtheta_X, dC_c/dtheta_Y) of channel c, eq. (40) [F/rad]: -eps sec^2(theta_X) Ix,
    eps sec^2(theta_Y) Iy with (Iy, Ix) of :func:`_grad_channel_small` on the fast path,
    :func:`_grad_channel` otherwise (tx, ty, sx, sy, small from :func:`_tilt_terms`)."""
    if small:
        iy, ix = _grad_channel_small(
            tx, ty, dn, lim[c, 0], lim[c, 1], lim[c, 2], lim[c, 3], glx, glw
        )
    else:
        iy, ix = _grad_channel(tx, ty, dn, lim[c, 0], lim[c, 1], lim[c, 2], lim[c, 3], glx, glw)
    return -eps * ix * sx, eps * iy * sy


@numba.njit(cache=True)
def _grad_dual(thx, thy, dn, lim, eps, glx, glw, out):
    """dC/dtheta_X, dC/dtheta_Y of eq. (40) for every sample and channel (:func:`_grad_channel`).

    d(1/D)/dtheta_Y = w_X sec^2(theta_Y)/D^2 ; d(1/D)/dtheta_X = -w_Y sec^2(theta_X)/D^2.
    out: (n, nch, 2).
    """
    n = thx.shape[0]
    nch = lim.shape[0]
    wxmax, wymax = _layout_extent(lim)
    for i in range(n):
        tx, ty, sx, sy, small = _tilt_terms(thx[i], thy[i], dn, wxmax, wymax)
        for c in range(nch):
            gx, gy = _grad_xy(tx, ty, sx, sy, small, dn, lim, c, eps, glx, glw)
            out[i, c, 0] = gx
            out[i, c, 1] = gy


@numba.njit(cache=True)
def _cap_dual(thx, thy, dn, lim, eps, glx, glw, out):
    """C of eq. (40) by GL quadrature (n, nch)."""
    n = thx.shape[0]
    nch = lim.shape[0]
    ng = glx.shape[0]
    for i in range(n):
        tx = math.tan(thx[i])
        ty = math.tan(thy[i])
        for c in range(nch):
            hx = 0.5 * (lim[c, 1] - lim[c, 0])
            mx = 0.5 * (lim[c, 1] + lim[c, 0])
            hy = 0.5 * (lim[c, 3] - lim[c, 2])
            my = 0.5 * (lim[c, 3] + lim[c, 2])
            acc = 0.0
            for a in range(ng):
                wx = mx + hx * glx[a]
                for b in range(ng):
                    wy = my + hy * glx[b]
                    acc += glw[a] * glw[b] / (dn - wx * ty + wy * tx)
            out[i, c] = eps * hx * hy * acc


def dual_axis_capacitance(
    theta_x, theta_y, gap_m: float, limits: np.ndarray, eps_r: float = 1.0
) -> np.ndarray:
    """C(theta_X, theta_Y) of eqs. (40)-(42) [F], shape (n, nch). Angles in rad, gap in m."""
    tx = np.atleast_1d(np.asarray(theta_x, float))
    ty = np.broadcast_to(np.atleast_1d(np.asarray(theta_y, float)), tx.shape).copy()
    out = np.empty((tx.size, limits.shape[0]))
    _cap_dual(
        tx, ty, float(gap_m), np.ascontiguousarray(limits, float), EPS0 * eps_r, _GL_X, _GL_W, out
    )
    return out


def dual_axis_gradient(
    theta_x, theta_y, gap_m: float, limits: np.ndarray, eps_r: float = 1.0
) -> np.ndarray:
    """[dC/dtheta_X, dC/dtheta_Y] of eq. (43) [F/rad], shape (n, nch, 2)."""
    tx = np.atleast_1d(np.asarray(theta_x, float))
    ty = np.broadcast_to(np.atleast_1d(np.asarray(theta_y, float)), tx.shape).copy()
    out = np.empty((tx.size, limits.shape[0], 2))
    _grad_dual(
        tx, ty, float(gap_m), np.ascontiguousarray(limits, float), EPS0 * eps_r, _GL_X, _GL_W, out
    )
    return out


@numba.njit(cache=True)
def dcdtheta_single(theta, dn, w1, w2, length, eps):
    """dC/dtheta of the single-axis model eq. (46) [F/rad] (8-point Gauss-Legendre).

    C = eps L int_{w1}^{w2} dw/(D_n - w tan th)  ->  dC/dth = eps L sec^2 th int w/(D)^2 dw.
    """
    return dcdtheta_single_tan(math.tan(theta), dn, w1, w2, length, eps)


#: Nodes and weights of the 8-point Gauss-Legendre quadrature on [-1, 1] of
#: :func:`dcdtheta_single_tan` (an estimator that tabulates the same integrand uses them too).
GL8_NODES = (
    -0.9602898564975363,
    -0.7966664774136267,
    -0.5255324099163290,
    -0.1834346424956498,
    0.1834346424956498,
    0.5255324099163290,
    0.7966664774136267,
    0.9602898564975363,
)
GL8_WEIGHTS = (
    0.1012285362903763,
    0.2223810344533745,
    0.3137066458778873,
    0.3626837833783620,
    0.3626837833783620,
    0.3137066458778873,
    0.2223810344533745,
    0.1012285362903763,
)


@numba.njit(cache=True)
def dcdtheta_single_tan(t, dn, w1, w2, length, eps):
    """:func:`dcdtheta_single` from t = tan(theta) (callers with several channels at one
    angle compute the tangent once)."""
    h = 0.5 * (w2 - w1)
    m = 0.5 * (w2 + w1)
    acc = 0.0
    for a in range(8):
        w = m + h * GL8_NODES[a]
        d = dn - w * t
        acc += GL8_WEIGHTS[a] * w / (d * d)
    return eps * length * h * acc * (1.0 + t * t)


def single_axis_dcdtheta(
    theta, gap_m: float, limits_row: Sequence[float], eps_r: float = 1.0
) -> np.ndarray:
    """Vectorised :func:`dcdtheta_single` for one channel's limits (w1, w2, w3, w4)."""
    th = np.atleast_1d(np.asarray(theta, float))
    w1, w2, w3, w4 = (float(v) for v in limits_row)
    return np.array([dcdtheta_single(t, gap_m, w1, w2, w4 - w3, EPS0 * eps_r) for t in th])

"""Numba kernels of the chapter-4 scanner's (hybrid) EKF: predict, y_cap and detection
updates, the fixed-lag re-propagation of late detections, and the 4-state comb filter.

Source: Y. Chen, PhD thesis, U. Michigan 2018, chapter 4, eqs. (67)-(71) and Table 4.1; the
algorithm (ZOH model, Joseph form, late detections, peak-slope angle) is described in
:mod:`mems_estimation.filters.scanner_threshold_ekf`.  The constants travel as NamedTuples:
the model (:class:`~mems_estimation.filters.scanner_threshold_specs.ScannerModel`), the
detection options (:class:`DetectionOptions`), the detections (:class:`DetectionArrays`),
the fixed-lag buffer (:class:`LagBuffer`) and the outputs (:class:`RunOutputs`).  Numba
re-validates a cached kernel on its own file only: after editing :func:`scalar_update`
or :func:`cov_predict`, clear the cache of :mod:`mems_estimation.studies.scanner_threshold` (its PCRB kernel).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

__all__ = [
    "DetectionOptions",
    "DetectionArrays",
    "LagBuffer",
    "RunOutputs",
    "ekf_run",
    "aug_run",
    "scalar_update",
    "cov_predict",
]


class DetectionOptions(NamedTuple):
    """How the filter uses a threshold detection (constants of a run).

    canny: R_theta,th from eq. (65) (else fixed).  peak: the peak-slope angle (else theta_th).
    wn: natural frequency of the model [rad/s] (amplitude of the prior).  gate: innovation
    gate [innovation std].  use_sub: use the sub-sample offset delta.
    """

    canny: bool
    peak: bool
    wn: float
    gate: float
    use_sub: bool


class DetectionArrays(NamedTuple):
    """Detections of a frame as contiguous arrays: index c (int64), arrival k (int64),
    sub-sample offset delta [samples], eq. (65) timing variance [samples^2]."""

    index: np.ndarray
    arrival: np.ndarray
    delta: np.ndarray
    timing_var: np.ndarray


class LagBuffer(NamedTuple):
    """Ring buffer of the last Lb priors: state x (Lb, n), covariance P (Lb, 3) or
    (Lb, 4, 4), measurement y (Lb,) [V], drive v (Lb,) [V]; slot i % Lb holds sample i."""

    x: np.ndarray
    P: np.ndarray
    y: np.ndarray
    v: np.ndarray


class RunOutputs(NamedTuple):
    """Outputs of a frame: final rows x (m, n) and P (m, 3) for sample i at row i - base
    (overwritten on re-propagation), real-time posterior rx (n, 2) at row i - k0, and
    stats [applied, gated, too_late, min_det, max_p00] (updated in place)."""

    base: int
    x: np.ndarray
    P: np.ndarray
    rx: np.ndarray
    stats: np.ndarray


@numba.njit(cache=True, inline="always")
def _torque_terms(theta, v, J, dc0, dth0, thth):
    """(acc, dacc): the drive's angular acceleration tau/J = 0.5 v^2 dC_d/dtheta / J over a
    sample [rad/s^2] and its derivative in theta (eq. (69)); both 0 where v = 0."""
    v2 = v * v
    acc = 0.0
    dacc = 0.0
    if v2 != 0.0:
        u = (theta - thth) / dth0
        e = math.exp(-u * u)
        acc = 0.5 * (-2.0 * dc0 * u / dth0 * e) * v2 / J
        dacc = 0.5 * (2.0 * dc0 / (dth0 * dth0) * (2.0 * u * u - 1.0) * e) * v2 / J
    return acc, dacc


@numba.njit(cache=True, inline="always")
def cov_predict(p00, p01, p11, Phi, Gam, Q, dacc):
    """P^- = G P G^T + Q (eq. (70), ZOH form), G = Phi + Gam [dacc, 0]; P as (p00, p01, p11).
    Returns the predicted (p00, p01, p11)."""
    g00 = Phi[0, 0] + Gam[0] * dacc
    g01 = Phi[0, 1]
    g10 = Phi[1, 0] + Gam[1] * dacc
    g11 = Phi[1, 1]
    a00 = g00 * p00 + g01 * p01
    a01 = g00 * p01 + g01 * p11
    a10 = g10 * p00 + g11 * p01
    a11 = g10 * p01 + g11 * p11
    return (
        a00 * g00 + a01 * g01 + Q[0, 0],
        a00 * g10 + a01 * g11 + Q[0, 1],
        a10 * g10 + a11 * g11 + Q[1, 1],
    )


@numba.njit(cache=True, inline="always")
def _predict(x, P, v, Phi, Gam, Q, J, dc0, dth0, thth, xo, Po):
    """x^- = Phi x + Gam tau/J; P^- = G P G^T + Q (eqs. (69)-(70), ZOH form). P as [p00,p01,p11]."""
    acc, dacc = _torque_terms(x[0], v, J, dc0, dth0, thth)
    xo[0] = Phi[0, 0] * x[0] + Phi[0, 1] * x[1] + Gam[0] * acc
    xo[1] = Phi[1, 0] * x[0] + Phi[1, 1] * x[1] + Gam[1] * acc
    Po[0], Po[1], Po[2] = cov_predict(P[0], P[1], P[2], Phi, Gam, Q, dacc)


@numba.njit(cache=True, inline="always")
def _copy_state(x, P, xs, Ps):
    """x (2,), P (3,) = xs, Ps."""
    x[0] = xs[0]
    x[1] = xs[1]
    P[0] = Ps[0]
    P[1] = Ps[1]
    P[2] = Ps[2]


@numba.njit(cache=True, inline="always")
def _store_row(X, PP, r, xs, Ps):
    """Row r of X (., 2), PP (., 3) = xs, Ps."""
    X[r, 0] = xs[0]
    X[r, 1] = xs[1]
    PP[r, 0] = Ps[0]
    PP[r, 1] = Ps[1]
    PP[r, 2] = Ps[2]


@numba.njit(cache=True, inline="always")
def _load_row(x, P, X, PP, r):
    """x, P = row r of X (., 2), PP (., 3)."""
    x[0] = X[r, 0]
    x[1] = X[r, 1]
    P[0] = PP[r, 0]
    P[1] = PP[r, 1]
    P[2] = PP[r, 2]


@numba.njit(cache=True, inline="always")
def scalar_update(x, P, h0, h1, nu, r):
    """Joseph-form scalar update with H = [h0, h1], innovation nu, variance r. Returns S."""
    p00, p01, p11 = P[0], P[1], P[2]
    ph0 = p00 * h0 + p01 * h1
    ph1 = p01 * h0 + p11 * h1
    S = h0 * ph0 + h1 * ph1 + r
    k0 = ph0 / S
    k1 = ph1 / S
    x[0] += k0 * nu
    x[1] += k1 * nu
    # Joseph: (I - K H) P (I - K H)^T + K r K^T
    a00 = 1.0 - k0 * h0
    a01 = -k0 * h1
    a10 = -k1 * h0
    a11 = 1.0 - k1 * h1
    b00 = a00 * p00 + a01 * p01
    b01 = a00 * p01 + a01 * p11
    b10 = a10 * p00 + a11 * p01
    b11 = a10 * p01 + a11 * p11
    P[0] = b00 * a00 + b01 * a01 + k0 * k0 * r
    P[1] = b00 * a10 + b01 * a11 + k0 * k1 * r
    P[2] = b10 * a10 + b11 * a11 + k1 * k1 * r
    return S


@numba.njit(cache=True, inline="always")
def _ycap_terms(x, y, gain, sc0, sth0, thth, full):
    """(H0, H1, nu) of the y_cap measurement, eq. (71): y = h(theta) omega, h = -R_s V_bias
    dC_s/dtheta; H = [h' omega (0 unless ``full``), h], nu = y - h omega [V]."""
    u = (x[0] - thth) / sth0
    e = math.exp(-u * u)
    h = -gain * (-2.0 * sc0 * u / sth0 * e)
    hp = -gain * (2.0 * sc0 / (sth0 * sth0) * (2.0 * u * u - 1.0) * e)
    nu = y - h * x[1]
    h0 = hp * x[1] if full else 0.0
    return h0, h, nu


@numba.njit(cache=True, inline="always")
def _ycap_update(x, P, y, gain, sc0, sth0, thth, rcap, full):
    """y_cap update, eq. (71) (:func:`_ycap_terms`)."""
    h0, h, nu = _ycap_terms(x, y, gain, sc0, sth0, thth, full)
    scalar_update(x, P, h0, h, nu, rcap)


@numba.njit(cache=True)
def peak_slope_angle(A, thth, sth0):
    """theta* = argmax_theta F, F = h'(theta)(A^2 - theta^2) - h(theta) theta (module doc)."""
    lo = max(thth - sth0, -A)
    hi = min(thth + sth0, A)
    if hi <= lo:
        return thth
    ng = 61
    best = -1e300
    ib = 0
    vals = np.empty(ng)
    for i in range(ng):
        th = lo + (hi - lo) * i / (ng - 1)
        u = (th - thth) / sth0
        e = math.exp(-u * u)
        hh = 2.0 * u / sth0 * e  # h / (gain c0), h = -gain C'
        hp = -2.0 / (sth0 * sth0) * (2.0 * u * u - 1.0) * e
        F = hp * (A * A - th * th) - hh * th
        vals[i] = F
        if F > best:
            best = F
            ib = i
    d = (hi - lo) / (ng - 1)
    th = lo + d * ib
    if 0 < ib < ng - 1:
        den = vals[ib - 1] - 2.0 * vals[ib] + vals[ib + 1]
        if den < 0.0:
            th += 0.5 * d * (vals[ib - 1] - vals[ib + 1]) / den
    return th


@numba.njit(cache=True)
def ekf_run(y, v, k0, det, opt, m, x, P, buf, out, adapt, ad):
    """Process samples k0..k0+n-1 of the 2-state filter. x, P: posterior of sample k0-1
    (in/out, P as [p00, p01, p11]).

    y, v: the frame's y_cap [V] and drive [V]; det: :class:`DetectionArrays` issued in the
    frame; opt: :class:`DetectionOptions`; m: the model
    (:class:`~mems_estimation.filters.scanner_threshold_specs.ScannerModel`); buf:
    :class:`LagBuffer` (size Lb, x (Lb, 2), P (Lb, 3)); out: :class:`RunOutputs`; adapt:
    [rate, scale max, gate^2] of the adaptive R_cap (rate 0: fixed), ad: its state [mean NIS,
    R_cap scale] (in/out).  Returns the number of detections consumed.
    """
    det_c, det_k, det_d, det_v = det.index, det.arrival, det.delta, det.timing_var
    canny, peak, wn, gate, use_sub = opt.canny, opt.peak, opt.wn, opt.gate, opt.use_sub
    Phi, Gam, Q, J = m.Phi, m.Gam, m.Q, m.J
    dc0, dth0, thth, sc0, sth0 = m.dc0, m.dth0, m.theta_th, m.sc0, m.sth0
    gain, rcap, rth, Ts, full = m.gain, m.r_cap, m.r_th, m.Ts, m.full_jac
    bx, bP, by, bv = buf.x, buf.P, buf.y, buf.v
    out_base, ox, oP, rx, stats = out.base, out.x, out.P, out.rx, out.stats
    Lb = by.shape[0]
    xp = np.empty(2)
    Pp = np.empty(3)
    xw = np.empty(2)
    Pw = np.empty(3)
    nd = det_c.shape[0]
    jd = 0
    n = y.shape[0]
    for i in range(n):
        k = k0 + i
        if k == 0:
            _copy_state(xp, Pp, x, P)
        else:
            _predict(
                x,
                P,
                v[i - 1] if i > 0 else bv[(k - 1) % Lb],
                Phi,
                Gam,
                Q,
                J,
                dc0,
                dth0,
                thth,
                xp,
                Pp,
            )
        s = k % Lb
        _store_row(bx, bP, s, xp, Pp)
        by[s] = y[i]
        bv[s] = v[i]
        _copy_state(x, P, xp, Pp)
        _ycap_update(x, P, y[i], gain, sc0, sth0, thth, rcap * ad[1], full)
        # late threshold detections issued at this sample
        while jd < nd and det_k[jd] <= k:
            c = det_c[jd]
            dlt = det_d[jd] if use_sub else 0.0
            jd += 1
            if k - c >= Lb or c < 0 or det_k[jd - 1] < k:
                stats[2] += 1
                continue
            sc = c % Lb
            _load_row(xw, Pw, bx, bP, sc)
            h1 = dlt * Ts
            rdet = rth
            if canny:
                rdet = rth + det_v[jd - 1] * (xw[1] * Ts) ** 2
            zth = thth
            if peak:
                amp = math.sqrt(xw[0] * xw[0] + (xw[1] / wn) ** 2)
                zth = peak_slope_angle(amp, thth, sth0)
            nu = zth - (xw[0] + h1 * xw[1])
            S = Pw[0] + 2.0 * h1 * Pw[1] + h1 * h1 * Pw[2] + rdet
            if adapt[0] > 0.0:
                # detection-aware R_cap: covariance matching on the detections' NIS
                ad[0] += adapt[0] * (min(nu * nu / S, adapt[2]) - ad[0])
                ad[1] = min(adapt[1], max(1.0, ad[0]))
            if nu * nu > gate * gate * S:
                stats[1] += 1
                continue
            stats[0] += 1
            # stacked update of Table 4.1 at sample c: both Jacobians at the prior
            hy0, hh, nu_y = _ycap_terms(xw, by[sc], gain, sc0, sth0, thth, full)
            scalar_update(xw, Pw, 1.0, h1, nu, rdet)
            scalar_update(xw, Pw, hy0, hh, nu_y, rcap * ad[1])
            r = c - out_base
            if r >= 0:
                _store_row(ox, oP, r, xw, Pw)
            for j in range(c + 1, k + 1):
                _predict(xw, Pw, bv[(j - 1) % Lb], Phi, Gam, Q, J, dc0, dth0, thth, xp, Pp)
                sj = j % Lb
                _store_row(bx, bP, sj, xp, Pp)
                _copy_state(xw, Pw, xp, Pp)
                _ycap_update(xw, Pw, by[sj], gain, sc0, sth0, thth, rcap * ad[1], full)
                r = j - out_base
                if r >= 0:
                    _store_row(ox, oP, r, xw, Pw)
            _copy_state(x, P, xw, Pw)
        r = k - out_base
        _store_row(ox, oP, r, x, P)
        rx[i, 0] = x[0]
        rx[i, 1] = x[1]
        det = P[0] * P[2] - P[1] * P[1]
        if det < stats[3] or P[0] <= 0.0 or P[2] <= 0.0:
            stats[3] = min(det, min(P[0], P[2]))
        if P[0] > stats[4]:
            stats[4] = P[0]
    return jd


# ------------------------------------------------------------------ comb-adaptive (4-state) kernels
@numba.njit(cache=True, inline="always")
def _aug_predict(z, P, v, Phi, Gam, Q, J, dc0, dth0, thth, qc, zo, Po):
    """Prediction of z = [theta, omega, a, b] (a, b: log gain and log width of the sensing
    comb, random walks of variance qc[0], qc[1] per sample); P full 4 x 4."""
    acc, dacc = _torque_terms(z[0], v, J, dc0, dth0, thth)
    zo[0] = Phi[0, 0] * z[0] + Phi[0, 1] * z[1] + Gam[0] * acc
    zo[1] = Phi[1, 0] * z[0] + Phi[1, 1] * z[1] + Gam[1] * acc
    zo[2] = z[2]
    zo[3] = z[3]
    G = np.eye(4)
    G[0, 0] = Phi[0, 0] + Gam[0] * dacc
    G[0, 1] = Phi[0, 1]
    G[1, 0] = Phi[1, 0] + Gam[1] * dacc
    G[1, 1] = Phi[1, 1]
    Po[:, :] = G @ P @ G.T
    Po[0, 0] += Q[0, 0]
    Po[0, 1] += Q[0, 1]
    Po[1, 0] += Q[1, 0]
    Po[1, 1] += Q[1, 1]
    Po[2, 2] += qc[0]
    Po[3, 3] += qc[1]


@numba.njit(cache=True, inline="always")
def _aug_scalar_update(z, P, H, nu, r):
    """Joseph-form scalar update of the 4-state filter. Returns S."""
    PH = P @ H
    S = H @ PH + r
    K = PH / S
    for i in range(4):
        z[i] += K[i] * nu
    A = np.eye(4) - np.outer(K, H)
    P[:, :] = A @ P @ A.T + np.outer(K, K) * r
    return S


@numba.njit(cache=True, inline="always")
def _aug_ycap_update(z, P, y, gain, sc0, sth0, thth, rcap):
    """y = h(theta; C0 e^a, theta0 e^b) omega, eq. (71) with the comb's gain and width as
    states; Jacobian [h' omega, h, y, y (2 u^2 - 2)]."""
    w0 = sth0 * math.exp(z[3])
    c0 = sc0 * math.exp(z[2])
    u = (z[0] - thth) / w0
    e = math.exp(-u * u)
    h = gain * 2.0 * c0 * u / w0 * e
    hp = -gain * (2.0 * c0 / (w0 * w0) * (2.0 * u * u - 1.0) * e)
    yh = h * z[1]
    H = np.empty(4)
    H[0] = hp * z[1]
    H[1] = h
    H[2] = yh
    H[3] = yh * (2.0 * u * u - 2.0)
    _aug_scalar_update(z, P, H, y - yh, rcap)


@numba.njit(cache=True)
def aug_run(y, v, k0, det, opt, m, qc, z, P, buf, out):
    """:func:`ekf_run` for the 4-state filter z = [theta, omega, log gain, log width] (z, P
    full; buf.x (Lb, 4), buf.P (Lb, 4, 4), out.x (m, 4)); qc: random-walk variances of the
    comb's log gain and log width per sample; R_cap fixed."""
    det_c, det_k, det_d, det_v = det.index, det.arrival, det.delta, det.timing_var
    canny, peak, wn, gate, use_sub = opt.canny, opt.peak, opt.wn, opt.gate, opt.use_sub
    Phi, Gam, Q, J = m.Phi, m.Gam, m.Q, m.J
    dc0, dth0, thth, sc0, sth0 = m.dc0, m.dth0, m.theta_th, m.sc0, m.sth0
    gain, rcap, rth, Ts = m.gain, m.r_cap, m.r_th, m.Ts
    bz, bP, by, bv = buf.x, buf.P, buf.y, buf.v
    out_base, oz, oP, rx, stats = out.base, out.x, out.P, out.rx, out.stats
    Lb = by.shape[0]
    zp = np.empty(4)
    Pp = np.empty((4, 4))
    zw = np.empty(4)
    Pw = np.empty((4, 4))
    Hd = np.zeros(4)
    nd = det_c.shape[0]
    jd = 0
    n = y.shape[0]
    for i in range(n):
        k = k0 + i
        if k == 0:
            zp[:] = z
            Pp[:, :] = P
        else:
            vv = v[i - 1] if i > 0 else bv[(k - 1) % Lb]
            _aug_predict(z, P, vv, Phi, Gam, Q, J, dc0, dth0, thth, qc, zp, Pp)
        s = k % Lb
        bz[s] = zp
        bP[s] = Pp
        by[s] = y[i]
        bv[s] = v[i]
        z[:] = zp
        P[:, :] = Pp
        _aug_ycap_update(z, P, y[i], gain, sc0, sth0, thth, rcap)
        while jd < nd and det_k[jd] <= k:
            c = det_c[jd]
            dlt = det_d[jd] if use_sub else 0.0
            jd += 1
            if k - c >= Lb or c < 0 or det_k[jd - 1] < k:
                stats[2] += 1
                continue
            sc = c % Lb
            zw[:] = bz[sc]
            Pw[:, :] = bP[sc]
            h1 = dlt * Ts
            rdet = rth
            if canny:
                rdet = rth + det_v[jd - 1] * (zw[1] * Ts) ** 2
            zth = thth
            if peak:
                amp = math.sqrt(zw[0] * zw[0] + (zw[1] / wn) ** 2)
                zth = peak_slope_angle(amp, thth, sth0 * math.exp(zw[3]))
                # the correction's size as its own uncertainty (detection bias at low SNR)
                rdet += (zth - thth) ** 2
            nu = zth - (zw[0] + h1 * zw[1])
            Hd[0] = 1.0
            Hd[1] = h1
            S = Hd @ Pw @ Hd + rdet
            if nu * nu > gate * gate * S:
                stats[1] += 1
                continue
            stats[0] += 1
            # stacked update of Table 4.1 at sample c (both Jacobians at the prior: the y_cap
            # update is re-done after the detection's, which is what the sequential form of the
            # stacked update with diagonal R is)
            by_c = by[sc]
            _aug_scalar_update(zw, Pw, Hd.copy(), nu, rdet)
            _aug_ycap_update(zw, Pw, by_c, gain, sc0, sth0, thth, rcap)
            r = c - out_base
            if r >= 0:
                oz[r] = zw
                oP[r, 0] = Pw[0, 0]
                oP[r, 1] = Pw[0, 1]
                oP[r, 2] = Pw[1, 1]
            for j in range(c + 1, k + 1):
                _aug_predict(zw, Pw, bv[(j - 1) % Lb], Phi, Gam, Q, J, dc0, dth0, thth, qc, zp, Pp)
                sj = j % Lb
                bz[sj] = zp
                bP[sj] = Pp
                zw[:] = zp
                Pw[:, :] = Pp
                _aug_ycap_update(zw, Pw, by[sj], gain, sc0, sth0, thth, rcap)
                r = j - out_base
                if r >= 0:
                    oz[r] = zw
                    oP[r, 0] = Pw[0, 0]
                    oP[r, 1] = Pw[0, 1]
                    oP[r, 2] = Pw[1, 1]
            z[:] = zw
            P[:, :] = Pw
        r = k - out_base
        oz[r] = z
        oP[r, 0] = P[0, 0]
        oP[r, 1] = P[0, 1]
        oP[r, 2] = P[1, 1]
        rx[i, 0] = z[0]
        rx[i, 1] = z[1]
        det = P[0, 0] * P[1, 1] - P[0, 1] * P[0, 1]
        if det < stats[3] or P[0, 0] <= 0.0 or P[1, 1] <= 0.0:
            stats[3] = min(det, min(P[0, 0], P[1, 1]))
        if P[0, 0] > stats[4]:
            stats[4] = P[0, 0]
    return jd

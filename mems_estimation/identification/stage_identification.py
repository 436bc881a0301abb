"""Identification of the micro-stage estimator's parameters (Chen 2018, sec. 3.5.4).

* wn, zeta, b_c (and the LDV delay) by circle fit of the stepped-sine sweep (Ewins [54]):
  the mobility FRF of eqs. (31)-(33), G(jw) = omega/u = jw b_c/(wn^2 - w^2 + 2j zeta wn w),
  is the circle Y = D/(1 + j x), x = (w^2 - wn^2)/(2 zeta wn w), D = b_c/(2 zeta wn), of
  diameter D through the origin. An algebraic (Kasa) circle fit gives the centre c;
  the angle of each point about c, psi = arg((Y - c)/c) = -2 atan(x), gives the linear
  least squares w^2 = wn^2 - (2 zeta wn) w tan(psi/2). A pure delay tau of the reference
  rotates the circle by -wn tau (the narrow band makes it a rigid rotation), so
  tau = -arg(c)/wn; the circle fit itself is rotation invariant.
* D_n per channel from the crest-to-trough distance lambda (eq. 55 a): the cancelled
  signal and the signal predicted by eqs. (46)-(47) from the LDV motion are each
  reduced to their first harmonics at the drive frequency (the paper's low-pass);
  lambda = phase from the maximum to the minimum [cycles]; D_n minimises
  sum over trials of (lambda_meas - lambda_pred(D_n))^2. lambda is gain invariant.
* eta per channel by least-squares amplitude match (eq. 55 b) with D_n fixed.
* R = covariance of the cancelled channels with zero drive.
* Q (input-noise variance of eq. 49) from the reference. The thesis' one-step prediction
  errors of the identified model driven by the LDV states (sec. 3.5.4),
  Q = var(e_omega) / B_d[1]^2, measure the LDV's white noise rather than the stage's input
  noise (:func:`identify_Q`); the default is the Q that minimises the EKF's deviation from
  the reference on the training sweep (:func:`identify_Q_reference`).
* Output correction alpha, beta (eqs. 59-61) of the EKF on the training data (last step
  of sec. 3.5.4).

Nothing here reads the emulator's truth: inputs are the drive, the cancelled ADC
channels and the LDV reference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
from scipy.optimize import minimize_scalar

from mems_estimation.filters.stage_ekf import StageEkf, StageModel
from mems_sim.devices.stage_capacitance import dual_axis_gradient

__all__ = [
    "harmonic_fit",
    "frequency_response",
    "circle_fit",
    "kasa_circle",
    "crest_trough",
    "identify_sensor",
    "identify_R",
    "identify_Q",
    "evaluate",
    "fold_period",
    "trial_fits",
    "TrialFit",
    "harmonic_eval",
    "output_correction",
    "integrate_harmonics",
    "identify",
    "reidentify_gap",
    "cancelled",
    "ldv_bias",
]

N_HARM = 6


@numba.njit(cache=True)
def _harmonic_normal(x, ph, n_harm, G, b):
    """Normal equations G = M^T M, b = M^T x of the harmonic regressor
    M = [1, cos(m ph), sin(m ph)] (ph in rad, m = 1..n_harm) without forming M.

    Per sample only the sums C_k = sum cos(k ph), S_k = sum sin(k ph), k <= 2 n_harm
    (angle-addition recursion, one cos/sin per sample) and b are accumulated; G follows
    from the product-to-sum identities, e.g. cos(m ph) cos(l ph) = (C_{m-l} + C_{m+l})/2.
    x: (n, k); G: (2 n_harm + 1,)^2, b: (2 n_harm + 1, k), both zeroed by the caller."""
    n = x.shape[0]
    k = x.shape[1]
    nk = 2 * n_harm
    C = np.zeros(nk + 1)
    S = np.zeros(nk + 1)
    cs = np.empty(nk + 1)
    sn = np.empty(nk + 1)
    for i in range(n):
        c1 = math.cos(ph[i])
        s1 = math.sin(ph[i])
        c, s = c1, s1
        for m in range(1, nk + 1):
            cs[m] = c
            sn[m] = s
            C[m] += c
            S[m] += s
            c, s = c * c1 - s * s1, s * c1 + c * s1
        for j in range(k):
            xv = x[i, j]
            b[0, j] += xv
            for m in range(1, n_harm + 1):
                b[2 * m - 1, j] += cs[m] * xv
                b[2 * m, j] += sn[m] * xv
    C[0] = n
    G[0, 0] = n
    for m in range(1, n_harm + 1):
        G[0, 2 * m - 1] = G[2 * m - 1, 0] = C[m]
        G[0, 2 * m] = G[2 * m, 0] = S[m]
        for l in range(1, n_harm + 1):
            d = abs(m - l)
            sd = S[d] if m >= l else -S[d]  # S_{m-l}, odd in m-l
            G[2 * m - 1, 2 * l - 1] = 0.5 * (C[d] + C[m + l])
            G[2 * m, 2 * l] = 0.5 * (C[d] - C[m + l])
            G[2 * m - 1, 2 * l] = 0.5 * (S[m + l] - sd)  # cos(m) sin(l)
            G[2 * m, 2 * l - 1] = 0.5 * (S[m + l] + sd)  # sin(m) cos(l)


def harmonic_fit(x: np.ndarray, phase: np.ndarray, n_harm: int = N_HARM) -> np.ndarray:
    """Least-squares Fourier coefficients of x(phase) (phase in cycles): returns
    (2 n_harm + 1, ...) [const, a_1, b_1, ..., a_M, b_M] with x ~ c + sum a_m cos + b_m sin.

    Solved through the normal equations (:func:`_harmonic_normal`): over whole drive periods
    the regressor columns are nearly orthogonal (M^T M ~ n diag(1, 1/2, ...)), so this is
    as accurate as an SVD least squares and ~50x faster on 10^5 samples."""
    xa = np.asarray(x, float)
    x2 = np.ascontiguousarray(xa.reshape(xa.shape[0], -1))
    ph = np.ascontiguousarray(2 * np.pi * np.asarray(phase, float).ravel())
    nc = 2 * n_harm + 1
    if x2.shape[0] < 4 * nc:  # too few samples for the normal equations: plain SVD
        cols = [np.ones_like(ph)]
        for m in range(1, n_harm + 1):
            cols += [np.cos(m * ph), np.sin(m * ph)]
        return np.linalg.lstsq(np.column_stack(cols), xa, rcond=None)[0]
    G = np.zeros((nc, nc))
    b = np.zeros((nc, x2.shape[1]))
    _harmonic_normal(x2, ph, int(n_harm), G, b)
    try:
        coef = np.linalg.solve(G, b)
    except np.linalg.LinAlgError:
        coef = np.linalg.lstsq(G, b, rcond=None)[0]
    return coef.reshape((nc,) + xa.shape[1:])


def harmonic_eval(coef: np.ndarray, phase: np.ndarray, const: bool = True) -> np.ndarray:
    """Evaluate :func:`harmonic_fit` coefficients on phases (cycles)."""
    ph = 2 * np.pi * np.asarray(phase, float)
    out = np.zeros(ph.shape + coef.shape[1:]) + (coef[0] if const else 0.0)
    nh = (coef.shape[0] - 1) // 2
    for m in range(1, nh + 1):
        c, s = np.cos(m * ph), np.sin(m * ph)
        if coef.ndim > 1:
            c, s = c[:, None], s[:, None]
        out = out + coef[2 * m - 1] * c + coef[2 * m] * s
    return out


def integrate_harmonics(coef: np.ndarray, freq: float) -> np.ndarray:
    """Coefficients of the zero-mean time integral of a harmonic series at freq Hz."""
    out = np.zeros_like(coef)
    nh = (coef.shape[0] - 1) // 2
    for m in range(1, nh + 1):
        w = 2 * np.pi * m * freq
        a, b = coef[2 * m - 1], coef[2 * m]
        out[2 * m - 1] = -b / w
        out[2 * m] = a / w
    return out


def frequency_response(
    u: np.ndarray,
    ref: np.ndarray,
    seg: np.ndarray,
    freqs: Sequence[float],
    fs: float,
    settle_fraction: float = 0.6,
) -> np.ndarray:
    """Complex FRF omega_ref/u at each stepped frequency, from the last (1 - settle_fraction)
    of each segment (phasor least squares with a constant for the reference bias).

    u[k] are the DAC's samples, held over [t_k, t_k + 1/fs): the analog drive is the
    sampled phasor times the zero-order hold's response e^{-j w T/2} sin(w T/2)/(w T/2),
    T = 1/fs. G is referred to the analog drive (divided by it), so the circle fit sees the
    continuous stage of eqs. (31)-(33) and the reference's delay alone (otherwise the hold's
    half sample, 0.8 us at 625 kHz, is taken for LDV delay)."""
    G = np.empty(len(freqs), complex)
    for i, f in enumerate(freqs):
        idx = np.flatnonzero(seg == i)
        if idx.size < 10:
            raise ValueError(f"sweep segment {i} ({f} Hz) has no data")
        idx = idx[int(settle_fraction * idx.size) :]
        t = idx / fs
        M = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t)])
        cu, *_ = np.linalg.lstsq(M, u[idx], rcond=None)
        cr, *_ = np.linalg.lstsq(M, ref[idx], rcond=None)
        wt2 = math.pi * f / fs
        zoh = np.exp(-1j * wt2) * math.sin(wt2) / wt2
        G[i] = (cr[0] - 1j * cr[1]) / ((cu[0] - 1j * cu[1]) * zoh)
    return G


def kasa_circle(z: np.ndarray) -> tuple[complex, float]:
    """Algebraic least-squares circle through complex points: (centre, radius)."""
    x, y = z.real, z.imag
    M = np.column_stack([x, y, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(M, -(x * x + y * y), rcond=None)
    c = complex(-sol[0] / 2, -sol[1] / 2)
    r = math.sqrt(max(abs(c) ** 2 - sol[2], 0.0))
    return c, r


def circle_fit(freqs: Sequence[float], G: np.ndarray) -> dict:
    """wn [rad/s], zeta, b_c [rad/s^2/V], delay [s], radius from the mobility circle (module doc)."""
    w = 2 * np.pi * np.asarray(freqs, float)
    c, r = kasa_circle(np.asarray(G))
    psi = np.angle((G - c) / c)
    M = np.column_stack([np.ones_like(w), -w * np.tan(psi / 2)])
    sol, *_ = np.linalg.lstsq(M, w * w, rcond=None)
    wn = math.sqrt(sol[0])
    zeta = sol[1] / (2 * wn)
    b_c = 2 * r * 2 * zeta * wn
    delay = -np.angle(c) / wn
    return {"wn": wn, "zeta": zeta, "b_c": b_c, "delay_s": delay, "radius": r, "centre": c}


def crest_trough(coef: np.ndarray, grid: int = 4096) -> np.ndarray:
    """lambda = (phase of minimum - phase of maximum) mod 1 [cycles] per column of coef,
    refined by a parabola through the grid extremum."""
    ph = np.arange(grid) / grid
    x = harmonic_eval(coef, ph)
    if x.ndim == 1:
        x = x[:, None]
    out = np.empty(x.shape[1])
    for j in range(x.shape[1]):
        pk = []
        for sgn in (1.0, -1.0):
            v = sgn * x[:, j]
            i = int(np.argmax(v))
            a, b, cc = v[i - 1], v[i], v[(i + 1) % grid]
            den = a - 2 * b + cc
            d = 0.5 * (a - cc) / den if den != 0 else 0.0
            pk.append((i + d) / grid)
        out[j] = (pk[1] - pk[0]) % 1.0
    return out


class TrialFit:
    """Harmonic reductions of one constant-drive trial (bias-on samples, settled part)."""

    def __init__(self, y_cancel, ldv, phase, freq, delay_s, mask):
        self.freq = freq
        on = mask & np.all(np.isfinite(y_cancel), axis=1)
        self.y = harmonic_fit(y_cancel[on], phase[on])  # (13, nch)
        cw = harmonic_fit(ldv[mask], phase[mask] - delay_s * freq)  # delay-compensated
        cw[0] = 0.0  # LDV bias (detrend)
        self.omega = cw
        self.theta = integrate_harmonics(cw, freq)


def trial_fits(y_cancel, ldv, phase, seg, f_drive, delay_s, settle_fraction=0.3):
    """One :class:`TrialFit` per segment index present in ``seg``."""
    fits = []
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        keep = np.zeros(seg.size, bool)
        keep[idx[int(settle_fraction * idx.size) :]] = True
        fits.append(TrialFit(y_cancel, ldv, phase, float(np.median(f_drive[idx])), delay_s, keep))
    return fits


def _predicted(fit: TrialFit, gap: float, limits_row, grid: int = 2048) -> np.ndarray:
    """Harmonics of y_hat/eta = dC/dtheta(theta_ref; D_n) omega_ref (eqs. 46-47)."""
    ph = np.arange(grid) / grid
    th = harmonic_eval(fit.theta, ph)
    om = harmonic_eval(fit.omega, ph)
    g = dual_axis_gradient(np.zeros_like(th), th, gap, np.asarray(limits_row)[None, :])
    yhat = g[:, 0, 1] * om
    return harmonic_fit(yhat, ph)


def identify_sensor(
    fits: Sequence[TrialFit], limits: np.ndarray, gap_bounds=(5e-6, 60e-6)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per channel (D_n [m], eta [-V R_s], lambda residual RMS [cycles]) (eq. 55)."""
    nch = limits.shape[0]
    gaps, etas, res = np.empty(nch), np.empty(nch), np.empty(nch)
    lam_meas = np.array([crest_trough(f.y) for f in fits])  # (trials, nch)
    for c in range(nch):
        # orientation: lambda runs from the maximum to the minimum of the signal, so the
        # prediction (eta = 1) takes the sign of the measured gain (eta < 0 in Table 3.3)
        g0 = 0.5 * (gap_bounds[0] + gap_bounds[1])
        sgn = math.copysign(
            1.0, sum(float(np.dot(f.y[1:, c], _predicted(f, g0, limits[c])[1:])) for f in fits)
        )

        def cost(dn):
            lp = np.array([crest_trough(sgn * _predicted(f, dn, limits[c]))[0] for f in fits])
            d = (lam_meas[:, c] - lp + 0.5) % 1.0 - 0.5
            return float(np.sum(d * d))

        r = minimize_scalar(cost, bounds=gap_bounds, method="bounded", options={"xatol": 1e-10})
        gaps[c] = r.x
        res[c] = math.sqrt(r.fun / len(fits))
        num = den = 0.0
        for f in fits:
            pr = _predicted(f, r.x, limits[c])
            num += float(np.dot(f.y[1:, c], pr[1:]))
            den += float(np.dot(pr[1:], pr[1:]))
        etas[c] = num / den
    return gaps, etas, res


def identify_R(y_cancel_zero: np.ndarray) -> np.ndarray:
    """Covariance of the cancelled channels recorded with zero drive [V^2]."""
    y = y_cancel_zero[np.all(np.isfinite(y_cancel_zero), axis=1)]
    if y.shape[0] < 100:
        raise ValueError("zero-input data too short to identify R")
    return np.atleast_2d(np.cov(y, rowvar=False))


def identify_Q(ldv, u, fs, A, B, delay_s, bias) -> float:
    """Q = var(e_omega)/B_d[1]^2, e = x_ref[k] - A_d x_ref[k-1] - B_d u[k-1] (sec. 3.5.4).

    x_ref: LDV rate shifted by the identified delay (linear interpolation), bias removed;
    theta by trapezoidal integration, detrended.
    """
    om = delayed_reference(ldv, delay_s, fs, bias)
    th = np.concatenate([[0.0], np.cumsum(0.5 * (om[1:] + om[:-1]) / fs)])
    t = np.arange(th.size)
    th = th - np.polyval(np.polyfit(t, th, 1), t)
    uu = u[: th.size]
    e = om[1:] - (A[1, 0] * th[:-1] + A[1, 1] * om[:-1] + B[1] * uu[:-1])
    return float(np.var(e) / B[1] ** 2)


def delayed_reference(ldv: np.ndarray, delay_s: float, fs: float, bias: float) -> np.ndarray:
    """LDV rate advanced by its identified delay (linear interpolation) with the bias
    removed [rad/s]; one sample per stage sample, shorter by the delay."""
    n = ldv.size
    k = np.arange(n) + delay_s * fs
    ok = k < n - 1
    i0 = np.floor(k[ok]).astype(int)
    fr = k[ok] - i0
    return ldv[i0] * (1 - fr) + ldv[i0 + 1] * fr - bias


def settled_mask(seg: np.ndarray, settle_fraction: float = 0.3) -> np.ndarray:
    """True on the samples of each trial after its first ``settle_fraction``."""
    mask = np.zeros(seg.size, bool)
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        mask[idx[int(settle_fraction * idx.size) :]] = True
    return mask


def identify_Q_reference(
    model: StageModel, y_cancel, u, ldv, seg, delay_s, bias, decades: int = 14, blocks: int = 50
) -> tuple[float, np.ndarray]:
    """Q [V^2] from the reference: the largest Q whose EKF is not significantly worse
    than the best one against the LDV on the training sweep.

    Why not the thesis' formula: the one-step prediction errors of sec. 3.5.4
    (:func:`identify_Q`), e = x_ref[k] - A x_ref[k-1] - B u[k-1], carry ~2 sigma_LDV^2 of
    white reference noise against a true input noise many orders smaller (here ~10 V^2
    against ~3e-7 V^2 of drive-amplifier noise), so the EKF they parametrise follows the
    capacitive measurements sample by sample and its omega is noisy.

    Here, for Q on a grid of one decade from Q_1step down ``decades`` decades, the EKF runs
    on the training data; its cost is the residual variance of the delay-compensated,
    de-biased LDV regressed on the EKF's omega (the affine part is what the output
    correction alpha, beta removes afterwards) over the settled samples. The LDV noise is
    white and independent of the estimate, so the cost is the error against the true rate
    plus a constant. The cost flattens once the filter is model-driven, so the chosen Q is
    the largest one whose cost exceeds the minimum by less than two standard errors of the
    paired difference (batch means over ``blocks`` contiguous blocks): the one-standard-
    error rule of model selection with a 2-sigma margin, which keeps the filter as close to
    its measurements as the reference can justify. Returns (Q, rows of (log10 Q, cost,
    cost excess, its standard error))."""
    import copy

    ref = delayed_reference(ldv, delay_s, model.fs, bias)
    m = ref.size
    mask = settled_mask(seg[:m])
    top = math.log10(float(model.Q))
    grid = top - np.arange(decades + 1, dtype=float)
    res = []
    for lq in grid:
        mm = copy.copy(model)
        mm.Q = 10.0**lq
        x, _ = StageEkf(mm).step(y_cancel, u, corrected=False)
        xs = x[:m, 1][mask]
        r = ref[mask]
        ok = np.isfinite(xs)
        xs, r = np.where(ok, xs, 0.0), np.where(ok, r, 0.0)
        M = np.column_stack([xs, ok.astype(float)])
        coef, *_ = np.linalg.lstsq(M, r, rcond=None)
        res.append((r - M @ coef) ** 2)
    cost = np.array([float(np.mean(e)) for e in res])
    best = int(np.argmin(cost))
    rows = []
    chosen = None
    for i, lq in enumerate(grid):
        d = res[i] - res[best]
        bm = np.array([b.mean() for b in np.array_split(d, blocks)])
        se = float(bm.std(ddof=1) / math.sqrt(blocks))
        excess = float(d.mean())
        rows.append((lq, cost[i], excess, se))
        if chosen is None and excess <= 2.0 * se:
            chosen = lq
    return float(10.0**chosen), np.array(rows)


def fold_period(x: np.ndarray, phase: np.ndarray, bins: int = 368) -> np.ndarray:
    """Average x over drive periods into ``bins`` phase bins (eq. 58 'averaged into one cycle')."""
    b = np.minimum((np.asarray(phase) % 1.0 * bins).astype(int), bins - 1)
    cnt = np.bincount(b, minlength=bins)
    s = np.bincount(b, weights=x, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return s / cnt


def evaluate(
    omega_est: np.ndarray,
    omega_ref: np.ndarray,
    phase: np.ndarray,
    seg: np.ndarray,
    settle_fraction: float = 0.3,
) -> dict:
    """omega RMSE (eq. 58, per trial averaged into one cycle, pooled), alpha and beta
    (eqs. 59-61, all settled samples)."""
    errs, xs, ys = [], [], []
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        idx = idx[int(settle_fraction * idx.size) :]
        fe = fold_period(omega_est[idx], phase[idx])
        fr = fold_period(omega_ref[idx], phase[idx])
        good = np.isfinite(fe) & np.isfinite(fr)
        errs.append(fe[good] - fr[good])
        xs.append(omega_ref[idx])
        ys.append(omega_est[idx])
    e = np.concatenate(errs)
    x, y = np.concatenate(xs), np.concatenate(ys)
    M = np.column_stack([x, np.ones_like(x)])
    (alpha, beta), *_ = np.linalg.lstsq(M, y, rcond=None)
    return {"rmse": float(np.sqrt(np.mean(e * e))), "alpha": float(alpha), "beta": float(beta)}


def output_correction(
    model: StageModel, y_cancel, u, ldv, phase, seg, delay_s, bias, channels=None, estimator=None
) -> tuple[float, float]:
    """alpha, beta of the EKF on training data vs the delay-compensated, de-biased LDV.
    ``estimator``: a fresh filter with ``step(y, u, corrected=False)`` (default
    ``StageEkf(model)``)."""
    ekf = estimator or StageEkf(model)
    x, _ = ekf.step(y_cancel, u, corrected=False)
    ref = delayed_reference(ldv, delay_s, model.fs, bias)
    m = ref.size
    r = evaluate(x[:m, 1], ref, phase[:m], seg[:m])
    return r["alpha"], r["beta"]


def ldv_bias(rec: dict) -> float:
    """Constant LDV bias = mean of the constant terms of the per-trial harmonic reductions."""
    return float(
        np.mean(
            [
                harmonic_fit(rec["ldv"][rec["segment"] == s], rec["phase"][rec["segment"] == s])[0]
                for s in np.unique(rec["segment"])
            ]
        )
    )


def cancelled(rec: dict, enabled: bool = True) -> np.ndarray:
    """Feedthrough-cancelled channels of a record (NaN where no update)."""
    from mems_estimation.filters.stage_ekf import FeedthroughCanceller

    return FeedthroughCanceller(rec["y"].shape[1], rec["fs"], enabled=enabled).step(
        rec["y"], rec["v_bias"], rec["f_drive"]
    )


def identify(
    sweep: dict,
    sweep_freqs: Sequence[float],
    train: dict,
    zero: dict,
    limits: np.ndarray,
    output_corr: bool = True,
    q_method: str = "reference",
) -> tuple[StageModel, dict]:
    """Whole identification (module doc) from three records (see
    :func:`mems_sim.devices.stage.record`): frequency sweep, training amplitude sweep, zero
    drive. ``limits``: the electrode layout (Table A.1 design data, not identified).
    ``q_method``: ``'reference'`` (:func:`identify_Q_reference`, default) or ``'one_step'``
    (:func:`identify_Q`, the thesis' formula, kept for comparison).
    Returns the model and a report dict."""
    if q_method not in ("reference", "one_step"):
        raise ValueError(f"q_method {q_method!r}: 'reference' or 'one_step'")
    from mems_sim.devices.stage import stage_matrices

    fs = sweep["fs"]
    G = frequency_response(sweep["u"], sweep["ldv"], sweep["segment"], sweep_freqs, fs)
    cf = circle_fit(sweep_freqs, G)
    yc = cancelled(train)
    fits = trial_fits(
        yc, train["ldv"], train["phase"], train["segment"], train["f_drive"], cf["delay_s"]
    )
    gaps, etas, lam_res = identify_sensor(fits, limits)
    bias = ldv_bias(train)
    A, B = stage_matrices(cf["wn"], cf["zeta"], cf["b_c"], 1.0 / fs)
    q_one_step = identify_Q(train["ldv"], train["u"], fs, A, B, cf["delay_s"], bias)
    R = identify_R(cancelled(zero))
    model = StageModel(
        cf["wn"], cf["zeta"], cf["b_c"], fs, etas, gaps, np.asarray(limits), R, q_one_step
    )
    q_evals = None
    if q_method == "reference":
        model.Q, q_evals = identify_Q_reference(
            model, yc, train["u"], train["ldv"], train["segment"], cf["delay_s"], bias
        )
    if output_corr:
        a, b = output_correction(
            model,
            yc,
            train["u"],
            train["ldv"],
            train["phase"],
            train["segment"],
            cf["delay_s"],
            bias,
        )
        model.alpha, model.beta = a, b
    model.extra = {
        "ldv_delay_s": cf["delay_s"],
        "ldv_bias_rad_s": bias,
        "temperature_c": float(train.get("temperature_c", math.nan)),
    }
    report = {
        "circle": cf,
        "frf": G,
        "lambda_residual": lam_res,
        "ldv_bias": bias,
        "Q_one_step": q_one_step,
        "Q_search": q_evals,
    }
    return model, report


def reidentify_gap(model: StageModel, train: dict) -> StageModel:
    """Sensor parameters P_s = (D_n, eta) re-identified at a new temperature (sec. 3.5.3:
    D_n from the crest-to-trough distance, eta then from the amplitude, eq. 55); the
    stage model, R, Q and the output correction are kept. eta must follow D_n: the two
    are identified jointly and compensate each other's errors."""
    import copy

    yc = cancelled(train)
    fits = trial_fits(
        yc,
        train["ldv"],
        train["phase"],
        train["segment"],
        train["f_drive"],
        model.extra.get("ldv_delay_s", 0.0),
    )
    gaps, etas, _ = identify_sensor(fits, model.limits)
    m = copy.deepcopy(model)
    m.gap = gaps
    m.eta = etas
    m.extra["temperature_c"] = float(train.get("temperature_c", math.nan))
    return m

"""Whittle maximum-likelihood identification of an inertial sensor's noise model.

Asymptotically efficient alternative to the Allan-variance fit of
:mod:`mems_estimation.noise_id` for the same five-term model (same
:class:`~mems_estimation.noise_id.NoiseModelFit` result).

Model per sample (dT = 1/fs, the discrete model of :mod:`mems_sim.imu_noise`)::

    y_k = bias + x_k + w_k + r_k          (+ rounding to the LSB)
    x_{k+1} = a x_k + sqrt(1 - a^2) B e_k, a = exp(-dT/T)   (first-order Gauss-Markov)
    w_k white, variance N^2 fs                               (white rate, density N)
    r_{k+1} = r_k + K sqrt(dT) v_k                           (random walk)

The first difference d_k = y_k - y_{k-1} is stationary (the bias drops out) and
its exact discrete spectrum (variance per radian/sample, E|DFT|^2/n) is::

    S(w) = g(w) [N^2 fs + B^2 (1 - a^2)/|1 - a e^{-iw}|^2] + K^2 dT,   g(w) = |1 - e^{-iw}|^2

with |1 - a e^{-iw}|^2 = (1 - a)^2 + a g(w) (no cancellation for a -> 1).

Quantisation: the simulator rounds the *rate* to its LSB; for a signal spread
over several codes the rounding error is white with variance LSB^2/12, i.e. it
is indistinguishable from (and is folded into) the white term, so N is the
white density of the quantised output (N_true^2 + LSB^2/(12 fs))^(1/2)
(+0.07 % gyro, +0.8 % accelerometer at the defaults).  The Allan Q term (angle
quantisation, rate spectrum ~ g(w)) is not fitted: Q = 0, se/CI nan.

Estimator (Whittle / Dahlhaus tapered likelihood):

* d is multiplied by a split-cosine-bell taper (``taper`` = fraction at each
  end, default 5 %).  Without a taper the end terms of the white component
  add 2 N^2 fs / n to every periodogram ordinate (the DFT of a differenced
  white sequence carries w_n - w_0), which at 1e6 samples is 5-80x the
  random-walk level K^2 dT at low frequency and would wreck B, T and K.
* Periodogram I_j = |rfft(h d)|^2 / sum(h^2) at w_j = 2 pi j / n, 0 < j < n/2.
* Negative log-likelihood sum_j m_j [ln E_j + Ibar_j / E_j]: every ordinate
  j < ``n_keep`` individually (m_j = 1), above it log-spaced bins of relative
  width ``bin_ratio`` - 1 with the bin-mean periodogram Ibar and m ordinates
  (Gamma likelihood of a mean of m exponential ordinates), S at the bin's mean
  frequency.
* E_j is the exact expected tapered periodogram for j < ``n_window``: S
  convolved with the taper's spectral window |H|^2/sum(h^2) (sampled at
  1/4 bin, +-64 bins), so the finite-record smoothing at the Gauss-Markov knee
  (a few bins wide) causes no bias; E_j = S(w_j) above (S smooth on the bin scale).
* Parameters theta = (ln N^2, ln B^2, ln T, ln K^2), L-BFGS-B with the analytic
  gradient, bounds: the variance terms between 1e-14 and 1e4 times var(d),
  T in [2 dT, 10 n dT].  Started from the Allan fit (``start``, or
  :func:`~mems_estimation.noise_id.identify` when None) and from T/4, 4 T;
  the best optimum is kept.  A variance term that ends on its lower bound is
  reported as 0 (and T as nan when B = 0).

Uncertainty: expected Fisher information of the Whittle likelihood,
F = sum_j m_j (d ln E_j/d theta)(d ln E_j/d theta)^T, inflated by the taper's
variance factor kappa = n sum h^4 / (sum h^2)^2 (Dahlhaus 1983; 1.03 for 5 %):
cov(theta) = kappa F^-1.  se by the delta method (se(N) = N se(ln N^2)/2 ...);
95 % intervals exp(theta +- 1.96 se) (positive, asymmetric).  For a term at
zero the interval is [0, sqrt(1.96 se(c))] with se(c) from the Fisher
information in the linear coefficient c (N^2, B^2 or K^2).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from mems_estimation.noise_id import NoiseModelFit, identify

__all__ = ["fit_whittle", "diff_spectrum", "split_cosine_taper", "whittle_nll"]

_Z95 = 1.959963984540054
_OVERSAMPLE = 4          # window samples per Fourier bin
_HALF_WIDTH = 64         # window half width, bins
_LOG_LO, _LOG_HI = math.log(1e-14), math.log(1e4)


def split_cosine_taper(n: int, p: float) -> np.ndarray:
    """Split-cosine-bell (Tukey) taper of length n with a fraction p cosine at each end."""
    h = np.ones(n)
    m = int(math.floor(p * n))
    if m > 0:
        t = (np.arange(m) + 0.5) / m
        ramp = 0.5 * (1.0 - np.cos(math.pi * t))
        h[:m] = ramp
        h[n - m:] = ramp[::-1]
    return h


def _spectrum_terms(w: np.ndarray, T: float, dt: float):
    """g(w), G(w) = (1-a^2)/|1-a e^-iw|^2 and dG/dlnT at frequencies w (rad/sample)."""
    g = 4.0 * np.sin(0.5 * w) ** 2
    x = dt / T
    a = math.exp(-x)
    one_m_a = -math.expm1(-x)
    one_m_a2 = -math.expm1(-2.0 * x)
    D = one_m_a ** 2 + a * g
    G = one_m_a2 / D
    # d/da [(1-a^2)/((1-a)^2 + a g)] = [-2a D - (1-a^2)(-2(1-a) + g)] / D^2 ; da/dlnT = a x
    dG_da = (-2.0 * a * D - one_m_a2 * (g - 2.0 * one_m_a)) / D ** 2
    return g, G, dG_da * a * x


def diff_spectrum(w, N: float, B: float, K: float, T: float, fs: float) -> np.ndarray:
    """Exact spectrum of d_k = y_k - y_{k-1}, u^2 per (rad/sample) in the E|DFT|^2/n convention.

    Args:
        w: angular frequency, rad/sample (0..pi).
        N: white density u*sqrt(s); B: GM std u; K: random walk u/sqrt(s); T: GM time s.
        fs: sample rate, Hz.
    """
    w = np.asarray(w, dtype=float)
    dt = 1.0 / fs
    g = 4.0 * np.sin(0.5 * w) ** 2
    S = g * N ** 2 * fs + K ** 2 * dt
    if B > 0 and np.isfinite(T):
        S = S + g * B ** 2 * _spectrum_terms(w, T, dt)[1]
    return S


class _Whittle:
    """Binned tapered periodogram of the first difference and its likelihood."""

    def __init__(self, rate: np.ndarray, fs: float, taper: float, n_keep: int, bin_ratio: float,
                 n_window: int):
        y = np.asarray(rate, dtype=float)
        d = np.diff(y)
        n = d.size
        self.fs, self.dt, self.n = fs, 1.0 / fs, n
        h = split_cosine_taper(n, taper)
        s2 = float(np.sum(h ** 2))
        self.kappa = n * float(np.sum(h ** 4)) / s2 ** 2
        self.var_d = float(np.var(d))
        I = np.abs(np.fft.rfft(h * d)) ** 2 / s2     # E d = 0: no mean removal
        j = np.arange(I.size)
        jmax = (n - 1) // 2                      # strictly below Nyquist
        I, j = I[1:jmax + 1], j[1:jmax + 1]
        keep = min(n_keep, j.size)
        # log-spaced bins above n_keep
        edges = [keep]
        while edges[-1] < j.size:
            edges.append(max(edges[-1] + 1, int(math.ceil(edges[-1] * bin_ratio))))
        edges[-1] = j.size
        edges = np.array(edges)
        sums_I = np.add.reduceat(I[keep:], edges[:-1] - keep) if j.size > keep else np.empty(0)
        sums_j = np.add.reduceat(j[keep:].astype(float), edges[:-1] - keep) if j.size > keep else np.empty(0)
        counts = np.diff(edges).astype(float)
        self.I = np.concatenate([I[:keep], sums_I / counts])
        self.m = np.concatenate([np.ones(keep), counts])
        self.w = 2.0 * math.pi * np.concatenate([j[:keep].astype(float), sums_j / counts]) / n
        self.n_ordinates = int(j.size)
        # spectral window of the taper for the low-frequency exact expectation
        self.nw = min(n_window, keep)
        if self.nw > 0:
            P, M = _OVERSAMPLE, _HALF_WIDTH
            L = P * n
            Hw = np.abs(np.fft.fft(h, L)) ** 2 / (s2 * L)     # sums to 1 over the circle
            k = np.arange(-M * P, M * P + 1)
            wts = Hw[k % L]
            self.win = wts / wts.sum()
            self.win_mass_lost = 1.0 - float(wts.sum())
            # fine grid: frequencies (j*P + k) * 2pi/(P n), j = 1..nw, |k| <= M P
            idx = np.arange(P - M * P, self.nw * P + M * P + 1)
            self.fine_w = np.abs(2.0 * math.pi * idx / L)
            self.fine_w = np.minimum(self.fine_w, 2.0 * math.pi - self.fine_w)
            self.P, self.M = P, M

    # -- model --------------------------------------------------------------------------
    def _S_and_grad(self, w, c, T):
        """S and dS/d(ln N^2, ln B^2, ln T, ln K^2) (columns) at w; c = (N^2 fs, B^2, K^2 dt)."""
        g, G, dG = _spectrum_terms(w, T, self.dt)
        cw, cb, ck = c
        S = g * (cw + cb * G) + ck
        J = np.column_stack([g * cw, g * cb * G, g * cb * dG, np.full_like(w, ck)])
        return S, J

    def expected(self, theta):
        """Expected (tapered) periodogram E_j and dE_j/dtheta at the fitted frequencies."""
        lN2, lB2, lT, lK2 = theta
        c = (math.exp(lN2) * self.fs, math.exp(lB2), math.exp(lK2) * self.dt)
        T = math.exp(lT)
        S, J = self._S_and_grad(self.w, c, T)
        if self.nw > 0:
            Sf, Jf = self._S_and_grad(self.fine_w, c, T)
            P, nw = self.P, self.nw
            # convolution evaluated at fine index j*P (offset by the grid start)
            conv = np.convolve(Sf, self.win[::-1], mode="valid")[::P][:nw]
            S = S.copy()
            S[:nw] = conv
            J = J.copy()
            for col in range(4):
                J[:nw, col] = np.convolve(Jf[:, col], self.win[::-1], mode="valid")[::P][:nw]
        return S, J

    def nll(self, theta):
        """Normalised negative log-likelihood and gradient (per ordinate)."""
        E, J = self.expected(theta)
        if np.any(E <= 0) or not np.all(np.isfinite(E)):
            return 1e300, np.zeros(4)
        r = self.I / E
        f = float(np.sum(self.m * (np.log(E) + r))) / self.n_ordinates
        grad = (self.m * (1.0 - r) / E) @ J / self.n_ordinates
        return f, grad

    def fisher(self, theta):
        """Expected Fisher information in theta (unnormalised)."""
        E, J = self.expected(theta)
        L = J / E[:, None]
        return (L * self.m[:, None]).T @ L


def whittle_nll(rate: np.ndarray, fs: float, N: float, B: float, K: float, T: float,
                taper: float = 0.05) -> float:
    """Whittle negative log-likelihood (sum over ordinates) of parameters, for diagnostics."""
    wh = _Whittle(rate, fs, taper, 2000, 1.01, 512)
    return wh.nll(np.log([N ** 2, B ** 2, T, K ** 2]))[0] * wh.n_ordinates


def _start_theta(start: NoiseModelFit, var_d: float, fs: float, dt: float, n: int) -> np.ndarray:
    N2 = start.N ** 2 if start.N > 0 else var_d / fs / 2
    K2 = start.K ** 2 if start.K > 0 else 1e-6 * var_d / dt
    B2 = start.B ** 2 if start.B > 0 else 1e-3 * var_d * fs
    T = start.T if (start.B > 0 and np.isfinite(start.T)) else 100.0 * dt * math.sqrt(n)
    return np.log([N2, B2, T, K2])


def fit_whittle(rate: np.ndarray, fs: float, start: NoiseModelFit | None = None, *,
                taper: float = 0.05, n_keep: int = 2000, bin_ratio: float = 1.01,
                n_window: int = 512) -> NoiseModelFit:
    """Whittle maximum-likelihood fit of N, B, K, T of one axis (see module doc).

    Args:
        rate: (L,) rate samples at rest, rad/s or m/s^2 (constant bias ignored).
        fs: sample rate, Hz.
        start: starting fit (e.g. from :func:`~mems_estimation.noise_id.fit_allan`);
            None runs :func:`~mems_estimation.noise_id.identify` first.
        taper: split-cosine-bell fraction at each end of the differenced record, -.
        n_keep: lowest ordinates kept individually (not binned), -.
        bin_ratio: ratio of consecutive log-spaced bin edges above n_keep, -.
        n_window: lowest ordinates whose expectation includes the taper window, -.
    Returns:
        :class:`NoiseModelFit` with Q = 0 (quantisation folded into N), se and
        ci95 from the inverse Fisher information; chi2/dof are nan/0,
        rms_log_residual is the rms of ln(Ibar/E) over the bins (a fit-quality
        hint, ~1.1 for single ordinates), n_points the number of likelihood terms.
    """
    rate = np.asarray(rate, dtype=float)
    if rate.ndim != 1 or rate.size < 1000:
        raise ValueError(f"rate must be 1-D with at least 1000 samples, got shape {rate.shape}")
    if not fs > 0:
        raise ValueError(f"fs must be > 0, got {fs!r}")
    wh = _Whittle(rate, fs, taper, n_keep, bin_ratio, n_window)
    dt, n = wh.dt, wh.n
    if start is None:
        start = identify(rate, fs)[0]
    lv = math.log(wh.var_d)
    bounds = [(lv - math.log(fs) + _LOG_LO, lv - math.log(fs) + _LOG_HI),   # ln N^2
              (lv + _LOG_LO, lv + math.log(n) + _LOG_HI),                    # ln B^2
              (math.log(2.0 * dt), math.log(10.0 * n * dt)),                 # ln T
              (lv - math.log(dt) + _LOG_LO, lv - math.log(dt) + _LOG_HI)]   # ln K^2
    th0 = _start_theta(start, wh.var_d, fs, dt, n)
    th0 = np.array([min(max(v, lo + 1.0), hi - 1.0) for v, (lo, hi) in zip(th0, bounds)])
    best = None
    for dlT in (0.0, math.log(4.0), -math.log(4.0)):
        x0 = th0.copy()
        x0[2] = min(max(x0[2] + dlT, bounds[2][0] + 0.1), bounds[2][1] - 0.1)
        res = optimize.minimize(wh.nll, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                                options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-9})
        if best is None or res.fun < best.fun:
            best = res
    theta = best.x
    at_lo = np.array([theta[i] <= bounds[i][0] + 1e-3 for i in range(4)])
    vals, se, ci = _summarise(wh, theta, at_lo)
    E, _ = wh.expected(theta)
    logres = np.log(np.maximum(wh.I, 1e-300) / E)
    return NoiseModelFit(**vals, Q=0.0, se={**se, "Q": math.nan},
                         ci95={**ci, "Q": (math.nan, math.nan)},
                         chi2=math.nan, dof=0, chi2_reduced=math.nan,
                         rms_log_residual=float(np.sqrt(np.mean(logres ** 2))),
                         n_points=int(wh.I.size))


def _summarise(wh: _Whittle, theta: np.ndarray, at_lo: np.ndarray):
    """Values, se and 95 % CI of N, B, K, T from the Fisher information (see module doc)."""
    names = ("N", "B", "T", "K")
    F = wh.fisher(theta)
    b_zero = bool(at_lo[1])
    free = ~at_lo
    if b_zero:
        free[2] = False                          # T undefined without a GM term
    # linear-coefficient Fisher columns for parameters at zero: dS/dc = (dS/dlnc)/c
    scale = np.exp(theta).copy()
    scale[2] = 1.0
    vals, se, ci = {}, {}, {}
    cov = np.full((4, 4), np.nan)
    idx = np.flatnonzero(free)
    if idx.size:
        try:
            cov[np.ix_(idx, idx)] = wh.kappa * np.linalg.inv(F[np.ix_(idx, idx)])
        except np.linalg.LinAlgError:
            pass
    for i, p in enumerate(names):
        if i == 2:
            continue
        if at_lo[i]:
            # Fisher of the linear coefficient c at c -> 0 with the free parameters fixed
            Fc = F[i, i] / scale[i] ** 2
            se_c = math.sqrt(wh.kappa / Fc) if Fc > 0 else math.inf
            vals[p], se[p], ci[p] = 0.0, math.nan, (0.0, math.sqrt(_Z95 * se_c))
        else:
            v = math.exp(0.5 * theta[i])
            s = math.sqrt(cov[i, i]) if np.isfinite(cov[i, i]) and cov[i, i] >= 0 else math.nan
            vals[p], se[p] = v, 0.5 * v * s
            ci[p] = (v * math.exp(-0.5 * _Z95 * s), v * math.exp(0.5 * _Z95 * s))
    if b_zero:
        vals["T"], se["T"], ci["T"] = math.nan, math.nan, (math.nan, math.nan)
    else:
        T = math.exp(theta[2])
        s = math.sqrt(cov[2, 2]) if np.isfinite(cov[2, 2]) and cov[2, 2] >= 0 else math.nan
        vals["T"], se["T"] = T, T * s
        ci["T"] = (T * math.exp(-_Z95 * s), T * math.exp(_Z95 * s))
    return vals, se, ci

"""Automatic identification of an inertial sensor's noise model from its Allan variance.

Model (sum of independent terms; IEEE Std 952-1997 Annex C for the white,
random-walk and quantisation terms; the Gauss-Markov term is the exact
continuous-time Allan variance of a first-order Markov process, Petkov eq. (3))::

    AVAR(tau) = N^2/tau + K^2 tau/3 + AVAR_GM(tau; B, T) + 3 Q^2/tau^2
    AVAR_GM   = (2 B^2 T / tau) [1 - (T/(2 tau)) (3 - 4 e^{-tau/T} + e^{-2 tau/T})]

The continuous-time forms are used; for sampled data they are exact for the
white term and within K^2 dT^2/(6 tau) (a negligible white-like term) for the
random walk; the GM form is exact to O(dT/T).

Fit: for each T on a log grid the linear coefficients c = (N^2, K^2, B^2, Q^2)
solve a weighted non-negative least-squares problem (scipy.optimize.nnls) with
weights 1/sd(AVAR_i), sd = AVAR_model(tau_i) sqrt(2/edf_i); the best grid T is
refined by a bounded scalar minimisation of the weighted chi-square over ln T.
The weights are iterated (first pass: measured AVAR, then the fitted model),
because weighting by the measured AVAR biases the fit towards low points. The
edf come from :func:`mems_estimation.identification.allan.edf_from_slope` with the model's local
slope (NIST SP 1065 Sec. 5.3 approximations).  No fixed-slope line fits.

Uncertainty: Jacobian of the weighted residuals in the parameters
theta = (N^2, K^2, B^2, Q^2, ln T) -> covariance (J^T J)^-1, inflated by the
reduced chi-square when it exceeds 1 (the octave AVAR points are correlated).
Standard errors of N, B, K, Q follow by the delta method (se(c)/(2 sqrt c));
95 % intervals are c +- 1.96 se(c) clipped at 0, then square-rooted (so a
coefficient fitted as 0 gets [0, upper]); for T: exp(ln T +- 1.96 se(ln T)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from mems_estimation.identification.allan import (
    AllanResult,
    allan_analysis,
    chi2_interval,
    edf_from_slope,
)

__all__ = [
    "NoiseModelFit",
    "DiscreteNoiseModel",
    "avar_gm",
    "avar_model",
    "fit_allan",
    "identify",
    "identify_axes",
    "discrete_model",
]

_Z95 = 1.959963984540054
_PARAMS = ("N", "B", "K", "T", "Q")


@dataclass(frozen=True)
class NoiseModelFit:
    """Identified noise model (SI: rate unit u = rad/s or m/s^2).

    Attributes:
        N: white-noise density (ARW/VRW), u/sqrt(Hz) = u*sqrt(s).
        B: Gauss-Markov stationary std (bias instability), u.
        K: random-walk coefficient (RRW/ARW), u/sqrt(s).
        T: Gauss-Markov correlation time, s (nan if B = 0).
        Q: quantisation coefficient (AVAR 3 Q^2/tau^2), u*s.
        se: standard error of each of N, B, K, T, Q (same units).
        ci95: 95 % interval (low, high) of each of N, B, K, T, Q.
        chi2: weighted chi-square of the fit, -.
        dof: degrees of freedom (points - fitted parameters), -.
        chi2_reduced: chi2/dof, -.
        rms_log_residual: rms of ln(AVAR_meas/AVAR_model), -.
        n_points: number of Allan points fitted, -.
    """

    N: float
    B: float
    K: float
    T: float
    Q: float
    se: dict = field(default_factory=dict)
    ci95: dict = field(default_factory=dict)
    chi2: float = math.nan
    dof: int = 0
    chi2_reduced: float = math.nan
    rms_log_residual: float = math.nan
    n_points: int = 0

    def as_dict(self) -> dict:
        """Flat dict of values, standard errors and intervals (for messages/logs)."""
        d = {p: getattr(self, p) for p in _PARAMS}
        for p in _PARAMS:
            d[f"{p}_se"] = self.se.get(p, math.nan)
            d[f"{p}_ci95_low"], d[f"{p}_ci95_high"] = self.ci95.get(p, (math.nan, math.nan))
        d.update(
            chi2=self.chi2,
            dof=self.dof,
            chi2_reduced=self.chi2_reduced,
            rms_log_residual=self.rms_log_residual,
            n_points=self.n_points,
        )
        return d


@dataclass(frozen=True)
class DiscreteNoiseModel:
    """Petkov's discrete model, eqs. (4)-(10) (corrected), for sample rate fs.

    Attributes:
        fs: sample rate, Hz.
        a_d, b_d: eq. (4) coefficients, -.
        sigma_eta: eq. (6) corrected, sqrt(1-a_d^2) B / b_d, u.
        sigma_white: per-sample white std N*sqrt(fs) (eq. (9) style), u.
        sigma_rw_increment: random-walk increment std K*sqrt(dT), u.
        sigma_omega: eq. (7) driving std for rrw = K dT/(z-1) omega, 1/sqrt(dT), 1/sqrt(s).
        sigma_x: GM stationary std B, u.
    """

    fs: float
    a_d: float
    b_d: float
    sigma_eta: float
    sigma_white: float
    sigma_rw_increment: float
    sigma_omega: float
    sigma_x: float


def _gm_shape(x: np.ndarray) -> np.ndarray:
    """f(x) = 1 - (3 - 4 e^-x + e^-2x)/(2x), x = tau/T; series below x = 1e-2."""
    x = np.asarray(x, dtype=float)
    out = np.empty_like(x)
    small = x < 1e-2
    xs = x[small]
    out[small] = xs**2 / 3.0 - xs**3 / 4.0 + 7.0 * xs**4 / 60.0 - xs**5 / 24.0
    xl = x[~small]
    out[~small] = 1.0 - (-4.0 * np.expm1(-xl) + np.expm1(-2.0 * xl)) / (2.0 * xl)
    return out


def avar_gm(taus, B: float, T: float) -> np.ndarray:
    """Allan variance of a first-order Gauss-Markov process (Petkov eq. (3)).

    AVAR_GM = (2 B^2 T / tau) [1 - (T/(2 tau)) (3 - 4 e^{-tau/T} + e^{-2 tau/T})].

    Args:
        taus: averaging times, s.
        B: stationary std, u.
        T: correlation time, s.
    Returns:
        AVAR, u^2.
    """
    taus = np.asarray(taus, dtype=float)
    return 2.0 * B**2 * T / taus * _gm_shape(taus / T)


def _basis(taus: np.ndarray, T: float) -> np.ndarray:
    """Columns of AVAR per unit coefficient: [1/tau, tau/3, AVAR_GM(B=1), 3/tau^2]."""
    return np.column_stack([1.0 / taus, taus / 3.0, avar_gm(taus, 1.0, T), 3.0 / taus**2])


def avar_model(taus, N: float, B: float, K: float, T: float, Q: float = 0.0) -> np.ndarray:
    """Model Allan variance N^2/tau + K^2 tau/3 + AVAR_GM + 3 Q^2/tau^2, u^2.

    Args: taus s; N u*sqrt(s); B u; K u/sqrt(s); T s; Q u*s.
    """
    taus = np.asarray(taus, dtype=float)
    gm = avar_gm(taus, B, T) if (B > 0 and np.isfinite(T)) else 0.0
    return N**2 / taus + K**2 * taus / 3.0 + gm + 3.0 * Q**2 / taus**2


def _nnls_for_T(taus, avar, sd, T):
    """Weighted NNLS of c = (N^2, K^2, B^2, Q^2) at fixed T -> (c, chi2)."""
    A = _basis(taus, T) / sd[:, None]
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    c, rnorm = optimize.nnls(A / scale, avar / sd)
    return c / scale, rnorm**2


def _best_T(taus, avar, sd, t_lo, t_hi):
    """Grid search of ln T then bounded refinement; returns (T, c, chi2)."""
    grid = np.geomspace(t_lo, t_hi, 49)
    chis = np.array([_nnls_for_T(taus, avar, sd, T)[1] for T in grid])
    i = int(np.argmin(chis))
    lo, hi = math.log(grid[max(i - 1, 0)]), math.log(grid[min(i + 1, grid.size - 1)])
    res = optimize.minimize_scalar(
        lambda lt: _nnls_for_T(taus, avar, sd, math.exp(lt))[1],
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-4},
    )
    T = math.exp(res.x) if res.fun <= chis[i] else grid[i]
    c, chi2 = _nnls_for_T(taus, avar, sd, T)
    return T, c, chi2


def _model_sd(taus, model, n_phase, m):
    """sd of each AVAR point from the model: model*sqrt(2/edf), edf from the model slope."""
    slope = np.gradient(np.log(model), np.log(taus)) if taus.size > 1 else np.full(taus.shape, -1.0)
    edf = edf_from_slope(n_phase, m, slope)
    return model * np.sqrt(2.0 / edf), edf


def _jacobian(taus, c, T, sd):
    """d(residual)/d(N^2, K^2, B^2, Q^2, ln T), residual = (model - avar)/sd."""
    cols = _basis(taus, T)
    h = 1e-5
    dgm = (avar_gm(taus, 1.0, T * math.exp(h)) - avar_gm(taus, 1.0, T * math.exp(-h))) / (2 * h)
    J = np.column_stack([cols, c[2] * dgm]) / sd[:, None]
    return J


def _uncertainty(taus, c, T, sd, chi2, dof):
    """Covariance of theta = (N^2, K^2, B^2, Q^2, ln T) from the Jacobian."""
    J = _jacobian(taus, c, T, sd)
    free = np.ones(5, dtype=bool)
    if c[2] <= 0.0:
        free[4] = False  # T undefined without a GM term
    cov = np.full((5, 5), np.inf)
    Jf = J[:, free]
    norms = np.linalg.norm(Jf, axis=0)
    ok = norms > 0
    Js = Jf[:, ok] / norms[ok]
    try:  # column-scaled normal equations
        sub = np.linalg.inv(Js.T @ Js) / np.outer(norms[ok], norms[ok])
    except np.linalg.LinAlgError:
        return cov
    idx = np.flatnonzero(free)[ok]
    cov[np.ix_(idx, idx)] = sub * max(1.0, chi2 / dof if dof > 0 else 1.0)
    if not free[4]:
        cov[4, :] = cov[:, 4] = np.nan
    return cov


def _summarise(c, T, cov):
    """Values, standard errors and 95 % intervals of N, B, K, T, Q."""
    order = {"N": 0, "K": 1, "B": 2, "Q": 3}
    vals, se, ci = {}, {}, {}
    for p, i in order.items():
        ci_c = math.sqrt(cov[i, i]) if cov[i, i] >= 0 else math.inf
        v = math.sqrt(max(c[i], 0.0))
        vals[p] = v
        se[p] = ci_c / (2.0 * v) if v > 0 else (math.sqrt(ci_c) if np.isfinite(ci_c) else math.nan)
        lo = max(c[i] - _Z95 * ci_c, 0.0)
        hi = c[i] + _Z95 * ci_c
        ci[p] = (math.sqrt(lo), math.sqrt(hi))
    if c[2] > 0 and cov[4, 4] >= 0:
        s = math.sqrt(cov[4, 4])
        # a short record leaves log T almost undetermined: the interval may reach [0, inf]
        z = min(_Z95 * s, 700.0)
        hi = T * math.exp(z) if z < 700.0 else math.inf
        vals["T"], se["T"], ci["T"] = T, T * s, (T * math.exp(-z), hi)
    else:
        vals["T"], se["T"], ci["T"] = math.nan, math.nan, (math.nan, math.nan)
    return vals, se, ci


def fit_allan(
    allan: AllanResult, iterations: int = 4, t_bounds: tuple[float, float] | None = None
) -> NoiseModelFit:
    """Weighted fit of the five-term AVAR model to an Allan result (see module doc).

    Args:
        allan: overlapping Allan deviation (taus s, adev u) of the rate data.
        iterations: reweighting passes (model-based weights), -.
        t_bounds: (low, high) search range of T, s; default (tau_min, 10*tau_max).
    Returns:
        :class:`NoiseModelFit`.
    """
    taus, avar = allan.taus, allan.adev**2
    ok = avar > 0
    taus, avar, m = taus[ok], avar[ok], allan.m[ok]
    if taus.size < 6:
        raise ValueError(
            f"need at least 6 Allan points with AVAR > 0 to fit 5 parameters, got {taus.size}"
        )
    n_phase = allan.n_samples + 1
    t_lo, t_hi = t_bounds or (taus[0], 10.0 * taus[-1])
    sd, _ = _model_sd(taus, avar, n_phase, m)
    for _ in range(max(1, iterations)):
        T, c, chi2 = _best_T(taus, avar, sd, t_lo, t_hi)
        model = _basis(taus, T) @ c
        sd, _ = _model_sd(taus, np.maximum(model, 1e-300), n_phase, m)
    chi2 = float(np.sum(((model - avar) / sd) ** 2))
    dof = max(int(taus.size) - 5, 1)
    vals, se, ci = _summarise(c, T, _uncertainty(taus, c, T, sd, chi2, dof))
    return NoiseModelFit(
        **vals,
        se=se,
        ci95=ci,
        chi2=chi2,
        dof=dof,
        chi2_reduced=chi2 / dof,
        rms_log_residual=float(np.sqrt(np.mean(np.log(avar / model) ** 2))),
        n_points=int(taus.size),
    )


def _with_model_ci(allan: AllanResult, fit: NoiseModelFit) -> AllanResult:
    """Allan result whose edf/CI use the fitted model's local slope."""
    model = avar_model(allan.taus, fit.N, fit.B, fit.K, fit.T, fit.Q)
    model = np.maximum(model, 1e-300)
    slope = np.gradient(np.log(model), np.log(allan.taus)) if allan.taus.size > 1 else -1.0
    edf = edf_from_slope(allan.n_samples + 1, allan.m, slope)
    lo, hi = chi2_interval(allan.adev**2, edf, allan.confidence)
    return AllanResult(
        taus=allan.taus,
        m=allan.m,
        adev=allan.adev,
        adev_error=allan.adev_error,
        n_terms=allan.n_terms,
        edf=edf,
        ci_low=np.sqrt(lo),
        ci_high=np.sqrt(hi),
        confidence=allan.confidence,
        fs=allan.fs,
        n_samples=allan.n_samples,
    )


def identify(
    rate: np.ndarray, fs: float, grid: str = "octave"
) -> tuple[NoiseModelFit, AllanResult]:
    """Identify N, B, K, T, Q of one axis from rate data at rest.

    Args:
        rate: (L,) rate samples, rad/s or m/s^2 (any constant is ignored).
        fs: sample rate, Hz.
        grid: Allan tau grid, "octave", "decade" or "all".
    Returns:
        (fit, Allan result with model-based edf and confidence intervals).
    """
    allan = allan_analysis(np.asarray(rate, dtype=float), fs, grid)
    fit = fit_allan(allan)
    return fit, _with_model_ci(allan, fit)


def identify_axes(
    rates: np.ndarray, fs: float, grid: str = "octave"
) -> list[tuple[NoiseModelFit, AllanResult]]:
    """:func:`identify` for each column of ``rates`` (L, k), rad/s or m/s^2."""
    rates = np.asarray(rates, dtype=float)
    if rates.ndim != 2:
        raise ValueError(f"rates must have shape (L, k), got {rates.shape}")
    return [identify(rates[:, j], fs, grid) for j in range(rates.shape[1])]


def discrete_model(fit: NoiseModelFit, fs: float) -> DiscreteNoiseModel:
    """Petkov's discrete model (eqs. (4)-(10), corrected) for a fit at sample rate fs.

    Args:
        fit: identified model (SI).
        fs: sample rate, Hz.
    """
    dt = 1.0 / fs
    if fit.B > 0 and np.isfinite(fit.T):
        x = dt / fit.T
        a_d, b_d = math.exp(-x), -math.expm1(-x)
        sigma_eta = math.sqrt(-math.expm1(-2.0 * x)) * fit.B / b_d
    else:
        a_d, b_d, sigma_eta = 0.0, 1.0, 0.0
    return DiscreteNoiseModel(
        fs=fs,
        a_d=a_d,
        b_d=b_d,
        sigma_eta=sigma_eta,
        sigma_white=fit.N * math.sqrt(fs),
        sigma_rw_increment=fit.K * math.sqrt(dt),
        sigma_omega=1.0 / math.sqrt(dt),
        sigma_x=fit.B,
    )

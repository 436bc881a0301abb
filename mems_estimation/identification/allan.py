"""Overlapping Allan deviation of rate data, with confidence intervals.

Implements the overlapping Allan-variance estimator of Petkov & Slavov,
"Stochastic Modeling of MEMS Inertial Sensors", Sec. 2, eq. (2)::

    sigma^2(tau) = 1 / (2 tau^2 (L - 2m)) * sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2

with ``theta`` the integrated rate ("phase", here angle or velocity), obtained
by a cumulative sum exactly as ``allantools.frequency2phase`` does (mean removed,
``cumsum * dT``, a leading zero), so that the numbers equal
``allantools.oadev(rate, rate=fs, data_type='freq', taus=...)`` to rounding.

The per-m sum is a numba loop without temporaries (allantools allocates three
length-L arrays per m); the m values are distributed over threads with
``prange`` (each m's sum is one thread's, so the thread count does not change it).
Each sum is accumulated in blocks of ``_BLOCK`` terms so that its rounding error
stays far below 1e-9 relative even for 1e8 terms, and every addition's order is
fixed in the source (no fastmath): the same floats on every CPU.

Confidence intervals: chi-square with equivalent degrees of freedom (edf) from
the simple Howe-Allan-Barnes (1981) approximations for the overlapping Allan
variance, as tabulated in NIST SP 1065 (Riley 2008), Sec. 5.3 (IEEE Std
1139 / IEEE Std 952 Annex C use the same formulae); the noise type is given
either as an integer power-law exponent alpha of the rate PSD (S ~ f^alpha,
2 = white PM ... -2 = random-walk FM) or, via :func:`edf_from_slope`, by the
local log-log slope of the Allan *variance*, interpolating between the types.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy import stats

__all__ = [
    "AllanResult",
    "tau_grid",
    "ms_from_taus",
    "rate_to_phase",
    "oadev",
    "oadev_phase",
    "edf_oadev",
    "edf_from_slope",
    "chi2_interval",
    "allan_analysis",
]

_BLOCK = 4096
TAU_KINDS = ("octave", "decade", "all")


@dataclass(frozen=True)
class AllanResult:
    """Overlapping Allan deviation with its uncertainty, one entry per tau.

    Attributes:
        taus: averaging times tau = m/fs, s.
        m: averaging factors (samples per tau), -.
        adev: Allan deviation, units of the rate (rad/s, m/s^2, ...).
        adev_error: adev/sqrt(n_terms) (allantools' simple error), rate units.
        n_terms: number of terms L+1-2m in the eq. (2) sum, -.
        edf: equivalent degrees of freedom of each AVAR point, -.
        ci_low, ci_high: confidence interval of adev at ``confidence``, rate units.
        confidence: two-sided confidence level of (ci_low, ci_high), -.
        fs: sample rate, Hz.
        n_samples: number of rate samples L, -.
    """

    taus: np.ndarray
    m: np.ndarray
    adev: np.ndarray
    adev_error: np.ndarray
    n_terms: np.ndarray
    edf: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    confidence: float
    fs: float
    n_samples: int

    @property
    def avar(self) -> np.ndarray:
        """Allan variance, (rate units)^2."""
        return self.adev**2


def _candidate_taus(n_phase: int, fs: float, kind: str) -> np.ndarray:
    """allantools.tau_generator's keyword tau lists (s) for ``n_phase`` phase points."""
    if kind == "all":
        return (1.0 / fs) * np.linspace(1.0, n_phase, n_phase)
    if kind == "octave":
        maxn = np.floor(np.log2(n_phase))
        return (1.0 / fs) * np.logspace(0, int(maxn), int(maxn + 1), base=2.0)
    if kind == "decade":
        maxn = int(np.floor(np.log10(n_phase)))
        return np.array(
            [f * (1.0 / fs) * 10.0**k for k in range(maxn + 1) for f in (1.0, 2.0, 4.0)]
        )
    raise ValueError(f"tau grid kind {kind!r} is invalid: allowed one of {', '.join(TAU_KINDS)}")


def ms_from_taus(taus, n: int, fs: float) -> np.ndarray:
    """Averaging factors m (int64) kept by allantools.oadev for rate data.

    Mirrors ``allantools.tau_generator`` (m = round(tau*fs), 0 < m < L+1,
    unique, sorted) followed by ``remove_small_ns`` (n_terms = L+1-2m > 1).

    Args:
        taus: requested averaging times, s.
        n: number of rate samples L, -.
        fs: sample rate, Hz.
    """
    n_phase = n + 1
    m = np.round(np.asarray(taus, dtype=float) * fs)
    m = m[(m < n_phase) & (m > 0)]
    m = np.unique(m).astype(np.int64)
    return m[n_phase - 2 * m > 1]


def tau_grid(n: int, fs: float, kind: str = "octave") -> np.ndarray:
    """Averaging times (s) that ``allantools.oadev(..., taus=kind)`` evaluates.

    For L rate samples the phase has L+1 points; allantools builds its keyword
    list from that length ("octave": 2^k, k <= floor(log2(L+1)); "decade":
    1, 2, 4 x 10^k, k <= floor(log10(L+1)); "all": 1..L+1), keeps m < L+1 and
    drops points with fewer than 2 terms, i.e. the largest m is floor((L-1)/2).

    Args:
        n: number of rate samples L, -.
        fs: sample rate, Hz.
        kind: "octave", "decade" or "all".
    Returns:
        taus m/fs, s, ascending.
    """
    if fs <= 0:
        raise ValueError(f"sample rate fs = {fs!r} is invalid: allowed (0, inf) Hz")
    m = ms_from_taus(_candidate_taus(int(n) + 1, float(fs), kind), int(n), float(fs))
    return m / float(fs)


def rate_to_phase(rate: np.ndarray, fs: float) -> np.ndarray:
    """Integrated rate theta (Petkov Sec. 2), as allantools.frequency2phase.

    Args:
        rate: (L,) rate samples, e.g. rad/s.
        fs: sample rate, Hz.
    Returns:
        (L+1,) theta_k = dT * sum_{j<k} (rate_j - mean), starting at 0, e.g. rad.
    """
    y = np.ascontiguousarray(rate, dtype=float)
    if y.ndim != 1:
        raise ValueError(f"rate must be one-dimensional, got shape {y.shape}")
    mean = np.mean(y)  # same pairwise sum as allantools' np.nanmean on finite data
    if not np.isfinite(mean):
        raise ValueError("rate contains NaN or inf samples")
    return _phase_from_rate(y, mean, 1.0 / float(fs))


@numba.njit(cache=True, nogil=True)
def _phase_from_rate(y, mean, dt):
    """[0, cumsum(y - mean) * dt] in one pass; same rounding as numpy's cumsum."""
    phase = np.empty(y.shape[0] + 1)
    phase[0] = 0.0
    acc = 0.0
    for i in range(y.shape[0]):
        acc += y[i] - mean
        phase[i + 1] = acc * dt
    return phase


@numba.njit(cache=True, nogil=True, inline="always")
def _block_sum(work, lo, hi, m):
    """sum_{l=lo}^{hi-1} (work[l] - 2 work[l-m] + work[l-2m])^2, in an order fixed here.

    Eight accumulators, the term l - lo = 8 i + r into accumulator r (the terms past the
    last whole group of eight into accumulator 0, in sequence), added pairwise at the
    end: the order of every addition is written in the source, so the compiler cannot
    choose it per CPU (no fastmath reassociation), and the eight independent chains give
    the vector units the same work a reassociated loop would.
    """
    a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = 0.0
    l = lo
    while l + 8 <= hi:
        d0 = work[l] - 2.0 * work[l - m] + work[l - 2 * m]
        d1 = work[l + 1] - 2.0 * work[l + 1 - m] + work[l + 1 - 2 * m]
        d2 = work[l + 2] - 2.0 * work[l + 2 - m] + work[l + 2 - 2 * m]
        d3 = work[l + 3] - 2.0 * work[l + 3 - m] + work[l + 3 - 2 * m]
        d4 = work[l + 4] - 2.0 * work[l + 4 - m] + work[l + 4 - 2 * m]
        d5 = work[l + 5] - 2.0 * work[l + 5 - m] + work[l + 5 - 2 * m]
        d6 = work[l + 6] - 2.0 * work[l + 6 - m] + work[l + 6 - 2 * m]
        d7 = work[l + 7] - 2.0 * work[l + 7 - m] + work[l + 7 - 2 * m]
        a0 += d0 * d0
        a1 += d1 * d1
        a2 += d2 * d2
        a3 += d3 * d3
        a4 += d4 * d4
        a5 += d5 * d5
        a6 += d6 * d6
        a7 += d7 * d7
        l += 8
    while l < hi:
        d = work[l] - 2.0 * work[l - m] + work[l - 2 * m]
        a0 += d * d
        l += 1
    return ((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7))


@numba.njit(cache=True, nogil=True, inline="always")
def _neumaier_add(s, comp, x):
    """Neumaier's compensated summation step (Neumaier 1974): (s + x, comp + the rounding
    error of s + x); the sum is s + comp."""
    t = s + x
    if abs(s) >= abs(x):
        comp += (s - t) + x
    else:
        comp += (x - t) + s
    return t, comp


@numba.njit(cache=True, nogil=True)
def _sum_sq_second_diff(phase, m):
    """sum_k (x[k+2m] - 2 x[k+m] + x[k])^2 over k < len(x)-2m, in blocks aligned on k = 0.

    Each block is summed by :func:`_block_sum` (fixed order), the block sums in sequence.
    """
    n = phase.shape[0] - 2 * m
    total = 0.0
    k = 0
    while k < n:
        stop = min(k + _BLOCK, n)
        total += _block_sum(phase, k + 2 * m, stop + 2 * m, m)
        k = stop
    return total


@numba.njit(cache=True, parallel=True)
def _sums_for_ms(phase, ms):
    """Eq. (2) sums for every averaging factor in ``ms`` (threads over m)."""
    out = np.empty(ms.shape[0])
    for i in numba.prange(ms.shape[0]):
        out[i] = _sum_sq_second_diff(phase, ms[i])
    return out


def oadev_phase(phase: np.ndarray, fs: float, ms: np.ndarray):
    """Overlapping Allan deviation from phase data, eq. (2) of Petkov Sec. 2.

    Args:
        phase: (L+1,) integrated rate, e.g. rad.
        fs: sample rate, Hz.
        ms: averaging factors, each with L+1-2m >= 1.
    Returns:
        (adev rate units, adev_error = adev/sqrt(n_terms), n_terms).
    """
    ms = np.ascontiguousarray(ms, dtype=np.int64)
    sums = _sums_for_ms(np.ascontiguousarray(phase, dtype=float), ms)
    n_terms = (phase.shape[0] - 2 * ms).astype(float)
    adev = np.sqrt(sums / (2.0 * n_terms)) / ms * float(fs)
    return adev, adev / np.sqrt(n_terms), n_terms


def oadev(rate: np.ndarray, fs: float, taus="octave"):
    """Overlapping Allan deviation of rate data (Petkov Sec. 2, eq. (2)).

    Equals ``allantools.oadev(rate, rate=fs, data_type='freq', taus=taus)``.

    Args:
        rate: (L,) rate samples (rad/s, m/s^2, ...), finite.
        fs: sample rate, Hz.
        taus: "octave", "decade", "all", or an array of averaging times, s.
    Returns:
        (taus_used s, adev rate units, adev_error rate units, n_terms -).
    """
    rate = np.asarray(rate, dtype=float)
    if isinstance(taus, str):
        ms = ms_from_taus(_candidate_taus(rate.shape[0] + 1, float(fs), taus), rate.shape[0], fs)
    else:
        ms = ms_from_taus(taus, rate.shape[0], fs)
    phase = rate_to_phase(rate, fs)
    adev, err, n_terms = oadev_phase(phase, fs, ms)
    return ms / float(fs), adev, err, n_terms


def edf_oadev(n_phase, m, alpha: int):
    """Equivalent degrees of freedom of an overlapping AVAR point.

    Howe, Allan & Barnes (1981) approximations, NIST SP 1065 Sec. 5.3.

    Args:
        n_phase: number of phase points N = L+1, -.
        m: averaging factor(s), -.
        alpha: rate-PSD power-law exponent: 2 white PM, 1 flicker PM,
            0 white FM (white rate noise, ARW/VRW), -1 flicker FM (bias
            instability), -2 random-walk FM (rate/acceleration random walk).
    Returns:
        edf, - (array like ``m``).
    """
    N = float(n_phase)
    m = np.asarray(m, dtype=float)
    if alpha == 2:
        return (N + 1.0) * (N - 2.0 * m) / (2.0 * (N - m))
    if alpha == 1:
        return np.exp(
            np.sqrt(np.log((N - 1.0) / (2.0 * m)) * np.log((2.0 * m + 1.0) * (N - 1.0) / 4.0))
        )
    if alpha == 0:
        return (3.0 * (N - 1.0) / (2.0 * m) - 2.0 * (N - 2.0) / N) * 4.0 * m**2 / (4.0 * m**2 + 5.0)
    if alpha == -1:
        return np.where(
            m == 1, 2.0 * (N - 2.0) ** 2 / (2.3 * N - 4.9), 5.0 * N**2 / (4.0 * m * (N + 3.0 * m))
        )
    if alpha == -2:
        return (N - 2.0) / m * ((N - 1.0) ** 2 - 3.0 * m * (N - 1.0) + 4.0 * m**2) / (N - 3.0) ** 2
    raise ValueError(f"noise exponent alpha = {alpha!r} is invalid: allowed one of 2, 1, 0, -1, -2")


def edf_from_slope(n_phase, m, slope):
    """Greenhall-Riley edf for a local AVAR log-log slope, interpolated between noise types.

    Slope -2 (white PM / quantisation), -1 (white rate noise), 0 (flicker), +1 (random
    walk) are the power laws alpha = 2, 0, -1, -2 of :func:`edf_greenhall` (d = 2,
    overlapping); between them ln(edf) is interpolated linearly in the slope (a mixture
    of two power laws has an edf between theirs); the result is at least 1.

    Args:
        n_phase: number of phase points L+1, -.
        m: (k,) averaging factors, -.
        slope: (k,) d ln AVAR / d ln tau, -.
    """
    m = np.atleast_1d(np.asarray(m, dtype=np.int64))
    s = np.clip(np.broadcast_to(np.asarray(slope, dtype=float), m.shape), -2.0, 1.0)
    anchors = np.array([-2.0, -1.0, 0.0, 1.0])
    table = np.log(np.stack([edf_oavar_greenhall(int(n_phase), m, a) for a in (2, 0, -1, -2)]))
    idx = np.clip(np.searchsorted(anchors, s, side="right") - 1, 0, 2)
    frac = s - anchors[idx]
    cols = np.arange(m.shape[0])
    edf = np.exp(table[idx, cols] * (1.0 - frac) + table[idx + 1, cols] * frac)
    return np.maximum(edf, 1.0)


def chi2_interval(avar, edf, confidence: float = 0.683):
    """Chi-square confidence interval of an AVAR estimate (NIST SP 1065 Sec. 5.3).

    avar*edf/chi2_{1-p/2}(edf) <= AVAR <= avar*edf/chi2_{p/2}(edf), p = 1-confidence.

    Args:
        avar: estimated Allan variance, (rate units)^2.
        edf: equivalent degrees of freedom, -.
        confidence: two-sided level in (0, 1), -.
    Returns:
        (low, high) of the Allan *variance*, (rate units)^2.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence = {confidence!r} is invalid: allowed (0, 1)")
    p = 1.0 - confidence
    avar = np.asarray(avar, dtype=float)
    edf = np.asarray(edf, dtype=float)
    low = avar * edf / stats.chi2.ppf(1.0 - p / 2.0, edf)
    high = avar * edf / stats.chi2.ppf(p / 2.0, edf)
    return low, high


def local_slope(taus, avar) -> np.ndarray:
    """d ln AVAR / d ln tau by finite differences on the (log) grid, -."""
    lt, la = np.log(np.asarray(taus, float)), np.log(np.maximum(np.asarray(avar, float), 1e-300))
    if lt.shape[0] < 2:
        return np.full(lt.shape, -1.0)
    return np.gradient(la, lt)


def allan_analysis(
    rate: np.ndarray, fs: float, taus="octave", confidence: float = 0.683, slope=None
) -> AllanResult:
    """oadev plus chi-square confidence intervals of every point.

    Args:
        rate: (L,) rate samples, rad/s or m/s^2.
        fs: sample rate, Hz.
        taus: "octave", "decade", "all" or averaging times, s.
        confidence: two-sided confidence level, -.
        slope: AVAR log-log slope per tau for the edf (default: -1, white
            rate noise, i.e. alpha = 0; pass a model's slope for better edf).
    """
    rate = np.asarray(rate, dtype=float)
    t, adev, _, n_terms = oadev(rate, fs, taus)
    return allan_result(t, adev, n_terms, fs, rate.shape[0], confidence, slope)


# ---------------------------------------------------------------------------
# Greenhall's EDF algorithm
# ---------------------------------------------------------------------------

_J_MAX = 100
# Greenhall & Riley (2003), Table 1 (modified variances) and Table 2 (unmodified), rows
# alpha = 2..-4, columns d = 1..3: (a0, a1) of 1/edf ~ (a0 - a1/r)/r; Table 3 for alpha = 1.
_GR_TABLE1 = {
    2: ((2 / 3, 1 / 3), (7 / 9, 1 / 2), (22 / 25, 2 / 3)),
    1: ((0.840, 0.345), (0.997, 0.616), (1.141, 0.843)),
    0: ((1.079, 0.368), (1.033, 0.607), (1.184, 0.848)),
    -1: (None, (1.048, 0.534), (1.180, 0.816)),
    -2: (None, (1.302, 0.535), (1.175, 0.777)),
    -3: (None, None, (1.194, 0.703)),
    -4: (None, None, (1.489, 0.702)),
}
_GR_TABLE2 = {
    2: ((3 / 2, 1 / 2), (35 / 18, 1.0), (231 / 100, 3 / 2)),
    1: ((78.6, 25.2), (790.0, 410.0), (9950.0, 6520.0)),
    0: ((2 / 3, 1 / 6), (2 / 3, 1 / 3), (7 / 9, 1 / 2)),
    -1: (None, (0.852, 0.375), (0.997, 0.617)),
    -2: (None, (1.079, 0.368), (1.033, 0.607)),
    -3: (None, None, (1.053, 0.553)),
    -4: (None, None, (1.302, 0.535)),
}
_GR_TABLE3 = ((6.0, 4.0), (15.23, 12.0), (47.8, 40.0))
_BINOM_D = {1: (1, 2, 1), 2: (1, 4, 6, 4, 1), 3: (1, 6, 15, 20, 15, 6, 1)}


def _gr_sw(t, alpha: int):
    """Greenhall & Riley eq. (7): generalised autocovariance of the phase, power law alpha."""
    t = np.abs(np.asarray(t, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        lg = np.where(t > 0, np.log(np.where(t > 0, t, 1.0)), 0.0)
    if alpha == 2:
        return -t
    if alpha == 1:
        return t**2 * lg
    if alpha == 0:
        return t**3
    if alpha == -1:
        return t**4 * lg
    if alpha == -2:
        return t**5
    if alpha == -3:
        return t**6 * lg
    if alpha == -4:
        return t**7
    raise ValueError(f"noise exponent alpha = {alpha!r} is invalid: allowed integers -4..2")


def _gr_sx(t, F: float, alpha: int):
    """Eq. (8): the averaging filter of length 1/F applied to sw (F = inf: the limit)."""
    if math.isinf(F):
        return _gr_sw(t, alpha + 2)
    return F**2 * (2.0 * _gr_sw(t, alpha) - _gr_sw(t - 1.0 / F, alpha) - _gr_sw(t + 1.0 / F, alpha))


def _gr_sz(t, F: float, alpha: int, d: int):
    """Eq. (9): the d-th difference filter applied to sx (binomial weights, alternating)."""
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    for i, w in enumerate(_BINOM_D[d]):
        out += (-1) ** (i + d) * w * _gr_sx(t + (i - d), F, alpha)
    return out


def _gr_basic_sum(J: int, M: float, S: float, F: float, alpha: int, d: int) -> float:
    """Eq. (10): sz(0)^2 + (1 - J/M) sz(J/S)^2 + 2 sum_{j<J} (1 - j/M) sz(j/S)^2."""
    j = np.arange(1, int(J), dtype=float)
    first = _gr_sz(np.array([0.0]), F, alpha, d)[0] ** 2
    second = (1.0 - J / M) * _gr_sz(np.array([J / S]), F, alpha, d)[0] ** 2
    third = float(np.sum(2.0 * (1.0 - j / M) * _gr_sz(j / S, F, alpha, d) ** 2))
    return first + second + third


def edf_greenhall(
    alpha: int, d: int, m: int, n_phase: int, overlapping: bool = True, modified: bool = False
) -> float:
    """Equivalent degrees of freedom of a finite-difference stability variance.

    C. A. Greenhall and W. J. Riley, "Uncertainty of stability variances based on finite
    differences", Proc. 35th PTTI (2003), the algorithm Stable32 uses (and NIST SP 1065,
    Riley 2008, Sec. 5.3 recommends): the variance of the estimator computed from the
    generalised autocovariance of the power-law phase noise, Eqs. (7)-(10) for J <= 100
    lags and the fitted asymptotes of Tables 1-3 beyond.

    Args:
        alpha: exponent of the rate (fractional-frequency) PSD, S ~ f^alpha, -4..2
            (2 white PM / quantisation, 0 white rate noise, -1 flicker, -2 random walk).
        d: difference order, 1 (first difference), 2 (Allan), 3 (Hadamard); alpha + 2d > 1.
        m: averaging factor (tau = m/fs), -.
        n_phase: number of phase points (rate samples + 1), -.
        overlapping: overlapping estimator (stride 1) instead of stride m.
        modified: modified (MVAR-type) variance instead of the unmodified one.
    Returns:
        edf, -.
    """
    alpha, d, m = int(alpha), int(d), int(m)
    if alpha + 2 * d <= 1:
        raise ValueError(
            f"alpha = {alpha} with d = {d}: Greenhall's algorithm needs alpha + 2d > 1"
        )
    F = 1.0 if modified else float(m)
    S = float(m) if overlapping else 1.0
    L = m / F + m * d
    M = 1.0 + math.floor(S * (n_phase - L) / m)
    if M < 1:
        raise ValueError(f"m = {m} leaves no term for {n_phase} phase points (d = {d})")
    J = min(M, (d + 1) * S)
    r = M / S
    if modified:
        if J <= _J_MAX:
            return (
                _gr_sz(np.array([0.0]), 1.0, alpha, d)[0] ** 2
                * M
                / _gr_basic_sum(J, M, S, 1.0, alpha, d)
            )
        if r > d + 1:
            a0, a1 = _GR_TABLE1[alpha][d - 1]
            return r / (a0 - a1 / r)
        mp = _J_MAX / r
        return (
            _gr_sz(np.array([0.0]), 1.0, alpha, d)[0] ** 2
            * _J_MAX
            / _gr_basic_sum(_J_MAX, _J_MAX, mp, 1.0, alpha, d)
        )
    if alpha <= 0:
        if J <= _J_MAX:
            Fp = float(m) if m * (d + 1) <= _J_MAX else math.inf
            return (
                _gr_sz(np.array([0.0]), Fp, alpha, d)[0] ** 2
                * M
                / _gr_basic_sum(J, M, S, Fp, alpha, d)
            )
        if r > d + 1:
            a0, a1 = _GR_TABLE2[alpha][d - 1]
            return r / (a0 - a1 / r)
        mp = _J_MAX / r
        return (
            _gr_sz(np.array([0.0]), math.inf, alpha, d)[0] ** 2
            * _J_MAX
            / _gr_basic_sum(_J_MAX, _J_MAX, mp, math.inf, alpha, d)
        )
    if alpha == 1:
        if J <= _J_MAX:
            return (
                _gr_sz(np.array([0.0]), float(m), 1, d)[0] ** 2
                * M
                / _gr_basic_sum(J, M, S, float(m), 1, d)
            )
        b0, b1 = _GR_TABLE3[d - 1]
        if r > d + 1:
            a0, a1 = _GR_TABLE2[alpha][d - 1]
            return (b0 + b1 * math.log(m)) ** 2 * r / (a0 - a1 / r)
        mp = _J_MAX / r
        return (b0 + b1 * math.log(m)) ** 2 * _J_MAX / _gr_basic_sum(_J_MAX, _J_MAX, mp, mp, 1, d)
    # alpha = 2: the closed form for r > d; below it the basic sum with F = m (allantools
    # leaves this case open).  White PM filtered by an m-sample average and differenced at
    # lag m is correlated only at lags within one sample of 0, m, ..., d m: the sum's other
    # terms are zero, so only those lags are summed (exact, O(d) work for any m).
    if math.ceil(r) > d:
        a0 = math.comb(4 * d, 2 * d) / math.comb(2 * d, d) ** 2
        return M / (a0 - (d / 2.0) / r)
    return _gr_sz(np.array([0.0]), float(m), 2, d)[0] ** 2 * M / _gr_basic_sum_sparse(J, M, m, d)


def _gr_basic_sum_sparse(J: int, M: float, m: int, d: int) -> float:
    """Eq. (10) for alpha = 2, F = S = m, summing only the lags where sz is non-zero."""
    F = S = float(m)
    lags = sorted({k * m + e for k in range(d + 2) for e in (-1, 0, 1)} - {0})
    j = np.array([v for v in lags if 0 < v < J], dtype=float)
    first = _gr_sz(np.array([0.0]), F, 2, d)[0] ** 2
    second = (1.0 - J / M) * _gr_sz(np.array([J / S]), F, 2, d)[0] ** 2
    third = float(np.sum(2.0 * (1.0 - j / M) * _gr_sz(j / S, F, 2, d) ** 2)) if j.size else 0.0
    return first + second + third


@functools.lru_cache(maxsize=4096)
def _edf_oavar_cached(alpha: int, m: int, n_phase: int) -> float:
    return edf_greenhall(alpha, 2, m, n_phase, overlapping=True)


def edf_oavar_greenhall(n_phase: int, m, alpha: int) -> np.ndarray:
    """Greenhall-Riley edf of overlapping AVAR points, one per averaging factor in ``m``."""
    m = np.atleast_1d(np.asarray(m, dtype=np.int64))
    return np.array([_edf_oavar_cached(int(alpha), int(k), int(n_phase)) for k in m])


def allan_result(
    taus, adev, n_terms, fs: float, n_samples: int, confidence: float = 0.683, slope=None
) -> AllanResult:
    """AllanResult of given Allan deviations, with Greenhall-Riley edf and chi-square intervals.

    Args:
        taus: averaging times, s; adev: Allan deviation, rate units; n_terms: terms per point.
        fs: sample rate, Hz; n_samples: rate samples L, -.
        confidence: two-sided level of the intervals, -.
        slope: AVAR log-log slope per tau for the edf (default -1: white rate noise).
    """
    taus = np.asarray(taus, dtype=float)
    adev = np.asarray(adev, dtype=float)
    n_terms = np.asarray(n_terms, dtype=float)
    m = np.round(taus * fs).astype(np.int64)
    edf = edf_from_slope(int(n_samples) + 1, m, -1.0 if slope is None else slope)
    lo, hi = chi2_interval(adev**2, edf, confidence)
    return AllanResult(
        taus=taus,
        m=m,
        adev=adev,
        adev_error=adev / np.sqrt(n_terms),
        n_terms=n_terms,
        edf=edf,
        ci_low=np.sqrt(lo),
        ci_high=np.sqrt(hi),
        confidence=confidence,
        fs=float(fs),
        n_samples=int(n_samples),
    )

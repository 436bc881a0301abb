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
``prange``.  Each sum is accumulated in blocks of ``_BLOCK`` terms so that its
rounding error stays far below 1e-9 relative even for 1e8 terms.

Confidence intervals: chi-square with equivalent degrees of freedom (edf) from
the simple Howe-Allan-Barnes (1981) approximations for the overlapping Allan
variance, as tabulated in NIST SP 1065 (Riley 2008), Sec. 5.3 (IEEE Std
1139 / IEEE Std 952 Annex C use the same formulae); the noise type is given
either as an integer power-law exponent alpha of the rate PSD (S ~ f^alpha,
2 = white PM ... -2 = random-walk FM) or, via :func:`edf_from_slope`, by the
local log-log slope of the Allan *variance*, interpolating between the types.
"""

from __future__ import annotations

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


@numba.njit(cache=True, nogil=True, fastmath={"reassoc"})
def _sum_sq_second_diff(phase, m):
    """sum_k (x[k+2m] - 2 x[k+m] + x[k])^2 over k < len(x)-2m, block-accumulated."""
    n = phase.shape[0] - 2 * m
    total = 0.0
    k = 0
    while k < n:
        stop = min(k + 4096, n)
        part = 0.0
        for j in range(k, stop):
            d = phase[j + 2 * m] - 2.0 * phase[j + m] + phase[j]
            part += d * d
        total += part
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
    """edf for a local AVAR log-log slope, interpolated between noise types.

    Slope -2 (white PM / quantisation), -1 (white FM), 0 (flicker FM), +1
    (random-walk FM) map to alpha 2, 0, -1, -2 of :func:`edf_oadev`; in between
    the edf is interpolated linearly in the slope; the result is at least 1.

    Args:
        n_phase: number of phase points L+1, -.
        m: (k,) averaging factors, -.
        slope: (k,) d ln AVAR / d ln tau, -.
    """
    m = np.asarray(m, dtype=float)
    s = np.clip(np.broadcast_to(np.asarray(slope, dtype=float), m.shape), -2.0, 1.0)
    anchors = np.array([-2.0, -1.0, 0.0, 1.0])
    table = np.stack([edf_oadev(n_phase, m, a) for a in (2, 0, -1, -2)])
    idx = np.clip(np.searchsorted(anchors, s, side="right") - 1, 0, 2)
    frac = s - anchors[idx]
    cols = np.arange(m.shape[0])
    edf = table[idx, cols] * (1.0 - frac) + table[idx + 1, cols] * frac
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
    t, adev, err, n_terms = oadev(rate, fs, taus)
    m = np.round(t * fs).astype(np.int64)
    n_phase = rate.shape[0] + 1
    edf = edf_from_slope(n_phase, m, -1.0 if slope is None else slope)
    lo, hi = chi2_interval(adev**2, edf, confidence)
    return AllanResult(
        taus=t,
        m=m,
        adev=adev,
        adev_error=err,
        n_terms=n_terms,
        edf=edf,
        ci_low=np.sqrt(lo),
        ci_high=np.sqrt(hi),
        confidence=confidence,
        fs=float(fs),
        n_samples=int(rate.shape[0]),
    )

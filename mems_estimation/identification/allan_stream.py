"""Streaming (bounded-memory) overlapping Allan sums of rate data.

The sums of eq. (2) of Petkov & Slavov, "Stochastic Modeling of MEMS Inertial Sensors"
(:mod:`mems_estimation.identification.allan`), accumulated frame by frame for a recording
of any length (:class:`StreamingAllan`): every averaging factor up to :data:`EXACT_M_MAX`
summed exactly over every k, larger ones over a thinned set of k, in the same fixed order
of additions as the whole-array kernel (the same floats on every CPU).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mems_estimation.identification.allan import (
    _BLOCK,
    AllanResult,
    _block_sum,
    _neumaier_add,
    allan_result,
)

__all__ = ["EXACT_M_MAX", "STREAM_M_LIMIT", "StreamingAllan", "stream_ms", "stream_results"]


#: Averaging factors up to this are summed exactly over every k (fully overlapping).
EXACT_M_MAX = 2**18
#: Above EXACT_M_MAX the sum runs over every s-th k, s the smallest divisor of m with
#: m/s <= THIN_RATIO (ring of 2 m/s + 1 decimated phase points per m).
THIN_RATIO = 4096
#: Largest averaging factor the streaming accumulator prepares (2^40 samples).
STREAM_M_LIMIT = 2**40
_SUB_BLOCK = 2**18


def stream_ms(kind: str, limit: int = STREAM_M_LIMIT) -> np.ndarray:
    """Every averaging factor of an allantools keyword grid up to ``limit`` (int64).

    "octave": 2^k; "decade": 1, 2, 4 x 10^k.  (allantools keeps, of these, the m with
    m < L+1 and L+1-2m > 1 for L samples, which :meth:`StreamingAllan.result` applies.)
    """
    if kind == "octave":
        out = [2**k for k in range(int(math.log2(limit)) + 1)]
    elif kind == "decade":
        out = [f * 10**k for k in range(int(math.log10(limit)) + 1) for f in (1, 2, 4)]
    else:
        raise ValueError(f"streaming tau grid {kind!r} is invalid: allowed octave, decade")
    return np.array(sorted(v for v in out if v <= limit), dtype=np.int64)


def _thin_stride(m: int, ratio: int = THIN_RATIO) -> int:
    """Smallest divisor s of m with m/s <= ratio (1 if m <= ratio)."""
    if m <= ratio:
        return 1
    lo = -(-m // ratio)
    for s in range(lo, m + 1):
        if m % s == 0:
            return s
    return m


@numba.njit(cache=True, nogil=True)
def _stream_update(
    y,
    ref,
    phase,
    phase_c,
    p_last,
    hist_len,
    work,
    ms,
    sums,
    comps,
    committed,
    tm,
    ts,
    tr,
    ring,
    tsums,
    tcomps,
):
    """Feed rate samples y (n, C) into the streaming Allan state (see StreamingAllan)."""
    n, nch = y.shape
    start = 0
    while start < n:
        nb = min(n - start, work.shape[1] - hist_len)
        p_first = p_last + 1
        for c in range(nch):
            w = work[c]
            # compensated (Kahan) cumulative sum of y - ref: the phase in sample units
            acc, comp = phase[c], phase_c[c]
            for i in range(nb):
                v = (y[start + i, c] - ref[c]) - comp
                t = acc + v
                comp = (t - acc) - v
                acc = t
                w[hist_len + i] = acc
            phase[c], phase_c[c] = acc, comp
            p_end = p_first + nb  # exclusive
            for j in range(ms.shape[0]):
                m = ms[j]
                # terms k (phase points k, k+m, k+2m) in whole blocks of _BLOCK aligned
                # on k = 0, so the sums do not depend on how the samples were split into calls
                k = committed[c, j]
                while k + _BLOCK <= p_end - 2 * m:
                    lo = k + 2 * m - p_first + hist_len
                    x = _block_sum(w, lo, lo + _BLOCK, m)
                    # Neumaier compensated accumulation of the block sums
                    sums[c, j], comps[c, j] = _neumaier_add(sums[c, j], comps[c, j], x)
                    k += _BLOCK
                committed[c, j] = k
            for j in range(tm.shape[0]):
                s_, r_ = ts[j], tr[j]
                q0 = (p_first + s_ - 1) // s_
                size = 2 * r_ + 1
                for q in range(q0, (p_end - 1) // s_ + 1):
                    ring[c, j, q % size] = w[q * s_ - p_first + hist_len]
                    if q >= 2 * r_:
                        d = ring[c, j, q % size] - 2.0 * ring[c, j, (q - r_) % size]
                        d += ring[c, j, (q - 2 * r_) % size]
                        x = d * d
                        tsums[c, j], tcomps[c, j] = _neumaier_add(tsums[c, j], tcomps[c, j], x)
            # keep the last hist_len phase points in front of the next block
            w[:hist_len] = w[nb : nb + hist_len].copy()
        p_last += nb
        start += nb
    return p_last


@numba.njit(cache=True, nogil=True)
def _pending_sums(work, hist_len, p_last, ms, committed):
    """Sums of the terms not yet in a whole block (fewer than _BLOCK per m)."""
    nch = work.shape[0]
    out = np.zeros((nch, ms.shape[0]))
    for c in range(nch):
        for j in range(ms.shape[0]):
            m = ms[j]
            k = committed[c, j]
            end = p_last + 1 - 2 * m
            if k < end:
                lo = k + 2 * m - (p_last + 1) + hist_len
                out[c, j] = _block_sum(work[c], lo, lo + (end - k), m)
    return out


class StreamingAllan:
    """Overlapping Allan variance accumulated online, memory independent of the record.

    The overlapping estimator (IEEE Std 952-1997 Annex C; NIST SP 1065, Riley 2008,
    Sec. 5.2.4) at averaging factor m is sum_k (x_{k+2m} - 2 x_{k+m} + x_k)^2 / (2 tau^2
    (N - 2m)) over the N phase points x (the cumulative sum of the rate).  The sum can be
    kept running: a new phase point x_p adds the term with k = p - 2m, which needs only
    the phase points p - m and p - 2m.  So for every m on the grid one running sum, and the
    last 2 m_max + 1 phase points, are the whole state; nothing else grows with the
    record:

    - m <= ``exact_m_max`` (default 2^18, i.e. every octave point of a record up to
      2^20 samples): exactly the batch sum (:func:`oadev`), over every k, from one block
      buffer of the last 2 exact_m_max phase points plus a sub-block of new ones;
    - larger m (prepared up to 2^40 from the start, so their sums start at k = 0): the
      sum over every s-th k, s the smallest divisor of m with m/s <= 4096, from a ring of
      2 m/s + 1 decimated phase points per m.  This is the overlapping estimator thinned
      by s <= m/4096 (NIST SP 1065 Sec. 5.2.4: the stride only has to be small compared
      with m for full overlapping efficiency); its edf is the overlapping one.

    Memory: C channels x (2 exact_m_max + 4096 + 2^18 + 22 x 8193) doubles, about 48 MB for six
    channels at the defaults, for any record length.  Time: one pass, linear in samples.
    The phase is a Kahan-compensated cumulative sum of ``rate - ref`` with ``ref`` the
    first sample; the terms are summed in blocks of 4096 aligned on k = 0 (the last,
    incomplete block when the result is asked for) and the block sums added with Neumaier's
    compensation, so the result does not depend on how the record was split into calls
    (bit for bit) and equals :func:`oadev` on the same data to about 1e-13 relative (the
    second differences do not depend on the mean that :func:`rate_to_phase` removes).

    Args:
        n_channels: number of rate channels, -.
        fs: sample rate, Hz.
        kind: "octave" or "decade" grid (allantools' keyword lists), or an explicit
            array of averaging factors m.
        exact_m_max: largest m summed over every k, -.
    """

    def __init__(self, n_channels: int, fs: float, kind="octave", exact_m_max: int = EXACT_M_MAX):
        if fs <= 0:
            raise ValueError(f"sample rate fs = {fs!r} is invalid: allowed (0, inf) Hz")
        self.fs = float(fs)
        self.kind = kind if isinstance(kind, str) else "explicit"
        ms = stream_ms(kind) if isinstance(kind, str) else np.unique(np.asarray(kind, np.int64))
        if ms.size == 0 or ms[0] < 1:
            raise ValueError("averaging factors must be positive integers")
        self.n_channels = int(n_channels)
        exact = ms[ms <= exact_m_max]
        thin = ms[ms > exact_m_max]
        self.ms_exact = np.ascontiguousarray(exact)
        self.ms_thin = np.ascontiguousarray(thin)
        self.thin_stride = np.array([_thin_stride(int(m)) for m in thin], dtype=np.int64)
        self.thin_ratio = self.ms_thin // self.thin_stride if thin.size else np.zeros(0, np.int64)
        c = self.n_channels
        self._hist = int(2 * exact.max()) + _BLOCK if exact.size else 0
        self._work = np.zeros((c, self._hist + _SUB_BLOCK))
        self._sums = np.zeros((c, exact.size))
        self._comps = np.zeros((c, exact.size))
        self._committed = np.zeros((c, exact.size), dtype=np.int64)
        rmax = int(self.thin_ratio.max()) if thin.size else 0
        self._ring = np.zeros((c, thin.size, 2 * rmax + 1))
        self._tsums = np.zeros((c, thin.size))
        self._tcomps = np.zeros((c, thin.size))
        self._phase = np.zeros(c)
        self._phase_c = np.zeros(c)
        self._ref: np.ndarray | None = None
        self.p_last = 0  # index of the last phase point; phase point 0 is 0

    @property
    def num_samples(self) -> int:
        """Rate samples fed so far, -."""
        return self.p_last

    def add(self, rate: np.ndarray) -> None:
        """Feed rate samples, shape (n, n_channels) (or (n,) for one channel)."""
        y = np.asarray(rate, dtype=float)
        if y.ndim == 1:
            y = y[:, None]
        if y.ndim != 2 or y.shape[1] != self.n_channels:
            raise ValueError(f"rate must have shape (n, {self.n_channels}), got {y.shape}")
        if y.shape[0] == 0:
            return
        if not np.all(np.isfinite(y)):
            raise ValueError("rate contains NaN or inf samples")
        if self._ref is None:
            self._ref = y[0].copy()
        self.p_last = _stream_update(
            np.ascontiguousarray(y),
            self._ref,
            self._phase,
            self._phase_c,
            self.p_last,
            self._hist,
            self._work,
            self.ms_exact,
            self._sums,
            self._comps,
            self._committed,
            self.ms_thin,
            self.thin_stride,
            self.thin_ratio,
            self._ring,
            self._tsums,
            self._tcomps,
        )

    def mean(self) -> np.ndarray:
        """Mean of each channel so far, rate units."""
        if self._ref is None:
            return np.full(self.n_channels, np.nan)
        return self._ref + (self._phase - self._phase_c) / self.p_last

    def nbytes(self) -> int:
        """Bytes held by the state (independent of the record length)."""
        return sum(a.nbytes for a in (self._work, self._ring, self._sums, self._tsums))

    def sums(self):
        """(m, n_terms, sums (C, k)) of every m with at least 2 terms so far (allantools' rule)."""
        n_phase = self.p_last + 1
        me = self.ms_exact
        te = n_phase - 2 * me
        keep = (me < n_phase) & (te > 1)
        pend = _pending_sums(self._work, self._hist, self.p_last, me, self._committed)
        total = self._sums + (self._comps + pend)
        ms, nt, ss = [me[keep]], [te[keep]], [total[:, keep]]
        if self.ms_thin.size:
            tt = self.p_last // self.thin_stride - 2 * self.thin_ratio + 1
            keep_t = (self.ms_thin < n_phase) & (n_phase - 2 * self.ms_thin > 1) & (tt > 1)
            ms.append(self.ms_thin[keep_t])
            nt.append(tt[keep_t])
            ss.append((self._tsums + self._tcomps)[:, keep_t])
        return np.concatenate(ms), np.concatenate(nt).astype(float), np.concatenate(ss, axis=1)

    def adev(self):
        """(taus s, adev (C, k) rate units, n_terms (k,)) of the grid points reached so far."""
        m, nt, s = self.sums()
        adev = np.sqrt(s / (2.0 * nt)) / m
        return m / self.fs, adev, nt


def stream_results(stream: StreamingAllan, confidence: float = 0.683) -> list[AllanResult]:
    """One :class:`AllanResult` per channel of a :class:`StreamingAllan`."""
    taus, adev, nt = stream.adev()
    return [
        allan_result(taus, adev[c], nt, stream.fs, stream.num_samples, confidence)
        for c in range(stream.n_channels)
    ]

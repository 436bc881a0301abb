"""Synchronous averaging over drive periods (Chen 2018 sec. 3.5.2: 12.5 MHz acquired,
1024-period averaging, saved at 625 kHz).

A stream of samples x_k (the feedthrough-cancelled capacitive channels, sec. 3.5.4, NaN
where a sample has no value) becomes its running average over the last N drive periods
of the same kind, phase-locked to the drive::

    xbar_k = (1/n_k) sum_{j=0}^{N-1} x[k - o_j],   o_j = round(j d),   d = m fs / f_drive

with m drive periods between two periods of the same kind (m = 2 for the bias on/off
alternation of the cancellation: every other period carries the sensor signal), the
nearest sample to the exact same phase j periods back (a trigger on the sample clock,
offset error within +-half a sample, so the average is unbiased to first order), n_k the
number of those samples that have a value (NaN, a period before the start of the segment
or inside its ``skip_periods`` do not). A change of drive segment (amplitude, frequency)
starts the average again: only periods of one steady drive are averaged.

White noise of the input is reduced by exactly 1/sqrt(n_k) (distinct samples of distinct
periods); a periodic signal passes (the offsets' rounding smooths it like a one-sample
boxcar on average: (2 pi f/fs)^2 / 24 = 1.2e-5 of the fundamental at 1700 Hz, 625 kHz).

Cost: the taps are grouped by the exact repetition of the sampling pattern. When q d is an
integer L for a small q (1700 Hz at 625 kHz: 2 periods = 12500/17 samples, q = 17), the
taps j and j + q are exactly L apart, so xbar needs one comb recursion over L and q
look-ups per sample; otherwise (q = N) the N taps are summed directly.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["SynchronousAverager", "tap_plan"]


def tap_plan(d: float, n_periods: int, tol: float = 1e-6) -> tuple[int, int, np.ndarray, int]:
    """(q, L, offsets o_r for r < q, M_hi): the smallest q <= n_periods with q d an
    integer L (to ``tol`` samples), else q = n_periods; M_hi = ceil(N / q) taps per residue."""
    q = n_periods
    for c in range(1, n_periods + 1):
        if abs(c * d - round(c * d)) <= tol:
            q = c
            break
    L = int(round(q * d))
    offsets = np.floor(np.arange(q) * d + 0.5).astype(np.int64)
    m_hi = -(-n_periods // q)
    return q, L, offsets, m_hi


@numba.njit(cache=True)
def _average_run(x, n_periods, q, L, offs, m_hi, skip, t0, xr, vr, cr, nr, out, count):
    """One frame of one segment; t0: samples of the segment before this frame. Ring
    buffers: xr/vr (R, nch)/(R,) input values (0 if none) and validity, cr/nr (Rc, nch)/(Rc,)
    comb sums C_hi[t] = sum_{i < m_hi} x[t - i L] and their counts."""
    n, nch = x.shape
    R = xr.shape[0]
    Rc = cr.shape[0]
    r_split = n_periods - (m_hi - 1) * q  # residues r < r_split have m_hi taps, others m_hi-1
    span = (m_hi - 1) * L
    for k in range(n):
        t = t0 + k
        ok = t >= skip
        if ok:
            for c in range(nch):
                if not math.isfinite(x[k, c]):
                    ok = False
                    break
        ir = t % R
        vr[ir] = 1.0 if ok else 0.0
        for c in range(nch):
            xr[ir, c] = x[k, c] if ok else 0.0
        ic = t % Rc
        ic_prev = (t - L) % Rc
        drop = t - m_hi * L
        idrop = drop % R
        for c in range(nch):
            prev = cr[ic_prev, c] if t >= L else 0.0
            old = xr[idrop, c] if drop >= 0 else 0.0
            cr[ic, c] = prev + xr[ir, c] - old
        prevn = nr[ic_prev] if t >= L else 0.0
        oldn = vr[idrop] if drop >= 0 else 0.0
        nr[ic] = prevn + vr[ir] - oldn
        total_n = 0.0
        for c in range(nch):
            out[k, c] = 0.0
        for r in range(q):
            kk = t - offs[r]
            if kk < 0:
                break
            j = kk % Rc
            total_n += nr[j]
            for c in range(nch):
                out[k, c] += cr[j, c]
            if r >= r_split and kk - span >= 0:
                jj = (kk - span) % R
                total_n -= vr[jj]
                for c in range(nch):
                    out[k, c] -= xr[jj, c]
        count[k] = total_n
        if total_n > 0.5 and vr[ir] > 0.0:
            for c in range(nch):
                out[k, c] /= total_n
        else:
            for c in range(nch):
                out[k, c] = np.nan


class SynchronousAverager:
    """Streaming synchronous average (module doc).

    Args:
        n_channels: channels of the input.
        fs: sample rate [Hz].
        n_periods: N, periods averaged (1024 in Chen 2018 sec. 3.5.2).
        period_step: m, drive periods between two averaged periods (2: the bias on/off
            alternation of the feedthrough cancellation; 1: every period).
        skip_periods: drive periods at the start of each segment left out (the transient
            of the lightly damped mode: 1/(zeta wn) = 18.6 ms = 32 periods at 1700 Hz).
    """

    def __init__(
        self,
        n_channels: int,
        fs: float,
        n_periods: int = 1024,
        period_step: int = 2,
        skip_periods: int = 0,
    ) -> None:
        if n_periods < 1 or period_step < 1 or skip_periods < 0:
            raise ValueError("n_periods and period_step must be >= 1, skip_periods >= 0")
        self.nch = int(n_channels)
        self.fs = float(fs)
        self.n_periods = int(n_periods)
        self.period_step = int(period_step)
        self.skip_periods = int(skip_periods)
        self._key = None

    def _start(self, f_drive: float, segment: int) -> None:
        d = self.period_step * self.fs / f_drive
        self.q, self.L, self.offsets, self.m_hi = tap_plan(d, self.n_periods)
        R = self.m_hi * self.L + 1
        self._xr = np.zeros((R, self.nch))
        self._vr = np.zeros(R)
        self._cr = np.zeros((self.L + 1, self.nch))
        self._nr = np.zeros(self.L + 1)
        self._t = 0
        self._skip = int(math.ceil(self.skip_periods * self.fs / f_drive))
        self._key = (float(f_drive), int(segment))

    def reset(self) -> None:
        """Forget everything: the next sample starts a new average."""
        self._key = None

    def step(
        self, x: np.ndarray, f_drive: np.ndarray, segment: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Averages (n, n_channels) [input unit] (NaN where no period has a value) and the
        number of periods in each (n,)."""
        x = np.ascontiguousarray(x, float).reshape(len(f_drive), self.nch)
        f_drive = np.asarray(f_drive, float)
        segment = np.asarray(segment)
        out = np.full(x.shape, np.nan)
        count = np.zeros(x.shape[0])
        # split the frame where the drive segment or frequency changes
        change = np.flatnonzero((np.diff(f_drive) != 0) | (np.diff(segment) != 0)) + 1
        bounds = [0, *change.tolist(), x.shape[0]]
        for a, b in zip(bounds[:-1], bounds[1:]):
            if a == b:
                continue
            f, s = float(f_drive[a]), int(segment[a])
            if not (f > 0 and math.isfinite(f)):
                self._key = None
                continue
            if self._key != (f, s):
                self._start(f, s)
            _average_run(
                x[a:b],
                self.n_periods,
                self.q,
                self.L,
                self.offsets,
                self.m_hi,
                self._skip,
                self._t,
                self._xr,
                self._vr,
                self._cr,
                self._nr,
                out[a:b],
                count[a:b],
            )
            self._t += b - a
        return out, count

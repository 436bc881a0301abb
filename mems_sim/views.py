"""Plotting views: a device's signals reduced to a low-rate stream a plotter draws without
aliasing (no ROS import; the node is :mod:`mems_sim.nodes.view_node`).

A plotter (Foxglove, PlotJuggler) draws the points it receives joined by lines; fed every
n-th sample of a 100 kHz signal it draws an alias. Two reductions avoid that:

* :class:`PeriodFitter`, for carriers and resonances: per period (or per M periods) of a
  carrier of frequency f, the amplitude A, phase phi and offset c of
  ``y(t) = A cos(2 pi f t + phi) + c`` by a linear least-squares sine fit over the
  samples of that period (the three-parameter sine fit of IEEE Std 1057-2017,
  Sec. 4.1.4.1, known frequency); t is the sensor time since the epoch, so a stationary
  carrier has a constant phase. Exact for a sine of that frequency. The frequency is given,
  or estimated once from the mean period between rising zero crossings of the first
  samples (then held).
* :class:`Decimator`, for slow signals: anti-alias low-pass filtering and decimation to the
  output rate, as ``scipy.signal.decimate`` does (SciPy reference, ``scipy.signal.decimate``
  and ``scipy.signal.firwin``/``kaiserord``), but streaming: a cascade of linear-phase
  FIR stages (Kaiser-window designs with 60 dB stopband from each stage's output Nyquist
  frequency, transition band 20 % of it; factor <= 8 per stage, as the SciPy reference
  advises for large factors; earlier stages only stop what folds into the final band),
  each with its state carried between blocks. The group delay
  of a linear-phase FIR of N taps is (N - 1) / 2 samples (Oppenheim & Schafer, Discrete-Time
  Signal Processing, 3rd ed., Sec. 5.7); each output is stamped at the time its filter
  is centred on, so the view is not delayed against the data. With each output also the
  minimum and maximum of the raw samples over the output interval centred on it (the
  envelope a min/max plot decimation shows), so content above the output Nyquist frequency
  stays visible as a band instead of an alias.

Outputs are ``(index, values...)`` with ``index`` the (fractional) input sample index the
output belongs to; the node turns it into a stamp epoch + index / fs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Stopband attenuation of the anti-alias stages [dB] and their transition band (fraction of
#: the stage's output Nyquist frequency below it).
STOPBAND_DB = 60.0
TRANSITION = 0.2
#: Largest decimation factor of one stage.
MAX_STAGE_FACTOR = 8


def stage_factors(q: int) -> list[int]:
    """Factors (each <= :data:`MAX_STAGE_FACTOR`, largest first) whose product is q; a prime
    factor above the limit is one stage of its own."""
    if q < 1:
        raise ValueError(f"decimation factor {q} must be >= 1")
    out, rest = [], q
    for f in range(MAX_STAGE_FACTOR, 1, -1):
        while rest % f == 0:
            out.append(f)
            rest //= f
    if rest > 1:
        out.append(rest)
    return sorted(out, reverse=True)


def antialias_taps(q: int, rest: int = 1) -> np.ndarray:
    """Linear-phase low-pass FIR for decimation by q, followed by stages decimating by
    ``rest`` more: Kaiser window design (``scipy.signal.kaiserord`` for :data:`STOPBAND_DB`,
    ``scipy.signal.firwin`` with the cutoff in the middle of the transition band); an odd
    number of taps (an integer group delay).

    The passband is that of the final output, up to (1 - :data:`TRANSITION`) times its
    Nyquist frequency. The last stage (``rest`` = 1) stops from the final Nyquist frequency
    on; an earlier stage only has to stop what its decimation folds into the final band
    (from its own output rate minus the final Nyquist frequency on), so its transition
    band is wide and its filter short (the usual multistage decimator design: Crochiere &
    Rabiner, Multirate Digital Signal Processing, 1983, ch. 5).
    """
    from scipy.signal import firwin, kaiserord

    final = 1.0 / (q * rest)  # final output rate, in cycles per input sample of this stage
    passband = (1.0 - TRANSITION) * final / 2
    stopband = final / 2 if rest == 1 else 1.0 / q - final / 2
    # firwin/kaiserord take frequencies in units of the Nyquist frequency (0.5 cycle/sample)
    n, beta = kaiserord(STOPBAND_DB, 2.0 * (stopband - passband))
    n += 1 - n % 2
    return firwin(n, passband + stopband, window=("kaiser", beta))


class _FirStage:
    """One streaming FIR decimation stage (state: the last N - 1 inputs)."""

    def __init__(self, q: int, rest: int = 1) -> None:
        self.q = q
        self.h = antialias_taps(q, rest) if q > 1 else np.ones(1)
        self.delay = (self.h.size - 1) // 2
        self.buf: np.ndarray | None = None
        self.count = 0  # inputs taken so far

    def push(self, x: np.ndarray) -> tuple[int, np.ndarray]:
        """Filter and decimate the block x (n, channels); return (index of the first output
        in this stage's output numbering, outputs (m, channels)). Output j filters inputs up
        to index q*j (causal), i.e. it is centred on input q*j - delay."""
        if self.buf is None:  # start in the steady state of the first value (no edge step)
            self.buf = np.repeat(x[:1], self.h.size - 1, axis=0)
        ext = np.concatenate([self.buf, x])
        first = -(-self.count // self.q)  # first output index j with q*j >= count
        last = (self.count + x.shape[0] - 1) // self.q
        self.buf = ext[ext.shape[0] - (self.h.size - 1) :] if self.h.size > 1 else ext[:0]
        start = self.count
        self.count += x.shape[0]
        if last < first:
            return first, np.empty((0, x.shape[1]))
        # input index m sits at ext row m - start + N - 1; the window ending there
        rows = np.arange(first, last + 1) * self.q - start + self.h.size - 1
        windows = np.lib.stride_tricks.sliding_window_view(ext, self.h.size, axis=0)
        return first, windows[rows - (self.h.size - 1)] @ self.h[::-1]


class Decimator:
    """Streaming anti-alias decimation of multichannel blocks by an integer factor q
    (module docstring): outputs with their input index and min/max envelope.

    Args:
        q: decimation factor (output rate = input rate / q).
        channels: number of channels.
    """

    def __init__(self, q: int, channels: int) -> None:
        self.q = int(q)
        self.channels = int(channels)
        factors = stage_factors(self.q)
        self.stages = [
            _FirStage(f, int(np.prod(factors[i + 1 :], dtype=np.int64)))
            for i, f in enumerate(factors)
        ]
        # output j is centred on input index q*j - offset
        offset, scale = 0, 1
        for s in self.stages:
            offset += scale * s.delay
            scale *= s.q
        self.offset = offset
        self._raw = np.empty((0, self.channels))
        self._raw_start = 0  # input index of _raw[0]
        self._pending: list[tuple[int, np.ndarray]] = []
        self.inputs = 0

    def push(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Take the next block x (n, channels) (consecutive input samples); return the
        outputs complete so far: (input indices (m,), values (m, channels), min (m, channels),
        max (m, channels)). Outputs centred before input 0 (filter start-up) are dropped."""
        x = np.asarray(x, dtype=float).reshape(-1, self.channels)
        self.inputs += x.shape[0]
        j0, y = self.inputs - x.shape[0], x  # q = 1: every input is an output
        for s in self.stages:
            j0, y = s.push(y)
        idx = np.arange(j0, j0 + y.shape[0]) * self.q - self.offset
        self._raw = np.concatenate([self._raw, x])
        self._pending += list(zip(idx.tolist(), y))
        out_i, out_v, out_lo, out_hi = [], [], [], []
        half = self.q // 2
        keep = []
        for i, v in self._pending:
            lo_i, hi_i = i - half, i - half + self.q  # the output interval centred on i
            if i < 0:
                continue
            if hi_i > self.inputs:  # its envelope needs inputs not taken yet
                keep.append((i, v))
                continue
            seg = self._raw[max(lo_i, self._raw_start) - self._raw_start : hi_i - self._raw_start]
            out_i.append(i)
            out_v.append(v)
            out_lo.append(seg.min(axis=0))
            out_hi.append(seg.max(axis=0))
        self._pending = keep
        # raw samples still needed: from the interval of the oldest output not given yet
        oldest = keep[0][0] - half if keep else self.inputs - self.offset - 2 * self.q
        drop = max(0, min(oldest, self.inputs) - self._raw_start)
        self._raw, self._raw_start = self._raw[drop:], self._raw_start + drop
        c = self.channels
        if not out_i:
            e = np.empty((0, c))
            return np.empty(0), e, e, e
        return np.asarray(out_i, dtype=float), np.array(out_v), np.array(out_lo), np.array(out_hi)


def zero_crossing_frequency(x: np.ndarray, fs: float, min_crossings: int = 16) -> float | None:
    """Frequency [Hz] of a carrier from the mean period between its rising zero crossings
    (mean removed, crossings located by linear interpolation); None with fewer than
    ``min_crossings`` crossings."""
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    k = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    if k.size < min_crossings:
        return None
    t = k + x[k] / (x[k] - x[k + 1])  # fractional index of each crossing
    return fs * (k.size - 1) / (t[-1] - t[0])


@dataclass
class PeriodFit:
    """Per-window results of :class:`PeriodFitter`: window centre index, amplitude, phase
    [rad] in (-pi, pi], offset, one row per window."""

    index: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    offset: np.ndarray


class PeriodFitter:
    """Streaming per-period amplitude and phase of a carrier (module docstring): window w
    holds the samples with t = index / fs in [w M / f, (w + 1) M / f); per window the
    least-squares fit of ``A cos(2 pi f t + phi) + c`` (IEEE Std 1057-2017 three-parameter
    sine fit).

    Args:
        fs: sample rate [Hz].
        frequency: carrier frequency f [Hz]; 0: estimated from the first samples
            (:func:`zero_crossing_frequency`) and then held.
        periods: M, carrier periods per window (>= 1).
        start_index: sample index of the first sample pushed (the stream's time origin is
            index 0: t = index / fs); windows begin at the first boundary at or after it.
    """

    def __init__(
        self, fs: float, frequency: float = 0.0, periods: int = 1, start_index: int = 0
    ) -> None:
        self.fs = float(fs)
        self.frequency = float(frequency) or None
        self.periods = int(periods)
        self._buf = np.empty(0)
        self._start = int(start_index)  # input index of _buf[0]
        self._window: int | None = None  # next window to fit
        self._estimating = np.empty(0)

    def _bound(self, w: int) -> int:
        """First input index of window w: ceil(w M fs / f)."""
        return math.ceil(w * self.periods * self.fs / self.frequency - 1e-9)

    def push(self, x: np.ndarray) -> PeriodFit:
        """Take the next consecutive samples (1-D); return the windows completed (``index``:
        the absolute sample index of each window's centre)."""
        x = np.asarray(x, dtype=float).ravel()
        if self.frequency is None:
            self._estimating = np.concatenate([self._estimating, x])
            f = zero_crossing_frequency(self._estimating, self.fs)
            if f is None or not 0 < f < self.fs / 2:
                return self._empty()
            self.frequency = f
            x, self._estimating = self._estimating, np.empty(0)
        if self._window is None:  # the first window that starts at or after the first sample
            self._window = math.ceil(self._start * self.frequency / (self.periods * self.fs))
            while self._bound(self._window) < self._start:
                self._window += 1
        self._buf = np.concatenate([self._buf, x])
        end = self._start + self._buf.size
        rows = []
        while self._bound(self._window + 1) <= end:
            a, b = self._bound(self._window), self._bound(self._window + 1)
            self._window += 1
            if a < self._start or b - a < 3:
                continue
            rows.append(self._fit(a, self._buf[a - self._start : b - self._start]))
        drop = self._bound(self._window) - self._start
        if drop > 0:
            self._buf, self._start = self._buf[drop:], self._start + drop
        if not rows:
            return self._empty()
        r = np.array(rows)
        return PeriodFit(r[:, 0], r[:, 1], r[:, 2], r[:, 3])

    def _fit(self, first: int, y: np.ndarray) -> tuple[float, float, float, float]:
        n = np.arange(y.size)
        # carrier phase 2 pi f t at each sample, the cycles of the window's first sample
        # reduced modulo 1 (precision at large t)
        cycles0 = math.fmod(first * self.frequency / self.fs, 1.0)
        arg = 2.0 * math.pi * (cycles0 + n * self.frequency / self.fs)
        basis = np.column_stack([np.cos(arg), np.sin(arg), np.ones(y.size)])
        (a, b, c), *_ = np.linalg.lstsq(basis, y, rcond=None)
        # A cos(arg + phi) = A cos(phi) cos(arg) - A sin(phi) sin(arg)
        return (first + (y.size - 1) / 2.0, math.hypot(a, b), math.atan2(-b, a), c)

    @staticmethod
    def _empty() -> PeriodFit:
        e = np.empty(0)
        return PeriodFit(e, e, e, e)


#: Default view per device (the namespace's last name): channels of the truth and estimate
#: frames viewed per carrier period (the device's resonances); every other channel is
#: decimated to ``output_rate_hz``. Carrier frequencies are estimated from the signal
#: unless ``carrier_hz`` is set.
DEVICE_VIEWS: dict[str, dict] = {
    "imu": dict(carriers=(), output_rate_hz=10.0),
    "accelerometer": dict(carriers=(), output_rate_hz=1000.0),
    "stage": dict(carriers=("theta_y", "omega_y", "theta_x", "omega_x"), output_rate_hz=100.0),
    "scanner": dict(carriers=("theta", "omega"), output_rate_hz=100.0),
    "scanner_amdm": dict(carriers=("theta", "omega"), output_rate_hz=100.0),
    "resonator": dict(carriers=("position", "velocity"), output_rate_hz=100.0),
    "": dict(carriers=(), output_rate_hz=10.0),
}

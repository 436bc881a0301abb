"""Innovation consistency monitor of a Kalman-type filter: the normalised innovation
squared (NIS) summed over non-overlapping windows against its chi-square distribution.

For a consistent linear-Gaussian filter the innovations nu(k) with predicted covariance
S(k) are white and nu' S^-1 nu is chi-square with m degrees of freedom (m measurements
per sample), so the sum over a window of W samples is chi-square with m W degrees of
freedom (Bar-Shalom, Li & Kirubarajan, "Estimation with Applications to Tracking and
Navigation", Wiley 2001, Sec. 5.4.2, the time-average NIS test). A window whose sum exceeds
the chi-square quantile 1 - alpha is an alarm; alpha is the false-alarm probability per
window, so the designed false-alarm rate is alpha fs / W per second. A window below the
lower quantile alpha (a filter that overstates its innovation covariance) is reported
apart, as ``low``. The verdict of a window: ``OK``, ``WARN`` (above the alpha quantile) or
``ERROR`` (above the alpha / 100 quantile, or a non-finite NIS in it).

Where the innovations are not Gaussian (the one-bit sigma-delta loop) the thresholds must
come from training data instead (:meth:`NisMonitor.from_training`: the empirical quantiles
of fault-free windows), or, with far fewer training windows, from the two moments of their
sums (:func:`nis_moments`, :meth:`NisMonitor.moment_matched`: a scaled chi-square g chi2(h)
of the same mean and variance, Satterthwaite 1946, Box 1954).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

#: Verdicts, in diagnostic_msgs/DiagnosticStatus order (OK = 0, WARN = 1, ERROR = 2).
VERDICTS = ("OK", "WARN", "ERROR")


@dataclass(frozen=True)
class WindowVerdict:
    """One window of the monitor.

    Attributes:
        first: sample index of its first NIS value, -.
        n: samples in it, -.
        statistic: sum of NIS over it, -.
        level: 0 OK, 1 WARN, 2 ERROR.
        low: True when the sum is below the lower threshold (covariance overstated).
    """

    first: int
    n: int
    statistic: float
    level: int
    low: bool

    @property
    def verdict(self) -> str:
        return VERDICTS[self.level]


class NisMonitor:
    """Windowed NIS test, streamed in blocks of any size (the same windows either way).

    Args:
        window: samples per window W, -.
        false_alarm: designed false-alarm probability per window alpha, -.
        dof: measurements per sample m, -.
        error_factor: the ERROR threshold's alpha is ``false_alarm / error_factor``, -.
    """

    def __init__(
        self, window: int, false_alarm: float, dof: int = 1, error_factor: float = 100.0
    ) -> None:
        if not (isinstance(window, int) and window >= 1):
            raise ValueError(f"window = {window!r} samples is invalid: a whole number >= 1")
        if not 0.0 < false_alarm < 0.5:
            raise ValueError(f"false_alarm = {false_alarm!r} is invalid: allowed (0, 0.5)")
        if not (isinstance(dof, int) and dof >= 1) or not error_factor >= 1.0:
            raise ValueError("dof must be a whole number >= 1 and error_factor >= 1")
        self.window, self.false_alarm, self.dof = window, float(false_alarm), dof
        k = dof * window
        self.thresholds = (
            float(stats.chi2.isf(false_alarm, k)),
            float(stats.chi2.isf(false_alarm / error_factor, k)),
        )
        self.lower = float(stats.chi2.ppf(false_alarm, k))
        self._sum = 0.0
        self._count = 0
        self._first = 0
        self._bad = False
        self.next_index = 0

    @classmethod
    def from_training(
        cls, nis: np.ndarray, window: int, false_alarm: float, error_factor: float = 100.0
    ) -> NisMonitor:
        """A monitor whose thresholds are the empirical quantiles of the window sums of
        fault-free training NIS (``nis``, per sample), for non-Gaussian innovations; it
        needs at least 10 / (false_alarm / error_factor) training windows."""
        sums = window_sums(np.asarray(nis, dtype=float), window)
        need = math.ceil(10.0 * error_factor / false_alarm)
        if sums.size < need:
            raise ValueError(f"{sums.size} training windows: at least {need} needed")
        m = cls(window, false_alarm, 1, error_factor)
        m.thresholds = (
            float(np.quantile(sums, 1.0 - false_alarm)),
            float(np.quantile(sums, 1.0 - false_alarm / error_factor)),
        )
        m.lower = float(np.quantile(sums, false_alarm))
        return m

    @classmethod
    def moment_matched(
        cls,
        window: int,
        false_alarm: float,
        nis_mean: float,
        dispersion: float,
        error_factor: float = 100.0,
        dof: int = 1,
    ) -> NisMonitor:
        """A monitor whose thresholds are those of the scaled chi-square g chi2(h) with the
        mean ``nis_mean m W`` and variance ``2 dispersion m W`` of a fault-free window sum
        (Satterthwaite 1946; Box 1954): g = dispersion / nis_mean,
        h = nis_mean^2 m W / dispersion, m = ``dof`` measurements per sample. ``nis_mean``
        (mean NIS per sample and degree of freedom, -) and ``dispersion`` (variance of a
        window sum over that of chi2(m W), -) come from fault-free training data
        (:func:`nis_moments`); 1 and 1: the chi-square monitor.

        Raises:
            ValueError: ``nis_mean`` or ``dispersion`` not finite and > 0, or the
                constructor's reasons.
        """
        m = cls(window, false_alarm, dof, error_factor)
        for name, val in (("nis_mean", nis_mean), ("dispersion", dispersion)):
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"{name} = {val!r} is invalid: finite and > 0")
        if nis_mean == 1.0 and dispersion == 1.0:
            return m
        g, h = dispersion / nis_mean, nis_mean * nis_mean * (dof * window) / dispersion
        m.thresholds = (
            g * float(stats.chi2.isf(false_alarm, h)),
            g * float(stats.chi2.isf(false_alarm / error_factor, h)),
        )
        m.lower = g * float(stats.chi2.ppf(false_alarm, h))
        return m

    def designed_rate_per_hour(self, fs: float) -> float:
        """Designed false alarms per hour at sample rate ``fs`` [Hz]: alpha fs / W * 3600."""
        return self.false_alarm * fs / self.window * 3600.0

    def _close(self) -> WindowVerdict:
        s = self._sum
        level = 2 if (self._bad or s > self.thresholds[1]) else (1 if s > self.thresholds[0] else 0)
        v = WindowVerdict(self._first, self._count, s, level, (not self._bad) and s < self.lower)
        self._sum, self._count, self._bad = 0.0, 0, False
        self._first = self.next_index
        return v

    def update(self, nis: np.ndarray) -> list[WindowVerdict]:
        """Add the NIS of the next samples; the windows completed by them, in order. The sum
        of a window is accumulated sample by sample in index order (the same floats at any
        block size: ``np.add.accumulate`` adds one value after the other; a non-finite
        value marks the window and adds nothing, as 0.0 does)."""
        out = []
        values = np.asarray(nis, dtype=float).ravel()
        pos = 0
        while pos < values.size:
            take = min(self.window - self._count, values.size - pos)
            chunk = values[pos : pos + take]
            finite = np.isfinite(chunk)
            if not finite.all():
                self._bad = True
                chunk = np.where(finite, chunk, 0.0)
            self._sum = float(np.add.accumulate(np.concatenate(([self._sum], chunk)))[-1])
            self._count += take
            self.next_index += take
            pos += take
            if self._count == self.window:
                out.append(self._close())
        return out


def window_sums(nis: np.ndarray, window: int) -> np.ndarray:
    """Sums of ``nis`` over consecutive non-overlapping windows (the incomplete tail left
    out), each accumulated in index order."""
    n = nis.size // window
    sums = np.empty(n)
    for i in range(n):
        s = 0.0
        for v in nis[i * window : (i + 1) * window].tolist():
            s += v
        sums[i] = s
    return sums


def nis_moments(nis: np.ndarray, window: int, dof: int = 1) -> tuple[float, float]:
    """(mean NIS per sample and degree of freedom, dispersion) of fault-free training NIS
    (per sample, -; ``dof`` measurements m per sample) over windows of ``window`` samples:
    the mean window sum over m W, and the variance of the window sums over 2 m W (that of
    chi2(m W)); the moments of :meth:`NisMonitor.moment_matched`.

    Raises:
        ValueError: fewer than 30 complete windows, or a non-finite window sum.
    """
    return window_moments(window_sums(np.asarray(nis, dtype=float), window), window, dof)


def window_moments(sums: np.ndarray, window: int, dof: int = 1) -> tuple[float, float]:
    """(mean NIS per sample, dispersion) of fault-free window sums ``sums`` (each over
    ``window`` samples, -): the mean sum over W, and the sums' variance over 2 W (that of
    chi2(W)), the moments of :meth:`NisMonitor.moment_matched` (:func:`nis_moments` of the
    per-sample NIS; a recording's ``health`` statistics). With ``dof`` measurements m per
    sample: per degree of freedom, over m W and 2 m W (chi2(m W)).

    Raises:
        ValueError: fewer than 30 windows, or a non-finite sum.
    """
    sums = np.asarray(sums, dtype=float)
    if sums.size < 30 or not np.all(np.isfinite(sums)):
        raise ValueError(f"{sums.size} training windows (all finite): at least 30 needed")
    k = dof * window
    return float(sums.mean() / k), float(sums.var(ddof=1) / (2.0 * k))

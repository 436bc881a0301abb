"""Fault detection as a measured figure: a monitor's window verdicts scored against the
labelled truth of a fault schedule.

The verdicts are those of a windowed consistency test (the windowed NIS test of
Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2: one verdict per window of samples, known
at the window's end); the faults are the schedule's entries in sample indices of the same
stream. The scores are those of detection practice (Basseville & Nikiforov 1993, ch. 1:
probability of detection, mean time between false alarms, detection delay):

* a fault is **detected** when a window that holds one of its faulty samples and ends at
  most ``horizon`` samples after its onset raised an alarm (level >= ``min_level``, or,
  for the two-sided test, a statistic below the lower threshold: too little noise); the
  **delay** is the end of the first such window minus the onset, in samples;
* a **false alarm episode** is a run of consecutive alarming windows none of which holds
  a sample of a fault or of the ``guard`` samples after one (the filter's settling), and
  the **false-alarm rate** is their number over the fault-free time;
* the **magnitude at 95 % detection** is where the detection probability, interpolated
  linearly in the magnitude between the grid points of a campaign, first reaches 0.95.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Verdicts:
    """A monitor's windows, in stream order.

    Attributes:
        first: stream sample index of each window's first sample, -.
        n: samples in each window, -.
        level: 0 OK, 1 WARN, 2 ERROR.
        low: whether each window's statistic fell below the lower threshold (the
            covariance overstated: too little noise, as from a frozen or clipped output).
    """

    first: np.ndarray
    n: np.ndarray
    level: np.ndarray
    low: np.ndarray

    @classmethod
    def of(cls, first, n, level, low=None) -> Verdicts:
        first = np.asarray(first, dtype=np.int64)
        n = np.asarray(n, dtype=np.int64)
        level = np.asarray(level, dtype=np.int64)
        low = np.zeros(first.shape, bool) if low is None else np.asarray(low, dtype=bool)
        if not first.shape == n.shape == level.shape == low.shape or first.ndim != 1:
            raise ValueError("first, n, level and low must be 1-D arrays of one length")
        if first.size > 1 and np.any(np.diff(first) < n[:-1]):
            raise ValueError("windows must be in stream order and must not overlap")
        return cls(first, n, level, low)

    def alarms(self, min_level: int = 1, two_sided: bool = False) -> np.ndarray:
        """Which windows alarm: level >= ``min_level``, or (``two_sided``) low."""
        out = self.level >= min_level
        return out | self.low if two_sided else out

    @property
    def end(self) -> np.ndarray:
        """One past each window's last sample (when its verdict is known), -."""
        return self.first + self.n


@dataclass(frozen=True)
class Fault:
    """One labelled fault: samples ``[first, end)`` (``end`` None: to the end of the
    stream), with its kind and magnitude (the schedule's unit)."""

    first: int
    end: int | None
    kind: str = ""
    magnitude: float = 0.0


@dataclass(frozen=True)
class Detection:
    """The score of one fault: whether it was detected, and the delay [samples] from its
    onset to the end of the first alarming window (None when not detected)."""

    fault: Fault
    detected: bool
    delay: int | None


def detections(
    faults: Sequence[Fault],
    verdicts: Verdicts,
    horizon: int,
    min_level: int = 1,
    two_sided: bool = False,
) -> list[Detection]:
    """Score each fault: detected by an alarming window (:meth:`Verdicts.alarms`) that
    holds one of its faulty samples and ends at most ``horizon`` samples after its onset."""
    if horizon < 1:
        raise ValueError(f"horizon = {horizon!r} samples is invalid: >= 1")
    end = verdicts.end
    alarm = verdicts.alarms(min_level, two_sided)
    out = []
    for f in faults:
        last = np.iinfo(np.int64).max if f.end is None else f.end
        hit = alarm & (end > f.first) & (verdicts.first < last) & (end <= f.first + horizon)
        if hit.any():
            out.append(Detection(f, True, int(end[np.argmax(hit)] - f.first)))
        else:
            out.append(Detection(f, False, None))
    return out


@dataclass(frozen=True)
class FalseAlarms:
    """False alarms over the fault-free windows: ``episodes`` runs of consecutive
    alarming windows, ``windows`` fault-free windows with ``alarm_windows`` of them
    alarming, ``samples`` fault-free samples."""

    episodes: int
    alarm_windows: int
    windows: int
    samples: int

    def per_window(self) -> float:
        """Alarming windows per fault-free window, - (the designed alpha's measure)."""
        return self.alarm_windows / self.windows if self.windows else float("nan")

    def per_hour(self, fs: float) -> float:
        """Episodes per hour of fault-free data at sample rate ``fs`` [Hz]."""
        return self.episodes / (self.samples / fs / 3600.0) if self.samples else float("nan")


def fault_free(faults: Sequence[Fault], verdicts: Verdicts, guard: int) -> np.ndarray:
    """Which windows hold no sample of a fault nor of the ``guard`` samples after one."""
    free = np.ones(verdicts.first.size, bool)
    end = verdicts.end
    for f in faults:
        last = np.iinfo(np.int64).max if f.end is None else f.end + guard
        free &= ~((end > f.first) & (verdicts.first < last))
    return free


def false_alarms(
    faults: Sequence[Fault],
    verdicts: Verdicts,
    guard: int,
    min_level: int = 1,
    two_sided: bool = False,
) -> FalseAlarms:
    """The false alarms of ``verdicts`` outside the faults and their ``guard`` samples
    (:func:`fault_free`); an episode is a run of alarming fault-free windows that are
    consecutive in the stream (no window between them)."""
    free = fault_free(faults, verdicts, guard)
    alarm = free & verdicts.alarms(min_level, two_sided)
    starts = alarm.copy()
    starts[1:] &= ~alarm[:-1]
    return FalseAlarms(
        episodes=int(np.count_nonzero(starts)),
        alarm_windows=int(np.count_nonzero(alarm)),
        windows=int(np.count_nonzero(free)),
        samples=int(verdicts.n[free].sum()),
    )


def detection_curve(
    scores: Sequence[Detection],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(magnitudes, detection probability, trials) per distinct magnitude of ``scores``,
    magnitudes ascending."""
    mags = np.array([s.fault.magnitude for s in scores], dtype=float)
    hit = np.array([s.detected for s in scores], dtype=float)
    grid = np.unique(mags)
    p = np.array([hit[mags == m].mean() for m in grid])
    n = np.array([np.count_nonzero(mags == m) for m in grid])
    return grid, p, n


def magnitude_at(magnitudes, probability, target: float = 0.95) -> float | None:
    """The magnitude where the detection probability first reaches ``target``, linear
    interpolation between the grid points (ascending magnitudes); None when it never does.
    A grid whose first point already reaches it gives that point (an upper bound)."""
    m = np.asarray(magnitudes, dtype=float)
    p = np.asarray(probability, dtype=float)
    above = np.flatnonzero(p >= target)
    if above.size == 0:
        return None
    i = int(above[0])
    if i == 0:
        return float(m[0])
    m0, m1, p0, p1 = m[i - 1], m[i], p[i - 1], p[i]
    return float(m0 + (target - p0) * (m1 - m0) / (p1 - p0))

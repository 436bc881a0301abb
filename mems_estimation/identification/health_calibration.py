"""The calibration of an estimator's consistency monitor on the bench: the moments of its
fault-free window NIS sums, as a recording's ``health`` verdicts carry them.

A windowed NIS monitor (Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2) whose innovations
are not exactly those of its model (a filter on a nominal model of a drawn device, a
one-bit loop) needs the thresholds of the scaled chi-square g chi2(h) with the measured
mean and variance of its fault-free window sums (Satterthwaite 1946); this module measures
them, with 95 % intervals, from the window sums of a fault-free run.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from mems_estimation.filters.consistency_monitor import NisMonitor, window_moments


@dataclass(frozen=True)
class HealthCalibration:
    """The measured moments of a monitor's fault-free window sums.

    Attributes:
        window: samples per window W, -.
        dof: measurements per sample m, -.
        windows: windows measured, -.
        nis_mean: mean NIS per sample and degree of freedom (mean window sum over m W), -.
        dispersion: variance of a window sum over 2 m W (that of chi2(m W)), -.
        nis_mean_interval: 95 % interval of ``nis_mean`` (normal, the sums' standard
            error), -.
        dispersion_interval: 95 % interval of ``dispersion`` (chi-square of the sample
            variance with windows - 1 degrees of freedom; independent Gaussian sums), -.
        alarm_windows: windows above the WARN threshold of the calibrated monitor at
            ``false_alarm`` (in sample: a check, not an evaluation), -.
        false_alarm: the designed false-alarm probability per window of that check, -.
    """

    window: int
    dof: int
    windows: int
    nis_mean: float
    dispersion: float
    nis_mean_interval: tuple[float, float]
    dispersion_interval: tuple[float, float]
    alarm_windows: int
    false_alarm: float

    def as_dict(self) -> dict:
        return asdict(self)


def calibrate(
    sums: np.ndarray, window: int, false_alarm: float = 1e-2, dof: int = 1
) -> HealthCalibration:
    """The calibration of fault-free window sums ``sums`` (each of ``window`` samples of
    ``dof`` measurements, -): :func:`window_moments` with their 95 % intervals, and the
    alarms of the monitor they calibrate at ``false_alarm`` on the same windows.

    Raises:
        ValueError: fewer than 30 windows, a non-finite sum, or ``false_alarm`` outside
            (0, 0.5).
    """
    sums = np.asarray(sums, dtype=float)
    mean, disp = window_moments(sums, window, dof)
    n = sums.size
    z = float(stats.norm.isf(0.025))
    se = float(sums.std(ddof=1)) / math.sqrt(n) / (window * dof)
    lo_chi, hi_chi = float(stats.chi2.isf(0.025, n - 1)), float(stats.chi2.ppf(0.025, n - 1))
    monitor = NisMonitor.moment_matched(window, false_alarm, mean, disp, dof=dof)
    return HealthCalibration(
        window=int(window),
        dof=int(dof),
        windows=int(n),
        nis_mean=mean,
        dispersion=disp,
        nis_mean_interval=(mean - z * se, mean + z * se),
        dispersion_interval=(disp * (n - 1) / lo_chi, disp * (n - 1) / hi_chi),
        alarm_windows=int(np.count_nonzero(sums > monitor.thresholds[0])),
        false_alarm=float(false_alarm),
    )

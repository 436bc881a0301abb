"""Innovation consistency health of an estimator node, shared by the nodes that have it.

A :class:`HealthReporter` feeds the normalised innovation squared (NIS) of every sample
whose estimate the node publishes to a
:class:`~mems_estimation.filters.consistency_monitor.NisMonitor` (windowed NIS test,
Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2), publishes each completed window's verdict
on the device's ``health`` (diagnostic_msgs/DiagnosticStatus: level OK, WARN or ERROR,
name the node's name, message the verdict, values the window's first stream sample index,
samples, statistic, thresholds and the designed false alarms per hour) and keeps on
/diagnostics the last verdict and statistic and the counts of windows, WARN and ERROR
windows. A window continues over a gap (its first sample index is the stream's), and over
the samples without a measurement of a filter that has some (they carry no NIS);
:meth:`HealthReporter.reset` (the filter re-initialised) drops the open window. The
thresholds are chi-square quantiles, or, for a node with :func:`calibration_specs`, those
of the scaled chi-square of the measured fault-free moments.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from mems_estimation.filters.consistency_monitor import NisMonitor, WindowVerdict
from mems_sim.params import ParamSpec
from mems_sim.ros.qos import HEALTH_QOS

#: diagnostic_msgs/DiagnosticStatus level of a window's verdict level 0, 1, 2.
LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)


def health_specs(window: int, window_source: str) -> tuple[ParamSpec, ParamSpec]:
    """The parameters ``health_window`` (default ``window`` samples, its source text
    ``window_source``) and ``health_false_alarm`` of an estimator node's consistency
    monitor (windowed NIS test, Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2)."""
    return (
        ParamSpec(
            "health_window",
            window,
            "samples",
            "samples per window of the innovation consistency monitor (NIS summed over the "
            "window against chi-square thresholds); one verdict on 'health' per window",
            window_source,
            min=1,
            max=2**31 - 1,
        ),
        ParamSpec(
            "health_false_alarm",
            1e-3,
            "-",
            "designed false-alarm probability per window of the consistency monitor: WARN "
            "above the chi-square quantile 1 - alpha, ERROR above 1 - alpha/100; below 0.5",
            "chosen",
            min=0.0,
            max=0.5,
            min_exclusive=True,
            max_exclusive=True,
        ),
    )


def calibration_specs(nis_mean: float, dispersion: float, source: str) -> tuple[ParamSpec, ...]:
    """The parameters ``health_nis_mean`` and ``health_nis_dispersion`` (defaults
    ``nis_mean`` and ``dispersion``, -, their source text ``source``): the moments of a
    fault-free window's NIS sum, for innovations that are not Gaussian (the scaled
    chi-square of :meth:`~mems_estimation.filters.consistency_monitor.NisMonitor.moment_matched`,
    Satterthwaite 1946); 1 and 1: the chi-square of Kalman theory."""
    return (
        ParamSpec(
            "health_nis_mean",
            nis_mean,
            "-",
            "mean NIS per sample of the fault-free filter (measured: nis_moments of "
            "fault-free data); 1: Kalman theory",
            source,
            min=0.0,
            max=1.0e6,
            min_exclusive=True,
        ),
        ParamSpec(
            "health_nis_dispersion",
            dispersion,
            "-",
            "variance of a fault-free window's NIS sum over that of chi-square(window) "
            "(measured: nis_moments of fault-free data); 1: Kalman theory",
            source,
            min=0.0,
            max=1.0e6,
            min_exclusive=True,
        ),
    )


class HealthReporter:
    """Windowed NIS verdicts of one estimator node on ``health`` and /diagnostics.

    Args:
        node: the estimator node (an :class:`~mems_estimation.nodes.frame_input.EstimatorNode`
            with the parameters of :func:`health_specs`).
        fs: rate of the NIS samples fed, Hz (the designed false alarms per hour): the
            sample rate of the estimates, or of the samples with a measurement.
        what: the filter's name in the ERROR warning (e.g. ``"hybrid EKF"``).
        dof: measurements per sample m, -: a window's fault-free NIS sum is chi-square with
            m W degrees of freedom (Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2).
    """

    def __init__(self, node, fs: float, what: str, dof: int = 1) -> None:
        self.node, self.fs, self.what, self.dof = node, float(fs), what, dof
        self.pub = node.create_publisher(DiagnosticStatus, node.device_topic("health"), HEALTH_QOS)
        node.diag.counters.update(
            health_verdict="none",
            health_statistic="none",
            health_windows=0,
            health_warn_windows=0,
            health_error_windows=0,
        )
        self.reset()

    def reset(self) -> None:
        """A new monitor whose first window starts with the next sample fed (the open
        window is dropped): the filter was re-initialised."""
        p = self.node.p
        self.monitor = NisMonitor.moment_matched(
            p["health_window"],
            p["health_false_alarm"],
            p.get("health_nis_mean", 1.0),
            p.get("health_nis_dispersion", 1.0),
            dof=self.dof,
        )
        #: (monitor sample index, stream sample index) of the first sample of each frame
        #: fed to the monitor since the start of its current window
        self._frames: deque[tuple[int, int]] = deque()

    def monitor_frame(
        self, first: int, nis: np.ndarray, measured: np.ndarray | None = None
    ) -> None:
        """Feed the NIS (per sample, -) of the frame at stream index ``first`` to the
        monitor; report the windows it completes. ``measured`` (bool per sample): only the
        samples with a measurement update carry a NIS, the others are left out (a window
        counts measured samples; its first sample index is still the stream's)."""
        if measured is not None:
            on = np.concatenate(([False], np.asarray(measured, bool), [False]))
            edges = np.flatnonzero(on[1:] != on[:-1])
            for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
                self.monitor_frame(first + a, nis[a:b])
            return
        self._frames.append((self.monitor.next_index, first))
        for v in self.monitor.update(nis):
            self.report_window(v)
        w = self.monitor.window
        start = self.monitor.next_index // w * w  # the open window's first sample
        while len(self._frames) > 1 and self._frames[1][0] <= start:
            self._frames.popleft()

    def stream_index(self, monitor_index: int) -> int:
        """Stream sample index of the monitor's sample ``monitor_index`` (of a frame held)."""
        base, first = next(f for f in reversed(self._frames) if f[0] <= monitor_index)
        return first + monitor_index - base

    def report_window(self, v: WindowVerdict) -> None:
        """Publish one window's verdict on ``health`` and account it on /diagnostics."""
        m, node = self.monitor, self.node
        first = self.stream_index(v.first)
        values = {
            "first_sample_index": first,
            "samples": v.n,
            "dof": m.dof,
            "statistic": repr(v.statistic),
            "threshold_warn": repr(m.thresholds[0]),
            "threshold_error": repr(m.thresholds[1]),
            "threshold_low": repr(m.lower),
            "low": str(v.low).lower(),
            "false_alarm": repr(m.false_alarm),
            "designed_false_alarms_per_hour": repr(m.designed_rate_per_hour(self.fs)),
        }
        self.pub.publish(
            DiagnosticStatus(
                level=LEVELS[v.level],
                name=node.get_name(),
                message=v.verdict,
                hardware_id=node.get_fully_qualified_name(),
                values=[KeyValue(key=k, value=str(x)) for k, x in values.items()],
            )
        )
        self.count(v, first)

    def count(self, v: WindowVerdict, first: int) -> None:
        """Account one window (from stream index ``first``) on /diagnostics; warn on ERROR."""
        diag = self.node.diag
        diag.count("health_windows")
        diag.counters["health_verdict"] = v.verdict
        diag.counters["health_statistic"] = repr(v.statistic)
        if v.level == 1:
            diag.count("health_warn_windows")
        elif v.level == 2:
            diag.count("health_error_windows")
            diag.warn(
                f"{self.what} innovations inconsistent (ERROR) in the window from index "
                f"{first}: NIS sum {v.statistic:.6g} over {v.n} samples, threshold "
                f"{self.monitor.thresholds[1]:.6g}"
            )

"""The shared health reporter of the estimator nodes through real topics: one
diagnostic_msgs/DiagnosticStatus per window (its statistic the window's NIS sum, its first
sample index the stream's across gaps), WARN and ERROR windows counted on /diagnostics, a
reset dropping the open window, and its parameters (defaults chosen by the node)."""

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticStatus
from node_helpers import status_values, wait_matched

from mems_estimation.filters.consistency_monitor import NisMonitor
from mems_estimation.nodes.frame_input import DEVICE_NAMESPACE, EstimatorNode
from mems_estimation.nodes.health import HealthReporter, calibration_specs, health_specs
from mems_sim.params import ParameterError
from mems_sim.ros.qos import HEALTH_QOS

FS = 1000.0


class HealthOnly(EstimatorNode):
    """An estimator node with nothing but the health reporter (the NIS fed by the test)."""

    NODE_NAME = "health_only"
    DEFAULT_NAMESPACE = "dev"
    SPECS = (DEVICE_NAMESPACE, *health_specs(1200, "test"), *calibration_specs(1.0, 1.0, "test"))
    DIAGNOSTICS_TITLE = "health only"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        self.health = HealthReporter(self, FS, "test filter")


def test_specs_carry_the_nodes_default_and_refuse_bad_values():
    window, alpha = health_specs(777, "chosen: 777 samples")
    assert (window.name, window.default, window.source) == (
        "health_window",
        777,
        "chosen: 777 samples",
    )
    assert (alpha.name, alpha.default) == ("health_false_alarm", 1e-3)
    for spec, bad in ((window, 0), (window, 2.5), (alpha, 0.0), (alpha, 0.5)):
        with pytest.raises(ParameterError, match=spec.name):
            spec.validate(bad)
    assert window.validate(1) == 1 and alpha.validate(0.49) == 0.49
    mean, dispersion = calibration_specs(1.13, 0.16, "measured")
    assert (mean.default, dispersion.default) == (1.13, 0.16)
    for spec in (mean, dispersion):
        with pytest.raises(ParameterError, match=spec.name):
            spec.validate(0.0)


def test_windows_map_to_stream_indices_over_gaps_and_a_reset_drops_the_open_window(graph):
    """Windows of 1200 samples fed frames of 1000 at stream indices 0, 1000, 2500 (gap of
    500), 3500, 4500: windows at monitor samples 0, 1200, 2400, 3600 start at stream indices
    0, 1200, 2900, 4100. A reset drops the 200 samples of the open window; frames at 100 000,
    101 000, 102 000 then give windows at 100 000 and 101 200. The window holding a NIS of
    10 per sample is ERROR, one at the WARN threshold's level WARN; the statistic is the
    window's sum; /diagnostics counts them."""
    ctx, ex, probe = graph
    node = HealthOnly(context=ctx, parameter_overrides=params(health_false_alarm=1e-2))
    got = []
    probe.create_subscription(DiagnosticStatus, "/dev/health", got.append, HEALTH_QOS)
    assert wait_matched(ex, node.health.pub)
    ref = NisMonitor(1200, 1e-2)
    warn_level = (ref.thresholds[0] + ref.thresholds[1]) / 2 / 1200  # per sample: WARN
    rng = np.random.default_rng(3)
    nis = rng.chisquare(1, 5000)
    nis[2400:3600] = warn_level  # the third window: WARN
    nis[3600:4800] = 10.0  # the fourth: ERROR
    for k, first in enumerate((0, 1000, 2500, 3500, 4500)):
        node.health.monitor_frame(first, nis[1000 * k : 1000 * (k + 1)])
    node.health.reset()
    after = rng.chisquare(1, 3000)
    for k, first in enumerate((100_000, 101_000, 102_000)):
        node.health.monitor_frame(first, after[1000 * k : 1000 * (k + 1)])
    assert spin_until(ex, lambda: len(got) == 6)
    ex.spin_once(timeout_sec=0.1)
    firsts = [int(status_values(m)["first_sample_index"]) for m in got]
    assert firsts == [0, 1200, 2900, 4100, 100_000, 101_200]
    windows = ref.update(nis[:4800]) + NisMonitor(1200, 1e-2).update(after[:2400])
    assert [float(status_values(m)["statistic"]) for m in got] == [w.statistic for w in windows]
    levels = [m.level for m in got]
    assert levels[2:4] == [DiagnosticStatus.WARN, DiagnosticStatus.ERROR]
    assert [m.message for m in got][2:4] == ["WARN", "ERROR"]
    assert {status_values(m)["samples"] for m in got} == {"1200"}
    assert float(status_values(got[0])["designed_false_alarms_per_hour"]) == pytest.approx(
        1e-2 * FS / 1200 * 3600
    )
    assert {m.name for m in got} == {"health_only"}
    c = node.diag.counters
    oks = levels.count(DiagnosticStatus.OK)
    assert c["health_windows"] == 6 and oks == 4
    assert (c["health_warn_windows"], c["health_error_windows"]) == (1, 1)
    assert c["health_verdict"] == got[-1].message
    assert any("test filter innovations inconsistent (ERROR)" in w for w in node.diag.warnings)


def test_a_non_finite_nis_makes_its_window_error(graph):
    ctx, ex, probe = graph
    node = HealthOnly(context=ctx, parameter_overrides=params(health_window=100))
    got = []
    probe.create_subscription(DiagnosticStatus, "/dev/health", got.append, HEALTH_QOS)
    assert wait_matched(ex, node.health.pub)
    nis = np.ones(200)
    nis[150] = np.nan
    node.health.monitor_frame(7, nis)
    assert spin_until(ex, lambda: len(got) == 2)
    assert [m.level for m in got] == [DiagnosticStatus.OK, DiagnosticStatus.ERROR]
    assert [int(status_values(m)["first_sample_index"]) for m in got] == [7, 107]


def test_calibration_moments_set_the_scaled_chi_square_thresholds(ros_context):
    node = HealthOnly(
        context=ros_context,
        parameter_overrides=params(health_nis_mean=1.13, health_nis_dispersion=0.16),
    )
    m = NisMonitor.moment_matched(1200, 1e-3, 1.13, 0.16)
    assert node.health.monitor.thresholds == m.thresholds
    assert node.health.monitor.thresholds != NisMonitor(1200, 1e-3).thresholds

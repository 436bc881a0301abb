"""ROS 2 node: hybrid EKF (Zhang 2010, eqs. 4-48 .. 4-57) downstream of a force-rebalance
accelerometer.

Subscribes ``adc`` (readout AdcFrame, one channel [V]) and ``drive`` (SignalFrame whose
first channel is the feedback voltage v_F [V]) of the device (the node's namespace, default
``/accelerometer``, or ``device_namespace``), pairs the frames by ``first_sample_index``
and publishes the device's ``estimate`` (mems_msgs/StateEstimate:
displacement [m], velocity [m/s], acceleration [m/s^2] with variances) for every
sample. The filter's model is built from the same parameter table as the device
(:data:`mems_sim.devices.accelerometer.ACCEL_SPECS`: the designer's model, Table I/II), so
one parameter file configures both; ``params_yaml`` names an identified model's YAML
(:mod:`mems_estimation.identification.accelerometer_identification`) whose mass,
stiffness, damping, gap and electronic noise replace the parameters' values (the
filter then runs with the model the bench found). Frames with non-finite values, another sample
rate or mismatched lengths are rejected and counted on /diagnostics; the filter keeps
running on the next good frames (input path: :class:`EstimatorNode`). A filter that
diverges (non-finite state, covariance not positive definite, displacement outside the
gap) is re-initialised from its prior and counted (``divergences``); that frame's
estimates are not published. A stream reset re-initialises it too; over a gap the filter
continues without the missing samples.

Health: an innovation consistency monitor
(:class:`~mems_estimation.filters.consistency_monitor.NisMonitor`) sums the normalised
innovation squared ``nu^2 / S`` of every sample whose estimate is published over windows of
``health_window`` samples against the thresholds of ``health_false_alarm``: those of the
scaled chi-square with the filter's measured fault-free moments (``health_nis_mean``,
``health_nis_dispersion``; Satterthwaite 1946), since the plain chi-square of a mean NIS
of 0.99 gives a quarter of the designed false alarms at 1e-3 (the defaults are the nominal
device's; a drawn device or a real part has its own, measured on a fault-free recording of
its ``health`` by the ``calibrate_health`` tool); each completed window is
published on the device's ``health``
(diagnostic_msgs/DiagnosticStatus: level OK, WARN or ERROR, name the node's name, message
the verdict, values the window's first sample index, samples, statistic, thresholds and
the designed false alarms per hour), and /diagnostics carries the last verdict and
statistic and the counts of WARN and ERROR windows. The monitor only reports: the estimate
is the same with it. A re-initialised filter (divergence, stream reset) starts a new
window (the incomplete one is dropped); a window continues over a gap.
"""

from __future__ import annotations

import numpy as np

from mems_estimation.filters.accelerometer_ekf import (
    FAULT_FREE_NIS_DISPERSION,
    FAULT_FREE_NIS_MEAN,
    HEALTH_MOMENTS_SOURCE,
    HEALTH_WINDOW,
    HybridEkf,
)
from mems_estimation.identification.accelerometer_identification import load_identification
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    Diverged,
    EstimatorNode,
    input_specs,
    output_frame,
)
from mems_estimation.nodes.health import HealthReporter, calibration_specs, health_specs
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices import accelerometer
from mems_sim.kernels.accelerometer_ekf import STATE_NAMES, STATE_UNITS
from mems_sim.kernels.divergence import state_ok
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import adc_physical, make_state_estimate, signal_data
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

NODE_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec("output_topic", "", "-", "StateEstimate topic; empty: the device's 'estimate'", ""),
    ParamSpec(
        "params_yaml",
        "",
        "-",
        "identified model YAML (accelerometer_identification): its "
        + ", ".join(accelerometer.LOOP_MODEL_KEYS)
        + " replace the parameters'; empty: the parameters' values",
        "the device identified on the bench from its own records, not its parameter table",
    ),
    *health_specs(
        HEALTH_WINDOW,
        "chosen: 1 ms at 1 MHz (1000 verdicts/s), short against the loop's "
        "nulling of a readout fault",
    ),
    *calibration_specs(FAULT_FREE_NIS_MEAN, FAULT_FREE_NIS_DISPERSION, HEALTH_MOMENTS_SOURCE),
)


class AccelerometerEkfNode(EstimatorNode):
    """Hybrid EKF on an accelerometer's readout and feedback-voltage frames."""

    GAP_NOTE = "the filter continues without them"

    NODE_NAME = "accelerometer_ekf"
    DEFAULT_NAMESPACE = "accelerometer"
    SPECS = accelerometer.ACCEL_SPECS + NODE_SPECS + input_specs()
    DIAGNOSTICS_TITLE = "hybrid EKF"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        p = self.p
        if p["params_yaml"]:
            # the node runs with (and reports) the identified model
            p.update(self.parameter_file("params_yaml", load_identification))
        model = accelerometer.validate_params(self.values_of(accelerometer.ACCEL_SPECS))
        v_b = accelerometer.bias_voltage(model) if model["mode"] != "open_loop" else 0.0
        self.filter = HybridEkf(accelerometer.ekf_config(model, v_b))
        self.fs = model["sample_rate_hz"]
        self.pub = self.create_publisher(
            StateEstimate, p["output_topic"] or self.device_topic("estimate"), FRAME_QOS
        )
        self.health = HealthReporter(self, self.fs, "hybrid EKF")
        self.pub_health = self.health.pub
        self.subscribe_pair(
            ("adc", AdcFrame, lambda msg: adc_physical(msg)[:, 0]),
            ("drive", SignalFrame, lambda msg: signal_data(msg)[:, 0]),
        )

    def reset_estimator(self) -> None:
        """The hybrid EKF starts again from its prior (x0 = 0, P0); so does the monitor's
        window."""
        self.filter.reset()
        self.health.reset()

    def process_pair(self, first: int, stamp_ns: int, y: np.ndarray, v_f: np.ndarray) -> None:
        """Filter one readout frame y [V] with its feedback voltage v_F [V]; publish."""
        out = self.filter.run(y, v_f)
        if not out["positive_definite"].all():
            self.diag.count(
                "covariance_not_pd_samples", int(np.count_nonzero(~out["positive_definite"]))
            )
            self.diag.warn("hybrid EKF covariance lost positive definiteness")
        if self.filter.diverged() or not state_ok(out["estimate"], out["variance"]):
            self.reset_estimator()
            raise Diverged("hybrid EKF")
        msg = output_frame(
            make_state_estimate,
            out["estimate"],
            out["variance"],
            first=first,
            fs=self.fs,
            stamp_ns=stamp_ns,
            estimator="hybrid_ekf",
            state_names=STATE_NAMES,
            state_units=STATE_UNITS,
            frame_id="accelerometer",
        )
        self.pub.publish(msg)
        innov = out["innovation"]
        self.health.monitor_frame(first, innov * innov / out["innovation_variance"])


def main(argv: list[str] | None = None) -> int:
    """Entry point ``accelerometer_ekf_node``."""
    return run_node(AccelerometerEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""ROS 2 node: in-situ gyro scale-factor calibration from the stage estimate (Chen 2018
sec. 3.3.1 and 3.6.3, eq. 27).

Subscribes the stage's ``estimate`` (StateEstimate theta, omega), ``drive`` (phase,
f_drive, trial) and ``gyro/adc`` (the gyro's own-clock AdcFrame) -- the node's namespace,
default ``/stage``, or ``device_namespace`` --; pairs
the peak-to-peak rates per trial (:class:`mems_estimation.identification.stage_gyro_calibration.StreamingCalibrator`)
and publishes the stage's ``gyro_scale_factor`` (mems_msgs/CalibrationResult: scale_factor,
bias with standard errors) once ``n_trials`` trials are paired (and again at shutdown if
more arrived). Malformed / non-finite frames are rejected and counted on /diagnostics.
"""

from __future__ import annotations

import numpy as np
from rclpy.duration import Duration

from mems_estimation.identification.stage_gyro_calibration import StreamingCalibrator
from mems_estimation.identification.stage_identification import harmonic_fit
from mems_estimation.nodes.frame_input import DEVICE_NAMESPACE, EstimatorNode
from mems_msgs.msg import AdcFrame, CalibrationResult, SignalFrame, StateEstimate
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import FrameError, adc_physical, ns_to_time, signal_data, time_to_ns
from mems_sim.ros.node_base import run_node
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS

CAL_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec(
        "sample_rate_hz",
        625.0e3,
        "Hz",
        "stage sample rate",
        "sec. 3.5.2",
        min=0.0,
        max=1e8,
        min_exclusive=True,
    ),
    ParamSpec(
        "n_trials",
        7,
        "-",
        "trials after which the result is published",
        "eq. (24)",
        min=3,
        max=100000,
    ),
    ParamSpec(
        "half_window", 15, "samples", "+-samples around the peaks", "sec. 3.6.3", min=0, max=10000
    ),
    ParamSpec(
        "settle_fraction",
        0.5,
        "-",
        "leading fraction of each trial skipped (transient)",
        "assumption (1/(zeta wn) = 18.6 ms)",
        min=0.0,
        max=0.95,
    ),
    ParamSpec("device", "stage/gyro", "-", "device name in the result", ""),
)


def _estimate_omega(msg: StateEstimate) -> np.ndarray:
    names = list(msg.state_names)
    if "omega" not in names:
        raise FrameError(f"estimate at {msg.first_sample_index}: no 'omega' state")
    s = np.asarray(msg.states, float)
    if s.size != msg.num_samples * len(names):
        raise FrameError(f"estimate at {msg.first_sample_index}: size mismatch")
    if not np.all(np.isfinite(s)):
        raise FrameError(f"estimate at {msg.first_sample_index}: non-finite values")
    return s.reshape(msg.num_samples, len(names))[:, names.index("omega")]


def _drive_trials(msg: SignalFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(phase, f_drive, trial) of a drive frame; FrameError when absent or non-finite."""
    data = signal_data(msg)
    names = list(msg.channel_names)
    try:
        cols = [names.index(c) for c in ("phase", "f_drive", "trial")]
    except ValueError as exc:
        raise FrameError(f"drive frame at {msg.first_sample_index}: {exc}") from None
    return tuple(np.ascontiguousarray(data[:, c]) for c in cols)


def _gyro_rate(msg: AdcFrame) -> np.ndarray:
    """Angular rate [rad/s] of a gyro frame; FrameError when non-finite."""
    v = adc_physical(msg)[:, 0]
    if not np.all(np.isfinite(v)):
        raise FrameError("non-finite gyro values")
    return v


class GyroCalibrationNode(EstimatorNode):
    """Peak-to-peak pairing + least squares eq. (27) (see module doc)."""

    NODE_NAME = "stage_gyro_calibration"
    DEFAULT_NAMESPACE = "stage"
    SPECS = CAL_SPECS
    DIAGNOSTICS_TITLE = "gyro scale factor"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        p = self.p
        self.cal = StreamingCalibrator(p["sample_rate_hz"], p["settle_fraction"], p["half_window"])
        # load the compiled (numba) harmonic fit now, not at the first trial (~1 s)
        harmonic_fit(np.zeros(64), np.arange(64) / 64.0)
        self.pub = self.create_publisher(
            CalibrationResult, self.device_topic("gyro_scale_factor"), RESULT_QOS
        )
        self.t0_ns = None
        self.results: list[dict] = []
        self.last_stamp = 0
        self.estimates_received = 0
        self.subscribe_pair(
            ("estimate", StateEstimate, self._decode_estimate),
            ("drive", SignalFrame, _drive_trials),
            check_rate=False,
        )
        self.create_subscription(AdcFrame, self.device_topic("gyro/adc"), self.on_gyro, FRAME_QOS)

    def _decode_estimate(self, msg: StateEstimate) -> np.ndarray:
        """omega of an estimate frame; the first one sets the time origin of the stage."""
        om = _estimate_omega(msg)
        if self.t0_ns is None:
            self.t0_ns = time_to_ns(msg.header.stamp) - round(
                msg.first_sample_index * 1e9 / self.p["sample_rate_hz"]
            )
        self.last_stamp = time_to_ns(msg.header.stamp)
        self.estimates_received += 1
        return om

    def on_gyro(self, msg: AdcFrame) -> None:
        """Gyro samples, placed on the stage's sample index through their stamps."""
        v = self.accept_frame(msg, _gyro_rate, check_rate=False)
        if v is None:
            return
        t0 = self.t0_ns if self.t0_ns is not None else 0
        t_first = (time_to_ns(msg.header.stamp) - t0) / 1e9
        k = (t_first + np.arange(v.size) / msg.sample_rate_hz) * self.p["sample_rate_hz"]
        self.cal.add_gyro(k, v)
        self._check_done()

    def process_pair(self, first: int, stamp_ns: int, om: np.ndarray, drive) -> None:
        """One trial's worth of rate estimate with its drive phase, frequency, trial."""
        ph, fd, tr = drive
        self.cal.add_stage(first, om, ph, fd, tr.astype(np.int64))
        self._check_done()

    def _check_done(self) -> None:
        if len(self.cal.pairs) >= self.p["n_trials"] and len(self.results) == 0:
            self.publish_result()

    def publish_result(self) -> dict | None:
        """Publish eq. (27) over the pairs so far; None with fewer than 3 pairs."""
        try:
            res = self.cal.result()
        except ValueError:
            return None
        m = CalibrationResult()
        m.header.stamp = ns_to_time(self.last_stamp)
        m.header.frame_id = "imu_link"
        m.device = self.p["device"]
        m.method = "least_squares_eq27_peak_to_peak"
        m.names = ["scale_factor", "bias"]
        m.units = ["1", "rad/s"]
        m.values = [res["scale_factor"], res["bias"]]
        m.standard_errors = [res["scale_factor_se"], res["bias_se"]]
        m.num_points = res["n"]
        m.residual_rms = res["residual_rms"]
        m.residual_unit = "rad/s"
        self.pub.publish(m)
        self.results.append(res)
        self.diag.count("results")
        return res

    def close(self) -> None:
        """At shutdown: process the remaining trials and publish if new pairs arrived."""
        n = len(self.cal.pairs)
        self.cal.finish()
        if len(self.cal.pairs) > n or not self.results:
            if self.publish_result() is not None:
                # the process may end right after: let the subscribers (recorder) have it
                self.pub.wait_for_all_acked(Duration(seconds=2.0))


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_gyro_calibration_node``."""
    return run_node(GyroCalibrationNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

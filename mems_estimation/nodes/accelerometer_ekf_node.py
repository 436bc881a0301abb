"""ROS 2 node: hybrid EKF (Zhang 2010, eqs. 4-48 .. 4-57) downstream of a force-rebalance
accelerometer.

Subscribes ``<device>/adc`` (readout AdcFrame, one channel [V]) and ``<device>/drive``
(SignalFrame whose first channel is the feedback voltage v_F [V]), pairs the frames by
``first_sample_index`` and publishes ``<device>/estimate`` (mems_msgs/StateEstimate:
displacement [m], velocity [m/s], acceleration [m/s^2] with variances) for every
sample. The filter's model is built from the same parameter table as the device
(:data:`mems_sim.devices.accelerometer.ACCEL_SPECS`: the designer's model, Table I/II), so
one parameter file configures both. Frames with non-finite values, another sample
rate or mismatched lengths are rejected and counted on /diagnostics; the filter keeps
running on the next good frames.
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node

from mems_estimation.filters.accelerometer_ekf import HybridEkf
from mems_estimation.nodes.frame_input import FrameInputMixin, FramePairer
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices import accelerometer as fra
from mems_sim.kernels.accelerometer_ekf import STATE_NAMES, STATE_UNITS
from mems_sim.params import ParamSpec
from mems_sim.ros.diagnostics import DiagnosticsReporter
from mems_sim.ros.frames import (
    FrameError,
    IndexTracker,
    adc_physical,
    make_state_estimate,
    signal_data,
    time_to_ns,
)
from mems_sim.ros.node_base import run_node
from mems_sim.ros.params import declare_specs
from mems_sim.ros.qos import FRAME_QOS

NODE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "device_namespace", "/accelerometer", "-", "namespace of the device's adc/drive topics", ""
    ),
    ParamSpec(
        "output_topic", "", "-", "StateEstimate topic; empty: <device_namespace>/estimate", ""
    ),
)


class HybridEkfNode(FrameInputMixin, Node):
    """Hybrid EKF on an accelerometer's readout and feedback-voltage frames."""

    def __init__(self, **node_kwargs) -> None:
        super().__init__("hybrid_ekf", **node_kwargs)
        self.p = p = declare_specs(self, fra.ACCEL_SPECS + NODE_SPECS)
        model = fra.validate_params({s.name: p[s.name] for s in fra.ACCEL_SPECS})
        v_b = fra.bias_voltage(model) if model["mode"] != "open_loop" else 0.0
        self.filter = HybridEkf(fra.ekf_config(model, v_b))
        self.fs = model["sample_rate_hz"]
        ns = p["device_namespace"].rstrip("/")
        self.pub = self.create_publisher(
            StateEstimate, p["output_topic"] or f"{ns}/estimate", FRAME_QOS
        )
        self.pairer = FramePairer()
        self.tracker = IndexTracker()
        self.stamps: dict[int, int] = {}
        self.frames_done = 0
        self.diag = DiagnosticsReporter(self, f"{self.get_name()}: hybrid EKF")
        self.create_subscription(AdcFrame, f"{ns}/adc", self.on_adc, FRAME_QOS)
        self.create_subscription(SignalFrame, f"{ns}/drive", self.on_drive, FRAME_QOS)

    def on_adc(self, msg: AdcFrame) -> None:
        """Validate a readout frame and filter the pairs it completes."""
        try:
            self._check_rate(msg)
            values = adc_physical(msg)[:, 0]
        except FrameError as exc:
            self._reject(str(exc))
            return
        self.stamps[msg.first_sample_index] = time_to_ns(msg.header.stamp)
        self._process(self.pairer.add("adc", msg.first_sample_index, values))

    def on_drive(self, msg: SignalFrame) -> None:
        """Validate a drive frame (finite samples) and filter the pairs it completes."""
        try:
            self._check_rate(msg)
            values = signal_data(msg)[:, 0]
        except FrameError as exc:
            self._reject(str(exc))
            return
        self._process(self.pairer.add("drive", msg.first_sample_index, values))

    def _process(self, pairs) -> None:
        for first, y, v_f in pairs:
            t0 = self.stamps.pop(first)
            if y.shape != v_f.shape:
                self._reject(
                    f"frames at {first}: {y.size} readout samples for {v_f.size} feedback samples"
                )
                continue
            missing = self.tracker.update(first, y.size)
            if missing:
                self.diag.count("gaps")
                self.diag.warn(
                    f"gap of {missing} samples before index {first}: the filter "
                    "continues without them"
                )
            out = self.filter.run(y, v_f)
            if not out["positive_definite"].all():
                self.diag.count(
                    "covariance_not_pd_samples", int(np.count_nonzero(~out["positive_definite"]))
                )
                self.diag.warn("hybrid EKF covariance lost positive definiteness")
            msg = make_state_estimate(
                out["estimate"],
                out["variance"],
                first,
                self.fs,
                estimator="hybrid_ekf",
                state_names=STATE_NAMES,
                state_units=STATE_UNITS,
                frame_id="accelerometer",
            )
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0, 10**9)
            self.pub.publish(msg)
            self.frames_done += 1
            self.diag.count("frames")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``accelerometer_ekf_node``."""
    return run_node(HybridEkfNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

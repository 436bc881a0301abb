"""ROS 2 node of the force-to-rebalance capacitive accelerometer
(thin wrapper of :mod:`mems_sim.fr_accelerometer`; Zhang 2010).

Topics (relative to the namespace, default ``/accelerometer``):
    ``adc``            mems_msgs/AdcFrame      demodulated readout (eq. 2-9 + noise) [V codes]
    ``drive``          mems_msgs/SignalFrame   feedback voltage v_F and bias V_B [V]
    ``truth``          mems_msgs/SignalFrame   input a [m/s^2], x [m], x_dot [m/s],
                                               contact (1 at the stop), saturated (1: v_F clipped)
    ``loop_estimate``  mems_msgs/StateEstimate the in-loop hybrid EKF's [x, v, a] with
                                               variances (``ekf_rebalance`` only)
    ``/diagnostics``   contact with the stop, feedback saturation, input beyond the dynamic
                       range, ADC saturation, non-positive-definite covariance: WARN.
Parameters: :data:`mems_sim.fr_accelerometer.ACCEL_SPECS` and ``EMULATOR_SPECS``.
"""
from __future__ import annotations

import numpy as np
from rclpy.node import Node

from mems_estimation.hybrid_ekf import STATE_NAMES, STATE_UNITS
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim import fr_accelerometer as fra
from mems_sim.diagnostics import DiagnosticsReporter
from mems_sim.node_common import PacedEmulator, emulator_specs, run_node
from mems_sim.params import ParamSpec
from mems_sim.qos import FRAME_QOS
from mems_sim.ros_frames import make_adc_frame, make_signal_frame, make_state_estimate
from mems_sim.ros_params import declare_specs

NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=10000, frame_id="accelerometer")

TRUTH_CHANNELS = ("acceleration", "displacement", "velocity", "contact", "saturated")
TRUTH_UNITS = ("m/s^2", "m", "m/s", "1", "1")


class FrAccelerometerNode(PacedEmulator, Node):
    """Emulated force-rebalance accelerometer publishing readout codes, drive and truth.

    Args:
        drive_externally: no timer; the owner calls :meth:`step` (scenario runner).
        autostart: start the wall-clock timer at once (else call :meth:`start`).
    """

    def __init__(self, *, drive_externally: bool = False, autostart: bool = True,
                 **node_kwargs) -> None:
        node_kwargs.setdefault("namespace", "accelerometer")
        super().__init__("fr_accelerometer", **node_kwargs)
        self.p = declare_specs(self, fra.ACCEL_SPECS + NODE_SPECS)
        device = {s.name: self.p[s.name] for s in fra.ACCEL_SPECS}
        self.device = fra.ForceRebalanceAccelerometer(device, seed=self.p["seed"])
        self.fs = self.device.fs
        self.init_emulator(self.fs)
        self.ekf_mode = self.p["mode"] == "ekf_rebalance"
        self.pub_adc = self.create_publisher(AdcFrame, "adc", FRAME_QOS)
        self.pub_drive = self.create_publisher(SignalFrame, "drive", FRAME_QOS)
        self.pub_truth = self.create_publisher(SignalFrame, "truth", FRAME_QOS)
        self.pub_estimate = (self.create_publisher(StateEstimate, "loop_estimate", FRAME_QOS)
                             if self.ekf_mode else None)
        self.diag = DiagnosticsReporter(self, f"{self.get_name()}: force-rebalance accelerometer",
                                        hardware_id=self.get_fully_qualified_name())
        if not drive_externally and autostart:
            self.start()

    def _report(self, f: fra.AccelFrame, first: int) -> None:
        """Count and warn about contact, saturation, over-range input, lost definiteness."""
        d, dr = self.device, self.p["dynamic_range"]
        checks = (
            ("contact_samples", f.contact, "the proof mass hit the mechanical stop "
             f"(+-{d.x_stop:.3g} m, pull-in)"),
            ("feedback_saturated_samples", f.saturated, "feedback voltage clipped at "
             f"+-V_B = {d.v_b:.4g} V: the rebalance force is at its limit"),
            ("over_range_samples", np.abs(f.accel) > dr, "input acceleration beyond the "
             f"configured dynamic range {dr:.4g} m/s^2"),
            ("adc_saturated_samples", (f.code >= d.code_max) | (f.code <= -d.code_max - 1),
             f"readout ADC saturated at +-{self.p['adc_full_scale']} V"),
            ("covariance_not_pd_samples", ~f.positive_definite,
             "hybrid EKF covariance lost positive definiteness"),
        )
        for key, mask, text in checks:
            k = int(np.count_nonzero(mask))
            if k:
                if key not in self.diag.counters:   # warn once per kind; then count
                    i = first + int(np.argmax(mask))
                    self.diag.warn(f"{text} (first at sample {i}, t = {i / self.fs:.6f} s)")
                self.diag.count(key, k)

    def step(self) -> int:
        """Run and publish the next frame; return the number of samples (0 when done)."""
        n = self.next_frame_size()
        if n <= 0:
            return 0
        first = self.next_index
        d = self.device
        f = d.step(n)
        common = dict(frame_id=self.p["frame_id"], t0_ns=self.t0_ns)
        sat = int(np.count_nonzero((f.code >= d.code_max) | (f.code <= -d.code_max - 1)))
        self.pub_adc.publish(make_adc_frame(
            f.code.reshape(n, 1), first, self.fs, bits=self.p["adc_bits"],
            channel_names=("readout",), channel_units=("V",), lsb=(d.lsb,),
            full_scale=(self.p["adc_full_scale"],), saturated_count=sat, **common))
        self.pub_drive.publish(make_signal_frame(
            np.column_stack([f.v_f, np.full(n, d.v_b)]), first, self.fs,
            channel_names=("feedback_voltage", "bias_voltage"), channel_units=("V", "V"),
            **common))
        self.pub_truth.publish(make_signal_frame(
            np.column_stack([f.accel, f.x, f.v, f.contact, f.saturated]), first, self.fs,
            channel_names=TRUTH_CHANNELS, channel_units=TRUTH_UNITS, **common))
        if self.pub_estimate is not None:
            self.pub_estimate.publish(make_state_estimate(
                f.estimate, f.variance, first, self.fs, estimator="hybrid_ekf_in_loop",
                state_names=STATE_NAMES, state_units=STATE_UNITS, **common))
        self.diag.count("frames")
        self._report(f, first)
        self.frame_published(n)
        return n


def main(argv: list[str] | None = None) -> int:
    """Entry point ``fr_accelerometer_node``."""
    return run_node(FrAccelerometerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

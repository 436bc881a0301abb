"""ROS 2 node of the pulse-actuated resonator read through a one-bit sigma-delta ADC
(thin wrapper of mems_sim.sd_resonator; Colinet et al.).

Topics (relative to the namespace, default ``/resonator``):
    ``adc``           mems_msgs/AdcFrame     the one-bit stream: codes -1/+1, bits = 1, lsb 1 V
    ``drive``         mems_msgs/SignalFrame  the pulses applied to the actuator: height of the
                      pulse fired in each sample interval [V], its firing offset after the
                      sample instant [s] and its width [s] (0 where no pulse)
    ``truth``         mems_msgs/SignalFrame  position [V], velocity [V/s], f0 [Hz], position
                      at the firing instant of the interval's pulse [V] and at the centre of
                      a pulse centred in the interval [V] (0 where none)
    ``loop_estimate`` mems_msgs/StateEstimate the in-loop Kalman observer's position (observer mode)
    ``/diagnostics``
Parameters: ``mems_sim.sd_resonator.RESONATOR_SPECS`` and ``EMULATOR_SPECS``.
"""
from __future__ import annotations

import numpy as np
from rclpy.node import Node

from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim import sd_resonator
from mems_sim.diagnostics import DiagnosticsReporter
from mems_sim.node_common import PacedEmulator, emulator_specs, run_node
from mems_sim.params import ParamSpec
from mems_sim.qos import FRAME_QOS
from mems_sim.ros_frames import make_adc_frame, make_signal_frame, make_state_estimate
from mems_sim.ros_params import declare_specs

NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=1000, frame_id="resonator")

TRUTH_CHANNELS = ("position", "velocity", "f0", "position_at_pulse_start",
                  "position_at_pulse_center")
TRUTH_UNITS = ("V", "V/s", "Hz", "V", "V")
DRIVE_CHANNELS = ("pulse", "pulse_start", "pulse_width")
DRIVE_UNITS = ("V", "s", "s")


class SdResonatorNode(PacedEmulator, Node):
    """Emulated resonator + sigma-delta + pulse loop publishing the bit stream and truth.

    Args:
        drive_externally: no timer; the owner calls :meth:`step` (scenario runner).
        autostart: start the wall-clock timer at once (else call :meth:`start`).
    """

    def __init__(self, *, drive_externally: bool = False, autostart: bool = True,
                 **node_kwargs) -> None:
        node_kwargs.setdefault("namespace", "resonator")
        super().__init__("sd_resonator", **node_kwargs)
        self.p = declare_specs(self, sd_resonator.RESONATOR_SPECS + NODE_SPECS)
        device = {s.name: self.p[s.name] for s in sd_resonator.RESONATOR_SPECS}
        sd_resonator.validate_params(device)
        self.device = sd_resonator.SdResonatorDevice(device, seed=self.p["seed"])
        self.fs = self.p["sample_rate_hz"]
        self.init_emulator(self.fs)
        self.observer_mode = self.p["mode"] == "observer"
        self.pub_adc = self.create_publisher(AdcFrame, "adc", FRAME_QOS)
        self.pub_drive = self.create_publisher(SignalFrame, "drive", FRAME_QOS)
        self.pub_truth = self.create_publisher(SignalFrame, "truth", FRAME_QOS)
        self.pub_estimate = (self.create_publisher(StateEstimate, "loop_estimate", FRAME_QOS)
                             if self.observer_mode else None)
        self.diag = DiagnosticsReporter(self, f"{self.get_name()}: sigma-delta resonator",
                                        hardware_id=self.get_fully_qualified_name())
        if not drive_externally and autostart:
            self.start()




    def step(self) -> int:
        """Run and publish the next frame; return the number of samples (0 when done)."""
        n = self.next_frame_size()
        if n <= 0:
            return 0
        first = self.next_index
        f = self.device.step(n)
        common = dict(frame_id=self.p["frame_id"], t0_ns=self.t0_ns)
        self.pub_adc.publish(make_adc_frame(
            f.bits.reshape(n, 1), first, self.fs, bits=1, channel_names=("sd_bit",),
            channel_units=("V",), lsb=(1.0,), full_scale=(1.0,), **common))
        self.pub_drive.publish(make_signal_frame(
            np.column_stack([f.pulses, f.pulse_start, f.pulse_width]), first, self.fs,
            channel_names=DRIVE_CHANNELS, channel_units=DRIVE_UNITS, **common))
        self.pub_truth.publish(make_signal_frame(
            np.column_stack([f.position, f.velocity, f.f0, f.x_pulse_start, f.x_pulse_center]),
            first, self.fs,
            channel_names=TRUTH_CHANNELS, channel_units=TRUTH_UNITS, **common))
        if self.pub_estimate is not None:
            self.pub_estimate.publish(make_state_estimate(
                f.estimate.reshape(n, 1), f.estimate_var.reshape(n, 1), first, self.fs,
                estimator="kalman_observer_in_loop", state_names=("position",),
                state_units=("V",), **common))
        self.diag.count("frames")
        self.diag.count("pulses", int(np.count_nonzero(f.pulses)))
        self.frame_published(n)
        return n


def main(argv: list[str] | None = None) -> int:
    """Entry point ``sd_resonator_node``."""
    return run_node(SdResonatorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

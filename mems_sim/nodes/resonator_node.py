"""ROS 2 node of the pulse-actuated resonator read through a one-bit sigma-delta ADC
(thin wrapper of mems_sim.devices.resonator; Colinet et al.).

Topics (relative to the namespace, default ``/resonator``):
    ``adc``           mems_msgs/AdcFrame     the one-bit stream: codes -1/+1, bits = 1, lsb 1 V
                      (``quantizer: gaussian`` stand-in: its real-valued output as 24-bit
                      codes, lsb 2^-20 V)
    ``drive``         mems_msgs/SignalFrame  the pulses applied to the actuator: height of the
                      pulse fired in each sample interval [V], its firing offset after the
                      sample instant [s] and its width [s] (0 where no pulse)
    ``truth``         mems_msgs/SignalFrame  position [V], velocity [V/s], f0 [Hz], position
                      at the firing instant of the interval's pulse [V] and at the centre of
                      a pulse centred in the interval [V] (0 where none)
    ``loop_estimate`` mems_msgs/StateEstimate the in-loop Kalman observer's position (observer mode)
    ``faults``        mems_msgs/FaultEvent   each fault of ``fault_schedule`` when it begins
                      (timing kinds only: ``dropped_samples``)
    ``/diagnostics``
Input: ``temperature`` sensor_msgs/Temperature: the device's temperature (``temperature_c``).
Parameters: ``mems_sim.devices.resonator.RESONATOR_SPECS``, ``device_seed`` and
``temperature_c`` (the resonator drawn from the table's spreads at a temperature, reference
25 C; the in-loop observer keeps the nominal model, or with ``loop_params_yaml`` the f0
and Q of an identified model's YAML) and ``EMULATOR_SPECS``.
"""

from __future__ import annotations

import numpy as np

from mems_sim.devices import resonator as sd_resonator
from mems_sim.hardware.fault_schedule import TIMING_ONLY
from mems_sim.nodes.fault_topic import FAULT_SCHEDULE_SPEC, FaultTopic
from mems_sim.nodes.loop_model import loop_model, loop_params_spec
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import make_adc_frame, make_state_estimate
from mems_sim.ros.node_base import EmulatorNode, emulator_specs, variation_specs
from mems_sim.ros.node_main import run_node

#: 10,000 samples (10 ms at 1 MHz) per frame: with 1000-sample frames the graph's per-frame
#: cost (callbacks, messages, recorder) kept a device and three observers below real time,
#: and readers more than the frame QoS depth behind lost frames.
NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=10000, frame_id="resonator") + (
    loop_params_spec(sd_resonator.LOOP_MODEL_KEYS, "Kalman observer (observer mode)"),
)

TRUTH_CHANNELS = (
    "position",
    "velocity",
    "f0",
    "position_at_pulse_start",
    "position_at_pulse_center",
)
TRUTH_UNITS = ("V", "V/s", "Hz", "V", "V")
DRIVE_CHANNELS = ("pulse", "pulse_start", "pulse_width")
#: Code step of the ``quantizer: gaussian`` stand-in's output (24-bit codes, +-8 V), V: its
#: rounding variance (2^-40/12 V^2) is negligible against the model's 1/3 V^2.
STANDIN_LSB = 2.0**-20
DRIVE_UNITS = ("V", "s", "s")


class ResonatorNode(EmulatorNode):
    """Emulated resonator + sigma-delta + pulse loop publishing the bit stream and truth.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`.
    """

    NODE_NAME = "resonator"
    DEFAULT_NAMESPACE = "resonator"
    SPECS = sd_resonator.RESONATOR_SPECS + variation_specs() + NODE_SPECS + (FAULT_SCHEDULE_SPEC,)
    DEVICE_SPECS = sd_resonator.RESONATOR_SPECS
    DIAGNOSTICS_TITLE = "sigma-delta resonator"

    def make_device(self) -> float:
        nominal = self.values_of(sd_resonator.RESONATOR_SPECS)
        sd_resonator.validate_params(nominal)
        identified = loop_model(
            self,
            sd_resonator.LOOP_MODEL_KEYS,
            sd_resonator.RESONATOR_SPECS,
            "resonator model YAML",
        )
        nominal.update(identified or {})  # the observer's model only (the device's own)
        self.device = sd_resonator.SdResonatorDevice(
            self.device_values(), seed=self.p["seed"], nominal=nominal
        )
        self.observer_mode = self.p["mode"] == "observer"
        self.fault_topic = FaultTopic(
            self, ("sd_bit",), ("V",), self.p["sample_rate_hz"], kinds=TIMING_ONLY
        )
        self.pub_adc, self.pub_drive, self.pub_truth = self.create_frame_publishers(
            "adc", "drive", "truth"
        )
        self.pub_estimate = (
            self.create_frame_publishers("loop_estimate")[0] if self.observer_mode else None
        )
        return self.p["sample_rate_hz"]

    def publish_frame(self, first: int, n: int) -> None:
        self.fault_topic.publish_starting(first, n)
        f = self.device.step(n)
        common = self.frame_kwargs
        if self.p["quantizer"] == "gaussian":
            # the linear-Gaussian stand-in's real-valued output v = q + w as 24-bit codes
            codes = np.clip(np.rint(f.bits / STANDIN_LSB), -(2**23), 2**23 - 1).astype(np.int32)
            adc = dict(bits=24, lsb=(STANDIN_LSB,), full_scale=(2**23 * STANDIN_LSB,))
        else:
            codes, adc = f.bits, dict(bits=1, lsb=(1.0,), full_scale=(1.0,))
        self.pub_adc.publish(
            make_adc_frame(
                codes.reshape(n, 1),
                first,
                self.fs,
                channel_names=("sd_bit",),
                channel_units=("V",),
                **adc,
                **common,
            )
        )
        self.publish_signals(
            self.pub_drive,
            first,
            np.column_stack([f.pulses, f.pulse_start, f.pulse_width]),
            DRIVE_CHANNELS,
            DRIVE_UNITS,
        )
        self.publish_signals(
            self.pub_truth,
            first,
            np.column_stack([f.position, f.velocity, f.f0, f.x_pulse_start, f.x_pulse_center]),
            TRUTH_CHANNELS,
            TRUTH_UNITS,
        )
        if self.pub_estimate is not None:
            self.pub_estimate.publish(
                make_state_estimate(
                    f.estimate.reshape(n, 1),
                    f.estimate_var.reshape(n, 1),
                    first,
                    self.fs,
                    estimator="kalman_observer_in_loop",
                    state_names=("position",),
                    state_units=("V",),
                    **common,
                )
            )
        self.diag.count("pulses", int(np.count_nonzero(f.pulses)))


def main(argv: list[str] | None = None) -> int:
    """Entry point ``resonator_node``."""
    return run_node(ResonatorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

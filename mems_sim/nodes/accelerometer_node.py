"""ROS 2 node of the force-to-rebalance capacitive accelerometer
(thin wrapper of :mod:`mems_sim.devices.accelerometer`; Zhang 2010).

Topics (relative to the namespace, default ``/accelerometer``):
    ``adc``            mems_msgs/AdcFrame      demodulated readout (eq. 2-9 + noise) [V codes]
    ``drive``          mems_msgs/SignalFrame   feedback voltage v_F and bias V_B [V]
    ``truth``          mems_msgs/SignalFrame   input a [m/s^2], x [m], x_dot [m/s],
                                               contact (1 at the stop), saturated (1: v_F clipped)
    ``loop_estimate``  mems_msgs/StateEstimate the in-loop hybrid EKF's [x, v, a] with
                                               variances (``ekf_rebalance`` only)
    ``faults``         mems_msgs/FaultEvent    each fault of ``fault_schedule`` when it begins
                                               (sensor faults on the readout voltage before
                                               the ADC, inside the loop; docs/faults.md)
    ``/diagnostics``   contact with the stop, feedback saturation, input beyond the dynamic
                       range, ADC saturation, non-positive-definite covariance: WARN.
Input: ``temperature`` sensor_msgs/Temperature: the device's temperature (``temperature_c``).
Parameters: :data:`mems_sim.devices.accelerometer.ACCEL_SPECS`, ``device_seed`` and
``temperature_c`` (reference 26.85 C = the 300 K of Zhang 2010 eq. (3-1)) and
``EMULATOR_SPECS``. The plant is the device drawn for ``device_seed`` at ``temperature_c``;
V_B and the in-loop EKF are designed from the nominal device (the parameters as given);
``loop_params_yaml`` gives the in-loop EKF an identified model instead (the bench's).
"""

from __future__ import annotations

import numpy as np

from mems_sim.devices import accelerometer
from mems_sim.kernels.accelerometer_ekf import STATE_NAMES, STATE_UNITS
from mems_sim.nodes.fault_topic import FAULT_SCHEDULE_SPEC, FaultTopic
from mems_sim.nodes.loop_model import loop_model, loop_params_spec
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import make_adc_frame, make_state_estimate
from mems_sim.ros.node_base import EmulatorNode, emulator_specs, variation_specs
from mems_sim.ros.node_main import run_node

NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=10000, frame_id="accelerometer") + (
    loop_params_spec(accelerometer.LOOP_MODEL_KEYS, "hybrid EKF (ekf_rebalance)"),
)
#: Reference temperature of the table [degC]: the 300 K of Zhang 2010 eq. (3-1).
REFERENCE_TEMPERATURE_C = 26.85

TRUTH_CHANNELS = ("acceleration", "displacement", "velocity", "contact", "saturated")
TRUTH_UNITS = ("m/s^2", "m", "m/s", "1", "1")


class AccelerometerNode(EmulatorNode):
    """Emulated force-rebalance accelerometer publishing readout codes, drive and truth.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`.
    """

    NODE_NAME = "accelerometer"
    DEFAULT_NAMESPACE = "accelerometer"
    SPECS = (
        accelerometer.ACCEL_SPECS
        + variation_specs(REFERENCE_TEMPERATURE_C)
        + NODE_SPECS
        + (FAULT_SCHEDULE_SPEC,)
    )
    DEVICE_SPECS = accelerometer.ACCEL_SPECS
    DIAGNOSTICS_TITLE = "force-rebalance accelerometer"

    def make_device(self) -> float:
        self.device = accelerometer.ForceRebalanceAccelerometer(
            self.device_values(),
            seed=self.p["seed"],
            nominal=self.values_of(accelerometer.ACCEL_SPECS),
            loop_model=loop_model(
                self,
                accelerometer.LOOP_MODEL_KEYS,
                accelerometer.ACCEL_SPECS,
                "accelerometer model YAML",
            ),
        )
        self.fault_topic = FaultTopic(
            self, ("readout",), ("V",), self.device.fs, white_std=(self.device.v_noise_std,)
        )
        self.device.faults = self.fault_topic.injector
        self.ekf_mode = self.p["mode"] == "ekf_rebalance"
        self.pub_adc, self.pub_drive, self.pub_truth = self.create_frame_publishers(
            "adc", "drive", "truth"
        )
        self.pub_estimate = (
            self.create_frame_publishers("loop_estimate")[0] if self.ekf_mode else None
        )
        return self.device.fs

    def _report(self, f: accelerometer.AccelFrame, first: int) -> None:
        """Count and warn about contact, saturation, over-range input, lost definiteness."""
        d, dr = self.device, self.p["dynamic_range"]
        checks = (
            (
                "contact_samples",
                f.contact,
                f"the proof mass hit the mechanical stop (+-{d.x_stop:.3g} m, pull-in)",
            ),
            (
                "feedback_saturated_samples",
                f.saturated,
                "feedback voltage clipped at "
                f"+-V_B = {d.v_b:.4g} V: the rebalance force is at its limit",
            ),
            (
                "over_range_samples",
                np.abs(f.accel) > dr,
                f"input acceleration beyond the configured dynamic range {dr:.4g} m/s^2",
            ),
            (
                "adc_saturated_samples",
                (f.code >= d.code_max) | (f.code <= -d.code_max - 1),
                f"readout ADC saturated at +-{self.p['adc_full_scale']} V",
            ),
            (
                "covariance_not_pd_samples",
                ~f.positive_definite,
                "hybrid EKF covariance lost positive definiteness",
            ),
        )
        for key, mask, text in checks:
            k = int(np.count_nonzero(mask))
            if k:
                if key not in self.diag.counters:  # warn once per kind; then count
                    i = first + int(np.argmax(mask))
                    self.diag.warn(f"{text} (first at sample {i}, t = {i / self.fs:.6f} s)")
                self.diag.count(key, k)

    def publish_frame(self, first: int, n: int) -> None:
        d = self.device
        self.fault_topic.publish_starting(first, n)
        f = d.step(n)
        common = self.frame_kwargs
        sat = int(np.count_nonzero((f.code >= d.code_max) | (f.code <= -d.code_max - 1)))
        self.pub_adc.publish(
            make_adc_frame(
                f.code.reshape(n, 1),
                first,
                self.fs,
                bits=self.p["adc_bits"],
                channel_names=("readout",),
                channel_units=("V",),
                lsb=(d.lsb,),
                full_scale=(self.p["adc_full_scale"],),
                saturated_count=sat,
                **common,
            )
        )
        self.publish_signals(
            self.pub_drive,
            first,
            np.column_stack([f.v_f, np.full(n, d.v_b)]),
            ("feedback_voltage", "bias_voltage"),
            ("V", "V"),
        )
        self.publish_signals(
            self.pub_truth,
            first,
            np.column_stack([f.accel, f.x, f.v, f.contact, f.saturated]),
            TRUTH_CHANNELS,
            TRUTH_UNITS,
        )
        if self.pub_estimate is not None:
            self.pub_estimate.publish(
                make_state_estimate(
                    f.estimate,
                    f.variance,
                    first,
                    self.fs,
                    estimator="hybrid_ekf_in_loop",
                    state_names=STATE_NAMES,
                    state_units=STATE_UNITS,
                    **common,
                )
            )
        self._report(f, first)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``accelerometer_node``."""
    return run_node(AccelerometerNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

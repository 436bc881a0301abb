"""ROS 2 node of the piezo tilt micro-stage with its on-stage gyro and LDV reference
(thin wrapper of mems_sim.devices.stage and mems_sim.devices.stage_gyro; Chen 2018 ch. 3).

Topics (relative to the namespace, default ``/stage``):
    ``adc``          mems_msgs/AdcFrame     capacitive channels 1A, 1B, 2A, 2B [V], 16 bit
    ``drive``        mems_msgs/SignalFrame  u [V], v_bias [V], f_drive [Hz], phase [cycle],
                                            trial [-] (drive-schedule segment index)
    ``truth``        mems_msgs/SignalFrame  theta_y, omega_y (main), theta_x, omega_x (off axis)
    ``ldv``          mems_msgs/SignalFrame  LDV reference omega [rad/s] (identification only)
    ``temperature``  sensor_msgs/Temperature  stage temperature [degC]
    ``gyro/adc``     mems_msgs/AdcFrame     gyro codes (own ~8 kHz clock: sample_rate_hz is
                                            the gyro's f_g, sample j is stamped epoch +
                                            gyro_start_offset_s + j / f_g, the stage's
                                            epoch: its time base)
    ``gyro/imu``     sensor_msgs/Imu        the same samples (angular_velocity.y = main axis),
                                           with publish_imu and while subscribed
    ``faults``       mems_msgs/FaultEvent   each fault of ``fault_schedule`` when it begins
                                            (sensor faults on the readout voltages of
                                            1A..2B before the ADC; docs/faults.md)
    ``/diagnostics``
Input: ``temperature_input`` sensor_msgs/Temperature: the stage's temperature follows it
(``temperature_c``, from the next frame; ``temperature`` is the node's output).
Parameters: STAGE_SPECS (its own ``device_seed``: the channel gain mismatch; its own
``temperature_c`` with ``ref_temperature_c``), GYRO_SPECS, SCHEDULE_SPECS (``gyro_seed``: the
gyro's noise seed, -1 = the node's ``seed``), ``fault_schedule`` and EMULATOR_SPECS.
"""

from __future__ import annotations

import numpy as np
from sensor_msgs.msg import Imu, Temperature

from mems_sim.devices import stage as micro_stage
from mems_sim.devices.stage_gyro import GYRO_SPECS, MemsGyro
from mems_sim.nodes.fault_topic import FAULT_SCHEDULE_SPEC, FaultTopic
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import index_to_ns, make_adc_frame, ns_to_time
from mems_sim.ros.node_base import EmulatorNode, emulator_specs
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

SCHEDULE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "schedule",
        "calibration",
        "-",
        "drive schedule: amplitude sweep (calibration), "
        "frequency sweep (identification) or zero drive (noise)",
        "Table 3.2",
        choices=("calibration", "identification", "zero"),
    ),
    ParamSpec(
        "drive_freq_hz",
        1700.0,
        "Hz",
        "drive frequency of the amplitude sweep",
        "Table 3.2 row 3",
        min=1.0,
        max=1e5,
    ),
    ParamSpec(
        "amp_lo_v", 1.0, "V", "first amplitude of the sweep", "Table 3.2", min=0.0, max=100.0
    ),
    ParamSpec("amp_hi_v", 1.3, "V", "last amplitude of the sweep", "Table 3.2", min=0.0, max=100.0),
    ParamSpec("n_trials", 7, "-", "amplitude steps (trials)", "assumption", min=1, max=1000),
    ParamSpec(
        "periods_per_trial",
        400,
        "periods",
        "drive periods per trial / sweep step (even)",
        "assumption (settling 1/(zeta wn) = 18.6 ms)",
        min=2,
        max=10**7,
    ),
    ParamSpec(
        "sweep_lo_hz",
        1711.0,
        "Hz",
        "first frequency of the sweep",
        "Table 3.2 row 1",
        min=1.0,
        max=1e5,
    ),
    ParamSpec(
        "sweep_hi_hz",
        1719.0,
        "Hz",
        "last frequency of the sweep",
        "Table 3.2 row 1",
        min=1.0,
        max=1e5,
    ),
    ParamSpec(
        "sweep_step_hz",
        1.0,
        "Hz",
        "frequency step of the sweep",
        "assumption",
        min=0.0,
        max=1e4,
        min_exclusive=True,
    ),
    ParamSpec(
        "sweep_amp_v",
        0.8,
        "V",
        "amplitude of the frequency sweep",
        "Table 3.2 row 1",
        min=0.0,
        max=100.0,
    ),
    ParamSpec("gyro_enabled", True, "-", "emulate the on-stage gyro", "sec. 3.5.2"),
    ParamSpec(
        "gyro_seed",
        -1,
        "-",
        "run seed of the on-stage gyro's noise; -1: the node's seed",
        "deterministic: the gyro may be seeded apart from the stage",
        min=-1,
        max=2**62,
    ),
    ParamSpec(
        "publish_imu",
        False,
        "-",
        "also publish every gyro sample as sensor_msgs/Imu "
        "(one message per sample, ~8 kHz; skipped while nobody subscribes)",
        "interoperable: sensor_msgs/Imu so existing tools (imu_tools, robot_localization) can subscribe",
    ),
)

NODE_SPECS: tuple[ParamSpec, ...] = emulator_specs(frame_size=5000, frame_id="stage")

CHANNEL_UNITS = ("V",) * 4
DRIVE_CHANNELS = ("u", "v_bias", "f_drive", "phase", "trial")
DRIVE_UNITS = ("V", "V", "Hz", "cycle", "-")
TRUTH_CHANNELS = ("theta_y", "omega_y", "theta_x", "omega_x")
TRUTH_UNITS = ("rad", "rad/s", "rad", "rad/s")


def make_schedule(p: dict) -> micro_stage.DriveSchedule:
    """DriveSchedule from the node's schedule parameters (ParameterError when invalid)."""
    n = int(p["periods_per_trial"])
    n += n % 2
    if p["schedule"] == "identification":
        if p["sweep_hi_hz"] < p["sweep_lo_hz"]:
            raise ParameterError(
                f"parameter 'sweep_hi_hz' = {p['sweep_hi_hz']!r} is out of "
                f"range: must be >= sweep_lo_hz = {p['sweep_lo_hz']!r}"
            )
        return micro_stage.DriveSchedule.frequency_sweep(
            p["sweep_lo_hz"], p["sweep_hi_hz"], p["sweep_step_hz"], p["sweep_amp_v"], n
        )
    if p["schedule"] == "zero":
        return micro_stage.DriveSchedule([(p["drive_freq_hz"], 0.0, n)])
    return micro_stage.DriveSchedule.amplitude_sweep(
        p["amp_lo_v"], p["amp_hi_v"], p["n_trials"], p["drive_freq_hz"], n
    )


class StageNode(EmulatorNode):
    """Emulated micro-stage + gyro + LDV publishing raw frames and truth.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`.
    """

    NODE_NAME = "stage"
    DEFAULT_NAMESPACE = "stage"
    SPECS = (
        micro_stage.STAGE_SPECS + GYRO_SPECS + SCHEDULE_SPECS + NODE_SPECS + (FAULT_SCHEDULE_SPEC,)
    )
    DEVICE_SPECS = micro_stage.STAGE_SPECS
    DIAGNOSTICS_TITLE = "piezo tilt micro-stage"
    #: ``temperature`` is the stage's output (its temperature as emulated).
    TEMPERATURE_INPUT = "temperature_input"

    def make_device(self) -> float:
        dev = self.values_of(micro_stage.STAGE_SPECS)
        micro_stage.validate_params(dev)
        schedule = make_schedule(self.p)
        self.device = micro_stage.MicroStage(
            dev, schedule, seed=self.p["seed"], fixed=getattr(self, "fixed_parameters", ())
        )
        self.fault_topic = FaultTopic(
            self,
            micro_stage.CHANNELS,
            CHANNEL_UNITS,
            self.device.fs,
            white_std=(self.device.noise_std,) * len(micro_stage.CHANNELS),
        )
        self.device.faults = self.fault_topic.injector
        # load the compiled (numba) kernels now: at the first frame a paced node would
        # publish ~1 s late (a throwaway device: the node's own device is untouched)
        micro_stage.MicroStage(dev, schedule, seed=0).step(2)
        self.gyro = (
            MemsGyro(
                self.values_of(GYRO_SPECS),
                seed=self.p["seed"] if self.p["gyro_seed"] < 0 else self.p["gyro_seed"],
                temperature_c=self.p["temperature_c"],
            )
            if self.p["gyro_enabled"]
            else None
        )
        (
            self.pub_adc,
            self.pub_drive,
            self.pub_truth,
            self.pub_ldv,
            self.pub_gyro,
        ) = self.create_frame_publishers("adc", "drive", "truth", "ldv", "gyro/adc")
        self.pub_temp = self.create_publisher(Temperature, "temperature", 10)
        self.pub_imu = self.create_publisher(Imu, "gyro/imu", FRAME_QOS)
        self.publish_imu = self.p["publish_imu"]
        self._imu_msg = None
        return self.device.fs

    def schedule_samples(self) -> int:
        """Samples of the drive schedule: the node stops after them."""
        return self.device.total_samples()

    def temperature_changed(self) -> None:
        """``temperature_c`` changed (parameter or input topic): :meth:`set_temperature`."""
        self.set_temperature(self.p["temperature_c"])

    def set_temperature(self, temperature_c: float) -> None:
        """Temperature input: moves D_n of the stage (wn, b_c only if their tempcos are set)
        and k_I, bias of the gyro."""
        self.device.set_temperature(temperature_c)
        if self.gyro is not None:
            self.gyro.temperature_c = self.device.temperature_c

    def _publish_imu(self, t: np.ndarray, value: np.ndarray) -> None:
        """One sensor_msgs/Imu per gyro sample. The message is built once and only its stamp
        and rate are rewritten (publish serialises a copy), stamps as integer ns."""
        m = self._imu_msg
        if m is None:
            m = self._imu_msg = Imu()
            m.header.frame_id = "imu_link"
            m.orientation_covariance[0] = -1.0
            m.linear_acceleration_covariance[0] = -1.0
            var = self.p["gyro_noise_rms"] ** 2
            m.angular_velocity_covariance[0] = var
            m.angular_velocity_covariance[4] = var
            m.angular_velocity_covariance[8] = var
        stamp, av, pub = m.header.stamp, m.angular_velocity, self.pub_imu.publish
        ns = np.rint(t * 1e9).astype(np.int64) + np.int64(self.t0_ns)
        sec, nsec = np.divmod(ns, 10**9)
        for s_, n_, v_ in zip(sec.tolist(), nsec.tolist(), value.tolist()):
            stamp.sec = s_
            stamp.nanosec = n_
            av.y = v_
            pub(m)

    def publish_frame(self, first: int, n: int) -> None:
        self.fault_topic.publish_starting(first, n)
        f = self.device.step(n)
        common = self.frame_kwargs
        lsb = self.device.lsb
        self.pub_adc.publish(
            make_adc_frame(
                f.codes,
                first,
                self.fs,
                bits=self.p["adc_bits"],
                channel_names=micro_stage.CHANNELS,
                channel_units=CHANNEL_UNITS,
                lsb=(lsb,) * 4,
                full_scale=(self.p["adc_full_scale_v"],) * 4,
                saturated_count=f.saturated,
                **common,
            )
        )
        self.publish_signals(
            self.pub_drive,
            first,
            np.column_stack([f.u, f.v_bias, f.f_drive, f.phase, f.segment.astype(float)]),
            DRIVE_CHANNELS,
            DRIVE_UNITS,
        )
        self.publish_signals(
            self.pub_truth,
            first,
            np.column_stack([f.theta[:, 0], f.omega[:, 0], f.theta[:, 1], f.omega[:, 1]]),
            TRUTH_CHANNELS,
            TRUTH_UNITS,
        )
        self.publish_signals(self.pub_ldv, first, f.ldv.reshape(-1, 1), ("omega_ldv",), ("rad/s",))
        tmsg = Temperature()
        tmsg.header.stamp = ns_to_time(index_to_ns(first, self.fs, self.t0_ns))
        tmsg.header.frame_id = self.p["frame_id"]
        tmsg.temperature = float(self.device.temperature_c)
        self.pub_temp.publish(tmsg)
        if self.gyro is not None:
            g = self.gyro.step(
                first,
                self.fs,
                f.theta[:, 0],
                f.omega[:, 0],
                self.device.last_applied,
                self.device.wn,
                self.device.zeta,
                self.device.b_c,
            )
            if g.index.size:
                t0g = self.t0_ns + int(round(self.p["gyro_start_offset_s"] * 1e9))
                self.pub_gyro.publish(
                    make_adc_frame(
                        g.codes.reshape(-1, 1),
                        int(g.index[0]),
                        self.gyro.rate,
                        bits=self.p["gyro_bits"],
                        channel_names=("gyro_y",),
                        channel_units=("rad/s",),
                        lsb=(self.gyro.lsb,),
                        full_scale=(self.p["gyro_full_scale"],),
                        saturated_count=g.saturated,
                        frame_id="imu_link",
                        t0_ns=t0g,
                    )
                )
                if self.publish_imu and self.pub_imu.get_subscription_count() > 0:
                    self._publish_imu(g.t, g.value)  # ~8 kHz of messages: only if heard
                self.diag.count("gyro_samples", int(g.index.size))
        if f.saturated:
            self.diag.count("saturated_samples", f.saturated)
            self.diag.warn("capacitive ADC clipped")


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_node``."""
    return run_node(StageNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""ROS 2 node of the IMU emulator (thin wrapper of mems_sim.devices.imu and
mems_sim.devices.imu_profiles).

Topics (relative to the node namespace, default ``/imu``):
    ``adc``   mems_msgs/AdcFrame   6 channels gyro_x..z [rad/s], accel_x..z [m/s^2], ADC codes
    ``truth`` mems_msgs/SignalFrame true angular rate and specific force, same channels
    ``data``  sensor_msgs/Imu      one message per sample (``publish_imu``), stamped in sensor
                                   time (epoch + k / fs), the ADC codes times their LSB as a
                                   driver converts them, model covariances, no orientation
                                   (REP-145 raw IMU data: remap to ``data_raw`` for imu_tools)
    ``temperature_sensor`` mems_msgs/SignalFrame  the IMU's own temperature reading per
                                   sample, channel ``temperature`` [degC] (under the
                                   ideal hardware profile the device temperature the model
                                   used; ``temp_sensor_*``, or ``hardware:=realistic``,
                                   add lag, noise, offset, resolution),
                                   same frames as ``adc``; with ``calibration_topics``
    ``truth_calibration``  mems_msgs/CalibrationResult (transient local, once, at the first
                                   frame): the realised error terms, method "truth", names
                                   ``{s}_bias_{a}``, ``{s}_matrix_{a}{b}``,
                                   ``{s}_bias_tempco_{a}``, ``{s}_sf_tempco_{a}``,
                                   ``gyro_g_sensitivity_{a}{b}`` (SI units, standard errors 0);
                                   with ``calibration_topics``
    ``faults`` mems_msgs/FaultEvent (reliable, transient local): each fault of
                                   ``fault_schedule`` when it begins (labelled truth; sensor
                                   faults act on the low-passed analog values before the ADC;
                                   ``temperature_step`` on the device temperature the model
                                   and the temperature sensor see)
    ``/diagnostics``               frames, saturated samples
Input: ``temperature`` sensor_msgs/Temperature: the device's temperature (``temperature_c``).
Parameters: the table ``mems_sim.devices.imu.IMU_SPECS`` (units, ranges, sources; ``preset``
selects the defaults of the error terms, a parameter given explicitly overrides the
preset's), ``device_seed`` (-1: the preset's nominal device; else every per-axis bias, scale
factor, misalignment, temperature coefficient and g-sensitivity drawn within the preset's
datasheet tolerance) and ``temperature_c`` (device temperature; the temperature terms of
the model act around 25 C; the published covariances are the nominal ones, a datasheet's),
``EMULATOR_SPECS`` and the motion parameters below. ``motion`` 'profile' plays the truth
motion and temperature of ``motion_profile`` (a built-in profile of
``mems_sim.devices.imu_profiles`` or a profile YAML file) and ends the stream at the
profile's end unless ``duration_s`` is given (after the end the last state is held);
``motion`` 'trajectory' plays the attitude (and position) rows of the CSV
``motion_trajectory`` the same way. The Earth's rate, the gravity model, vibration of the
specific force and the sensor latency are parameters of the table (``earth_rate``,
``gravity_model``, ``latitude_deg``, ``height_m``, ``vibration*``, ``latency_s``;
mems_sim.devices.imu_motion); the truth topic carries the motion at each sample's time, the
ADC the motion of t - latency_s.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from sensor_msgs.msg import Imu

from mems_msgs.msg import CalibrationResult
from mems_sim.devices import imu, imu_motion, imu_profiles
from mems_sim.hardware.fault_schedule import FAULT_KINDS, PHYSICAL_KINDS, physical_offset
from mems_sim.hardware.sensor_lag import TEMPERATURE_SENSOR_SPECS, LaggedTemperatureSensor
from mems_sim.nodes.fault_topic import FAULT_SCHEDULE_SPEC, FaultTopic
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import index_to_ns, make_adc_frame, ns_to_time
from mems_sim.ros.imu_msg import ImuSerializer
from mems_sim.ros.node_base import EMULATOR_SPECS, EmulatorNode, variation_specs
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import RESULT_QOS, sample_stream_qos

MOTION_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "motion",
        "static",
        "-",
        "true motion: at rest, constant rate or sinusoidal rate about z, the positions, "
        "rate-table runs and temperature of a calibration profile ('profile', "
        "motion_profile), or a 6-DoF trajectory CSV ('trajectory', motion_trajectory)",
        "",
        choices=("static", "constant_rate", "sinusoid", "profile", "trajectory"),
    ),
    ParamSpec(
        "motion_trajectory",
        "",
        "-",
        "CSV file of motion 'trajectory': time_s, attitude (qw, qx, qy, qz or roll, pitch, "
        "yaw), optionally x_m, y_m, z_m (ENU / FLU, mems_sim.devices.imu_motion)",
        "6-DoF motion input as gnss-ins-sim's motion files and MATLAB's waypointTrajectory",
    ),
    ParamSpec(
        "motion_profile",
        "multi_position",
        "-",
        "profile of motion 'profile': a built-in name ("
        + ", ".join(imu_profiles.BUILTIN_PROFILES)
        + ") or the path of a profile YAML file",
        "multi-position and rate-table calibration (Titterton & Weston, Strapdown Inertial "
        "Navigation Technology, Sec. 8.3-8.4)",
    ),
    ParamSpec(
        "calibration_topics",
        "auto",
        "-",
        "publish 'temperature_sensor' and 'truth_calibration': 'on', 'off', or 'auto' (on "
        "with motion 'profile' or a latency_s > 0, which truth_calibration records)",
        "truth of the error terms to evaluate calibrations against",
        choices=("auto", "on", "off"),
    ),
    ParamSpec("motion_rate", 0.1, "rad/s", "rate of 'constant_rate'", "", min=-30.0, max=30.0),
    ParamSpec("motion_amplitude", 0.5, "rad/s", "amplitude of 'sinusoid'", "", min=0.0, max=30.0),
    ParamSpec("motion_frequency", 1.0, "Hz", "frequency of 'sinusoid'", "", min=0.0, max=1.0e4),
    ParamSpec(
        "publish_imu",
        True,
        "-",
        "also publish sensor_msgs/Imu on 'data', one message per sample stamped in sensor "
        "time (fast scenario runs: off unless set, e.g. --set imu.publish_imu=true)",
        "interoperable: sensor_msgs/Imu so existing tools (imu_tools, robot_localization) can subscribe",
    ),
)

#: The terms of the IMU's temperature reading that the ideal hardware profile switches off
#: (0: no lag, no noise, no rounding); the realistic profile has the sensor's own values.
_READING_TERMS = ("temp_sensor_time_constant_s", "temp_sensor_noise_k", "temp_sensor_resolution_k")
#: The IMU's own temperature sensor (``temperature_sensor``): lag, noise, offset and
#: resolution of the reading; under the ideal profile (``hardware``) it reads the device
#: temperature itself, under the realistic one with the sensor table's lag, noise and
#: resolution (the offset is a batch spread around 0).
TEMPERATURE_READING_SPECS: tuple[ParamSpec, ...] = tuple(
    replace(
        spec,
        default=0.0,
        source="ideal hardware: 0",
        realistic=spec.default,
        realistic_source=spec.source,
    )
    if spec.name in _READING_TERMS
    else spec
    for spec in TEMPERATURE_SENSOR_SPECS
)
#: The ideal reading's values: the temperature sensor is the identity.
_IDEAL_READING = {
    spec.name: spec.default
    for spec in TEMPERATURE_READING_SPECS
    if spec.name in _READING_TERMS or spec.name == "temp_sensor_offset_k"
}

CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3


#: The IMU's fault kinds: every sensor and timing kind, and the thermal shock.
IMU_FAULT_KINDS = {**FAULT_KINDS, "temperature_step": PHYSICAL_KINDS["temperature_step"]}


class ImuNode(EmulatorNode):
    """Emulated 3-axis gyro + 3-axis accelerometer publishing ADC frames and truth.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`
    (``drive_externally``, ``autostart``, rclpy Node arguments).
    """

    NODE_NAME = "imu"
    DEFAULT_NAMESPACE = "imu"
    SPECS = (
        imu.IMU_SPECS
        + variation_specs()
        + EMULATOR_SPECS
        + MOTION_SPECS
        + (FAULT_SCHEDULE_SPEC,)
        + TEMPERATURE_READING_SPECS
    )
    DEVICE_SPECS = imu.IMU_SPECS
    DIAGNOSTICS_TITLE = "IMU emulator"

    def make_device(self) -> float:
        self.profile = None
        if self.p["motion"] == "profile":
            try:
                self.profile = imu_profiles.load_profile(self.p["motion_profile"])
            except imu_profiles.ProfileError as exc:
                raise ParameterError(
                    f"parameter 'motion_profile' = {self.p['motion_profile']!r} is invalid: {exc}"
                ) from None
        self.nominal = self.preset_values()
        fs = self.nominal["sample_rate_hz"]
        if self.p["motion"] == "sinusoid" and self.p["motion_frequency"] >= fs / 2:
            raise ParameterError(
                f"parameter 'motion_frequency' = {self.p['motion_frequency']!r} is out of range: "
                f"allowed [0.0, {fs / 2!r}) Hz (below Nyquist of sample_rate_hz)"
            )
        self.motion = self._make_motion(fs)
        self.model = imu.ImuNoiseModel(
            self.device_values(), seed=self.p["seed"], temperature_c=self.p["temperature_c"]
        )
        self.fault_topic = FaultTopic(
            self, CHANNELS, UNITS, fs, self.model.white_sample_stds(), IMU_FAULT_KINDS
        )
        self.model.faults = self.fault_topic.injector
        gyro_var, accel_var = imu.imu_covariances(self.nominal)
        self._gyro_cov = imu.covariance9(gyro_var)
        self._accel_cov = imu.covariance9(accel_var)
        v = self.nominal
        bits = v["bits"]
        self._adc_static = dict(
            bits=bits,
            channel_names=CHANNELS,
            channel_units=UNITS,
            lsb=[v["gyro_lsb"]] * 3 + [v["accel_lsb"]] * 3,
            full_scale=[v["gyro_lsb"] * 2 ** (bits - 1)] * 3
            + [v["accel_lsb"] * 2 ** (bits - 1)] * 3,
        )
        self.pub_adc, self.pub_truth = self.create_frame_publishers("adc", "truth")
        topics = self.p["calibration_topics"]
        self.pub_temperature = self.pub_truth_calibration = None
        self.temperature_reading = None
        auto = self.profile is not None or self.p["latency_s"] > 0.0
        if topics == "on" or (topics == "auto" and auto):
            (self.pub_temperature,) = self.create_frame_publishers("temperature_sensor")
            self.temperature_reading = self._make_temperature_reading(fs)
            self.pub_truth_calibration = self.create_publisher(
                CalibrationResult, "truth_calibration", RESULT_QOS
            )
        self.pub_imu = None
        if self.p["publish_imu"]:
            # one message per sample: the history holds a frame and seconds of samples
            qos = sample_stream_qos(fs, self.p["frame_size"])
            self.pub_imu = self.create_publisher(Imu, "data", qos)
            self._imu_cdr = ImuSerializer(self.p["frame_id"], self._gyro_cov, self._accel_cov)
        return fs

    def _make_temperature_reading(self, fs: float):
        """The temperature sensor's model (mems_sim.hardware.sensor_lag) and its generator,
        or None for the ideal reading (every term 0: the device temperature itself)."""
        values = {spec.name: self.p[spec.name] for spec in TEMPERATURE_READING_SPECS}
        if all(values[k] == v for k, v in _IDEAL_READING.items()):
            return None
        sensor = LaggedTemperatureSensor(1.0 / fs, values)
        rng = np.random.Generator(np.random.PCG64([self.p["seed"], 0x7E4D]))
        return sensor, rng

    def _make_motion(self, fs: float) -> imu_motion.ImuMotion:
        """The true motion (mems_sim.devices.imu_motion) of the node's motion, environment
        and vibration parameters; a bad trajectory file or combination is a ParameterError."""
        p = self.p
        trajectory = None
        if p["motion"] == "trajectory":
            try:
                trajectory = imu_motion.load_trajectory(p["motion_trajectory"])
            except imu_motion.TrajectoryError as exc:
                raise ParameterError(
                    f"parameter 'motion_trajectory' = {p['motion_trajectory']!r} is invalid: {exc}"
                ) from None
        try:
            motion = imu_motion.ImuMotion(
                p["motion"],
                p,
                p["seed"],
                rate=p["motion_rate"],
                amplitude=p["motion_amplitude"],
                frequency=p["motion_frequency"],
                profile=self.profile,
                trajectory=trajectory,
                temperature_c=p["temperature_c"],
            )
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        top = motion.vibration.max_frequency_hz()
        if top >= fs / 2:
            name = (
                "vibration_frequency_hz"
                if p["vibration"] == "sinusoid"
                else "vibration_band_high_hz"
            )
            raise ParameterError(
                f"parameter '{name}' = {top!r} is out of range: allowed below {fs / 2!r} Hz "
                "(Nyquist of sample_rate_hz: the truth is sampled)"
            )
        return motion

    def preset_values(self) -> dict:
        """The nominal device: the defaults of the node's ``preset`` updated with the device
        parameters given explicitly at construction (those override the preset's)."""
        given = set(self._parameter_overrides) | set(self.fixed_parameters) | self.profile_changed
        values = {
            name: self.p[name]
            for name in (s.name for s in imu.IMU_SPECS)
            if name in given or name == "preset"
        }
        return imu.imu_values(values)

    def device_values(self) -> dict:
        """The device this node emulates: the preset's nominal device
        (:meth:`preset_values`) drawn for ``device_seed`` within the preset's datasheet
        tolerances (:func:`~mems_sim.devices.imu.draw_imu_device`; parameters set
        explicitly are not drawn). The temperature acts in the model per sample (eq. (1)
        of mems_sim.devices.imu), not on these values."""
        self.drawn = imu.draw_imu_device(
            self.preset_values(), self.p["device_seed"], fixed=self.fixed_parameters
        )
        return dict(self.drawn)

    def retune_device(self, values: dict) -> None:
        """Not used: the IMU's temperature terms act per sample in the model (the device's
        values do not depend on the temperature)."""

    def schedule_samples(self) -> int | None:
        """With motion 'profile' or 'trajectory' and no ``duration_s``: its samples."""
        if self.p["duration_s"] <= 0:
            return self.motion.n_samples(self.model.fs)
        return None

    def _truth(self, first: int, n: int) -> imu_motion.MotionTruth:
        """(gyro (n,3) rad/s, specific force (n,3) m/s^2, temperature (n,) degC) at the
        samples' own times."""
        return self.motion.truth(first, n, self.model.fs, self.p["temperature_c"])

    def publish_truth_calibration(self) -> None:
        """The realised error terms (the model's ``calibration_truth``) as a
        CalibrationResult, method "truth", stamped at sample 0."""
        m = CalibrationResult()
        m.header.stamp = ns_to_time(index_to_ns(0, self.fs, self.t0_ns or 0))
        m.header.frame_id = self.p["frame_id"]
        m.device = self.get_namespace().strip("/") or self.get_name()
        m.method = "truth"
        rows = self.model.calibration_truth()
        m.names = [r[0] for r in rows]
        m.values = [r[1] for r in rows]
        m.units = [r[2] for r in rows]
        m.standard_errors = [0.0] * len(rows)
        m.num_points = 0
        m.residual_rms = 0.0
        m.residual_unit = ""
        self.pub_truth_calibration.publish(m)

    def publish_frame(self, first: int, n: int) -> None:
        if self.pub_truth_calibration is not None and first == 0:
            self.publish_truth_calibration()
        truth = self._truth(first, n)
        shock = physical_offset(self.fault_topic.entries, "temperature_step", first, n)
        if shock is not None:  # a thermal shock: the device temperature steps
            truth = truth._replace(temperature_c=truth.temperature_c + shock)
        truth_gyro, truth_accel, temperature = truth
        # the sensor measures the motion of t - latency_s (truth itself without one)
        seen = self.motion.measured(first, n, self.model.fs, truth)
        self.fault_topic.publish_starting(first, n)
        frame = self.model.generate(n, seen.gyro, seen.accel, temperature)
        codes = np.hstack([frame.gyro_codes, frame.accel_codes])
        sat = int(frame.saturated.sum())
        if sat:
            self.diag.count("saturated_samples", sat)
            self.diag.warn(f"{sat} samples clipped at full scale in frame starting at {first}")
        self.pub_adc.publish(
            make_adc_frame(
                codes,
                first,
                self.fs,
                saturated_count=sat,
                **self._adc_static,
                **self.frame_kwargs,
            )
        )
        self.publish_signals(
            self.pub_truth, first, np.hstack([truth_gyro, truth_accel]), CHANNELS, UNITS
        )
        if self.pub_temperature is not None:
            reading = temperature
            if self.temperature_reading is not None:
                sensor, rng = self.temperature_reading
                reading = sensor.measure(temperature, rng).reading_c
            self.publish_signals(
                self.pub_temperature, first, reading[:, None], ("temperature",), ("degC",)
            )
        if self.pub_imu is not None:
            self._publish_imu(first, frame.gyro_si, frame.accel_si)

    def _publish_imu(self, first: int, gyro: np.ndarray, accel: np.ndarray) -> None:
        """One sensor_msgs/Imu per sample delivered (dropped samples of the schedule are
        not): stamp epoch + k / fs (the frames' definition), the values of the ADC codes
        (code * LSB), serialised for the frame at once."""
        runs = self.fault_topic.delivered(first, gyro.shape[0])
        if runs is not None:  # dropped samples: only those delivered
            keep = np.concatenate([np.arange(lo, hi) for lo, hi in runs] or [np.arange(0)])
            first_of = [first + int(i) for i in keep]
            gyro, accel = gyro[keep], accel[keep]
        else:
            first_of = range(first, first + gyro.shape[0])
        stamps = [index_to_ns(i, self.fs, self.t0_ns) for i in first_of]
        publish = self.pub_imu.publish
        for raw in self._imu_cdr.serialize(stamps, gyro, accel):
            publish(raw)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``imu_node`` (``ros2 run mems_emulator imu_node``)."""
    return run_node(ImuNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

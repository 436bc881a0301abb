"""ROS 2 node: IMU multi-position / rate-table / thermal calibration along a profile.

Subscribes the IMU's ``adc`` (mems_msgs/AdcFrame, channels gyro_x..z [rad/s], accel_x..z
[m/s^2]; the node's namespace, default ``/imu``, or ``device_namespace``) through the
estimator input path (:class:`~mems_estimation.nodes.frame_input.EstimatorNode`: malformed,
foreign, repeated and out-of-order frames rejected and counted on /diagnostics, gaps counted
and the samples around them kept with their indices). The profile (parameter ``profile``: a
built-in of :mod:`mems_sim.devices.imu_profiles` or a profile YAML) starts at the stream's
first sample. With ``temperature_source`` 'sensor' the ``temperature_sensor`` frames
(mems_msgs/SignalFrame, channel ``temperature`` [degC]) are paired with the ``adc`` frames
by sample index and give the temperature of the thermal terms. When the stream reaches the
profile's end (or at shutdown, if it has not), the node calibrates
(:func:`mems_estimation.identification.imu_calibration.calibrate_profile`) and publishes
``calibration`` (mems_msgs/CalibrationResult, reliable, transient local: a late subscriber
still gets it) with the estimated parameters (names and SI units of the emulator's
``truth_calibration``), their standard errors, the number of segments and the RMS of the
whitened residual; it writes the calibration YAML to ``output_yaml`` if set. A stream reset
starts the calibration again (the profile restarts with the new stream).
"""

from __future__ import annotations

import math

import numpy as np
from rclpy.duration import Duration

from mems_estimation.identification import imu_calibration as ic
from mems_estimation.identification import imu_calibration_io as icio
from mems_estimation.nodes.frame_input import DEVICE_NAMESPACE, EstimatorNode, input_specs
from mems_msgs.msg import AdcFrame, CalibrationResult, SignalFrame
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import (
    FrameError,
    adc_physical,
    index_to_ns,
    ns_to_time,
    signal_data,
)
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import RESULT_QOS

CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")


def imu_values(msg: AdcFrame) -> np.ndarray:
    """(n, 6) physical values of an IMU frame in :data:`CHANNELS` order (rad/s, m/s^2),
    whatever the frame's channel order; a frame without these channels is foreign."""
    names = list(msg.channel_names)
    if not all(c in names for c in CHANNELS):
        raise FrameError(f"frame at {msg.first_sample_index}: channels {names}", "foreign")
    return adc_physical(msg)[:, [names.index(c) for c in CHANNELS]]


CAL_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec(
        "profile",
        "multi_position",
        "-",
        "calibration profile: a built-in (six_position, multi_position, thermal_ramp, "
        "thermal_multi_position) or a profile YAML file",
        "mems_sim.devices.imu_profiles",
    ),
    ParamSpec(
        "noise_model",
        "adis16350",
        "-",
        "noise model of the segment-mean covariance: an emulator preset (petkov, adis16350, "
        "icm42688p), 'data' (estimated inside the segments; bias intervals too narrow), or "
        "an identify_noise --json file",
        "mems_estimation.identification.imu_calibration",
    ),
    ParamSpec(
        "thermal",
        "auto",
        "-",
        "fit the temperature terms: auto (if the profile spans > 1 K), on, off",
        "",
        choices=("auto", "on", "off"),
    ),
    ParamSpec(
        "device_temperature_c",
        25.0,
        "degC",
        "device temperature of profile segments without their own",
        "",
        min=-100.0,
        max=300.0,
    ),
    ParamSpec(
        "base_yaml",
        "",
        "-",
        "calibration YAML whose values stand for parameters the profile cannot observe",
        "",
    ),
    ParamSpec(
        "temperature_source",
        "profile",
        "-",
        "device temperature of the thermal terms: the profile's ('profile') or the IMU's "
        "'temperature_sensor' frames paired with 'adc' ('sensor')",
        "",
        choices=("profile", "sensor"),
    ),
    ParamSpec("output_yaml", "", "-", "write the calibration YAML here (empty: no file)", ""),
    ParamSpec("device", "imu", "-", "device name in the result", ""),
)


def subscribe_imu_inputs(node: EstimatorNode, decode) -> None:
    """Subscribe the IMU's ``adc`` frames (decoded by ``decode``), paired with its
    ``temperature_sensor`` frames (:func:`_temperature`) when the parameter
    ``temperature_source`` is ``sensor``; both without the sample-rate check."""
    if node.p["temperature_source"] == "sensor":
        node.subscribe_pair(
            ("adc", AdcFrame, decode),
            ("temperature_sensor", SignalFrame, _temperature),
            check_rate=False,
        )
    else:
        node.subscribe_single(("adc", AdcFrame, decode), check_rate=False)


def _temperature(msg: SignalFrame) -> np.ndarray:
    """Temperature [degC] of a ``temperature_sensor`` frame (channel ``temperature``)."""
    names = list(msg.channel_names)
    if "temperature" not in names:
        raise FrameError(
            f"temperature frame at {msg.first_sample_index}: no 'temperature'", "foreign"
        )
    t = signal_data(msg)[:, names.index("temperature")]
    if not np.all(np.isfinite(t)):
        raise FrameError("non-finite temperature", "non_finite")
    return np.ascontiguousarray(t)


class ImuCalibrationNode(EstimatorNode):
    """Collects the profile's samples and publishes the calibration (module doc)."""

    NODE_NAME = "imu_calibration"
    DEFAULT_NAMESPACE = "imu"
    SPECS = CAL_SPECS + input_specs(paired=False, max_frame_samples=100_000)
    DIAGNOSTICS_TITLE = "IMU calibration"
    GAP_NOTE = "the samples around it are kept with their indices"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        from mems_sim.devices.imu_profiles import ProfileError, load_profile

        try:
            self.profile = load_profile(self.p["profile"])
            self.noise = icio.noise_option(self.p["noise_model"])
            self.base = icio.load_yaml(self.p["base_yaml"]) if self.p["base_yaml"] else None
        except (ProfileError, ic.CalibrationError) as exc:
            raise ParameterError(str(exc)) from None
        self.results: list[ic.ImuCalibration] = []
        self.messages: list[CalibrationResult] = []
        self.pub = self.create_publisher(
            CalibrationResult, self.device_topic("calibration"), RESULT_QOS
        )
        self._start()
        subscribe_imu_inputs(self, self._decode)

    def _start(self) -> None:
        self.chunks_idx: list[np.ndarray] = []
        self.chunks_val: list[np.ndarray] = []
        self.chunks_temp: list[np.ndarray] = []
        self.first: int | None = None
        self.rate_hz: float | None = None
        self.end: int | None = None
        self.last_stamp_ns = 0
        self.done = False

    def reset_estimator(self) -> None:
        """Stream reset: the profile starts again with the new stream."""
        self._start()

    def on_format_change(self, kind: str) -> None:
        """A new format (rate, channels): start again."""
        self._start()

    def _decode(self, msg: AdcFrame) -> np.ndarray:
        self._pair_rate = float(msg.sample_rate_hz)
        return imu_values(msg)

    def process_frame(self, first: int, stamp_ns: int, values, msg: AdcFrame) -> None:
        """Keep one good frame; calibrate at the profile's end."""
        self._take(first, values, None, stamp_ns, msg.sample_rate_hz)

    def process_pair(self, first: int, stamp_ns: int, values, temperature) -> None:
        """A frame with its temperature frame (``temperature_source`` 'sensor')."""
        self._take(first, values, temperature, stamp_ns, self._pair_rate)

    def _take(self, first, values, temperature, stamp_ns, rate) -> None:
        n = values.shape[0]
        if self.first is None:
            self.first = first
            self.rate_hz = float(rate)
            self.end = first + self.profile.n_samples(self.rate_hz)
        if self.done:
            return
        take = max(0, min(n, self.end - first))
        if take:
            self.chunks_idx.append(first + np.arange(take, dtype=np.int64))
            self.chunks_val.append(values[:take])
            if temperature is not None:
                self.chunks_temp.append(temperature[:take])
            self.last_stamp_ns = index_to_ns(take - 1, self.rate_hz, stamp_ns)
        if first + n >= self.end:
            self.publish_result()

    def calibrate(self) -> ic.ImuCalibration:
        """The calibration on the samples so far (CalibrationError if it cannot)."""
        if not self.chunks_idx:
            raise ic.CalibrationError("no samples")
        idx = np.concatenate(self.chunks_idx)
        val = np.concatenate(self.chunks_val)
        temp = np.concatenate(self.chunks_temp) if self.chunks_temp else None
        self.chunks_idx, self.chunks_val = [idx], [val]
        self.chunks_temp = [] if temp is None else [temp]
        thermal = {"auto": None, "on": True, "off": False}[self.p["thermal"]]
        return ic.calibrate_profile(
            val[:, :3],
            val[:, 3:],
            self.profile,
            self.rate_hz,
            index=idx,
            temperature=temp,
            device_temperature_c=self.p["device_temperature_c"],
            noise=self.noise,
            thermal=thermal,
            base=self.base,
        )

    def publish_result(self) -> CalibrationResult | None:
        """Calibrate, publish, write the YAML; None (counted, warned) if it fails."""
        self.done = True
        try:
            cal = self.calibrate()
        except (ic.CalibrationError, ValueError, np.linalg.LinAlgError) as exc:
            self.diag.count("calibration_failures")
            self.diag.warn(f"IMU calibration failed: {exc}")
            return None
        msg = result_message(cal, self.p["device"], self.last_stamp_ns)
        self.pub.publish(msg)
        self.results.append(cal)
        self.messages.append(msg)
        self.diag.count("results")
        if self.p["output_yaml"]:
            try:
                icio.save_yaml(cal, self.p["output_yaml"])
            except OSError as exc:
                self.diag.warn(f"cannot write {self.p['output_yaml']}: {exc}")
        return msg

    def close(self) -> None:
        """At shutdown: calibrate on what arrived if the profile's end was not reached."""
        if not self.done and self.chunks_idx:
            if self.publish_result() is not None:
                self.pub.wait_for_all_acked(Duration(seconds=2.0))


def result_message(cal: ic.ImuCalibration, device: str, stamp_ns: int) -> CalibrationResult:
    """CalibrationResult of the estimated parameters; those that carry an inseparable
    other parameter (:attr:`ImuCalibration.aliases`) are left out (they are in the YAML
    with the alias noted)."""
    m = CalibrationResult()
    m.header.stamp = ns_to_time(stamp_ns)
    m.header.frame_id = "imu_link"
    m.device = device
    m.method = cal.method
    names = [n for n in cal.estimated if n not in cal.aliases]
    m.names = names
    m.units = [ic.parameter_unit(n) for n in names]
    m.values = [float(cal.values[n]) for n in names]
    m.standard_errors = [float(cal.standard_errors[n]) for n in names]
    m.num_points = int(cal.info.get("segments", 0))
    rows = cal.info.get("rows", {})
    chi2 = sum(r["chi2"] for r in rows.values())
    cnt = sum(r["segments"] for r in rows.values())
    m.residual_rms = math.sqrt(chi2 / cnt) if cnt else math.nan
    m.residual_unit = "1 (whitened)"
    return m


def main(argv: list[str] | None = None) -> int:
    """Entry point ``imu_calibration_node``."""
    return run_node(ImuCalibrationNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

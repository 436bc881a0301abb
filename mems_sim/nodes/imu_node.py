"""ROS 2 node of the IMU stochastic-noise emulator (thin wrapper of mems_sim.devices.imu).

Topics (relative to the node namespace, default ``/imu``):
    ``adc``   mems_msgs/AdcFrame   6 channels gyro_x..z [rad/s], accel_x..z [m/s^2], 14-bit codes
    ``truth`` mems_msgs/SignalFrame true angular rate and specific force, same channels
    ``data``  sensor_msgs/Imu      one message per sample (``publish_imu``), stamped in sensor
                                   time (epoch + k / fs), the ADC codes times their LSB as a
                                   driver converts them, model covariances, no orientation
                                   (REP-145 raw IMU data: remap to ``data_raw`` for imu_tools)
    ``/diagnostics``               frames, saturated samples
Input: ``temperature`` sensor_msgs/Temperature: the device's temperature (``temperature_c``).
Parameters: the table ``mems_sim.devices.imu.IMU_SPECS`` (units, ranges, sources),
``device_seed`` and ``temperature_c`` (the device drawn from the table's spreads at a
temperature, reference 25 C; the published covariances stay the nominal ones, a datasheet's),
``EMULATOR_SPECS`` and the motion parameters below.
"""

from __future__ import annotations

import numpy as np
from rclpy.qos import QoSProfile
from sensor_msgs.msg import Imu

from mems_sim.devices import imu as imu_noise
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import index_to_ns, make_adc_frame
from mems_sim.ros.imu_msg import ImuSerializer
from mems_sim.ros.node_base import EMULATOR_SPECS, EmulatorNode, run_node, variation_specs
from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS

MOTION_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "motion",
        "static",
        "-",
        "true motion: at rest, constant rate or sinusoidal rate about z",
        "",
        choices=("static", "constant_rate", "sinusoid"),
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

CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3


class ImuNoiseNode(EmulatorNode):
    """Emulated 3-axis gyro + 3-axis accelerometer publishing ADC frames and truth.

    Keyword arguments: those of :class:`~mems_sim.ros.node_base.EmulatorNode`
    (``drive_externally``, ``autostart``, rclpy Node arguments).
    """

    NODE_NAME = "imu"
    DEFAULT_NAMESPACE = "imu"
    SPECS = imu_noise.IMU_SPECS + variation_specs() + EMULATOR_SPECS + MOTION_SPECS
    DEVICE_SPECS = imu_noise.IMU_SPECS
    DIAGNOSTICS_TITLE = "IMU emulator"

    def make_device(self) -> float:
        fs = self.p["sample_rate_hz"]
        if self.p["motion"] == "sinusoid" and self.p["motion_frequency"] >= fs / 2:
            raise ParameterError(
                f"parameter 'motion_frequency' = {self.p['motion_frequency']!r} is out of range: "
                f"allowed [0.0, {fs / 2!r}) Hz (below Nyquist of sample_rate_hz)"
            )
        self.model = imu_noise.ImuNoiseModel(self.device_values(), seed=self.p["seed"])
        gyro_var, accel_var = imu_noise.imu_covariances(self.values_of(imu_noise.IMU_SPECS))
        self._gyro_cov = imu_noise.covariance9(gyro_var)
        self._accel_cov = imu_noise.covariance9(accel_var)
        bits = self.p["bits"]
        self._adc_static = dict(
            bits=bits,
            channel_names=CHANNELS,
            channel_units=UNITS,
            lsb=[self.p["gyro_lsb"]] * 3 + [self.p["accel_lsb"]] * 3,
            full_scale=[self.p["gyro_lsb"] * 2 ** (bits - 1)] * 3
            + [self.p["accel_lsb"] * 2 ** (bits - 1)] * 3,
        )
        self.pub_adc, self.pub_truth = self.create_frame_publishers("adc", "truth")
        self.pub_imu = None
        if self.p["publish_imu"]:
            # one message per sample: the history holds a whole frame of them on top of the
            # frames' depth, so a reader up to FRAME_DEPTH messages behind loses none
            qos = QoSProfile(
                reliability=FRAME_QOS.reliability,
                durability=FRAME_QOS.durability,
                history=FRAME_QOS.history,
                depth=FRAME_DEPTH + int(self.p["frame_size"]),
            )
            self.pub_imu = self.create_publisher(Imu, "data", qos)
            self._imu_cdr = ImuSerializer(self.p["frame_id"], self._gyro_cov, self._accel_cov)
        return fs

    def retune_device(self, values: dict) -> None:
        """The noise model at a new temperature (its ``retune``, where it has one)."""
        retune = getattr(self.model, "retune", None)
        if retune is None:
            self.diag.warn("temperature change not applied: the IMU noise model has no retune")
            return
        retune(values)

    def _truth(self, first: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        p = self.p
        return imu_noise.truth_motion(
            p["motion"],
            first,
            n,
            self.fs,
            rate=p["motion_rate"],
            amplitude=p["motion_amplitude"],
            frequency=p["motion_frequency"],
        )

    def publish_frame(self, first: int, n: int) -> None:
        truth_gyro, truth_accel = self._truth(first, n)
        frame = self.model.generate(n, truth_gyro, truth_accel)
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
        if self.pub_imu is not None:
            self._publish_imu(first, frame.gyro_si, frame.accel_si)

    def _publish_imu(self, first: int, gyro: np.ndarray, accel: np.ndarray) -> None:
        """One sensor_msgs/Imu per sample: stamp epoch + k / fs (the frames' definition),
        the values of the ADC codes (code * LSB), serialised for the frame at once."""
        stamps = [index_to_ns(first + i, self.fs, self.t0_ns) for i in range(gyro.shape[0])]
        publish = self.pub_imu.publish
        for raw in self._imu_cdr.serialize(stamps, gyro, accel):
            publish(raw)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``imu_node`` (``ros2 run mems_emulator imu_node``)."""
    return run_node(ImuNoiseNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

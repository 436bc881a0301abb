"""ROS 2 node of the IMU stochastic-noise emulator (thin wrapper of mems_sim.devices.imu).

Topics (relative to the node namespace, default ``/imu``):
    ``adc``   mems_msgs/AdcFrame   6 channels gyro_x..z [rad/s], accel_x..z [m/s^2], 14-bit codes
    ``truth`` mems_msgs/SignalFrame true angular rate and specific force, same channels
    ``data``  sensor_msgs/Imu      one message per sample, SI, model covariances
    ``/diagnostics``               frames, saturated samples
Parameters: the table ``mems_sim.devices.imu.IMU_SPECS`` (units, ranges, sources),
``EMULATOR_SPECS`` and the motion parameters below.
"""

from __future__ import annotations

import numpy as np
from sensor_msgs.msg import Imu

from mems_sim.devices import imu as imu_noise
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import index_to_ns, make_adc_frame, ns_to_time
from mems_sim.ros.node_base import EMULATOR_SPECS, EmulatorNode, run_node
from mems_sim.ros.qos import FRAME_QOS

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
        "also publish sensor_msgs/Imu, one message per sample",
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
    SPECS = imu_noise.IMU_SPECS + EMULATOR_SPECS + MOTION_SPECS
    DIAGNOSTICS_TITLE = "IMU emulator"

    def make_device(self) -> float:
        fs = self.p["sample_rate_hz"]
        if self.p["motion"] == "sinusoid" and self.p["motion_frequency"] >= fs / 2:
            raise ParameterError(
                f"parameter 'motion_frequency' = {self.p['motion_frequency']!r} is out of range: "
                f"allowed [0.0, {fs / 2!r}) Hz (below Nyquist of sample_rate_hz)"
            )
        device = self.values_of(imu_noise.IMU_SPECS)
        self.model = imu_noise.ImuNoiseModel(device, seed=self.p["seed"])
        gyro_var, accel_var = imu_noise.imu_covariances(device)
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
        self.pub_imu = (
            self.create_publisher(Imu, "data", FRAME_QOS) if self.p["publish_imu"] else None
        )
        return fs

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
        for i in range(gyro.shape[0]):
            msg = Imu()
            msg.header.stamp = ns_to_time(index_to_ns(first + i, self.fs, self.t0_ns))
            msg.header.frame_id = self.p["frame_id"]
            msg.orientation_covariance[0] = -1.0
            g, a = gyro[i], accel[i]
            msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (
                float(g[0]),
                float(g[1]),
                float(g[2]),
            )
            msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (
                float(a[0]),
                float(a[1]),
                float(a[2]),
            )
            msg.angular_velocity_covariance = self._gyro_cov
            msg.linear_acceleration_covariance = self._accel_cov
            self.pub_imu.publish(msg)


def main(argv: list[str] | None = None) -> int:
    """Entry point ``imu_node`` (``ros2 run mems_emulator imu_node``)."""
    return run_node(ImuNoiseNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

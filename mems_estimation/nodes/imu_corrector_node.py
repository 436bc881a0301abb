"""ROS 2 node: corrected IMU output -- applies a calibration YAML to live data.

Loads ``calibration_yaml`` (:func:`mems_estimation.identification.imu_calibration_io.load_yaml`;
written by ``calibrate_imu --out`` or the ``imu_calibration_node``'s ``output_yaml``),
subscribes the IMU's ``adc`` (mems_msgs/AdcFrame gyro_x..z [rad/s], accel_x..z [m/s^2];
node namespace, default ``/imu``, or ``device_namespace``) through the estimator input
path, inverts the measurement model (:func:`~mems_estimation.identification.imu_calibration.correct`:
bias, temperature terms, g-sensitivity, scale factor and misalignment) at the device
temperature, and publishes one ``sensor_msgs/Imu`` per sample on ``data_corrected``
(REP-145 raw-style message without orientation, stamped like the frame's samples:
header stamp of the frame + i / fs; covariances ``angular_velocity_variance`` /
``linear_acceleration_variance`` on the diagonal, 0 = unknown).

Temperature (``temperature_source``): 'parameter' -- the parameter ``temperature_c`` [degC],
changeable at run time; 'sensor' -- the IMU's ``temperature_sensor`` frames
(mems_msgs/SignalFrame, channel ``temperature`` [degC], one value per sample), paired with the
``adc`` frames by sample index; 'topic' -- sensor_msgs/Temperature messages on
``temperature_topic`` (relative to the device namespace; default ``temperature``, the
emulator's temperature input, so in an emulated graph the corrector follows the temperature
the emulator is set to; on a real IMU remap it to the driver's temperature topic). In 'topic'
mode the latest message holds (zero-order hold, in arrival order; ``temperature_c`` until the
first one): a frame is corrected at the temperature last received when it is processed, not
matched by stamp (at 1 K/min a 0.1 s frame is 1.7 mK). The subscription is best effort (it
matches reliable and best-effort publishers, e.g. drivers publishing with the sensor-data
QoS). A message whose temperature is not finite or outside the range of ``temperature_c`` is
ignored (counted as ``temperature_ignored`` on /diagnostics, with a warning).
"""

from __future__ import annotations

import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature

from mems_estimation.identification import imu_calibration as ic
from mems_estimation.identification import imu_calibration_io as icio
from mems_estimation.nodes.frame_input import DEVICE_NAMESPACE, EstimatorNode, input_specs
from mems_estimation.nodes.imu_calibration_node import imu_values, subscribe_imu_inputs
from mems_msgs.msg import AdcFrame
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import index_to_ns
from mems_sim.ros.imu_msg import ImuSerializer
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS

CORRECTOR_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec("calibration_yaml", "", "-", "calibration YAML to apply (required)", ""),
    ParamSpec(
        "temperature_c",
        25.0,
        "degC",
        "device temperature ('parameter'; 'topic': until the first temperature message)",
        "",
        min=-100.0,
        max=300.0,
    ),
    ParamSpec(
        "temperature_source",
        "parameter",
        "-",
        "device temperature: the parameter temperature_c, the 'temperature_sensor' frames "
        "paired by sample index ('sensor'), or sensor_msgs/Temperature on temperature_topic "
        "('topic', latest message held)",
        "",
        choices=("parameter", "sensor", "topic"),
    ),
    ParamSpec(
        "temperature_topic",
        "temperature",
        "-",
        "sensor_msgs/Temperature topic of 'topic' mode, relative to the device namespace "
        "(default: the emulator's temperature input; remap to an IMU driver's topic)",
        "",
    ),
    ParamSpec("frame_id", "imu_link", "-", "header.frame_id of the corrected messages", ""),
    ParamSpec(
        "angular_velocity_variance",
        0.0,
        "(rad/s)^2",
        "diagonal of angular_velocity_covariance (0: unknown)",
        "",
        min=0.0,
        max=1e6,
    ),
    ParamSpec(
        "linear_acceleration_variance",
        0.0,
        "(m/s^2)^2",
        "diagonal of linear_acceleration_covariance (0: unknown)",
        "",
        min=0.0,
        max=1e6,
    ),
)


class ImuCorrectorNode(EstimatorNode):
    """Applies a calibration to the IMU's frames (module doc)."""

    NODE_NAME = "imu_corrector"
    DEFAULT_NAMESPACE = "imu"
    SPECS = CORRECTOR_SPECS + input_specs(paired=False, max_frame_samples=10_000)
    DIAGNOSTICS_TITLE = "IMU corrected output"
    RUNTIME_PARAMETERS = ("temperature_c",)

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        if not self.p["calibration_yaml"]:
            raise ParameterError("parameter 'calibration_yaml' is required: a calibration YAML")
        try:
            self.cal = icio.load_yaml(self.p["calibration_yaml"])
        except ic.CalibrationError as exc:
            raise ParameterError(f"parameter 'calibration_yaml': {exc}") from None
        self.samples_published = 0
        gv, av = self.p["angular_velocity_variance"], self.p["linear_acceleration_variance"]
        self._cdr = ImuSerializer(
            self.p["frame_id"], list(np.diag([gv] * 3).ravel()), list(np.diag([av] * 3).ravel())
        )
        qos = QoSProfile(
            reliability=FRAME_QOS.reliability,
            durability=FRAME_QOS.durability,
            history=FRAME_QOS.history,
            depth=FRAME_DEPTH + int(self.p["max_frame_samples"]),
        )
        self.pub = self.create_publisher(Imu, self.device_topic("data_corrected"), qos)
        #: Temperature of the next frame in 'topic' mode [degC]: the latest message's.
        self.temperature_c = float(self.p["temperature_c"])
        self.temperature_messages = 0
        subscribe_imu_inputs(self, self._decode)
        if self.p["temperature_source"] == "topic":
            self.create_subscription(
                Temperature,
                self.device_topic(self.p["temperature_topic"]),
                self._on_temperature,
                QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT),
            )

    def _on_temperature(self, msg: Temperature) -> None:
        """sensor_msgs/Temperature ('topic' mode): the temperature of the next frames."""
        spec = next(s for s in CORRECTOR_SPECS if s.name == "temperature_c")
        try:
            t = spec.validate(float(msg.temperature))
        except ParameterError as exc:
            self.diag.count("temperature_ignored")
            self.diag.warn(f"temperature message ignored: {exc}")
            return
        self.temperature_c = t
        self.temperature_messages += 1
        self.diag.counters["temperature_c"] = t

    def current_temperature_c(self) -> float:
        """Temperature of a frame of the single input [degC]: the latest message's ('topic')
        or the parameter ``temperature_c``."""
        if self.p["temperature_source"] == "topic":
            return self.temperature_c
        return self.p["temperature_c"]

    def _decode(self, msg: AdcFrame) -> np.ndarray:
        self._rate = float(msg.sample_rate_hz)
        return imu_values(msg)

    def process_frame(self, first: int, stamp_ns: int, values, msg: AdcFrame) -> None:
        """Correct one good frame and publish its samples."""
        self._publish(values, self.current_temperature_c(), stamp_ns)

    def process_pair(self, first: int, stamp_ns: int, values, temperature) -> None:
        """A frame with its temperature frame (``temperature_source`` 'sensor')."""
        self._publish(values, temperature, stamp_ns)

    def _publish(self, values: np.ndarray, temperature, t0_ns: int) -> None:
        n = values.shape[0]
        gyro, accel = ic.correct(values[:, :3], values[:, 3:], temperature, self.cal)
        stamps = [index_to_ns(i, self._rate, t0_ns) for i in range(n)]
        for raw in self._cdr.serialize(stamps, gyro, accel):
            self.pub.publish(raw)
        self.samples_published += n


def main(argv: list[str] | None = None) -> int:
    """Entry point ``imu_corrector_node``."""
    return run_node(ImuCorrectorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""``sensor_msgs/Imu`` for every sample of a frame, serialised in one numpy pass.

An IMU driver publishes one ``sensor_msgs/Imu`` per sample (REP-145: raw gyro and
accelerometer data, no orientation, ``orientation_covariance[0] = -1``). Building one
rclpy message object per sample costs tens of microseconds each; this module builds the
serialised CDR bytes of a whole frame at once and rclpy publishes them as they are
(``Publisher.publish`` takes the serialised bytes of a message of its type).

Method: one message with the constant fields (frame_id, covariances, orientation
covariance) is serialised once by rclpy (:func:`rclpy.serialization.serialize_message`);
the byte offsets of the per-sample fields (stamp, angular_velocity, linear_acceleration)
are found in it by serialising marker values, so the layout (encapsulation header, CDR
alignment, OMG CORBA 3.4 Part 2 Sec. 9.3 and DDS-XTypes 1.3 Sec. 7.4) is the middleware's
own and is not restated here; then each sample's row is that template with those fields
overwritten (little-endian values where the encapsulation header says CDR_LE, big-endian
for CDR_BE). The alignment padding after ``frame_id`` (which the serialiser leaves
uninitialised) is set to zero, so equal samples give equal bytes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Marker values of the per-sample fields in the probe message (distinct, exact doubles).
_MARKERS = {
    "sec": 0x1357_2468,
    "nanosec": 0x0246_8ACE,
    "angular_velocity": (1.0e-300 * 3, 1.0e-300 * 5, 1.0e-300 * 7),
    "linear_acceleration": (1.0e-300 * 11, 1.0e-300 * 13, 1.0e-300 * 17),
    "orientation_x": 1.0e-300 * 19,
}

#: Encapsulation identifiers of big-endian CDR representations (DDS-XTypes 1.3 Table 60):
#: CDR_BE, PL_CDR_BE, CDR2_BE, D_CDR2_BE, PL_CDR2_BE.
_BIG_ENDIAN_IDS = {0x0000, 0x0002, 0x0006, 0x0008, 0x000A}


class ImuSerializer:
    """Serialised ``sensor_msgs/Imu`` messages of many samples at once.

    Args:
        frame_id: ``header.frame_id`` (REP-103/REP-145: the IMU's body frame).
        angular_velocity_covariance, linear_acceleration_covariance: row-major 3x3
            [(rad/s)^2], [(m/s^2)^2] (9 values each; all zeros means unknown).
        orientation_covariance: 9 values; element 0 = -1 says "no orientation" (default).
    """

    def __init__(
        self,
        frame_id: str,
        angular_velocity_covariance: Sequence[float],
        linear_acceleration_covariance: Sequence[float],
        orientation_covariance: Sequence[float] | None = None,
    ) -> None:
        from rclpy.serialization import serialize_message
        from sensor_msgs.msg import Imu

        msg = Imu()
        msg.header.frame_id = frame_id
        msg.orientation_covariance = (
            [-1.0] + [0.0] * 8
            if orientation_covariance is None
            else [float(v) for v in orientation_covariance]
        )
        msg.angular_velocity_covariance = [float(v) for v in angular_velocity_covariance]
        msg.linear_acceleration_covariance = [float(v) for v in linear_acceleration_covariance]
        self.template = np.frombuffer(serialize_message(msg), dtype=np.uint8).copy()
        encapsulation = int(self.template[0]) << 8 | int(self.template[1])
        order = ">" if encapsulation in _BIG_ENDIAN_IDS else "<"
        self._u4, self._f8 = np.dtype(order + "u4"), np.dtype(order + "f8")
        probe = msg
        probe.header.stamp.sec = _MARKERS["sec"]
        probe.header.stamp.nanosec = _MARKERS["nanosec"]
        ax, ay, az = _MARKERS["angular_velocity"]
        lx, ly, lz = _MARKERS["linear_acceleration"]
        probe.angular_velocity.x, probe.angular_velocity.y, probe.angular_velocity.z = ax, ay, az
        probe.linear_acceleration.x = lx
        probe.linear_acceleration.y = ly
        probe.linear_acceleration.z = lz
        probe.orientation.x = _MARKERS["orientation_x"]
        raw = serialize_message(probe)
        if len(raw) != self.template.size:
            raise RuntimeError("sensor_msgs/Imu serialises to a size that depends on its values")
        self.size = len(raw)

        def find(value: bytes) -> int:
            pos = raw.find(value)
            if pos < 0 or raw.find(value, pos + 1) >= 0:
                raise RuntimeError("cannot locate a field of sensor_msgs/Imu in its CDR bytes")
            return pos

        u4, f8 = self._u4, self._f8
        self.sec_at = find(np.array(_MARKERS["sec"], u4).tobytes())
        self.nanosec_at = find(np.array(_MARKERS["nanosec"], u4).tobytes())
        self.gyro_at = [find(np.array(v, f8).tobytes()) for v in (ax, ay, az)]
        self.accel_at = [find(np.array(v, f8).tobytes()) for v in (lx, ly, lz)]
        # header: stamp (sec, nanosec), frame_id as uint32 length (with its NUL) + bytes;
        # then padding up to the alignment of the first float64, orientation.x
        string_end = self.nanosec_at + 8 + len(frame_id.encode()) + 1
        orientation_at = find(np.array(_MARKERS["orientation_x"], f8).tobytes())
        if not 0 <= orientation_at - string_end < 8:
            raise RuntimeError("unexpected CDR layout of sensor_msgs/Imu's header")
        #: Alignment padding bytes (zero in every serialised message).
        self.padding = slice(string_end, orientation_at)
        self.template[self.padding] = 0

    def serialize(
        self, stamps_ns: Sequence[int], gyro: np.ndarray, accel: np.ndarray
    ) -> list[bytes]:
        """Serialised messages, one per sample.

        Args:
            stamps_ns: ``header.stamp`` of each sample [ns] (integers >= 0).
            gyro: (n, 3) angular velocity [rad/s].
            accel: (n, 3) linear acceleration (specific force) [m/s^2].
        Returns:
            n ``bytes``, each the CDR serialisation of one ``sensor_msgs/Imu``.
        """
        gyro = np.asarray(gyro, dtype=float)
        accel = np.asarray(accel, dtype=float)
        n = gyro.shape[0]
        if gyro.shape != (n, 3) or accel.shape != (n, 3) or len(stamps_ns) != n:
            raise ValueError(
                f"{len(stamps_ns)} stamps, gyro {gyro.shape} and accel {accel.shape} do not "
                "describe the same (n, 3) samples"
            )
        ns = np.asarray([int(s) for s in stamps_ns], dtype=np.int64)
        if n and ns.min() < 0:
            raise ValueError("stamps must be >= 0 ns")
        rows = np.tile(self.template, (n, 1))
        sec, nanosec = np.divmod(ns, 1_000_000_000)
        self._put(rows, self.sec_at, sec.astype(self._u4))
        self._put(rows, self.nanosec_at, nanosec.astype(self._u4))
        for j in range(3):
            self._put(rows, self.gyro_at[j], gyro[:, j].astype(self._f8))
            self._put(rows, self.accel_at[j], accel[:, j].astype(self._f8))
        return [row.tobytes() for row in rows]

    @staticmethod
    def _put(rows: np.ndarray, at: int, values: np.ndarray) -> None:
        width = values.dtype.itemsize
        rows[:, at : at + width] = values.reshape(-1, 1).view(np.uint8).reshape(-1, width)

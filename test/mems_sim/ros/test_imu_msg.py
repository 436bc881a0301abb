"""sensor_msgs/Imu at the sample rate: the serialiser against rclpy's, and a fast imu_noise
run with the option on, recorded losslessly, one message per sample in sensor time."""

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu

from mems_msgs.msg import AdcFrame
from mems_sim.devices import imu as imu_device
from mems_sim.ros.frames import adc_physical, index_to_ns, ns_to_time
from mems_sim.ros.imu_msg import ImuSerializer


def _reference(stamp_ns, g, a, frame_id, gcov, acov) -> Imu:
    msg = Imu()
    msg.header.stamp = ns_to_time(stamp_ns)
    msg.header.frame_id = frame_id
    msg.orientation_covariance[0] = -1.0
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, g)
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = map(float, a)
    msg.angular_velocity_covariance = gcov
    msg.linear_acceleration_covariance = acov
    return msg


@pytest.mark.parametrize("frame_id", ["imu_link", "", "a_frame_id_of_odd_length"])
def test_serializer_bytes_equal_rclpy_serialisation(frame_id):
    rng = np.random.default_rng(4)
    gyro, accel = rng.normal(size=(7, 3)), rng.normal(size=(7, 3)) * 10
    gcov = [float(v) for v in rng.random(9)]
    acov = [float(v) for v in rng.random(9)]
    stamps = [0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, 10**12, 2**40 + 7]
    ser = ImuSerializer(frame_id, gcov, acov)
    raws = ser.serialize(stamps, gyro, accel)
    assert len(raws) == 7
    for k, raw in enumerate(raws):
        ref = _reference(stamps[k], gyro[k], accel[k], frame_id, gcov, acov)
        assert deserialize_message(raw, Imu) == ref
        # byte for byte as rclpy serialises it, except the alignment padding that Fast CDR
        # leaves uninitialised: zero here, so equal samples give equal bytes
        expected = bytearray(serialize_message(ref))
        expected[ser.padding] = bytes(ser.padding.stop - ser.padding.start)
        assert raw == bytes(expected)


def test_serializer_refuses_mismatched_shapes():
    ser = ImuSerializer("imu_link", [0.0] * 9, [0.0] * 9)
    with pytest.raises(ValueError, match="same"):
        ser.serialize([0, 1], np.zeros((2, 3)), np.zeros((3, 3)))
    assert ser.serialize([], np.zeros((0, 3)), np.zeros((0, 3))) == []


def test_fast_imu_noise_run_records_one_imu_per_sample_in_sensor_time(tmp_path, domain_id):
    """Acceptance: a fast imu_noise run with the Imu option yields one sensor_msgs/Imu per
    sample, stamped in sensor time (epoch 0 + k / fs), values = ADC codes * LSB."""
    from mcap.reader import make_reader

    from mems_scenarios import imu_noise
    from mems_scenarios.base import ScenarioOptions
    from mems_sim.ros.params_file import Override

    out = tmp_path / "imu.mcap"
    duration, fs = 3.0, 100.0
    options = ScenarioOptions(
        duration_s=duration,
        seed=5,
        out=out,
        domain_id=domain_id,
        progress=False,
        plots=False,
        # as `run_scenario imu_noise --set imu.publish_imu=true` gives them; the identifier
        # takes the short record
        overrides=[
            Override("/imu/imu", "publish_imu", True, "--set"),
            Override("/imu/imu_noise_identifier", "min_duration_s", 1.0, "--set"),
        ],
    )
    result = imu_noise.run(options)
    assert result["published"]["/imu/data"] == int(duration * fs)
    assert result["recorder"]["losses"] == []
    assert result["recorder"]["counts"]["/imu/data"] == int(duration * fs)

    n = int(duration * fs)
    imus, frames = [], []
    with open(out, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=["/imu/data", "/imu/adc"]):
            if channel.topic == "/imu/data":
                imus.append((message.log_time, message.sequence, message.data))
            else:
                frames.append(deserialize_message(message.data, AdcFrame))
    assert len(imus) == n
    # one publisher, sequence numbers 1..n without a gap
    assert [s for _, s, _ in imus] == list(range(1, n + 1))
    msgs = [deserialize_message(d, Imu) for _, _, d in imus]
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs])
    expected = np.array([index_to_ns(k, fs) for k in range(n)])
    np.testing.assert_array_equal(stamps, expected)  # exact integer nanoseconds
    np.testing.assert_array_equal([t for t, _, _ in imus], expected)  # MCAP log_time
    # values: the AdcFrame codes converted as a driver does (code * lsb + offset)
    si = np.concatenate([adc_physical(m) for m in frames])
    assert si.shape == (n, 6)
    got = np.array(
        [
            [
                m.angular_velocity.x,
                m.angular_velocity.y,
                m.angular_velocity.z,
                m.linear_acceleration.x,
                m.linear_acceleration.y,
                m.linear_acceleration.z,
            ]
            for m in msgs
        ]
    )
    np.testing.assert_array_equal(got, si)
    gyro_var, accel_var = imu_device.imu_covariances()
    m = msgs[17]
    assert m.header.frame_id == "imu_link" and m.orientation_covariance[0] == -1.0
    np.testing.assert_allclose(np.diag(np.reshape(m.angular_velocity_covariance, (3, 3))), gyro_var)
    np.testing.assert_allclose(
        np.diag(np.reshape(m.linear_acceleration_covariance, (3, 3))), accel_var
    )

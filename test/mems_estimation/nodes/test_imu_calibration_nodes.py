"""IMU calibration and corrector nodes through real topics: the emulator plays a short
multi-position profile (ADIS16350 preset), the calibration node publishes the calibration
(temperature from the paired temperature_sensor frames) and writes the YAML, and the
corrector applies that YAML to the frames and publishes sensor_msgs/Imu, at the temperature
of a sensor_msgs/Temperature topic in 'topic' mode."""

import numpy as np
import pytest
from conftest import params, spin_until
from sensor_msgs.msg import Imu, Temperature

from mems_estimation.identification import imu_calibration_io as icio
from mems_estimation.nodes.imu_calibration_node import ImuCalibrationNode
from mems_estimation.nodes.imu_corrector_node import ImuCorrectorNode
from mems_msgs.msg import CalibrationResult
from mems_sim.devices.imu_profiles import builtin_profile, dump_profile
from mems_sim.nodes.imu_node import ImuNode
from mems_sim.params import ParameterError
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS


def _acc_rate(imu: list) -> tuple[np.ndarray, np.ndarray]:
    """The (n, 3) linear accelerations [m/s^2] and angular velocities [rad/s] of Imu messages."""
    acc = [[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imu]
    rate = [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in imu]
    return np.array(acc), np.array(rate)


def _short_profile(path):
    """multi_position with 8 s segments (96 s, 9600 samples at 100 Hz)."""
    prof = builtin_profile("multi_position")
    text = dump_profile(prof).replace("duration_s: 60.0", "duration_s: 8.0")
    path.write_text(text)
    return str(path)


def test_calibration_and_corrected_output(graph, tmp_path):
    ctx, ex, probe = graph
    profile = _short_profile(tmp_path / "short.yaml")
    out = tmp_path / "calib.yaml"
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4,
            preset="adis16350",
            motion="profile",
            motion_profile=profile,
            frame_size=400,
            publish_imu=False,
        ),
    )
    cal = ImuCalibrationNode(
        context=ctx,
        parameter_overrides=params(
            profile=profile,
            noise_model="adis16350",
            output_yaml=str(out),
            temperature_source="sensor",
        ),
    )
    for node in (emu, cal):
        ex.add_node(node)
    got, truth = [], []
    probe.create_subscription(CalibrationResult, "/imu/calibration", got.append, RESULT_QOS)
    probe.create_subscription(CalibrationResult, "/imu/truth_calibration", truth.append, RESULT_QOS)
    assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() >= 1)
    assert spin_until(ex, lambda: emu.pub_temperature.get_subscription_count() >= 1)
    for k in range(24):
        emu.step()
        assert spin_until(ex, lambda: cal.frames_done >= k + 1), k
    assert spin_until(ex, lambda: len(got) == 1 and len(truth) == 1)
    res, tr = got[0], truth[0]
    assert res.method.startswith("multi_position_gls")
    assert res.num_points == 12
    t = dict(zip(tr.names, tr.values))
    est = dict(zip(res.names, zip(res.values, res.standard_errors)))
    assert "gyro_matrix_zz" in est and "gyro_g_sensitivity_xy" in est
    assert not any("tempco" in n for n in est)
    z = [(v - t[n]) / se for n, (v, se) in est.items()]
    assert np.max(np.abs(z)) < 5.0, sorted(zip(np.abs(z), est))[-3:]
    assert list(res.units)[res.names.index("gyro_bias_x")] == "rad/s"
    # the YAML the node wrote loads back to the published values
    loaded = icio.load_yaml(out)
    assert loaded.values["accel_matrix_xy"] == pytest.approx(est["accel_matrix_xy"][0])

    # corrected output: the calibration applied to the live frames of a second run (static)
    emu2 = ImuNode(
        context=ctx,
        namespace="imu2",
        drive_externally=True,
        parameter_overrides=params(seed=5, preset="adis16350", frame_size=100, publish_imu=False),
    )
    corr = ImuCorrectorNode(
        context=ctx, namespace="imu2", parameter_overrides=params(calibration_yaml=str(out))
    )
    for node in (emu2, corr):
        ex.add_node(node)
    imu = []
    probe.create_subscription(Imu, "/imu2/data_corrected", imu.append, FRAME_QOS)
    assert spin_until(ex, lambda: emu2.pub_adc.get_subscription_count() >= 1)
    assert spin_until(ex, lambda: corr.pub.get_subscription_count() >= 1)
    for _ in range(5):
        emu2.step()
    assert spin_until(ex, lambda: len(imu) == 500)
    acc, rate = _acc_rate(imu)
    # z up at rest: the ADIS16350 device's 0.5 % scale factors and 0.12 deg misalignments
    # leave ~0.05 m/s^2 raw; corrected: the mean is +g within the noise and the bias error
    assert np.abs(acc.mean(0) - [0, 0, 9.80665]).max() < 0.01
    assert np.abs(rate.mean(0)).max() < 3e-3
    assert imu[1].header.stamp.nanosec - imu[0].header.stamp.nanosec == 10_000_000
    assert imu[0].header.frame_id == "imu_link"


def test_bad_parameters_are_refused(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="neither a built-in"):
        ImuCalibrationNode(context=ros_context, parameter_overrides=params(profile="nope"))
    with pytest.raises(ParameterError, match="calibration_yaml"):
        ImuCorrectorNode(context=ros_context)
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: something_else\n")
    with pytest.raises(ParameterError, match="format"):
        ImuCorrectorNode(context=ros_context, parameter_overrides=params(calibration_yaml=str(bad)))


def test_corrector_follows_a_temperature_topic(graph, tmp_path):
    """temperature_source 'topic': the corrector takes the device temperature from
    sensor_msgs/Temperature (here the emulator's own temperature input, set to 45 C) and
    corrects with the temperature terms at it; a message outside the range of temperature_c
    is ignored and counted. The calibration is the emulator's truth, so the corrected mean
    is the truth within the noise; at the parameter's 25 C the accelerometer z would be off
    by b_T,z x 20 K = 0.49 m/s^2 (ADIS16350 preset: 2.5 mg/K)."""
    ctx, ex, probe = graph
    emu = ImuNode(
        context=ctx,
        namespace="imu3",
        drive_externally=True,
        parameter_overrides=params(seed=6, preset="adis16350", frame_size=100, publish_imu=False),
    )
    yaml_path = tmp_path / "truth.yaml"
    rows = emu.model.calibration_truth()
    icio.save_yaml(
        icio.calibration_from_values([r[0] for r in rows], [r[1] for r in rows]), yaml_path
    )
    corr = ImuCorrectorNode(
        context=ctx,
        namespace="imu3",
        parameter_overrides=params(calibration_yaml=str(yaml_path), temperature_source="topic"),
    )
    for node in (emu, corr):
        ex.add_node(node)
    imu = []
    probe.create_subscription(Imu, "/imu3/data_corrected", imu.append, FRAME_QOS)
    pub = probe.create_publisher(Temperature, "/imu3/temperature", 10)
    assert spin_until(ex, lambda: pub.get_subscription_count() >= 2)
    assert spin_until(ex, lambda: corr.pub.get_subscription_count() >= 1)
    pub.publish(Temperature(temperature=45.0))
    assert spin_until(ex, lambda: corr.temperature_messages == 1 and emu.p["temperature_c"] == 45)
    pub.publish(Temperature(temperature=float("nan")))
    assert spin_until(ex, lambda: corr.diag.counters.get("temperature_ignored") == 1)
    assert corr.current_temperature_c() == 45.0
    for _ in range(3):
        emu.step()
    assert spin_until(ex, lambda: len(imu) == 300)
    acc, rate = _acc_rate(imu)
    assert np.abs(acc.mean(0) - [0, 0, 9.80665]).max() < 0.02
    assert np.abs(rate.mean(0)).max() < 3e-3  # b_T x 20 K would leave 0.035 rad/s


def test_corrector_refuses_an_unknown_temperature_source(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="temperature_source"):
        ImuCorrectorNode(
            context=ros_context,
            parameter_overrides=params(calibration_yaml="x.yaml", temperature_source="driver"),
        )

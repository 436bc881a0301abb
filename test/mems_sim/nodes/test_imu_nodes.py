"""IMU emulator and noise-identifier nodes through real topics (rclpy executors)."""

import array
import subprocess
import sys

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Imu

from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
from mems_msgs.msg import AdcFrame, NoiseModel, SignalFrame
from mems_sim.devices import imu
from mems_sim.nodes.imu_node import ImuNode
from mems_sim.params import ParameterError
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS


def test_emulator_publishes_consecutive_frames_truth_and_imu(graph):
    ctx, ex, probe = graph
    emu = ImuNode(
        context=ctx, drive_externally=True, parameter_overrides=params(seed=3, frame_size=20)
    )
    ex.add_node(emu)
    got = {"adc": [], "truth": [], "imu": []}
    probe.create_subscription(AdcFrame, "/imu/adc", got["adc"].append, FRAME_QOS)
    probe.create_subscription(SignalFrame, "/imu/truth", got["truth"].append, FRAME_QOS)
    probe.create_subscription(Imu, "/imu/data", got["imu"].append, FRAME_QOS)
    assert spin_until(
        ex,
        lambda: (
            emu.pub_adc.get_subscription_count() == 1 and emu.pub_imu.get_subscription_count() == 1
        ),
    )
    for _ in range(5):
        emu.step()
    assert spin_until(ex, lambda: len(got["adc"]) == 5 and len(got["imu"]) == 100)
    first = [m.first_sample_index for m in got["adc"]]
    assert first == [0, 20, 40, 60, 80]
    m = got["adc"][1]
    assert m.sample_rate_hz == 100.0 and m.num_samples == 20 and m.bits == 14
    assert list(m.channel_names) == ["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"]
    # header.stamp is the time of the first sample: index 20 at 100 Hz = 0.2 s
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (0, 200_000_000)
    codes = np.asarray(m.codes).reshape(20, 6)
    # at rest the accelerometer z reads +g within noise: codes * lsb ~ 9.8 m/s^2
    assert abs(np.mean(codes[:, 5]) * m.lsb[5] - 9.80665) < 0.2
    truth = np.asarray(got["truth"][0].data).reshape(20, 6)
    assert np.all(truth[:, :5] == 0) and np.all(truth[:, 5] == 9.80665)
    # Imu messages carry the same values as the ADC codes, in SI, with the model covariances
    sample = got["imu"][20]
    assert sample.angular_velocity.x == pytest.approx(codes[0, 0] * m.lsb[0], abs=1e-12)
    assert sample.linear_acceleration.z == pytest.approx(codes[0, 5] * m.lsb[5], abs=1e-12)
    gyro_var, accel_var = imu.imu_covariances()
    assert sample.angular_velocity_covariance[0] == pytest.approx(gyro_var[0])
    assert sample.linear_acceleration_covariance[8] == pytest.approx(accel_var[2])
    assert sample.orientation_covariance[0] == -1.0


def test_emulator_frames_equal_core_model_output(graph):
    """The node adds nothing to the core: its codes are ImuNoiseModel's for the same seed."""
    ctx, ex, probe = graph
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=11, frame_size=50, publish_imu=False),
    )
    ex.add_node(emu)
    got = []
    probe.create_subscription(AdcFrame, "/imu/adc", got.append, FRAME_QOS)
    assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() == 1)
    for _ in range(4):
        emu.step()
    assert spin_until(ex, lambda: len(got) == 4)
    codes = np.concatenate([np.asarray(m.codes).reshape(-1, 6) for m in got])
    frame = imu.ImuNoiseModel(seed=11).generate(200)
    np.testing.assert_array_equal(codes, np.hstack([frame.gyro_codes, frame.accel_codes]))


def test_invalid_parameter_refused_with_name_value_range(ros_context):
    with pytest.raises(ParameterError) as err:
        ImuNode(
            context=ros_context,
            drive_externally=True,
            parameter_overrides=params(gyro_correlation_time=-5.0),
        )
    text = str(err.value)
    assert "gyro_correlation_time" in text and "-5.0" in text and "allowed" in text


def test_node_executable_refuses_invalid_parameter(subprocess_env):
    exe = subprocess.run(
        [
            sys.executable,
            "-m",
            "mems_sim.nodes.imu_node",
            "--ros-args",
            "-p",
            "sample_rate_hz:=-100.0",
        ],
        env=subprocess_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert exe.returncode == 2
    lines = exe.stderr.strip().splitlines()
    assert len(lines) == 1 and "sample_rate_hz" in lines[0] and "-100.0" in lines[0]


def _frame(first, n=100, fs=100.0, value=0.0):
    m = AdcFrame(
        first_sample_index=first,
        sample_rate_hz=fs,
        num_samples=n,
        bits=14,
        channel_names=["gyro_x"],
        channel_units=["rad/s"],
    )
    m.lsb = array.array("d", [1e-3])
    m.offset = array.array("d", [0.0])
    m.full_scale = array.array("d", [8.192])
    rng = np.random.default_rng(first)
    m.codes = array.array("i", np.rint(rng.normal(0, 50, n) + value).astype(np.int32).tolist())
    return m


def test_identifier_rejects_malformed_frames_and_counts_gaps(graph):
    ctx, ex, probe = graph
    ident = ImuNoiseIdentifierNode(
        context=ctx,
        namespace="imu",
        parameter_overrides=params(min_duration_s=5.0, publish_period_s=0.0),
    )
    ex.add_node(ident)
    pub = probe.create_publisher(AdcFrame, "/imu/adc", FRAME_QOS)
    models, diags = [], []
    probe.create_subscription(NoiseModel, "/imu/noise_model", models.append, RESULT_QOS)
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    bad_size = _frame(100)
    bad_size.num_samples = 99  # 100 codes for 99 samples
    bad_lsb = _frame(100)
    bad_lsb.lsb = array.array("d", [float("nan")])  # non-finite scale
    frames = [_frame(0), bad_size, bad_lsb] + [_frame(i * 100) for i in range(1, 10)]
    frames += [_frame(i * 100) for i in range(11, 20)]  # frame 10 missing: one gap
    for f in frames:
        pub.publish(f)
    assert spin_until(ex, lambda: ident.frames_received == len(frames))
    assert ident.diag.counters["rejected_frames"] == 2
    assert ident.diag.counters["gaps"] == 1
    assert ident.acc.tracker.missing_samples == 100
    ident.close()
    assert spin_until(ex, lambda: len(models) == 1)
    assert models[0].final and models[0].num_samples == 1900
    # the counters reach /diagnostics with level WARN
    ident.diag.publish()
    assert spin_until(
        ex,
        lambda: any(
            s.name.startswith("imu_noise_identifier")
            and s.level == b"\x01"
            or s.name.startswith("imu_noise_identifier")
            and s.level == 1
            for d in diags
            for s in d.status
        ),
    )
    status = [s for d in diags for s in d.status if s.name.startswith("imu_noise_identifier")][-1]
    values = {kv.key: kv.value for kv in status.values}
    assert values["rejected_frames"] == "2" and values["gaps"] == "1"


def test_profile_run_publishes_truth_temperature_and_truth_calibration(graph, tmp_path):
    """motion 'profile': truth motion and temperature follow the profile, the stream ends at
    the profile's end, temperature_sensor carries T per sample and truth_calibration the
    model's realised error terms (transient local, method 'truth')."""
    from mems_msgs.msg import CalibrationResult
    from mems_sim.devices.imu_profiles import (
        ImuProfile,
        Segment,
        dump_profile,
        profile_truth,
    )

    prof = ImuProfile(
        "short",
        (
            Segment(0.3, (1, 0, 0), rate_rad_s=1.5, temperature_start_c=30.0),
            Segment(0.25, (0, 0, -1), temperature_start_c=30.0, temperature_end_c=40.0),
        ),
        settle_s=0.0,
    )
    path = tmp_path / "short.yaml"
    dump_profile(prof, path)
    ctx, ex, probe = graph
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=5,
            frame_size=20,
            publish_imu=False,
            motion="profile",
            motion_profile=str(path),
            preset="adis16350",
            device_seed=3,
        ),
    )
    ex.add_node(emu)
    got = {"adc": [], "truth": [], "temp": [], "cal": []}
    probe.create_subscription(AdcFrame, "/imu/adc", got["adc"].append, FRAME_QOS)
    probe.create_subscription(SignalFrame, "/imu/truth", got["truth"].append, FRAME_QOS)
    probe.create_subscription(SignalFrame, "/imu/temperature_sensor", got["temp"].append, FRAME_QOS)
    assert spin_until(
        ex,
        lambda: (
            emu.pub_adc.get_subscription_count() == 1
            and emu.pub_temperature.get_subscription_count() == 1
        ),
    )
    while emu.step():
        pass
    assert emu.next_index == 55 and emu.finished  # round(0.55 s * 100 Hz)
    # a late joiner still gets the truth calibration (transient local)
    probe.create_subscription(
        CalibrationResult, "/imu/truth_calibration", got["cal"].append, RESULT_QOS
    )
    assert spin_until(ex, lambda: len(got["temp"]) == 3 and len(got["cal"]) == 1)
    truth = np.concatenate([np.asarray(m.data).reshape(-1, 6) for m in got["truth"]])
    temp = np.concatenate([np.asarray(m.data) for m in got["temp"]])
    expect = profile_truth(prof, 0, 55, 100.0)
    np.testing.assert_allclose(truth[:, :3], expect.gyro)
    np.testing.assert_allclose(truth[:, 3:], expect.accel)
    np.testing.assert_allclose(temp, expect.temperature_c)
    assert list(got["temp"][0].channel_names) == ["temperature"]
    assert list(got["temp"][0].channel_units) == ["degC"]
    cal = got["cal"][0]
    assert cal.method == "truth" and cal.device == "imu"
    values = dict(zip(cal.names, cal.values))
    expected = {name: value for name, value, _ in emu.model.calibration_truth()}
    assert values == expected
    assert values["gyro_sf_tempco_x"] != 0.0 and list(cal.standard_errors) == [0.0] * len(values)
    # the drawn device differs from the preset's nominal one, within its tolerance
    assert (
        values["gyro_matrix_xy"] != imu.imu_values({"preset": "adis16350"})["gyro_misalignment_xy"]
    )
    assert abs(values["gyro_matrix_xy"]) <= 0.05 * imu.DEG


def test_profile_parameter_errors(ros_context, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("segments:\n  - {duration_s: 0, up_body: [0, 0, 1]}\n")
    for value, field in (("nope", "nope"), (str(bad), "segments[0].duration_s")):
        with pytest.raises(ParameterError) as err:
            ImuNode(
                context=ros_context,
                drive_externally=True,
                parameter_overrides=params(motion="profile", motion_profile=value),
            )
        assert "motion_profile" in str(err.value) and field in str(err.value)


def test_fault_schedule_acts_and_is_labelled_on_the_faults_topic(graph, tmp_path):
    """A stuck gyro_x and a permanent accel_z bias step: the codes freeze and move where
    the schedule says, and the faults topic carries the schedule, stamped in sensor time."""
    from mems_msgs.msg import FaultEvent
    from mems_sim.nodes.fault_topic import fault_qos

    schedule = tmp_path / "faults.yaml"
    schedule.write_text(
        "faults:\n"
        "  - {kind: stuck_at, channel: gyro_x, start_sample: 30, duration_samples: 40}\n"
        "  - {kind: bias_step, channel: accel_z, start_s: 0.7, magnitude: 0.5}\n"
    )
    ctx, ex, probe = graph
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=2, frame_size=20, publish_imu=False, fault_schedule=str(schedule)
        ),
    )
    ex.add_node(emu)
    adc, events = [], []
    probe.create_subscription(AdcFrame, "/imu/adc", adc.append, FRAME_QOS)
    probe.create_subscription(FaultEvent, "/imu/faults", events.append, fault_qos(2))
    assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() == 1)
    for _ in range(5):
        emu.step()
    assert spin_until(ex, lambda: len(adc) == 5 and len(events) == 2)
    codes = np.concatenate([np.asarray(m.codes).reshape(-1, 6) for m in adc])
    clean = imu.ImuNoiseModel(seed=2).generate(100)
    clean = np.hstack([clean.gyro_codes, clean.accel_codes])
    assert np.all(codes[30:70, 0] == clean[30, 0]) and np.ptp(clean[30:70, 0]) > 0
    np.testing.assert_array_equal(codes[:30], clean[:30])
    lsb = imu.imu_values()["accel_lsb"]
    assert np.all(np.abs(codes[70:, 5] - clean[70:, 5] - 0.5 / lsb) <= 1)
    np.testing.assert_array_equal(codes[:70, 1:], clean[:70, 1:])
    stuck, step = sorted(events, key=lambda m: m.number)
    assert (stuck.kind, stuck.channel, stuck.first_faulty_sample, stuck.faulty_samples) == (
        "stuck_at",
        "gyro_x",
        30,
        40,
    )
    assert not stuck.permanent and (stuck.start.nanosec, stuck.end.nanosec) == (3e8, 7e8)
    assert (step.kind, step.channel, step.first_faulty_sample, step.permanent) == (
        "bias_step",
        "accel_z",
        70,
        True,
    )
    assert (step.magnitude, step.magnitude_unit, step.header.stamp.nanosec) == (0.5, "m/s^2", 7e8)


def test_bad_fault_schedule_is_one_parameter_error(ros_context, tmp_path):
    schedule = tmp_path / "faults.yaml"
    schedule.write_text("faults:\n  - {kind: stuck_at, channel: gyro_w, start_s: 1}\n")
    with pytest.raises(ParameterError) as err:
        ImuNode(
            context=ros_context,
            drive_externally=True,
            parameter_overrides=params(fault_schedule=str(schedule)),
        )
    text = str(err.value)
    assert text.startswith("parameter 'fault_schedule'") and "gyro_w" in text
    assert "\n" not in text


def test_temperature_reading_with_lag_offset_and_resolution(graph):
    """temp_sensor_*: the reading of a device at 30.3 C through a sensor with a lag, an
    offset of 0.5 K and a resolution of 1/256 K is 25 C + round(5.8 K * 256) / 256 (the
    lag starts at the first input, so a constant temperature stays); by default the reading
    is the device temperature itself."""
    ctx, ex, probe = graph
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=1,
            frame_size=20,
            publish_imu=False,
            calibration_topics="on",
            temperature_c=30.3,
            temp_sensor_time_constant_s=2.0,
            temp_sensor_offset_k=0.5,
            temp_sensor_resolution_k=1.0 / 256.0,
        ),
    )
    ex.add_node(emu)
    got = []
    probe.create_subscription(SignalFrame, "/imu/temperature_sensor", got.append, FRAME_QOS)
    assert spin_until(ex, lambda: emu.pub_temperature.get_subscription_count() == 1)
    for _ in range(3):
        emu.step()
    assert spin_until(ex, lambda: len(got) == 3)
    reading = np.concatenate([np.asarray(m.data) for m in got])
    assert np.all(reading == 25.0 + np.round(5.8 * 256) / 256)
    ideal = ImuNode(
        context=ctx, drive_externally=True, parameter_overrides=params(calibration_topics="on")
    )
    assert ideal.temperature_reading is None
    ideal.destroy_node()


def test_temperature_step_moves_the_device_temperature_and_its_bias(graph, tmp_path):
    """A thermal shock of +10 K over samples 40..139 with an accel_z bias tempco of
    0.02 m/s^2/K: the device temperature (the ideal sensor's reading) is 10 K higher exactly
    there, accel_z moves by 0.2 m/s^2 (within 1 LSB once settled) and the codes before the
    onset equal the fault-free run's; the faults topic labels it in kelvin."""
    from mems_msgs.msg import FaultEvent
    from mems_sim.nodes.fault_topic import fault_qos

    schedule = tmp_path / "shock.yaml"
    schedule.write_text(
        "faults:\n"
        "  - {kind: temperature_step, start_sample: 40, duration_samples: 100, magnitude: 10}\n"
    )
    ctx, ex, probe = graph
    runs = {}
    for name, extra in (("clean", {}), ("shock", {"fault_schedule": str(schedule)})):
        emu = ImuNode(
            context=ctx,
            drive_externally=True,
            parameter_overrides=params(
                seed=3,
                frame_size=50,
                publish_imu=False,
                calibration_topics="on",
                accel_bias_tempco_z=0.02,
                **extra,
            ),
        )
        ex.add_node(emu)
        adc, temp, events = [], [], []
        subs = [
            probe.create_subscription(AdcFrame, "/imu/adc", adc.append, FRAME_QOS),
            probe.create_subscription(
                SignalFrame, "/imu/temperature_sensor", temp.append, FRAME_QOS
            ),
            probe.create_subscription(FaultEvent, "/imu/faults", events.append, fault_qos(1)),
        ]
        try:
            assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() == 1)
            assert spin_until(ex, lambda: emu.pub_temperature.get_subscription_count() == 1)
            for _ in range(4):
                emu.step()
            assert spin_until(ex, lambda: len(adc) == 4 and len(temp) == 4)
            assert spin_until(ex, lambda: len(events) == (1 if extra else 0), timeout=1.0)
            lsb = adc[0].lsb[5]
            runs[name] = (
                np.concatenate([np.asarray(m.codes).reshape(-1, 6) for m in adc]),
                np.concatenate([np.asarray(m.data) for m in temp]),
                list(events),
            )
        finally:
            for s in subs:
                probe.destroy_subscription(s)
            ex.remove_node(emu)
            emu.destroy_node()
    (c0, t0, _), (c1, t1, ev) = runs["clean"], runs["shock"]
    dt = t1 - t0
    assert np.all(dt[40:140] == 10.0) and np.all(dt[:40] == 0) and np.all(dt[140:] == 0)
    np.testing.assert_array_equal(c1[:40], c0[:40])
    moved = c1[60:140, 5] - c0[60:140, 5]
    assert np.all(np.abs(moved - 0.2 / lsb) <= 1), moved
    np.testing.assert_array_equal(c1[:, :5], c0[:, :5])  # no tempco on the other axes
    (e,) = ev
    assert (e.kind, e.channel, e.first_faulty_sample, e.faulty_samples) == (
        "temperature_step",
        "",
        40,
        100,
    )
    assert (e.magnitude, e.magnitude_unit) == (10.0, "K")

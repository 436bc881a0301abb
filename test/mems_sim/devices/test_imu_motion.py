"""Motion and vibration inputs of the IMU (mems_sim.devices.imu_motion): a 6-DoF trajectory
given as attitude (and position) against the analytic rates and specific force, the Earth's
rate and normal gravity at a latitude, vibration rectification through the gyro's g^2 term
and the accelerometer's K2 against their closed forms, the sensor latency, the bounded CSV
reader, and the node's wiring (truth topic, ADC, truth_calibration, exit 2 on a bad file)."""

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import params, spin_until

from mems_sim.devices import imu_motion
from mems_sim.devices.imu import G0, ImuNoiseModel, imu_values
from mems_sim.devices.imu_motion import (
    EARTH_RATE,
    ImuMotion,
    TrajectoryError,
    load_trajectory,
    normal_gravity,
    parse_trajectory,
    quat_multiply,
)
from mems_sim.devices.imu_profiles import builtin_profile

REPO = Path(__file__).resolve().parents[3]
DEG_PER_H = math.pi / 180.0 / 3600.0  # rad/s per deg/h
#: Every noise term and constant bias off.
QUIET = {
    f"{s}_{term}": 0.0
    for s in ("gyro", "accel")
    for term in ("noise_density", "bias_instability", "random_walk", "bias")
}


def _csv(columns: str, rows: np.ndarray) -> str:
    body = "\n".join(",".join(repr(float(x)) for x in row) for row in rows)
    return f"# test trajectory\n{columns}\n{body}\n"


def _qz(a):
    return np.stack([np.cos(a / 2), 0 * a, 0 * a, np.sin(a / 2)], -1)


def _qx(a):
    return np.stack([np.cos(a / 2), np.sin(a / 2), 0 * a, 0 * a], -1)


def _coning(theta, freq, t):
    """q = qz(W t) qx(theta) qz(-W t) and its analytic body rates and specific force."""
    w = 2 * math.pi * freq
    q = quat_multiply(quat_multiply(_qz(w * t), _qx(np.full_like(t, theta))), _qz(-w * t))
    s, c = math.sin(theta), math.cos(theta)
    rate = w * np.stack([-s * np.sin(w * t), s * np.cos(w * t), np.full_like(t, c - 1)], -1)
    force = G0 * np.stack([-s * np.sin(w * t), s * np.cos(w * t), np.full_like(t, c)], -1)
    return q, rate, force


def test_coning_given_as_attitude_only_gives_the_analytic_rates_and_specific_force():
    """Acceptance: a 2 Hz coning motion of half-angle 10 deg, quaternion rows at 1 kHz (signs
    flipped on every other row: q and -q are one attitude), sampled at 100 Hz: rates and
    specific force within 1e-9 of their amplitudes over the whole record."""
    theta, freq = math.radians(10.0), 2.0
    rows_t = np.arange(0, 10001) / 1000.0
    q, _, _ = _coning(theta, freq, rows_t)
    q[1::2] *= -1.0
    traj = parse_trajectory(_csv("time_s,qw,qx,qy,qz", np.column_stack([rows_t, q])), "coning")
    motion = ImuMotion("trajectory", {}, trajectory=traj)
    fs = 100.0
    n = motion.n_samples(fs)
    assert n == 1000
    truth = motion.truth(0, n, fs)
    _, rate, force = _coning(theta, freq, np.arange(n) / fs)
    rate_amp = 2 * math.pi * freq * math.sin(theta)
    assert np.max(np.abs(truth.gyro - rate)) < 1e-9 * rate_amp
    assert np.max(np.abs(truth.accel - force)) < 1e-9 * G0
    # the same motion as Euler angles (yaw-pitch-roll of the same attitude) gives the same truth
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    eul = np.column_stack([rows_t, np.degrees(roll), np.degrees(pitch), np.degrees(yaw)])
    traj_e = parse_trajectory(_csv("time_s,roll_deg,pitch_deg,yaw_deg", eul), "coning_euler")
    truth_e = ImuMotion("trajectory", {}, trajectory=traj_e).truth(0, n, fs)
    assert np.max(np.abs(truth_e.gyro - rate)) < 1e-9 * rate_amp


def test_circular_motion_given_as_attitude_and_position():
    """Acceptance: a circle of radius 5 m at 0.25 Hz, heading along the path (body x
    forward, FLU), rows at 100 Hz: rate [0, 0, w], specific force [0, R w^2, g] (centripetal
    to the left), within 1e-9 of their amplitudes. (Rows at 1 kHz would not do: rounding of
    the positions, eps R / h^2, reaches 1e-8 of R w^2 in the second derivative at the ends.)"""
    radius, freq = 5.0, 0.25
    w = 2 * math.pi * freq
    t = np.arange(0, 801) / 100.0
    pos = radius * np.column_stack([np.cos(w * t), np.sin(w * t), 0 * t])
    q = _qz(w * t + math.pi / 2)
    traj = parse_trajectory(
        _csv("time_s,qw,qx,qy,qz,x_m,y_m,z_m", np.column_stack([t, q, pos])), "circle"
    )
    truth = ImuMotion("trajectory", {}, trajectory=traj).truth(0, 800, 100.0)
    assert np.max(np.abs(truth.gyro - [0.0, 0.0, w])) < 1e-9 * w
    centripetal = radius * w * w
    assert np.max(np.abs(truth.accel - [0.0, centripetal, G0])) < 1e-9 * centripetal
    # past the end of the rows: the end attitude, at rest
    after = ImuMotion("trajectory", {}, trajectory=traj).truth(801, 5, 100.0)
    assert np.all(after.gyro == 0.0) and np.allclose(after.accel, [0, 0, G0], atol=1e-12)


def test_the_shipped_example_trajectory_reproduces_its_analytic_motion():
    traj = load_trajectory(REPO / "config" / "imu" / "coning_trajectory.csv")
    truth = ImuMotion("trajectory", {}, trajectory=traj).truth(0, traj.n_samples(100.0), 100.0)
    _, rate, force = _coning(math.radians(5.0), 0.5, np.arange(500) / 100.0)
    amp = math.pi * math.sin(math.radians(5.0))
    assert np.max(np.abs(truth.gyro - rate)) < 1e-9 * amp
    assert np.max(np.abs(truth.accel - force)) < 1e-9 * G0


def test_earth_rate_at_45_degrees_in_the_static_truth():
    """Acceptance: 15.041 deg/h at 45 deg latitude, at rest and level (body = ENU): 0 east,
    15.041 cos 45 = 10.636 deg/h north (y) and up (z); the magnitude is WGS-84's Omega_e.
    Turned by 90 deg in yaw (a trajectory), the north component moves to body x."""
    motion = ImuMotion("static", {"earth_rate": True, "latitude_deg": 45.0})
    gyro = motion.truth(0, 10, 100.0).gyro / DEG_PER_H
    assert EARTH_RATE / DEG_PER_H == pytest.approx(15.0411, abs=1e-4)
    np.testing.assert_allclose(gyro[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(gyro[:, 1:], 15.041067 * math.sqrt(0.5), rtol=1e-6)
    # with every noise term and bias off, the ADC reads it (at a fine LSB)
    model = ImuNoiseModel(dict(QUIET, gyro_lsb=1e-9, bits=32), seed=1)
    frame = model.generate(10, motion.truth(0, 10, 100.0).gyro)
    np.testing.assert_allclose(frame.gyro_si[:, 1] / DEG_PER_H, 10.6357, atol=1e-3)
    t = np.arange(0, 9) / 1.0
    yawed = _qz(np.full_like(t, math.pi / 2))
    traj = parse_trajectory(_csv("time_s,qw,qx,qy,qz", np.column_stack([t, yawed])), "turned")
    turned = ImuMotion("trajectory", {"earth_rate": True, "latitude_deg": 45.0}, trajectory=traj)
    g = turned.truth(0, 5, 1.0).gyro / DEG_PER_H
    np.testing.assert_allclose(g[:, 0], 10.6357, atol=1e-3)
    np.testing.assert_allclose(g[:, 1], 0.0, atol=1e-9)
    # off by default: the static truth of the references
    assert np.all(ImuMotion("static").truth(0, 4, 100.0).gyro == 0.0)


def test_normal_gravity_wgs84():
    """Somigliana's normal gravity: the equatorial and polar values of NIMA TR8350.2 Table
    3.1 (9.7803253359, 9.8321849378); in between the GRS80 series in sin^2 (Moritz,
    "Geodetic Reference System 1980", J. Geodesy 74, 2000) scaled to WGS-84's equatorial
    value (GRS80's is 1.4e-6 m/s^2 larger; the two ellipsoids' other constants differ by
    1e-8 m/s^2 at most); -3.086e-6 m/s^2 per m of height near the ground (free-air)."""
    assert normal_gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert normal_gravity(90.0) == pytest.approx(9.8321849378, abs=1e-9)
    for lat in (-75.0, -45.0, 10.0, 30.0, 45.0, 60.0):
        s2 = math.sin(math.radians(lat)) ** 2
        series = 9.7803267715 * (
            1 + 0.0052790414 * s2 + 0.0000232718 * s2**2 + 0.0000001262 * s2**3 + 7e-10 * s2**4
        )
        assert normal_gravity(lat) == pytest.approx(series * 9.7803253359 / 9.7803267715, abs=2e-8)
    assert normal_gravity(45.0) == pytest.approx(9.8061978, abs=1e-7)
    assert (normal_gravity(45.0, 100.0) - normal_gravity(45.0)) / 100.0 == pytest.approx(
        -3.086e-6, rel=2e-3
    )
    static = ImuMotion("static", {"gravity_model": "wgs84", "latitude_deg": 0.0})
    assert np.all(static.truth(0, 3, 100.0).accel[:, 2] == normal_gravity(0.0))


def _rectification(kind: str, seconds: float = 600.0):
    """Mean output error of a white-noise-only IMU (B, K, bias 0) under vibration along x
    and z, with K2 on the accelerometer x and z and G2[x,x], G2[y,z] on the gyro: the
    estimated rectification per sensor and axis with its standard error."""
    fs = 100.0
    vib = {
        "vibration": kind,
        "vibration_psd_x": 0.1,
        "vibration_psd_z": 0.1,
        "vibration_band_low_hz": 1.0,
        "vibration_band_high_hz": 40.0,
        "vibration_resolution_hz": 0.1,
        "vibration_amplitude_x": 3.0,
        "vibration_amplitude_z": 2.0,
        "vibration_frequency_hz": 7.3,
    }
    p = {
        "gyro_bias": 0.0,
        "gyro_bias_instability": 0.0,
        "gyro_random_walk": 0.0,
        "accel_bias_instability": 0.0,
        "accel_random_walk": 0.0,
        "accel_k2_x": 1e-3,
        "accel_k2_z": 1e-3,
        "gyro_g2_sensitivity_xx": 1e-4,
        "gyro_g2_sensitivity_yz": -1e-4,
    }
    motion = ImuMotion("static", vib, seed=7)
    model = ImuNoiseModel(p, seed=7)
    n = int(seconds * fs)
    truth = motion.truth(0, n, fs)
    frame = model.generate(n, truth.gyro, truth.accel)
    out = {}
    for s, y, u in (("gyro", frame.gyro_si, truth.gyro), ("accel", frame.accel_si, truth.accel)):
        e = y - u
        out[s] = (e.mean(axis=0), e.std(axis=0, ddof=1) / math.sqrt(n))
    return out, motion.vibration.variance()


@pytest.mark.parametrize("kind", ["random", "sinusoid"])
def test_vibration_rectification_matches_the_closed_form(kind):
    """Acceptance: rectified means K2 sigma^2 (accelerometer x; z: K2 (g^2 + sigma^2)) and
    G2 sigma^2 (gyro x from G2[x,x], gyro y from G2[y,z] with the z vibration on gravity)
    within 3 standard errors; sigma^2 = S (f_hi - f_lo) for random vibration, A^2/2 for a
    sinusoid. Each expected mean is at least 8 standard errors from 0, so a missing or
    wrongly scaled term fails."""
    (rect, var) = _rectification(kind)
    if kind == "random":
        np.testing.assert_allclose(var, [0.1 * 39.0, 0.0, 0.1 * 39.0], rtol=1e-12)
    else:
        np.testing.assert_allclose(var, [4.5, 0.0, 2.0], rtol=1e-12)
    expected = {
        "accel": np.array([1e-3 * var[0], 0.0, 1e-3 * (G0**2 + var[2])]),
        "gyro": np.array([1e-4 * var[0], -1e-4 * (G0**2 + var[2]), 0.0]),
    }
    for s in ("accel", "gyro"):
        mean, se = rect[s]
        z = (mean - expected[s]) / se
        assert np.all(np.abs(z) < 3.0), (s, mean, expected[s], se)
        assert np.all(np.abs(expected[s][expected[s] != 0]) > 8 * se[expected[s] != 0])


def test_random_vibration_is_band_limited_with_its_psd_and_frame_split_invariant():
    motion = ImuMotion(
        "static",
        {"vibration": "random", "vibration_psd_y": 0.5, "vibration_band_high_hz": 20.0},
        seed=3,
    )
    fs, n = 100.0, 20000  # 200 s: ten periods of the 0.1 Hz lines (period 2 / 0.1 Hz)
    whole = motion.truth(0, n, fs).accel
    parts = np.concatenate([motion.truth(k, 700, fs).accel for k in range(0, n, 700)])[:n]
    assert np.array_equal(whole, parts)
    v = whole[:, 1]
    assert v.var() == pytest.approx(0.5 * 19.0, rel=1e-9)
    spec = np.abs(np.fft.rfft(v)) ** 2
    f = np.fft.rfftfreq(n, 1 / fs)
    assert spec[(f < 0.99) | (f > 20.01)].sum() < 1e-18 * spec.sum()
    assert np.all(whole[:, 0] == 0.0) and np.all(whole[:, 2] == G0)


def test_latency_shift_is_exact():
    """The sample at t measures the motion of t - L: for a whole number of samples the ADC
    of a latency run equals the ADC of a run without latency m samples earlier, bit for
    bit (noise off); the truth stays the motion at t; any L shifts an analytic sinusoid."""
    fs = 100.0
    prof = builtin_profile("multi_position")
    lat = ImuMotion("profile", {"latency_s": 0.05}, profile=prof)
    ref = ImuMotion("profile", {}, profile=prof)
    first, n = 35995, 20  # across the start of the rate runs (sample 36000)
    t_lat = lat.truth(first, n, fs)
    seen = lat.measured(first, n, fs, t_lat)
    earlier = ref.truth(first - 5, n, fs)
    assert np.array_equal(t_lat.gyro, ref.truth(first, n, fs).gyro)
    assert np.array_equal(seen.gyro, earlier.gyro) and np.array_equal(seen.accel, earlier.accel)
    assert not np.array_equal(seen.gyro, t_lat.gyro)
    a = ImuNoiseModel(QUIET, seed=1).generate(n, seen.gyro, seen.accel)
    b = ImuNoiseModel(QUIET, seed=1).generate(n, earlier.gyro, earlier.accel)
    assert np.array_equal(a.gyro_codes, b.gyro_codes) and np.array_equal(
        a.accel_codes, b.accel_codes
    )
    # a fractional latency on an analytic motion
    sin = ImuMotion("sinusoid", {"latency_s": 0.0123}, amplitude=0.5, frequency=3.0)
    tt = sin.truth(10, 50, fs)
    t = (10 + np.arange(50)) / fs
    np.testing.assert_allclose(tt.gyro[:, 2], 0.5 * np.sin(2 * math.pi * 3.0 * t), atol=1e-15)
    np.testing.assert_allclose(
        sin.measured(10, 50, fs, tt).gyro[:, 2],
        0.5 * np.sin(2 * math.pi * 3.0 * (t - 0.0123)),
        atol=1e-15,
    )
    # truth records the latency
    rows = {r[0]: r[1] for r in ImuNoiseModel({"latency_s": 0.05}).calibration_truth()}
    assert rows["latency_s"] == 0.05
    assert "latency_s" not in {r[0] for r in ImuNoiseModel().calibration_truth()}


def test_new_terms_at_their_defaults_leave_the_truth_and_output_bit_identical():
    """Defaults (no Earth rate, standard gravity, no vibration, K2 = G2 = 0, no latency): the
    truth is truth_motion's / profile_truth's and the model's output that of the old path."""
    from mems_sim.devices.imu import truth_motion
    from mems_sim.devices.imu_profiles import profile_truth

    fs = 100.0
    for kind in ("static", "constant_rate", "sinusoid"):
        got = ImuMotion(kind, imu_values()).truth(37, 25, fs)
        gyro, accel = truth_motion(kind, 37, 25, fs, rate=0.1, amplitude=0.5, frequency=1.0)
        assert np.array_equal(got.gyro, gyro) and np.array_equal(got.accel, accel)
    prof = builtin_profile("thermal_ramp")
    got = ImuMotion("profile", profile=prof).truth(5990, 30, fs, temperature_c=30.0)
    ref = profile_truth(prof, 5990, 30, fs, 30.0)
    assert np.array_equal(got.gyro, ref.gyro) and np.array_equal(got.accel, ref.accel)
    assert np.array_equal(got.temperature_c, ref.temperature_c)


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "no header line"),
        ("time,qw,qx,qy,qz\n", "header 'time,qw,qx,qy,qz' is invalid"),
        ("time_s,qw,qx,qy,qz,x_m\n", "columns ['x_m'] after the attitude are invalid"),
        ("time_s,qw,qx,qy,qz\n0,1,0,0,0\n1,1,0,0\n", "line 3: 4 values, the header has 5"),
        ("time_s,qw,qx,qy,qz\n0,1,0,0,0\n1,1,0,zero,0\n", "line 3: qy = 'zero' is not a finite"),
        ("time_s,qw,qx,qy,qz\n0,1,0,0,0\n1,nan,0,0,0\n", "line 3: qw = 'nan' is not a finite"),
        ("time_s,qw,qx,qy,qz\n" + "0,1,0,0,0\n" * 3, "3 rows, need at least 8"),
        (
            "time_s,qw,qx,qy,qz\n" + "".join(f"{t},1,0,0,0\n" for t in (0, 1, 2, 2, 4, 5, 6, 7)),
            "line 5: time_s = 2.0 is not after the row before",
        ),
        (
            "time_s,qw,qx,qy,qz\n" + "".join(f"{t},{t != 3:d},0,0,0\n" for t in range(8)),
            "line 5: quaternion of (near) zero norm",
        ),
    ],
)
def test_bad_trajectory_text_is_one_line_naming_the_line(text, message):
    with pytest.raises(TrajectoryError) as err:
        parse_trajectory(text, "bad.csv")
    text = str(err.value)
    assert "\n" not in text and message in text and "'bad.csv'" in text


def test_bad_trajectory_files_are_refused_bounded(tmp_path, monkeypatch):
    with pytest.raises(TrajectoryError, match="cannot read"):
        load_trajectory(tmp_path / "missing.csv")
    with pytest.raises(TrajectoryError, match="cannot read: Is a directory"):
        load_trajectory(tmp_path)
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    with pytest.raises(TrajectoryError, match="not a regular file"):
        load_trajectory(fifo)  # opened without blocking, refused
    big = tmp_path / "big.csv"
    big.write_text("time_s,qw,qx,qy,qz\n" + "0,1,0,0,0\n" * 200)
    monkeypatch.setattr(imu_motion, "MAX_CSV_BYTES", 1000)
    with pytest.raises(TrajectoryError, match="larger than 1000 bytes"):
        load_trajectory(big)


def test_node_exits_2_with_one_line_on_a_bad_trajectory_file(subprocess_env, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,qw,qx,qy,qz\n0,1,0,0,0\n0.5,1,0,x,0\n")
    cmd = [sys.executable, "-m", "mems_sim.nodes.imu_node", "--ros-args"]
    cmd += ["-p", "motion:=trajectory", "-p", f"motion_trajectory:={bad}"]
    exe = subprocess.run(cmd, env=subprocess_env, capture_output=True, text=True, timeout=60)
    lines = exe.stderr.strip().splitlines()
    assert exe.returncode == 2 and len(lines) == 1, exe.stderr
    assert "motion_trajectory" in lines[0] and "line 3: qy = 'x'" in lines[0]


def test_node_plays_a_trajectory_with_earth_rate_vibration_and_latency(graph):
    """Through real topics: the truth topic is the core's truth at the samples' times, the
    ADC the core model fed the motion of t - latency, the stream ends at the trajectory's
    end and truth_calibration records the latency."""
    from mems_msgs.msg import AdcFrame, CalibrationResult, SignalFrame
    from mems_sim.nodes.imu_node import ImuNode
    from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS

    path = str(REPO / "config" / "imu" / "coning_trajectory.csv")
    extra = dict(
        earth_rate=True,
        latitude_deg=30.0,
        vibration="sinusoid",
        vibration_amplitude_x=1.0,
        vibration_frequency_hz=12.0,
        latency_s=0.02,
        accel_k2_x=1e-3,
    )
    base = dict(seed=4, frame_size=50, publish_imu=False, motion="trajectory")
    overrides = params(motion_trajectory=path, **base, **extra)
    ctx, ex, probe = graph
    emu = ImuNode(context=ctx, drive_externally=True, parameter_overrides=overrides)
    ex.add_node(emu)
    got = {"adc": [], "truth": [], "cal": []}
    probe.create_subscription(AdcFrame, "/imu/adc", got["adc"].append, FRAME_QOS)
    probe.create_subscription(SignalFrame, "/imu/truth", got["truth"].append, FRAME_QOS)
    probe.create_subscription(
        CalibrationResult, "/imu/truth_calibration", got["cal"].append, RESULT_QOS
    )
    assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() == 1)
    while emu.step():
        pass
    assert emu.next_index == 500 and emu.finished
    assert spin_until(
        ex, lambda: len(got["adc"]) == 10 and len(got["truth"]) == 10 and len(got["cal"]) == 1
    )
    truth = np.concatenate([np.asarray(m.data).reshape(-1, 6) for m in got["truth"]])
    codes = np.concatenate([np.asarray(m.codes).reshape(-1, 6) for m in got["adc"]])
    motion = ImuMotion("trajectory", extra, seed=4, trajectory=load_trajectory(path))
    core = motion.truth(0, 500, 100.0)
    assert np.array_equal(truth, np.hstack([core.gyro, core.accel]))
    seen = motion.measured(0, 500, 100.0, core)
    frame = ImuNoiseModel(
        dict(imu_values(), **{k: extra[k] for k in ("latency_s", "accel_k2_x")}), seed=4
    ).generate(500, seen.gyro, seen.accel)
    assert np.array_equal(codes, np.hstack([frame.gyro_codes, frame.accel_codes]))
    cal = dict(zip(got["cal"][0].names, got["cal"][0].values))
    assert cal["latency_s"] == 0.02 and cal["accel_k2_x"] == 1e-3


def test_invalid_combinations_are_refused_naming_the_parameter(ros_context):
    from mems_sim.nodes.imu_node import ImuNode
    from mems_sim.params import ParameterError

    with pytest.raises(ValueError, match="'earth_rate' = True is invalid with motion 'profile'"):
        ImuMotion("profile", {"earth_rate": True}, profile=builtin_profile("six_position"))
    with pytest.raises(ValueError, match="'vibration_band_high_hz' = 2.0 is invalid"):
        ImuMotion(
            "static",
            {"vibration": "random", "vibration_band_low_hz": 5.0, "vibration_band_high_hz": 2.0},
        )
    for extra, name in (
        ({"vibration": "sinusoid", "vibration_frequency_hz": 50.0}, "vibration_frequency_hz"),
        ({"vibration": "random", "vibration_band_high_hz": 60.0}, "vibration_band_high_hz"),
        ({"motion": "profile", "earth_rate": True}, "earth_rate"),
        ({"motion": "trajectory", "motion_trajectory": "/nonexistent.csv"}, "motion_trajectory"),
    ):
        with pytest.raises(ParameterError, match=name):
            ImuNode(context=ros_context, drive_externally=True, parameter_overrides=params(**extra))

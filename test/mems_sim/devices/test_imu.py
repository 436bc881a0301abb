"""Tests of the Petkov IMU noise model (mems_sim.devices.imu), no ROS."""

import math
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "..")))

from mems_sim.devices.imu import (
    ACCEL_SPECS,
    DEG,
    G0,
    GYRO_SPECS,
    IMU_SPECS,
    ImuNoiseModel,
    covariance9,
    discrete_gm_coefficients,
    imu_covariances,
    quantize,
    truth_motion,
)
from mems_sim.params import ParameterError


def test_discrete_gm_coefficients_match_paper():
    """Petkov Sec. 3, eqs. (4)-(6) corrected: a_d = 0.999917, b_d = 8.33299e-5, sigma_eta = 2.40125."""
    a_d, b_d, sigma_eta_unit = discrete_gm_coefficients(120.0, 0.01)
    assert a_d == pytest.approx(0.999917, abs=5e-7)
    assert b_d == pytest.approx(8.33299e-5, rel=1e-6)
    assert sigma_eta_unit * 1.55e-2 == pytest.approx(2.40125, rel=1e-5)  # B in deg/s as the paper


def test_discrete_gm_stationary_variance():
    """(1 - a_d^2) B^2 = b_d^2 sigma_eta^2 (eq. (5) for the scalar system)."""
    for T, dt in ((120.0, 0.01), (80.0, 0.01), (0.5, 0.1)):
        a_d, b_d, s = discrete_gm_coefficients(T, dt)
        assert (1 - a_d**2) == pytest.approx(b_d**2 * s**2, rel=1e-12)


def test_defaults_are_si_conversions_of_paper_values():
    g = {s.name: s.default for s in GYRO_SPECS}
    a = {s.name: s.default for s in ACCEL_SPECS}
    assert g["gyro_bias"] == pytest.approx(-0.1027 * DEG)
    assert g["gyro_bias_instability"] == pytest.approx(1.55e-2 * DEG)
    assert g["gyro_noise_density"] * math.sqrt(100.0) == pytest.approx(0.581188 * DEG)
    assert g["gyro_random_walk"] == pytest.approx(9e-4 * DEG)
    assert a["accel_bias_instability"] == pytest.approx(0.325e-3 * G0)
    assert a["accel_noise_density"] * math.sqrt(100.0) == pytest.approx(5.57178e-3 * G0)
    assert a["accel_random_walk"] == pytest.approx(3.4333e-4, rel=1e-4)
    for spec in IMU_SPECS:
        assert spec.unit and spec.source and spec.description
        spec.validate(spec.default)


def test_white_per_sample_std_at_100hz():
    """Per-sample white std equals Petkov's sigma_arw = 0.581188 deg/s within 1 %."""
    p = {
        "gyro_bias_instability": 0.0,
        "gyro_random_walk": 0.0,
        "gyro_bias": 0.0,
        "gyro_lsb": 1e-9,
        "bits": 32,
    }
    m = ImuNoiseModel(p, seed=11)
    f = m.generate(200_000)
    std_deg = np.std(f.gyro_si, axis=0) / DEG
    assert np.all(np.abs(std_deg / 0.581188 - 1.0) < 0.01), std_deg


def test_gm_state_stationary_std():
    """GM-only output has std B (eq. (6): sigma_x = B)."""
    B = 1e-3
    p = {
        "gyro_bias_instability": B,
        "gyro_correlation_time": 0.2,
        "gyro_noise_density": 0.0,
        "gyro_random_walk": 0.0,
        "gyro_bias": 0.0,
        "gyro_lsb": 1e-9,
        "bits": 32,
    }
    f = ImuNoiseModel(p, seed=2).generate(200_000)
    assert np.std(f.gyro_si) == pytest.approx(B, rel=0.03)


def test_frame_size_independence_bit_for_bit():
    whole = ImuNoiseModel({}, seed=42).generate(5000)
    split_model = ImuNoiseModel({}, seed=42)
    parts = [split_model.generate(k) for k in (1, 999, 3, 2997, 1000)]
    for field in ("gyro_codes", "accel_codes", "gyro_si", "accel_si"):
        joined = np.vstack([getattr(p, field) for p in parts])
        assert np.array_equal(joined, getattr(whole, field)), field
    assert whole.gyro_codes.dtype == np.int32 and whole.accel_codes.dtype == np.int32


def test_seed_changes_output_and_reproduces():
    a = ImuNoiseModel({}, seed=1).generate(100)
    b = ImuNoiseModel({}, seed=1).generate(100)
    c = ImuNoiseModel({}, seed=2).generate(100)
    assert np.array_equal(a.gyro_codes, b.gyro_codes)
    assert not np.array_equal(a.gyro_codes, c.gyro_codes)


def test_quantize_rounding_and_two_complement_clipping():
    codes, sat = quantize(np.array([0.0, 0.49, 0.51, -0.51, 1000.0, -1000.0, 7.0, -8.0]), 1.0, 4)
    assert codes.tolist() == [0, 0, 1, -1, 7, -8, 7, -8]
    assert sat.tolist() == [False] * 4 + [True, True, False, False]


def test_saturation_counted():
    """A rate of twice the 14-bit full scale (8191 * 0.07326 deg/s = 600 deg/s) saturates every sample."""
    fs, n = 100.0, 1000
    full_scale = (2**13 - 1) * 0.07326 * DEG  # ~10.47 rad/s = 600 deg/s
    gyro, accel = truth_motion("constant_rate", 0, n, fs, rate=2.0 * full_scale)
    m = ImuNoiseModel({}, seed=0)
    f = m.generate(n, gyro, accel)
    assert np.all(f.gyro_codes[:, 2] == 2**13 - 1)
    assert f.saturated.tolist() == [0, 0, n, 0, 0, 0]
    assert m.saturated_total.tolist() == [0, 0, n, 0, 0, 0]


def test_static_accel_codes_near_gravity():
    f = ImuNoiseModel({}, seed=3).generate(1000)
    lsb = 2.522e-3 * G0
    assert abs(np.mean(f.accel_codes[:, 2]) * lsb - G0) < 0.02
    assert np.allclose(f.accel_si, f.accel_codes * lsb)


def test_truth_motion_kinds():
    g, a = truth_motion("static", 0, 5, 100.0)
    assert np.all(g == 0) and np.allclose(a, [0, 0, G0])
    g, _ = truth_motion("constant_rate", 0, 5, 100.0, rate=0.3)
    assert np.allclose(g[:, 2], 0.3)
    g1, _ = truth_motion("sinusoid", 0, 200, 100.0, amplitude=2.0, frequency=1.0)
    g2, _ = truth_motion("sinusoid", 50, 150, 100.0, amplitude=2.0, frequency=1.0)
    assert np.allclose(g1[50:], g2) and g1[:, 2].max() == pytest.approx(2.0, rel=1e-3)
    with pytest.raises(ValueError, match="spin"):
        truth_motion("spin", 0, 5, 100.0)


def test_covariances():
    gv, av = imu_covariances()
    assert gv[0] == pytest.approx((0.581188 * DEG) ** 2 + (1.55e-2 * DEG) ** 2)
    assert av[0] == pytest.approx((5.57178e-3 * G0) ** 2 + (0.325e-3 * G0) ** 2)
    c9 = covariance9(gv)
    assert len(c9) == 9 and c9[0] == c9[4] == c9[8] and c9[1] == 0.0


@pytest.mark.parametrize(
    "name,value",
    [
        ("gyro_correlation_time", 0.0),
        ("accel_noise_density", -1.0),
        ("bits", 40),
        ("sample_rate_hz", -5.0),
    ],
)
def test_invalid_parameter_refused_with_name_value_range(name, value):
    with pytest.raises(ParameterError) as err:
        ImuNoiseModel({name: value}, seed=0)
    msg = str(err.value)
    assert name in msg and repr(value) in msg and "allowed" in msg
    spec = {s.name: s for s in IMU_SPECS}[name]
    assert spec.range_text() in msg


def test_unknown_parameter_refused():
    with pytest.raises(ParameterError, match="gyro_bogus"):
        ImuNoiseModel({"gyro_bogus": 1.0}, seed=0)


def test_flicker_bias_instability_gives_the_flat_allan_floor():
    """gyro_flicker_coefficient B alone (white noise small, no Gauss-Markov, random walk or
    quantisation): the Allan deviation at tau = 1..100 s sits at the generator's closed form
    (within 10 %: 3 axes x 2^19 samples, edf at m = 10^4 about 150 per axis), that is the
    flat 0.664 B floor; the same samples at any frame size; off by default."""
    from mems_estimation.identification.allan import oadev
    from mems_sim.hardware.flicker import FlickerConfig, flicker_adev

    b = 2e-4
    p = {
        "gyro_bias_instability": 0.0,
        "gyro_random_walk": 0.0,
        "gyro_noise_density": 1e-7,
        "gyro_bias": 0.0,
        "gyro_lsb": 1e-12,
        "bits": 32,
        "gyro_flicker_coefficient": b,
        "gyro_flicker_f_low_hz": 1e-4,
        "gyro_flicker_f_high_hz": 10.0,
    }
    n = 1 << 19
    g = ImuNoiseModel(p, seed=2).generate(n).gyro_si
    blocks = ImuNoiseModel(p, seed=2)
    again = np.concatenate([blocks.generate(k).gyro_si for k in (1000, 77, n - 1077)])
    np.testing.assert_array_equal(again, g)
    taus = np.array([1.0, 10.0, 100.0])
    want = flicker_adev(taus, 100.0, FlickerConfig(b, 1e-4, 10.0, 2))
    assert np.all(np.abs(want / (0.664 * b) - 1) < 0.03)
    for j in range(3):
        adev = oadev(g[:, j] - g[:, j].mean(), 100.0, taus)[1]
        assert np.all(np.abs(adev / want - 1) < 0.10), (adev, want)
    assert ImuNoiseModel().sensors["gyro"].flicker is None
    with pytest.raises(ParameterError, match="gyro_flicker_f_high_hz"):
        ImuNoiseModel(dict(p, gyro_flicker_f_high_hz=80.0))

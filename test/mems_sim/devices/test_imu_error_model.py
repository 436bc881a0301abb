"""Tests of the IMU error model (mems_sim.devices.imu, eq. (1)): each deterministic term
against its closed form, the turn-on bias spread, the presets and device draws, the truth of
the error terms, and bit-identity with the stochastic-only model when every new term is 0."""

import hashlib
import math

import numpy as np
import pytest

from mems_sim.devices.imu import (
    AXES,
    DEG,
    FLICKER_ALLAN_FLOOR,
    G0,
    IMU_SPECS,
    PRESETS,
    PRESETS_NAMES,
    T_REF_C,
    ImuNoiseModel,
    draw_imu_device,
    gm_allan_peak,
    gm_std_for_bias_instability,
    imu_covariances,
    imu_specs,
    imu_values,
    lowpass_alpha,
    truth_motion,
)
from mems_sim.devices.imu_profiles import builtin_profile, profile_truth
from mems_sim.params import ParameterError

#: Noise off, fine ADC (+-21 rad/s, +-214 m/s^2 in 1e-8 / 1e-7 steps): the output is the
#: deterministic part of eq. (1) within half an LSB.
QUIET = {
    "bits": 32,
    "gyro_lsb": 1e-8,
    "accel_lsb": 1e-7,
    "gyro_bias": 0.0,
    "accel_bias": 0.0,
    "gyro_bias_instability": 0.0,
    "accel_bias_instability": 0.0,
    "gyro_noise_density": 0.0,
    "accel_noise_density": 0.0,
    "gyro_random_walk": 0.0,
    "accel_random_walk": 0.0,
}


def _codes(params, seed, sizes):
    m = ImuNoiseModel(params, seed=seed)
    out, i = [], 0
    for n in sizes:
        g, a = truth_motion("sinusoid", i, n, m.fs)
        f = m.generate(n, g, a)
        out.append(np.hstack([f.gyro_codes, f.accel_codes]))
        i += n
    return np.vstack(out)


def _sha(codes):
    return hashlib.sha256(np.ascontiguousarray(codes, dtype="<i4").tobytes()).hexdigest()


#: SHA-256 of the int32 codes of the stochastic-only model (before the error terms were
#: added) for these seeds and parameters, frames of 1, 999, 500, 1500 samples.
STOCHASTIC_ONLY = {
    "default_s0": (
        {},
        0,
        "40db2ef56ae91d2875877d575a4f250fb88a18e2dd57398b1782b41f6ebbd3ab",
    ),
    "default_s12345": (
        {},
        12345,
        "95ebf20fb43d93178f2e0714a0690ba60408adcbfbb5006f9e5acc150a83a659",
    ),
    "fine": (
        {"bits": 32, "gyro_lsb": 1e-9, "accel_lsb": 1e-8, "accel_bias": 0.05},
        7,
        "7b3668535b1464108b5f5f0092304e46499f77dab62491d5156c137088c85132",
    ),
}


@pytest.mark.parametrize("case", list(STOCHASTIC_ONLY))
def test_all_new_terms_zero_is_bit_identical_to_stochastic_only_model(case):
    params, seed, digest = STOCHASTIC_ONLY[case]
    sizes = [1, 999, 500, 1500]
    assert _sha(_codes(params, seed, sizes)) == digest
    # explicit preset, a temperature away from 25 C and the nominal draw change nothing
    # either (a device seed on petkov, which has no spreads, is refused: see below)
    p = dict(params, preset="petkov")
    m = ImuNoiseModel(draw_imu_device(imu_values(p), -1), seed=seed, temperature_c=60.0)
    out, i = [], 0
    for n in sizes:
        g, a = truth_motion("sinusoid", i, n, m.fs)
        f = m.generate(n, g, a, temperature_c=np.linspace(-10, 80, n))
        out.append(np.hstack([f.gyro_codes, f.accel_codes]))
        i += n
    assert _sha(np.vstack(out)) == digest


def _matrix(sf, mis):
    c = np.eye(3) + np.diag(sf)
    for (i, j), v in mis.items():
        c[i, j] = v
    return c


def _error_params(s, sf, mis):
    p = {f"{s}_scale_factor_{a}": v for a, v in zip(AXES, sf)}
    for (i, j), v in mis.items():
        p[f"{s}_misalignment_{AXES[i]}{AXES[j]}"] = v
    return p


def test_misalignment_and_scale_factor_closed_form():
    """y = C u with C = I + diag(sf) + M, for a known input (noise and ADC off)."""
    sf_g, sf_a = [0.01, -0.02, 0.005], [-0.003, 0.004, 0.02]
    mis_g = {(0, 1): 0.002, (0, 2): -0.001, (1, 0): 0.003, (1, 2): 0.0005, (2, 0): -0.004}
    mis_a = {(0, 2): 0.01, (2, 1): -0.007, (1, 0): 0.002}
    p = dict(QUIET, **_error_params("gyro", sf_g, mis_g), **_error_params("accel", sf_a, mis_a))
    rng = np.random.default_rng(1)
    wg, fa = rng.normal(0, 2.0, (50, 3)), rng.normal(0, 9.0, (50, 3))
    f = ImuNoiseModel(p, seed=0).generate(50, wg, fa)
    np.testing.assert_allclose(f.gyro_si, wg @ _matrix(sf_g, mis_g).T, rtol=0, atol=1e-8)
    np.testing.assert_allclose(f.accel_si, fa @ _matrix(sf_a, mis_a).T, rtol=0, atol=1e-7)


def test_constant_per_axis_bias_and_g_sensitivity_closed_form():
    """y_gyro = w + b + G f; b = {s}_bias (every axis) + {s}_axis_bias_{a}."""
    gs = np.array([[1e-4, 2e-5, 0.0], [0.0, -3e-4, 1e-5], [5e-5, 0.0, 2e-4]])
    p = dict(QUIET, gyro_bias=0.01, accel_bias=-0.2, gyro_axis_bias_y=0.003, accel_axis_bias_z=0.5)
    p |= {
        f"gyro_g_sensitivity_{a}{b}": gs[i, j]
        for i, a in enumerate(AXES)
        for j, b in enumerate(AXES)
    }
    m = ImuNoiseModel(p, seed=0)
    rng = np.random.default_rng(2)
    wg, fa = rng.normal(0, 1.0, (20, 3)), rng.normal(0, 9.0, (20, 3))
    f = m.generate(20, wg, fa)
    np.testing.assert_allclose(f.gyro_si, wg + [0.01, 0.013, 0.01] + fa @ gs.T, atol=1e-8)
    np.testing.assert_allclose(f.accel_si, fa + [-0.2, -0.2, 0.3], atol=1e-7)
    t = m.error_terms()
    np.testing.assert_allclose(t["gyro"]["bias"], [0.01, 0.013, 0.01])
    np.testing.assert_array_equal(t["gyro"]["g_sensitivity"], gs)


def test_temperature_terms_closed_form():
    """y = diag(1 + s_T (T - 25)) C u + b_T (T - 25), per sample temperature."""
    sf = [0.01, 0.0, -0.01]
    p = dict(QUIET, **_error_params("gyro", sf, {(0, 1): 0.002}))
    p |= {"gyro_bias_tempco_x": 1e-4, "gyro_bias_tempco_z": -2e-4, "gyro_sf_tempco_y": 5e-4}
    p |= {"accel_bias_tempco_y": 1e-3, "accel_sf_tempco_z": -3e-4}
    m = ImuNoiseModel(p, seed=0)
    n = 40
    temp = np.linspace(-20.0, 80.0, n)
    rng = np.random.default_rng(3)
    wg, fa = rng.normal(0, 1.0, (n, 3)), rng.normal(0, 9.0, (n, 3))
    f = m.generate(n, wg, fa, temperature_c=temp)
    dk = (temp - T_REF_C)[:, None]
    c = _matrix(sf, {(0, 1): 0.002})
    expect_g = (wg @ c.T) * (1 + np.array([0, 5e-4, 0]) * dk) + np.array([1e-4, 0, -2e-4]) * dk
    expect_a = fa * (1 + np.array([0, 0, -3e-4]) * dk) + np.array([0, 1e-3, 0]) * dk
    np.testing.assert_allclose(f.gyro_si, expect_g, atol=1e-8)
    np.testing.assert_allclose(f.accel_si, expect_a, atol=1e-7)
    # a constant temperature: the constructor's, then set_temperature
    m2 = ImuNoiseModel(p, seed=0, temperature_c=45.0)
    f2 = m2.generate(1, wg[:1], fa[:1])
    m2.set_temperature(45.0)
    np.testing.assert_allclose(f2.gyro_si[0, 0], wg[0] @ c[0] + 1e-4 * 20.0, atol=1e-8)
    with pytest.raises(ValueError, match="temperature_c"):
        m2.generate(3, temperature_c=np.zeros(2))


def test_thermal_ramp_gives_documented_bias_and_sf_slopes():
    """The thermal_ramp profile (20 -> 60 C, +-100 deg/s about z) with Petkov's noise on:
    least squares of gyro z on [1, dT, w, w dT] returns the bias and SF temperature slopes."""
    prof = builtin_profile("thermal_ramp")
    fs = 10.0
    n = prof.n_samples(fs)
    tr = profile_truth(prof, 0, n, fs)
    bt, st, sf = 0.1 * DEG, 6e-4, 0.01  # rad/s/K (ADIS16350 size), 1/K, -
    p = {
        "sample_rate_hz": fs,
        "gyro_bias_tempco_z": bt,
        "gyro_sf_tempco_z": st,
        "gyro_scale_factor_z": sf,
        "gyro_bias_tempco_x": -1e-3,
    }
    f = ImuNoiseModel(p, seed=4).generate(n, tr.gyro, tr.accel, tr.temperature_c)
    dk = tr.temperature_c - T_REF_C
    w = tr.gyro[:, 2]
    a = np.column_stack([np.ones(n), dk, w, w * dk])
    coef, *_ = np.linalg.lstsq(a, f.gyro_si[:, 2], rcond=None)
    assert coef[1] == pytest.approx(bt, rel=0.03)  # bias slope, rad/s/K
    assert coef[2] == pytest.approx(1 + sf, abs=2e-4)  # gain at 25 C
    assert coef[3] == pytest.approx((1 + sf) * st, rel=0.02)  # gain slope, 1/K
    # x axis: no rate, bias slope only
    cx, *_ = np.linalg.lstsq(a[:, :2], f.gyro_si[:, 0], rcond=None)
    assert cx[1] == pytest.approx(-1e-3, rel=0.05)


def test_turn_on_bias_spread_over_1000_power_ups():
    """Turn-on bias: N(0, std^2) per axis and power-up; 1000 power-ups match std within 10 %."""
    std_g, std_a = np.array([1e-3, 2e-3, 5e-4]), np.array([0.05, 0.01, 0.02])
    p = dict(QUIET, gyro_bias=0.002)
    p |= {f"gyro_turnon_bias_std_{a}": v for a, v in zip(AXES, std_g)}
    p |= {f"accel_turnon_bias_std_{a}": v for a, v in zip(AXES, std_a)}
    ups = [ImuNoiseModel(p, seed=s).turn_on_bias for s in range(1000)]
    g, acc = np.array([u["gyro"] for u in ups]), np.array([u["accel"] for u in ups])
    np.testing.assert_allclose(g.std(axis=0), std_g, rtol=0.1)
    np.testing.assert_allclose(acc.std(axis=0), std_a, rtol=0.1)
    assert np.all(np.abs(g.mean(axis=0)) < 4 * std_g / math.sqrt(1000))
    # the drawn bias is in the output and in the truth; the same seed, the same power-up
    m = ImuNoiseModel(p, seed=7)
    f = m.generate(5)
    np.testing.assert_allclose(f.gyro_si, np.tile(0.002 + g[7], (5, 1)), atol=1e-8)
    np.testing.assert_allclose(m.error_terms()["gyro"]["bias"], 0.002 + g[7])


def test_lowpass_step_response_and_noise_reduction():
    """First-order low-pass: step response 1 - (1 - alpha)^k, alpha = 1 - exp(-2 pi fc/fs);
    white variance through it alpha/(2 - alpha) (imu_covariances)."""
    fs, fc = 100.0, 5.0
    alpha = lowpass_alpha(fc, fs)
    assert alpha == pytest.approx(1 - math.exp(-2 * math.pi * fc / fs))
    assert lowpass_alpha(0.0, fs) == 1.0
    p = dict(QUIET, gyro_bandwidth=fc)
    m = ImuNoiseModel(p, seed=0)
    u = np.zeros((60, 3))
    u[1:, 0] = 1.0
    y = np.vstack([m.generate(25, u[:25]).gyro_si, m.generate(35, u[25:]).gyro_si])
    k = np.arange(60)
    np.testing.assert_allclose(y[:, 0], np.where(k == 0, 0.0, 1 - (1 - alpha) ** k), atol=1e-8)
    # noise through the filter
    pn = {
        "gyro_bandwidth": fc,
        "gyro_bias_instability": 0.0,
        "gyro_random_walk": 0.0,
        "bits": 32,
        "gyro_lsb": 1e-9,
    }
    f = ImuNoiseModel(pn, seed=1).generate(200_000)
    var = imu_covariances(pn)[0][0]
    assert f.gyro_si[1000:, 0].var() == pytest.approx(var, rel=0.03)
    assert var == pytest.approx(imu_covariances()[0][0] * alpha / (2 - alpha), rel=0.2)


def test_split_frames_equal_one_frame_with_every_term_on():
    p = dict(imu_values({"preset": "adis16350"}), gyro_turnon_bias_std_x=1e-3)
    prof = builtin_profile("thermal_multi_position")
    tr = profile_truth(prof, 0, 3000, 100.0)
    whole = ImuNoiseModel(p, seed=9).generate(3000, tr.gyro, tr.accel, tr.temperature_c)
    m = ImuNoiseModel(p, seed=9)
    parts = [
        m.generate(b - a, tr.gyro[a:b], tr.accel[a:b], tr.temperature_c[a:b])
        for a, b in ((0, 1), (1, 1234), (1234, 3000))
    ]
    for i in range(4):
        np.testing.assert_array_equal(np.concatenate([x[i] for x in parts]), whole[i])


def test_gauss_markov_allan_peak_and_matlab_bias_instability_mapping():
    x, ratio = gm_allan_peak()
    assert x == pytest.approx(1.8926, abs=1e-3) and ratio == pytest.approx(0.61736, abs=1e-4)

    def adev(x):  # El-Sheimy et al. 2008 closed form, per unit B, x = tau/T
        return math.sqrt((2 / x) * (1 - (3 - 4 * math.exp(-x) + math.exp(-2 * x)) / (2 * x)))

    assert max(adev(v) for v in np.linspace(0.2, 20, 20000)) == pytest.approx(ratio, rel=1e-6)
    assert FLICKER_ALLAN_FLOOR == pytest.approx(0.66428, abs=1e-5)
    assert gm_std_for_bias_instability(1.0) == pytest.approx(1.0760, abs=1e-4)


@pytest.mark.parametrize("preset", PRESETS_NAMES)
def test_presets_valid_with_sources(preset):
    specs = imu_specs(preset)
    assert [s.name for s in specs] == [s.name for s in IMU_SPECS]
    for s in specs:
        s.validate(s.default)
        assert s.source and s.unit and s.description
    v = imu_values({"preset": preset})
    for name, (value, source, spread) in PRESETS[preset].items():
        assert v[name] == value and source
        if spread is not None:
            assert spread.source and not spread.relative
            # the nominal device lies within the datasheet tolerance
            assert abs(value) <= spread.width * (3 if spread.kind == "normal" else 1) + 1e-15
    gv, av = imu_covariances({"preset": preset})
    assert np.all(gv > 0) and np.all(av > 0)


def test_preset_values_and_explicit_overrides():
    v = imu_values({"preset": "adis16350"})
    assert v["gyro_sf_tempco_x"] == pytest.approx(600e-6)
    assert v["gyro_g_sensitivity_xx"] == pytest.approx(0.05 * DEG / G0)
    assert (
        v["gyro_bandwidth"] == 350.0
        and v["gyro_noise_density"] == imu_values()["gyro_noise_density"]
    )
    icm = imu_values({"preset": "icm42688p", "gyro_bandwidth": 0.0})
    assert icm["bits"] == 16 and icm["gyro_noise_density"] == pytest.approx(0.0028 * DEG)
    assert icm["gyro_bandwidth"] == 0.0  # explicit beats preset
    assert icm["gyro_lsb"] == pytest.approx(DEG / 131.0)
    with pytest.raises(ParameterError, match="preset"):
        imu_values({"preset": "mpu6050"})


def test_device_draw_within_datasheet_tolerance_and_deterministic():
    nominal = imu_values({"preset": "icm42688p"})
    assert draw_imu_device(nominal, -1) == nominal
    draws = [draw_imu_device(nominal, s, fixed={"gyro_scale_factor_x"}) for s in range(200)]
    assert draws[3] == draw_imu_device(nominal, 3, fixed={"gyro_scale_factor_x"})
    sf = np.array([d["gyro_scale_factor_y"] for d in draws])
    assert np.all(np.abs(sf) <= 0.005) and sf.std() == pytest.approx(0.005 / math.sqrt(3), rel=0.2)
    mis = np.array([d["accel_misalignment_zx"] for d in draws])
    assert np.all(np.abs(mis) <= 0.01) and abs(mis.mean()) < 0.002
    assert all(d["gyro_scale_factor_x"] == nominal["gyro_scale_factor_x"] for d in draws)
    assert all(d["gyro_noise_density"] == nominal["gyro_noise_density"] for d in draws)
    # 1-sigma datasheet bias (ADIS16350 initial bias error): normal, std 3 deg/s
    adis = imu_values({"preset": "adis16350"})
    b = np.array([draw_imu_device(adis, s)["gyro_axis_bias_z"] for s in range(400)])
    assert b.std() == pytest.approx(3 * DEG, rel=0.15)


def test_a_device_seed_on_the_petkov_preset_is_refused():
    """Petkov's preset has no batch spreads: a drawn device would be the nominal one, silently."""
    petkov = imu_values({})
    assert draw_imu_device(petkov, -1) == petkov  # nominal: nothing drawn, accepted
    with pytest.raises(ParameterError, match="preset 'petkov' has no batch spreads"):
        draw_imu_device(petkov, 5)


def test_calibration_truth_names_units_and_values():
    p = dict(imu_values({"preset": "adis16350"}), accel_turnon_bias_std_y=0.1)
    m = ImuNoiseModel(p, seed=2)
    rows = m.calibration_truth()
    names = [r[0] for r in rows]
    assert len(names) == len(set(names)) == 2 * (3 + 9 + 3 + 3) + 9
    d = {r[0]: r for r in rows}
    t = m.error_terms()
    assert d["accel_bias_y"][1] == pytest.approx(t["accel"]["bias"][1])
    assert d["accel_bias_y"][1] != p["accel_bias"] + p["accel_axis_bias_y"]  # turn-on included
    assert d["gyro_bias_x"][2] == "rad/s" and d["accel_bias_z"][2] == "m/s^2"
    assert d["gyro_matrix_xy"][1] == p["gyro_misalignment_xy"] and d["gyro_matrix_xy"][2] == "-"
    assert d["gyro_matrix_yy"][1] == 1 + p["gyro_scale_factor_y"]
    assert d["gyro_bias_tempco_z"][1:] == (p["gyro_bias_tempco_z"], "rad/s/K")
    assert d["accel_bias_tempco_x"][2] == "m/s^2/K"
    assert d["accel_sf_tempco_z"][1:] == (p["accel_sf_tempco_z"], "1/K")
    assert d["gyro_g_sensitivity_zz"][1:] == (p["gyro_g_sensitivity_zz"], "rad/s/(m/s^2)")

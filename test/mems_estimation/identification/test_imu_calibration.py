"""IMU multi-position / thermal calibration core against analytic cases: exact recovery
without noise, recovery within the stated intervals with the Petkov noise, the segment-mean
covariance against its closed forms, the inverse model, aliases and YAML round trip."""

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from mems_estimation.identification import imu_calibration as ic
from mems_estimation.identification import imu_calibration_io as icio
from mems_sim.devices.imu_profiles import ProfileTruth, builtin_profile, profile_truth

FS = 100.0


def _truth_calibration(rng) -> ic.ImuCalibration:
    v = {}
    for s in ic.SENSORS:
        C = np.eye(3) + np.diag(rng.normal(0, 5e-3, 3))
        C += rng.normal(0, 1e-3, (3, 3)) * (1 - np.eye(3))
        for i, a in enumerate("xyz"):
            for j, b in enumerate("xyz"):
                v[f"{s}_matrix_{a}{b}"] = C[i, j]
            v[f"{s}_bias_{a}"] = rng.normal(0, 3e-2 if s == "gyro" else 0.3)
            v[f"{s}_bias_tempco_{a}"] = rng.normal(0, 1.7e-3 if s == "gyro" else 2.4e-2)
            v[f"{s}_sf_tempco_{a}"] = rng.normal(0, 5e-4)
    for a in "xyz":
        for b in "xyz":
            v[f"gyro_g_sensitivity_{a}{b}"] = rng.normal(0, 9e-5)
    return icio.calibration_from_values(list(v), list(v.values()), method="truth")


def _noise(n, N, B, T, K, rng):
    a = math.exp(-1.0 / (FS * T))
    eta = rng.standard_normal(n) * B * math.sqrt(1 - a * a)
    gm, _ = lfilter([1.0], [1.0, -a], eta, zi=[a * rng.standard_normal() * B])
    rw = np.concatenate([[0.0], np.cumsum(rng.standard_normal(n - 1))]) * K / math.sqrt(FS)
    return rng.standard_normal(n) * N * math.sqrt(FS) + gm + rw


def forward(tc: ic.ImuCalibration, truth: ProfileTruth, rng=None, quantise=True):
    """The measurement model of the module docstring (and of the emulator), with the
    Petkov noise of the 'petkov' preset and its ADC resolution when rng is given."""
    dT = (truth.temperature_c - ic.T_REF_C)[:, None]
    out = {}
    noise = ic.nominal_noise("petkov")
    for s, u in (("accel", truth.accel), ("gyro", truth.gyro)):
        y = (u @ tc.matrix(s).T) * (1 + tc.vector(s, "sf_tempco") * dT)
        y += tc.vector(s, "bias") + tc.vector(s, "bias_tempco") * dT
        if s == "gyro":
            y += truth.accel @ tc.g_sensitivity().T
        if rng is not None:
            sp = noise[s]
            for k in range(3):
                y[:, k] += _noise(y.shape[0], sp.N[k], sp.B[k], sp.T[k], sp.K[k], rng)
            if quantise:
                y = np.round(y / sp.lsb) * sp.lsb
        out[s] = y
    return out["gyro"], out["accel"]


def _data(name, seed=None, tc_seed=3):
    prof = builtin_profile(name)
    truth = profile_truth(prof, 0, prof.n_samples(FS), FS)
    tc = _truth_calibration(np.random.default_rng(tc_seed))
    rng = None if seed is None else np.random.default_rng(seed)
    g, a = forward(tc, truth, rng)
    return prof, truth, tc, g, a


def test_multi_position_exact_without_noise():
    prof, truth, tc, g, a = _data("multi_position")
    cal = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    assert not cal.info["thermal"] and not cal.aliases
    # every matrix, bias and g-sensitivity element is observable in multi_position
    for s in ic.SENSORS:
        for n in ic.parameter_names(s):
            if "tempco" in n:
                assert n not in cal.estimated
                continue
            assert n in cal.estimated
            assert cal.values[n] == pytest.approx(tc.values[n], abs=1e-12), n


def test_thermal_multi_position_exact_without_noise():
    """The only model departure: the second-order products sf_T,a C_ab (a != b), below 1e-7
    of the parameters here."""
    prof, truth, tc, g, a = _data("thermal_multi_position")
    cal = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    assert cal.info["thermal"] and len(cal.estimated) == len(ic.ALL_NAMES)
    for n in ic.ALL_NAMES:
        tol = 3e-8 if "tempco" in n or "g_sens" in n else 3e-7
        scale = max(abs(tc.values[n]), 1e-3 if "tempco" not in n else 1e-4)
        assert abs(cal.values[n] - tc.values[n]) <= tol * scale * 1e3, n


def test_six_position_leaves_gyro_matrix_unobservable():
    prof, truth, tc, g, a = _data("six_position")
    cal = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    assert not any(n.startswith("gyro_matrix") for n in cal.estimated)
    assert cal.matrix("gyro") == pytest.approx(np.eye(3))
    assert cal.g_sensitivity() == pytest.approx(tc.g_sensitivity(), abs=1e-12)
    assert cal.matrix("accel") == pytest.approx(tc.matrix("accel"), abs=1e-12)


def test_thermal_ramp_observability_and_aliases():
    prof, truth, tc, g, a = _data("thermal_ramp")
    cal = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    assert "gyro_sf_tempco_z" in cal.estimated
    assert "gyro_sf_tempco_x" not in cal.estimated and "accel_sf_tempco_z" not in cal.estimated
    assert "accel_sf_tempco_z" in cal.aliases["accel_bias_tempco_z"]
    assert "gyro_g_sensitivity_xz" in cal.aliases["gyro_bias_x"]
    for n in ("gyro_bias_tempco_x", "gyro_bias_tempco_z"):
        assert cal.values[n] == pytest.approx(tc.values[n], rel=1e-6), n
    # the accelerometer's y bias tempco also carries sf_T,y C_yz g (5e-6 m/s^2/K here): the
    # x/y scale-factor tempcos are not observable in this profile, and not in a base
    assert cal.values["accel_bias_tempco_y"] == pytest.approx(
        tc.values["accel_bias_tempco_y"], abs=1e-5
    )
    assert cal.values["gyro_sf_tempco_z"] == pytest.approx(tc.values["gyro_sf_tempco_z"], rel=1e-3)
    # with the multi-position values as base, the biases are clean (no alias)
    base = icio.calibration_from_values(
        [n for n in ic.ALL_NAMES if "tempco" not in n],
        [tc.values[n] for n in ic.ALL_NAMES if "tempco" not in n],
        [0.0] * len([n for n in ic.ALL_NAMES if "tempco" not in n]),
    )
    cal2 = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise(), base=base)
    assert "gyro_bias_x" not in cal2.aliases
    # (up to sf_T,x C_xz w dT, the x scale-factor tempco being in neither)
    assert cal2.values["gyro_bias_x"] == pytest.approx(tc.values["gyro_bias_x"], abs=1e-5)
    assert "accel_bias_tempco_z" in cal2.aliases  # sf_tempco_z is not in the base


def test_noisy_multi_position_within_intervals():
    """Petkov noise and the ADC: every parameter within 4 standard errors and the 95 %
    intervals cover most of them (coverage over seeds: the acceptance tier)."""
    prof, truth, tc, g, a = _data("multi_position", seed=11)
    cal = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    z = np.array([(cal.values[n] - tc.values[n]) / cal.standard_errors[n] for n in cal.estimated])
    assert np.all(np.abs(z) < 4.5), z
    assert np.mean(np.abs(z) < ic.Z95) >= 0.85
    # physically: scale factors to ~1e-4, accelerometer biases well below 1 mg
    for s in ic.SENSORS:
        assert np.abs(np.diag(cal.matrix(s) - tc.matrix(s))).max() < 5e-4
    assert np.abs(cal.vector("accel", "bias") - tc.vector("accel", "bias")).max() < 1e-3 * 9.8


def test_gaps_are_tolerated():
    prof, truth, tc, g, a = _data("multi_position", seed=5)
    keep = np.ones(g.shape[0], bool)
    keep[30_000:30_500] = False  # 5 s missing inside segment 5
    idx = np.flatnonzero(keep)
    full = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    cut = ic.calibrate_profile(g[keep], a[keep], prof, FS, index=idx, noise=ic.nominal_noise())
    assert cut.info["samples"] == full.info["samples"] - 500
    for n in full.estimated:
        assert abs(cut.values[n] - full.values[n]) < 2 * full.standard_errors[n], n


def test_segment_mean_covariance_closed_forms():
    N, B, T, K = 0.01, 0.002, 100.0, 1e-4
    t0, t1 = np.array([0.0, 60.0, 300.0]), np.array([60.0, 120.0, 330.0])
    cnt = (t1 - t0) * FS
    L = t1 - t0
    S = ic.segment_mean_covariance(t0, t1, cnt, N, 0, T, 0)
    assert np.diag(S) == pytest.approx(N * N / L) and S[0, 1] == 0
    S = ic.segment_mean_covariance(t0, t1, cnt, 0, B, T, 0)
    x = L / T
    assert np.diag(S) == pytest.approx(B * B * 2 / x * (1 - (1 - np.exp(-x)) / x))
    # disjoint: B^2 T^2/(L_i L_j) e^{-gap/T} (1 - e^{-L_i/T})(1 - e^{-L_j/T})
    gap = t0[2] - t1[0]
    want = (
        B
        * B
        * T
        * T
        / (L[0] * L[2])
        * math.exp(-gap / T)
        * (1 - math.exp(-x[0]))
        * (1 - math.exp(-x[2]))
    )
    assert S[0, 2] == pytest.approx(want) and S[2, 0] == pytest.approx(want)
    S = ic.segment_mean_covariance(t0, t1, cnt, 0, 0, T, K)
    assert S[1, 1] == pytest.approx(K * K * (60 + 20)) and S[1, 2] == pytest.approx(K * K * 90)


def test_correct_inverts_the_model():
    rng = np.random.default_rng(2)
    tc = _truth_calibration(rng)
    prof = builtin_profile("thermal_multi_position")
    truth = profile_truth(prof, 0, prof.n_samples(FS), FS)
    g, a = forward(tc, truth)
    w, f = ic.correct(g, a, truth.temperature_c, tc)
    np.testing.assert_allclose(w, truth.gyro, rtol=0, atol=1e-12)
    np.testing.assert_allclose(f, truth.accel, rtol=0, atol=1e-11)


def test_yaml_round_trip_and_errors(tmp_path):
    prof, truth, tc, g, a = _data("multi_position", seed=1)
    cal = ic.calibrate_profile(g, a, prof, FS, noise=ic.nominal_noise())
    path = tmp_path / "calib.yaml"
    icio.save_yaml(cal, path)
    back = icio.load_yaml(path)
    for n in ic.ALL_NAMES:
        assert back.values[n] == cal.values[n]
    assert back.estimated == cal.estimated
    assert back.standard_errors["gyro_bias_x"] == cal.standard_errors["gyro_bias_x"]
    text = path.read_text()
    assert "correction_matrix" in text and "unit: rad/s" in text
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: mems_emulator/imu_calibration\ngyroscope: {matrix: [[1, 0], [0, 1]]}\n")
    with pytest.raises(ic.CalibrationError, match="gyroscope.matrix"):
        icio.load_yaml(bad)
    bad.write_text("{foo: 1}")
    with pytest.raises(ic.CalibrationError, match="format"):
        icio.load_yaml(bad)


def test_bad_input_is_one_clear_error():
    prof = builtin_profile("multi_position")
    with pytest.raises(ic.CalibrationError, match=r"\(n, 3\)"):
        ic.calibrate_profile(np.zeros((10, 2)), np.zeros((10, 3)), prof, FS)
    with pytest.raises(ic.CalibrationError, match="no profile segment"):
        ic.calibrate_profile(np.zeros((300, 3)), np.zeros((300, 3)), prof, FS)
    with pytest.raises(ic.CalibrationError, match="noise model"):
        icio.noise_option("/nonexistent.json")


def test_data_that_do_not_follow_the_profile_are_refused():
    """A static record, or a rate table that never turned, calibrated along multi_position:
    the fit would succeed (accelerometer matrix ~0, z bias ~g) -- refused instead, naming
    how many segments differ and the first one; the noisy data of the profile pass."""
    prof, truth, tc, g, a = _data("multi_position", seed=5)
    ic.calibrate_profile(g, a, prof, FS)  # the profile's own data: no refusal
    static = np.tile(a[: truth.segment.size // 12].mean(0), (a.shape[0], 1))
    still = np.where(np.abs(truth.gyro) > 0, 0.0, g)  # the table's rates missing
    assert np.any(np.abs(truth.gyro) > 0.5)
    moved = sum(s.up_body != prof.segments[0].up_body for s in prof.segments)
    cases = ((g, static, "accel", f" {moved} of 12 segments"), (still, a, "gyro", " of 12 "))
    for gyro, accel, sensor, count in cases:
        with pytest.raises(ic.CalibrationError, match="do not follow the profile") as err:
            ic.calibrate_profile(gyro, accel, prof, FS)
        text = str(err.value)
        assert f": {sensor} mean" in text and count in text and "\n" not in text, text

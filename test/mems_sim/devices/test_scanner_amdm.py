"""Chapter-5 micro-scanner with shared electrodes: AMDM chain (eqs. 92-104), Table 5.2 device."""

import math

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import ParameterError

RUN = dict(drive_voltage_max=150.0, sweep_start_hz=31.32e3, sweep_end_hz=31.27e3, sweep_time_s=0.03)


@pytest.fixture(scope="module")
def run40():
    dev = sa.AmdmScannerDevice(RUN, seed=1)
    fr = dev.step(40000)
    return dev, fr


@pytest.mark.parametrize(
    "name,value",
    [
        ("inertia", -1e-14),
        ("cap_theta0", 0.0),
        ("output_noise_var", -1.0),
        ("adc_bits", 40),
        ("carrier_freq_hz", 3e6),
        ("lpf_cutoff_hz", 6e5),
        ("sweep_start_hz", 3e5),
        ("nonsense", 1.0),
    ],
)
def test_invalid_parameters_refused_with_name(name, value):
    with pytest.raises(ParameterError, match=name):
        sa.AmdmScannerDevice({name: value})


def test_table_5_2_defaults_and_threshold():
    p = sa.resolve_amdm()
    assert p["inertia"] == 1.15e-14 and p["spring_constant"] == 1.10e-4
    assert p["circuit_gain"] == pytest.approx(-0.3574e12) and p["circuit_bias"] == 6.3945
    wn = math.sqrt(p["spring_constant"] / p["inertia"])
    assert wn / (2 * math.pi) == pytest.approx(15.566e3, rel=1e-3)  # 2 x f_n ~ 31.1 kHz drive
    vth = sa.parametric_threshold_voltage(p)
    assert 120.0 < vth < 135.0  # the paper's 0-60 V is below the Mathieu threshold


def test_table_5_1_drive_gives_no_motion_above_threshold_does():
    quiet = sa.AmdmScannerDevice(dict(RUN, drive_voltage_max=60.0), seed=0).step(20000)
    assert np.max(np.abs(quiet.theta[-2000:])) < 0.2 * 0.02  # decays from 0.02 rad
    moving = sa.AmdmScannerDevice(RUN, seed=0).step(20000)
    assert np.max(np.abs(moving.theta[-2000:])) > 0.08  # parametric growth


def test_chain_realises_eq_104_with_its_delay(run40):
    dev, fr = run40
    t = np.arange(fr.theta.size) / dev.fs
    cs = CubicSpline(t, fr.theta)
    sl = slice(25000, None)

    def resid(delay):
        return fr.y_clean[sl] - sa.measurement_model(cs(t[sl] - delay), dev.p)

    r = resid(dev.delay)
    swing = np.ptp(fr.y_clean[sl])
    assert swing > 0.5  # ~0.14 rad motion: ~0.8 V of y
    assert np.sqrt(np.mean(r**2)) < 0.015  # model error below the paper's sigma
    assert np.sqrt(np.mean(resid(0.0) ** 2)) > 5 * np.sqrt(np.mean(r**2))
    assert np.std(r) < np.std(resid(0.9 * dev.delay)) and np.std(r) < np.std(resid(1.1 * dev.delay))
    assert 1e-6 < dev.delay < 10e-6


def test_noise_variance_and_adc(run40):
    dev, fr = run40
    n = fr.y - fr.y_clean
    assert np.var(n) == pytest.approx(1.92e-4, rel=0.05)
    assert np.max(np.abs(fr.codes * dev.lsb - fr.y)) <= dev.lsb / 2 + 1e-12
    assert fr.saturated == 0


def test_frames_concatenate_and_seed_determinism():
    a = sa.AmdmScannerDevice(RUN, seed=5)
    parts = [a.step(700), a.step(300)]
    b = sa.AmdmScannerDevice(RUN, seed=5).step(1000)
    np.testing.assert_array_equal(np.concatenate([p.codes for p in parts]), b.codes)
    np.testing.assert_array_equal(np.concatenate([p.theta for p in parts]), b.theta)
    c = sa.AmdmScannerDevice(RUN, seed=6).step(1000)
    assert not np.array_equal(c.codes, b.codes)


def test_drive_waveform_unipolar_and_sweep():
    p = sa.resolve_amdm(dict(RUN, drive_voltage_max=60.0))
    t = np.arange(0, 0.04, 1e-7)
    v, dv = sa.drive_voltage(t, p)
    assert v.min() >= 0.0 and v.max() == pytest.approx(60.0, abs=1e-3)
    _, f = sa.drive_phase(np.array([0.0, 0.015, 0.035]), p)
    np.testing.assert_allclose(f, [31.32e3, 31.295e3, 31.27e3])
    # derivative consistent with the waveform
    np.testing.assert_allclose(np.gradient(v, t)[10:-10], dv[10:-10], atol=60 * 2e5 * 1e-3)


def test_far_from_resonance_no_motion():
    fr = sa.AmdmScannerDevice(
        dict(RUN, sweep_start_hz=25e3, sweep_end_hz=25e3, initial_angle=0.05), seed=2
    ).step(30000)
    assert np.max(np.abs(fr.theta[-5000:])) < 1e-3
    assert np.var(fr.y[-5000:]) < 1.5 * 1.92e-4  # only noise left at the output

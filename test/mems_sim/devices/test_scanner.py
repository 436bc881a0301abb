"""Chapter-4 micro-scanner core: capacitance (105), mechanics (66)-(67), readout (64)."""

import math

import numpy as np
import pytest

from mems_sim.devices.scanner import (
    REST_ANGLE,
    MicroScannerDevice,
    ScannerParams,
    capacitance,
    d2cap_dtheta2,
    dc_transimpedance_output,
    dcap_dtheta,
    drive_waveform,
    psd_reference,
    resolve_scanner,
    scanner_params,
    simulate_mechanics,
)
from mems_sim.params import ParameterError


@pytest.fixture(scope="module")
def run():
    dev = MicroScannerDevice(seed=3)
    return dev, dev.step(dev.total_samples)


def test_capacitance_peak_and_derivatives():
    p = scanner_params()
    th = np.linspace(-0.3, 0.3, 60001)
    c = capacitance(th, p)
    assert th[np.argmax(c)] == pytest.approx(0.0037, abs=2e-5)
    assert c.max() == pytest.approx(p.sense_c0 + p.sense_cb, rel=1e-9)
    h = 1e-7
    num = (capacitance(th + h, p) - capacitance(th - h, p)) / (2 * h)
    np.testing.assert_allclose(dcap_dtheta(th, p), num, atol=1e-6 * np.abs(num).max())
    num2 = (dcap_dtheta(th + h, p) - dcap_dtheta(th - h, p)) / (2 * h)
    np.testing.assert_allclose(d2cap_dtheta2(th, p), num2, atol=1e-6 * np.abs(num2).max())
    with pytest.raises(ValueError):
        capacitance(0.0, p, "other")


def test_free_decay_matches_wn_and_zeta():
    p = scanner_params()
    fs = 500e3
    th, om = simulate_mechanics(np.zeros(int(0.05 * fs)), fs, p, theta0=0.1)
    # peaks of theta: log decrement -> zeta, spacing -> damped frequency
    pk = np.where((th[1:-1] > th[:-2]) & (th[1:-1] >= th[2:]))[0] + 1
    period = np.diff(pk).mean() / fs
    wd = 2 * math.pi * 624.6 * math.sqrt(1 - 0.0066**2)
    assert 2 * math.pi / period == pytest.approx(wd, rel=2e-3)
    n = len(pk) - 1
    delta = math.log(th[pk[0]] / th[pk[-1]]) / n
    assert delta / math.sqrt(4 * math.pi**2 + delta**2) == pytest.approx(0.0066, rel=0.02)


def test_a_free_ring_down_comes_to_rest_at_zero_without_subnormal_floats():
    """Without drive or noise the mirror decays through every power of ten; the RK4 step
    sets it to exactly 0 below REST_ANGLE instead of entering the subnormal floats (10-100x
    slower arithmetic), and not before: the last motion is within a few decades of it."""
    p = scanner_params()
    p = p._replace(b=p.b * 100)  # zeta ~0.66: 666 time constants in ~0.26 s
    fs = 50e3
    th, om = simulate_mechanics(np.zeros(int(0.4 * fs)), fs, p, theta0=0.1)
    tiny = np.finfo(float).tiny
    for x in (th, om):
        assert np.all((x == 0.0) | (np.abs(x) >= tiny))
    moving = np.flatnonzero(th != 0.0)
    rest = moving[-1] + 1
    assert rest < len(th) - 1000 and np.all(th[rest:] == 0.0) and np.all(om[rest:] == 0.0)
    last = np.abs(th[rest - int(fs / 624.6) : rest]).max()  # over the last period
    assert 1e-300 < last < 1e-280, last
    assert 1e-300 < REST_ANGLE < 1e-280


def test_parametric_resonance_reaches_table_4_2_amplitude(run):
    dev, f = run
    hold = f.theta[dev.plan.sweep_end : dev.plan.cutoff]
    amp = np.abs(hold[-int(0.004 * dev.fs) :]).max()
    assert 0.12 < amp < 0.2  # Table 4.2: 0.15 rad
    # motion at half the drive frequency (625 Hz) during the hold
    seg = hold[-int(0.02 * dev.fs) :]
    zc = np.where(np.diff(np.sign(seg - seg.mean())) > 0)[0]
    assert dev.fs / np.diff(zc).mean() == pytest.approx(625.0, rel=5e-3)
    # ring-down after cut-off: no drive, amplitude decays by > 5x within 100 ms
    rd = f.theta[dev.plan.cutoff :]
    assert np.all(f.drive[dev.plan.cutoff :] == 0)
    assert np.abs(rd[-2000:]).max() < np.abs(rd[:2000]).max() / 5


def test_far_from_resonance_no_motion():
    dev = MicroScannerDevice(seed=1, drive_frequency_hz=3000.0)
    f = dev.step(int(0.1 * dev.fs))
    assert np.abs(f.theta).max() < 2e-3  # only the static/forced offset, no resonance
    assert np.mean(f.y_clean**2) / 0.0435**2 < 0.01


def test_readout_and_psd_delay(run):
    dev, f = run
    p = dev.params
    y = -10e6 * 10.0 * dcap_dtheta(f.theta, p) * f.omega
    np.testing.assert_allclose(f.y_clean, y, rtol=1e-12, atol=1e-15)
    noise = f.y - f.y_clean
    assert np.std(noise) == pytest.approx(0.0435, rel=0.02)
    d = dev.psd_delay_samples
    assert d == 57
    np.testing.assert_array_equal(f.psd[d:], f.theta[:-d])
    np.testing.assert_array_equal(psd_reference(f.theta, dev.fs, 0.0), f.theta)
    np.testing.assert_allclose(dc_transimpedance_output(f.theta, f.omega, p), y)


def test_frames_concatenate_bit_identically(run):
    dev, f = run
    d2 = MicroScannerDevice(seed=3)
    parts = [d2.step(n) for n in (1000, 7, 5000, dev.total_samples - 6007)]
    for name in ("theta", "y", "psd", "drive"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(q, name) for q in parts]), getattr(f, name)
        )


def test_invalid_parameters_refused():
    with pytest.raises(ParameterError, match="damping_ratio"):
        resolve_scanner({"damping_ratio": -0.1})
    with pytest.raises(ParameterError, match="noise_std"):
        MicroScannerDevice({"noise_std": float("nan")})
    with pytest.raises(ParameterError, match="sweep_start_hz"):
        resolve_scanner({"sample_rate_hz": 2000.0})
    with pytest.raises(ParameterError, match="unknown parameter"):
        resolve_scanner({"bogus": 1.0})
    with pytest.raises(ParameterError, match="J"):
        ScannerParams.from_physical(J=0.0, k=1.0, b=0.0, theta_th=0.0, c0=1e-12, theta0=0.2, cb=0.0)
    with pytest.raises(ValueError):
        simulate_mechanics(np.array([0.0, np.inf]), 500e3, scanner_params())


def test_drive_waveform_unipolar_sweep():
    plan = drive_waveform(500e3, 60.0, 1600.0, 1250.0, 0.01, 0.005, 0.002)
    assert plan.voltage.min() >= 0 and plan.voltage.max() <= 60.0 + 1e-12
    assert plan.frequency[0] == 1600.0 and plan.frequency[plan.sweep_end] == 1250.0
    assert np.all(plan.voltage[plan.cutoff :] == 0)

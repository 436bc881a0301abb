"""EKF / UKF of the shared-electrode scanner (Chen 2018 ch. 5, Algorithms 1-2), phase/amplitude."""

import math

import numpy as np
import pytest

from mems_estimation.filters import scanner_amdm_tracking as su
from mems_estimation.filters import scanner_amdm_ukf as sau
from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import ParameterError

RUN = dict(drive_voltage_max=150.0, sweep_start_hz=31.32e3, sweep_end_hz=31.27e3, sweep_time_s=0.03)
FS = 1.0e6
T_EVAL = 0.03  # after acquisition and the growth of the motion [s]


@pytest.fixture(scope="module")
def device_run():
    dev = sa.AmdmScannerDevice(RUN, seed=11)
    return dev, dev.step(50000)


def run_filter(kind, y, drive, delay, frame=1000, **kw):
    f = su.ScannerFilter(kind, dict(chain_delay_s=delay, **kw))
    al = su.DriveAligner(delay * FS, f.model.vc2)
    tk = su.PhaseAmplitudeTracker(f.p["min_amplitude"], FS, delay)
    outs, evs = [], []
    for i in range(0, y.size, frame):
        o = f.step(y[i : i + frame], al.push(i, drive[i : i + frame]))
        tk.push_drive(i, drive[i : i + frame])
        evs.append(tk.push_theta(i, o["x"][:, 0], o["p"][:, 0], o["p"][:, 1]))
        outs.append(o)
    cat = {k: np.concatenate([o[k] for o in outs]) for k in ("x", "p", "nis")}
    return f, cat, su.concat_events(evs)


def truth_events(fr):
    tk = su.PhaseAmplitudeTracker(0.03, FS)
    tk.push_drive(0, fr.drive)
    return tk.push_theta(0, fr.theta)


def test_unscented_weights_reproduce_mean_and_covariance():
    wm, wc, g = sau.ukf_weights(2, 1.0, 2.0, 1.0)
    assert wm.sum() == pytest.approx(1.0)
    x = np.array([0.1, -3e3])
    P = np.array([[4e-4, 0.3], [0.3, 1e4]])
    from mems_estimation.filters.scanner_amdm_ukf import _sigma

    S = np.empty((5, 2))
    assert _sigma(x, P, g, S)
    np.testing.assert_allclose(wm @ S, x)
    d = S - x
    np.testing.assert_allclose(
        (wc[:, None, None] * d[:, :, None] * d[:, None, :]).sum(0), P, rtol=1e-12
    )
    assert not _sigma(x, np.array([[1.0, 2.0], [2.0, 1.0]]), g, S)  # not PD: refused


def test_invalid_parameters_refused():
    with pytest.raises(ParameterError, match="sample_rate_hz"):
        su.ScannerFilter("ukf", dict(sample_rate_hz=5e4))
    with pytest.raises(ParameterError, match="output_noise_var"):
        su.ScannerFilter("ekf", dict(output_noise_var=0.0))
    with pytest.raises(ParameterError, match="kind"):
        su.ScannerFilter("pf")
    with pytest.raises(ParameterError, match="initial_angle_std"):
        su.ScannerFilter("ukf", dict(initial_angle_std=0.05))  # sigma points straddle 0
    with pytest.raises(ParameterError, match="cap_c0"):
        su.ScannerFilter("ukf", dict(cap_c0=-1.0))


def test_phase_amplitude_extraction_exact_on_sinusoids():
    t = np.arange(200000) / 10e6
    fm, ph0, A = 15.6e3, 0.7, 0.12
    theta = A * np.sin(2 * math.pi * fm * t + ph0)
    drive = 75 * (1 - np.cos(2 * math.pi * 2 * fm * t))
    # drive peaks at 2 pi 2 fm t = pi (mod 2 pi); theta extrema at 2 pi fm t + ph0 = pi/2 (mod pi)
    expect = ((math.pi / 2 - ph0) - math.pi / 2) % math.pi
    for sign in (1, -1):
        tk = su.PhaseAmplitudeTracker(0.03, 10e6)
        evs = []
        for i in range(0, t.size, 777):
            tk.push_drive(i, drive[i : i + 777])
            evs.append(tk.push_theta(i, sign * theta[i : i + 777]))
        ev = su.concat_events(evs)
        assert ev.t.size > 40
        err = np.mod(ev.phase - expect + math.pi / 2, math.pi) - math.pi / 2
        assert np.max(np.abs(err)) < math.radians(0.01)
        np.testing.assert_allclose(ev.amplitude, A, rtol=1e-4)


def test_filters_consistent_on_the_exact_measurement_model(device_run):
    """y = h(theta) + v exactly (no chain): both filters unbiased and consistent (NIS ~ 1)."""
    dev, fr = device_run
    rng = np.random.default_rng(3)
    y = sa.measurement_model(fr.theta, dev.p) + rng.standard_normal(fr.theta.size) * math.sqrt(
        1.92e-4
    )
    ref = truth_events(fr)
    for kind in ("ekf", "ukf"):
        f, out, ev = run_filter(kind, y, fr.drive, 0.0)
        rp, ra, n = su.event_rmse(ev, ref, 8e-6, T_EVAL)
        assert n > 500
        assert math.degrees(rp) < 0.05 and math.degrees(ra) < 0.01
        sel = slice(int(T_EVAL * FS), None)
        assert 0.9 < np.mean(out["nis"][sel]) < 1.1
        assert f.pd_failures == 0
        # theta error against the sign-aligned truth, normalised by the filter's variance
        th = out["x"][sel, 0]
        s = np.sign(np.sum(th * fr.theta[sel]))
        nees = np.mean((th - s * fr.theta[sel]) ** 2 / out["p"][sel, 0])
        assert 0.5 < nees < 2.0


def test_full_amdm_chain_accuracy_and_health(device_run):
    dev, fr = device_run
    y = fr.codes * dev.lsb
    ref = truth_events(fr)
    res = {}
    for kind in ("ekf", "ukf"):
        f, out, ev = run_filter(kind, y, fr.drive, dev.delay)
        rp, ra, n = su.event_rmse(ev, ref, 8e-6, T_EVAL)
        det = out["p"][:, 0] * out["p"][:, 1] - out["p"][:, 2] ** 2
        assert f.pd_failures == 0 and np.all(det > 0) and np.all(out["p"][:, :2] > 0)
        assert np.max(out["p"][int(T_EVAL * FS) :, 0]) < 1e-4  # no blow-up after settling
        assert f.acquisitions == 1
        res[kind] = (math.degrees(rp), math.degrees(ra), n)
    print("\nphase / amplitude RMSE [deg]:", res)
    assert res["ukf"][0] <= 0.39  # Table 5.3 UKF
    assert res["ukf"][0] <= 0.18  # target of eq. (79)
    assert res["ukf"][1] <= 0.63


@pytest.mark.xfail(
    strict=True,
    reason=(
        "measured UKF = EKF to < 1 % (phase ~0.15 deg, amplitude ~0.05 deg on the full AMDM chain, "
        "seeded): with R = 1.92e-4 V^2 at 1 MHz the posterior std of theta is ~1e-4 rad, far "
        "below the 0.2 rad scale of the Gaussian C_s, so the EKF linearisation error is "
        "negligible; the paper's 5.04/1.82 vs 0.63/0.39 deg gap is not reproduced. The "
        "remaining error of both is the chain's model error (square law, filter dispersion)"
    ),
)
def test_ukf_beats_ekf_by_five_percent(device_run):
    dev, fr = device_run
    y = fr.codes * dev.lsb
    ref = truth_events(fr)
    r = {
        k: su.event_rmse(run_filter(k, y, fr.drive, dev.delay)[2], ref, 8e-6, T_EVAL)
        for k in ("ekf", "ukf")
    }
    assert r["ukf"][0] <= 0.95 * r["ekf"][0] and r["ukf"][1] <= 0.95 * r["ekf"][1]


def test_no_motion_gives_low_signal_not_divergence():
    dev = sa.AmdmScannerDevice(
        dict(RUN, sweep_start_hz=25e3, sweep_end_hz=25e3, initial_angle=0.0), seed=4
    )
    fr = dev.step(20000)
    y = fr.codes * dev.lsb
    for kind in ("ekf", "ukf"):
        f, out, ev = run_filter(kind, y, fr.drive, dev.delay)
        assert not f.tracking and f.acquisitions == 0
        assert ev.t.size == 0
        assert np.all(out["x"] == 0.0) and np.all(np.isfinite(out["p"]))
        assert f.last_snr < 1.0
        assert su.ac_snr(y, 1.92e-4) < 0.5


def test_motion_lost_returns_to_acquisition():
    dev = sa.AmdmScannerDevice(
        dict(RUN, sweep_start_hz=25e3, sweep_end_hz=25e3, initial_angle=0.1), seed=4
    )
    fr = dev.step(30000)
    f, out, ev = run_filter("ukf", fr.codes * dev.lsb, fr.drive, dev.delay)
    assert f.acquisitions == 1 and not f.tracking and f.pd_failures == 0
    assert ev.t.size > 10  # tracked the ring-down while observable

"""EKF / UKF of the shared-electrode scanner (Chen 2018 ch. 5, Algorithms 1-2), phase/amplitude,
consistency on the full AMDM chain (NEES, Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4), the
identified square-law curve of the chain, and acquisition from a wrong start."""

import math

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from mems_estimation.filters import scanner_amdm_model as sam
from mems_estimation.filters import scanner_amdm_tracking as su
from mems_estimation.filters import scanner_amdm_ukf as sau
from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import ParameterError

RUN = dict(drive_voltage_max=150.0, sweep_start_hz=31.32e3, sweep_end_hz=31.27e3, sweep_time_s=0.03)
FS = 1.0e6
T_EVAL = 0.03  # after acquisition and the growth of the motion [s]
#: Table 5.2's Q_a = 1e11 rad^2/s^4 per 1 us step as torque held per 0.1 us sample: J sqrt(Q_a 10)
TORQUE_STD = 1.15e-14 * math.sqrt(1.0e11 * 10)


@pytest.fixture(scope="module")
def device_run():
    dev = sa.AmdmScannerDevice(dict(RUN, torque_noise_std=TORQUE_STD), seed=11)
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


def delayed_truth(fr, delay):
    """theta and omega at the instants the AMDM samples describe (t_k - delay)."""
    t = np.arange(fr.theta.size) / FS
    tq = np.maximum(t - delay, 0.0)
    return CubicSpline(t, fr.theta)(tq), CubicSpline(t, fr.omega)(tq)


def nees_theta(out, theta_ref, k0):
    """Mean NEES of theta against the sign-aligned reference from sample k0."""
    th = out["x"][k0:, 0]
    ref = theta_ref[k0:]
    s = np.sign(np.sum(th * ref)) or 1.0
    return float(np.mean((th - s * ref) ** 2 / out["p"][k0:, 0]))


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
    """y = h(theta) + v exactly (eq. (104), no chain; the filters' chain curve and their
    process-noise inflation switched off: the noise is exactly what they assume): both
    filters unbiased and consistent (NIS ~ 1, NEES ~ 1)."""
    dev, fr = device_run
    rng = np.random.default_rng(3)
    y = sa.measurement_model(fr.theta, dev.p) + rng.standard_normal(fr.theta.size) * math.sqrt(
        1.92e-4
    )
    ref = truth_events(fr)
    for kind in ("ekf", "ukf"):
        f, out, ev = run_filter(
            kind,
            y,
            fr.drive,
            0.0,
            chain_square_gain=0.0,
            chain_offset=0.0,
            process_noise_inflation=1.0,
        )
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


@pytest.fixture(scope="module")
def chain_runs(device_run):
    """Both filters on the full AMDM chain (ADC codes): kind -> (filter, outputs, events)."""
    dev, fr = device_run
    y = fr.codes * dev.lsb
    return {k: run_filter(k, y, fr.drive, dev.delay) for k in ("ekf", "ukf")}


def test_full_amdm_chain_accuracy_consistency_and_health(device_run, chain_runs):
    """Phase <= 0.18 deg (eq. (79)), amplitude <= 0.63 deg (Table 5.3), NEES of theta 0.5-2
    for both filters with the identified chain curve in h."""
    dev, fr = device_run
    ref = truth_events(fr)
    th_ref, _ = delayed_truth(fr, dev.delay)
    res = {}
    for kind, (f, out, ev) in chain_runs.items():
        rp, ra, n = su.event_rmse(ev, ref, 8e-6, T_EVAL)
        det = out["p"][:, 0] * out["p"][:, 1] - out["p"][:, 2] ** 2
        assert f.pd_failures == 0 and np.all(det > 0) and np.all(out["p"][:, :2] > 0)
        assert np.max(out["p"][int(T_EVAL * FS) :, 0]) < 1e-4  # no blow-up after settling
        assert f.acquisitions == 1
        res[kind] = (
            math.degrees(rp),
            math.degrees(ra),
            n,
            nees_theta(out, th_ref, int(T_EVAL * FS)),
        )
    print("\nphase / amplitude RMSE [deg], pairs, NEES:", res)
    for kind, (ph, am, n, nees) in res.items():
        assert n > 500
        assert ph <= 0.18 and am <= 0.63, kind
        assert 0.5 <= nees <= 2.0, kind


def test_eq_104_alone_leaves_the_filters_overconfident(device_run):
    """The cause of the inconsistency, measured: with the thesis's tangent (eq. (104)) as h,
    the chain's square-law curve (eq. (100)) offsets y by ~-5 mV, which biases the phase by
    ~-0.12 deg and makes the NEES ~70; the identified curve removes it."""
    dev, fr = device_run
    y = fr.codes * dev.lsb
    th_ref, _ = delayed_truth(fr, dev.delay)
    f, out, ev = run_filter("ekf", y, fr.drive, dev.delay, chain_square_gain=0.0, chain_offset=0.0)
    t, dph, _ = su.match_events(ev, truth_events(fr), 8e-6)
    assert nees_theta(out, th_ref, int(T_EVAL * FS)) > 20.0
    assert math.degrees(np.mean(dph[t >= T_EVAL])) < -0.08


def test_ukf_and_ekf_agree_within_one_percent(device_run, chain_runs):
    """Restated criterion: UKF/EKF RMSE ratio within +-1 % (the thesis's Table 5.3 has the UKF
    3-8x better).  Measured (seeds 1-10, full AMDM chain): the ratio is 1.0002 on amplitude
    and 1.0000 on phase.  At R = 1.92e-4 V^2 and 1 MHz the posterior std of theta is
    ~8e-5 rad, tiny against the 0.2 rad scale of the Gaussian C_s, so the unscented transform
    (Julier & Uhlmann 2004) and the EKF's linearisation see the same h; the thesis's 5 deg gap
    is not a linearisation effect.  With the angle 0.1 rad wrong at the start the two differ
    during acquisition only (:func:`test_acquisition_from_a_wrong_angle`)."""
    dev, fr = device_run
    ref = truth_events(fr)
    r = {k: su.event_rmse(ev, ref, 8e-6, T_EVAL) for k, (_, _, ev) in chain_runs.items()}
    for i in (0, 1):  # phase, amplitude
        assert abs(r["ukf"][i] / r["ekf"][i] - 1.0) <= 0.01


def test_identified_chain_curve_reproduces_the_defaults():
    """The defaults of chain_square_gain, chain_tangent_capacitance and chain_offset come from
    this calibration (tuning noise seeds 1001-1003; the scenario is evaluated on another drive
    and other seeds)."""
    ths, ys = [], []
    for seed in (1001, 1002, 1003):
        dev = sa.AmdmScannerDevice(RUN, seed=seed)
        fr = dev.step(50000)
        th, _ = delayed_truth(fr, dev.delay)
        ths.append(th[10000:])
        ys.append((fr.codes * dev.lsb)[10000:])
    p = sam.resolve_estimator()
    c = sam.identify_chain_curve(np.concatenate(ths), np.concatenate(ys), p)
    assert c["chain_square_gain"] == pytest.approx(p["chain_square_gain"], rel=1e-3)
    assert c["chain_tangent_capacitance"] == pytest.approx(p["chain_tangent_capacitance"], rel=1e-3)
    assert c["chain_offset"] == pytest.approx(p["chain_offset"], rel=1e-3)
    assert c["residual_rms"] < 1.2 * math.sqrt(1.92e-4 + 0.008**2)  # noise + carrier residue


def test_identify_chain_curve_exact_on_a_quadratic():
    p = sam.resolve_estimator()
    th = np.linspace(-0.15, 0.15, 2001)
    cs = p["cap_c0"] * np.exp(-((th / p["cap_theta0"]) ** 2)) + p["cap_cb"]
    y = p["circuit_gain"] * cs + p["circuit_bias"] + 1e-3 - 7e21 * (cs - 14.0e-12) ** 2
    c = sam.identify_chain_curve(th, y, p)
    assert c["chain_square_gain"] == pytest.approx(-7e21, rel=1e-6)
    assert c["chain_tangent_capacitance"] == pytest.approx(14.0e-12, rel=1e-6)
    assert c["chain_offset"] == pytest.approx(1e-3, rel=1e-5)
    np.testing.assert_allclose(sam.filter_measurement(th, dict(p, **c)), y, atol=1e-12)
    meas = sam.scanner_model(p).meas  # the kernels' h is the same function
    for x in (-0.12, 0.0, 0.07):
        assert sam._h(x, meas) == pytest.approx(float(sam.filter_measurement(x, p)), abs=1e-12)
    with pytest.raises(ValueError, match="curvature"):
        sam.identify_chain_curve(np.full(10, 0.1), np.ones(10), p)
    with pytest.raises(ValueError, match="equal"):
        sam.identify_chain_curve(th, y[:-1], p)


def test_time_to_acquire():
    assert su.time_to_acquire(np.array([5.0, 3.0, 0.5, 2.0, 0.1, 0.1]), 1.0, 1e6) == 4e-6
    assert su.time_to_acquire(np.array([0.1, 0.2]), 1.0, 1e6) == 0.0
    assert math.isnan(su.time_to_acquire(np.array([0.1, 2.0]), 1.0, 1e6))
    with pytest.raises(ParameterError, match="positive definite"):
        su.ScannerFilter("ekf").start((0.1, 0.0), np.eye(2) * -1.0)


def test_acquisition_from_a_wrong_angle(device_run):
    """Started 0.05 rad (0.25 theta_0) and 0.1 rad off, at two phases, too large and too small:
    both filters acquire (error < 1 mrad to the end) within a few motion periods (64 us)."""
    dev, fr = device_run
    y = fr.codes * dev.lsb
    th_ref, om_ref = delayed_truth(fr, dev.delay)
    par = dict(chain_delay_s=dev.delay)
    v2 = su.DriveAligner(dev.delay * FS, su.ScannerFilter("ekf", par).model.vc2).push(0, fr.drive)
    for dth in (0.05, 0.1):
        for kind in ("ekf", "ukf"):
            a = su.acquisition_study(
                kind, par, y, v2, th_ref, om_ref, [40000, 40016], dth, 2000, 1e-3
            )
            assert a.time.size == 4 and np.all(np.isfinite(a.time)), (dth, kind, a)
            assert np.max(a.time) < 3e-4 and np.all(a.final_rmse < 2e-4), (dth, kind, a)


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

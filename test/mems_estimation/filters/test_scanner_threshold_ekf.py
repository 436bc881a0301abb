"""Threshold detector (DOG + NMS, causal) and the hybrid EKF of Table 4.1 (chapter 4)."""

import numpy as np
import pytest
from scipy import stats

from mems_estimation.filters.scanner_threshold_detector import (
    Detections,
    OnlineThresholdDetector,
    detect_offline,
)
from mems_estimation.filters.scanner_threshold_ekf import (
    StreamingScannerEkf,
    model_from_device,
    run_ekf,
    signal_snr,
)
from mems_estimation.studies.scanner_threshold import (
    DRIFTED_SENSOR,
    EVALUATION_SEEDS,
    TUNING_SEEDS,
    detection_errors,
    grid_trial,
    threshold_trial,
)
from mems_sim.devices.scanner import MicroScannerDevice, resolve_scanner
from mems_sim.params import ParameterError

SEEDS = (1, 2, 3)
SIGMA = 45.0  # sigma_DOG used by the hybrid (Sec. 4.6.1: large sigma_DOG is better)


@pytest.fixture(scope="module")
def trials():
    return [threshold_trial(s, detector_overrides={"dog_sigma": SIGMA}) for s in SEEDS]


@pytest.fixture(scope="module")
def record():
    dev = MicroScannerDevice(DRIFTED_SENSOR, seed=11)
    return dev, dev.step(dev.total_samples)


def test_online_detector_matches_offline_within_one_sample(record):
    dev, f = record
    det = OnlineThresholdDetector()
    parts = [det.process(f.y[a : a + 777]) for a in range(0, f.y.size, 777)]
    on = Detections.concat(parts)
    off, _ = detect_offline(f.y)
    assert det.latency == 300
    assert len(on.index) > 300
    np.testing.assert_array_equal(on.arrival - on.index, det.latency)
    assert len(on.index) == len(off.index)
    assert np.abs(on.index - off.index).max() <= 1
    det2 = OnlineThresholdDetector()  # long frames: FFT path
    on2 = Detections.concat([det2.process(f.y[a : a + 5000]) for a in range(0, f.y.size, 5000)])
    assert len(on2.index) == len(off.index) and np.abs(on2.index - off.index).max() <= 1


def test_detector_is_causal(record):
    dev, f = record
    k = 160_000
    d1 = OnlineThresholdDetector()
    a = d1.process(f.y[:k])
    y2 = f.y.copy()
    y2[k:] = 10 * np.random.default_rng(0).standard_normal(y2.size - k)
    d2 = OnlineThresholdDetector()
    b = d2.process(y2)
    keep = b.arrival < k
    np.testing.assert_array_equal(a.index, b.index[keep])


def test_detection_errors_normal_and_sigma_dog(record):
    dev, f = record
    from mems_estimation.studies.scanner_threshold import snr_segments

    segs = snr_segments(f.y_clean, 0.0435, dev.plan.cutoff, dev.fs)
    var = {}
    for sig in (15.0, SIGMA):
        D, _ = detect_offline(f.y, dog_sigma=sig)
        e, et = detection_errors(f.theta, D, 0.0037)
        for lo, hi, snr in segs:
            m = (D.index >= lo) & (D.index < hi) & (np.abs(et) < 50)
            ee = e[m]
            var[sig, round(snr)] = ee.var() if ee.size > 2 else np.inf
            if ee.size >= 8:  # Kolmogorov-Smirnov against N(mean, var) (Sec. 4.6.1)
                p = stats.kstest((ee - ee.mean()) / ee.std(), "norm").pvalue
                assert p > 0.05, (sig, snr, p)
    low = [s for (_, s) in var if s <= 6]
    assert low
    for s in low:  # at low SNR a larger sigma_DOG lowers the detection-error variance
        assert var[SIGMA, s] < var[15.0, s]


def test_hybrid_beats_plain_in_every_snr_segment(trials):
    seg_plain = np.zeros(4)
    seg_hyb = np.zeros(4)
    tot_p = tot_h = 0.0
    for t in trials:
        th = t.record.theta
        snrs = [s for (_, _, s) in t.segments]
        assert 60 < snrs[0] < 120 and 15 < snrs[1] < 35 and 3 < snrs[2] < 8 and 0.5 < snrs[3] < 2
        for i, (lo, hi, _) in enumerate(t.segments):
            seg_plain[i] += np.sum((t.plain.theta[lo:hi] - th[lo:hi]) ** 2)
            seg_hyb[i] += np.sum((t.hybrid.theta[lo:hi] - th[lo:hi]) ** 2)
        lo, hi = t.segments[0][0], t.segments[-1][1]
        tot_p += np.sum((t.plain.theta[lo:hi] - th[lo:hi]) ** 2)
        tot_h += np.sum((t.hybrid.theta[lo:hi] - th[lo:hi]) ** 2)
        assert t.hybrid.applied > 300
    assert np.all(seg_hyb < seg_plain), (seg_hyb, seg_plain)
    assert 1 - np.sqrt(tot_h / tot_p) >= 0.10


def test_restated_hybrid_vs_full_jacobian_on_drift_corner_and_nominal():
    """Restated Table 4.3 criterion (one evaluation seed, nominal comb and one drift corner):
    the redesigned hybrid (comb gain/width estimated with the state, peak-slope angle with
    its correction as variance) against the full-Jacobian EKF; the full grid is in
    test/acceptance/test_scanner_threshold_grid.py."""
    seed = EVALUATION_SEEDS[0]
    assert seed not in TUNING_SEEDS
    nom = grid_trial(seed, 0.0, 0.0)
    assert nom["hyb"][-1] <= 1.05 * nom["base"][-1]  # never > 5 % worse on the nominal comb
    cor = grid_trial(seed, 0.2, -0.1)
    assert 1 - cor["hyb"][-1] / cor["base"][-1] >= 0.10
    for i in (2, 3):  # SNR ~5 and ~1
        assert 1 - cor["hyb"][i] / cor["base"][i] >= 0.10
    # the PCRB of the device is far below any of these filters (reported, not reached)
    assert all(b < h for b, h in zip(cor["pcrb"], cor["hyb"]))


def test_filters_consistent(trials):
    for t in trials:
        for r in (t.plain, t.hybrid):
            assert np.all(np.isfinite(r.theta)) and np.all(np.isfinite(r.P))
            assert r.min_det > 0
            assert np.all(r.P[:, 0] > 0) and np.all(r.P[:, 2] > 0)
            assert np.all(r.P[:, 0] * r.P[:, 2] - r.P[:, 1] ** 2 > 0)
            assert r.max_p_theta <= 0.2**2 + 1e-12  # never above the prior: no blow-up
            # the error stays bounded in the ring-down (no divergence).  Note: with the
            # drifted analog map the filter is overconfident (|err|/sqrt(P) up to ~60 at the
            # amplitude peaks, reported by the scenario), but it never diverges.
            lo = t.segments[0][0]
            assert np.abs(r.theta[lo:] - t.record.theta[lo:]).max() < 0.02


def test_late_detections_equal_immediate_application(record):
    """Re-propagation at arrival == applying the detection at its sample in one pass."""
    dev, f = record
    n = 200_000
    det = OnlineThresholdDetector()
    D = Detections.concat([det.process(f.y[a : a + 1000]) for a in range(0, n, 1000)])
    P = model_from_device(resolve_scanner({}))
    late = run_ekf(f.y[:n], f.drive[:n], P, detections=D, frame=1000)
    now = Detections(D.index, D.index.copy(), D.delta, D.response, D.timing_var)
    imm = run_ekf(f.y[:n], f.drive[:n], P, detections=now, frame=1000)
    assert late.applied == imm.applied > 100
    np.testing.assert_allclose(late.theta, imm.theta, rtol=0, atol=1e-12)
    # real-time estimates differ (the correction comes late) but final ones do not
    assert np.abs(late.theta_rt - imm.theta_rt).max() > 0
    one = run_ekf(f.y[:n], f.drive[:n], P, detections=D, frame=n)
    np.testing.assert_allclose(one.theta, late.theta, rtol=0, atol=1e-12)


def test_far_from_resonance_low_signal_no_divergence():
    dev = MicroScannerDevice(seed=4, drive_frequency_hz=3000.0)
    f = dev.step(int(0.1 * dev.fs))
    assert signal_snr(f.y, 0.0435) < 0.05
    det = OnlineThresholdDetector()
    D = det.process(f.y)
    assert len(D.index) <= 2
    r = run_ekf(f.y, f.drive, model_from_device(resolve_scanner({})), detections=D)
    assert np.all(np.isfinite(r.theta)) and r.min_det > 0
    assert np.abs(r.theta[-5000:]).max() < 0.02
    assert r.max_p_theta <= 0.2**2 + 1e-12


def test_invalid_parameters_refused():
    with pytest.raises(ParameterError, match="dog_width"):
        OnlineThresholdDetector(dog_sigma=100.0, dog_width=400)
    with pytest.raises(ParameterError, match="r_cap"):
        StreamingScannerEkf({"r_cap": -1.0})
    with pytest.raises(ParameterError, match="jacobian"):
        StreamingScannerEkf({"jacobian": "other"})
    with pytest.raises(ParameterError, match="model_natural_freq_hz"):
        StreamingScannerEkf({"model_natural_freq_hz": 3.0e5})
    with pytest.raises(ValueError):
        StreamingScannerEkf().process(np.zeros(3), np.zeros(4))

"""The windowed NIS monitor on a real (steady-state) Kalman filter: false-alarm rates at two
designed rates a decade apart, detection of a 5-sigma bias step, empirical thresholds for
non-Gaussian innovations, the same windows at any block size."""

import math

import numpy as np
import pytest
from scipy import signal

from mems_estimation.filters.consistency_monitor import NisMonitor, nis_moments, window_sums

FS = 100.0
Q, R = 1e-4, 1.0  # random-walk increment and measurement variances per sample


def steady_state():
    """Steady-state prior variance P, gain K and innovation variance S of the scalar random
    walk x(k+1) = x(k) + w, y = x + v (Riccati: P = P - P^2/(P + R) + Q)."""
    p = (Q + math.sqrt(Q * Q + 4 * Q * R)) / 2
    return p, p / (p + R), p + R


def nis_of(y: np.ndarray) -> np.ndarray:
    """NIS nu^2 / S of the steady-state filter x_pred(k+1) = (1 - K) x_pred(k) + K y(k)."""
    _, k, s = steady_state()
    pred = signal.lfilter([0.0, k], [1.0, -(1.0 - k)], y)
    return (y - pred) ** 2 / s


def measurements(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0, math.sqrt(Q), n)) + rng.normal(0, math.sqrt(R), n)


@pytest.mark.parametrize("alpha", [1e-2, 1e-3])
def test_false_alarm_rate_within_half_and_twice_the_designed(alpha):
    """Fault-free data long enough for >= 30 expected alarms: measured rate in [0.5, 2]x."""
    window = 20
    windows = int(40 / alpha)
    y = measurements(window * windows + 2000, seed=int(1 / alpha))
    nis = nis_of(y)[2000:]  # past the filter's start from 0
    mon = NisMonitor(window, alpha)
    verdicts = mon.update(nis)
    alarms = sum(v.level >= 1 for v in verdicts)
    expected = alpha * len(verdicts)
    assert expected >= 30 and 0.5 <= alarms / expected <= 2.0, (alarms, expected)
    low = sum(v.low for v in verdicts)
    assert 0.5 <= low / expected <= 2.0
    assert mon.designed_rate_per_hour(FS) == pytest.approx(alpha * FS / window * 3600)


def test_a_five_sigma_bias_step_is_detected_within_a_second():
    """A step of 5 sqrt(S) in y at a random onset: the window holding the onset or the next
    (<= 1 s at 100 Hz with windows of 50 samples) raises WARN in >= 95 % of 200 trials."""
    _, _, s = steady_state()
    window, hits = 50, 0
    rng = np.random.default_rng(5)
    for trial in range(200):
        y = measurements(6000, seed=1000 + trial)
        onset = 4000 + int(rng.integers(0, window))
        y[onset:] += 5 * math.sqrt(s)
        verdicts = NisMonitor(window, 1e-3).update(nis_of(y)[2000:])
        first = (onset - 2000) // window
        hits += any(v.level >= 1 for v in verdicts[first : first + 2])
    assert hits >= 190, hits


def test_empirical_thresholds_for_non_gaussian_innovations():
    """Uniform 'innovations' (a one-bit loop's are not Gaussian either): thresholds from
    training windows give the designed rate on other data; the chi-square ones do not."""
    window, alpha = 10, 1e-2
    rng = np.random.default_rng(2)
    train = rng.uniform(-1.8, 1.8, 10 * window * 10_000) ** 2
    test = rng.uniform(-1.8, 1.8, window * 20_000) ** 2
    mon = NisMonitor.from_training(train, window, alpha, error_factor=10.0)
    verdicts = mon.update(test)
    rate = sum(v.level >= 1 for v in verdicts) / len(verdicts)
    assert 0.5 <= rate / alpha <= 2.0
    chi2 = NisMonitor(window, alpha).update(test)
    assert sum(v.level >= 1 for v in chi2) / len(chi2) < 0.5 * alpha  # uniform: lighter tails
    with pytest.raises(ValueError, match="training windows"):
        NisMonitor.from_training(train[:1000], window, alpha)


def test_same_windows_at_any_block_size_and_non_finite_is_error():
    nis = nis_of(measurements(10_007, seed=3))
    whole = NisMonitor(64, 1e-2).update(nis)
    m = NisMonitor(64, 1e-2)
    parts = [v for k in range(0, nis.size, 333) for v in m.update(nis[k : k + 333])]
    assert parts == whole and len(whole) == 10_007 // 64
    assert [v.statistic for v in whole] == window_sums(nis, 64).tolist()
    bad = nis.copy()
    bad[100] = np.nan
    assert NisMonitor(64, 1e-2).update(bad)[1].verdict == "ERROR"
    for args in ((0, 0.1), (10, 0.0), (10, 0.6), (10, 0.1, 0)):
        with pytest.raises(ValueError):
            NisMonitor(*args)


def test_moment_matched_thresholds_for_correlated_non_gaussian_innovations():
    """Correlated bounded 'innovations' (uniform through an MA(1)) of a variance 1.2 S, as a
    one-bit loop's:
    the scaled chi-square of the moments of training windows (nis_moments) gives the designed
    rate on other data within [0.5, 2]x; the chi-square thresholds do not. A scaled
    chi-square of twice the NIS (mean 2, dispersion 4) has twice the chi-square thresholds;
    moments 1 and 1 are the chi-square monitor itself."""
    window, alpha = 50, 1e-2

    def nis(n, seed):
        u = np.random.default_rng(seed).uniform(-1.0, 1.0, n + 1)
        e = u[1:] + 0.8 * u[:-1]
        return 1.2 * e**2 / np.mean(e**2)  # S understated by 20 %

    mu, d = nis_moments(nis(window * 20_000, 1), window)
    # exact: 1.2^2 (var NIS + 2 (W-1)/W cov lag 1) / 2 = 1.44 (1.37113 + 0.98 * 0.38074) / 2
    assert mu == pytest.approx(1.2, abs=1e-9) and d == pytest.approx(1.2558, abs=0.04)
    test = nis(window * 20_000, 2)
    verdicts = NisMonitor.moment_matched(window, alpha, mu, d).update(test)
    rate = sum(v.level >= 1 for v in verdicts) / len(verdicts)
    chi2 = NisMonitor(window, alpha).update(test)
    chi2_rate = sum(v.level >= 1 for v in chi2) / len(chi2)
    print(f"\nmoments {mu:.4f} {d:.4f}: rate {rate:.4f}, chi-square {chi2_rate:.4f}, alpha {alpha}")
    assert 0.5 <= rate / alpha <= 2.0
    assert chi2_rate > 4.0 * alpha  # the mean 1.2 W is one chi-square sd above W at W = 50
    m, twice = NisMonitor(window, alpha), NisMonitor.moment_matched(window, alpha, 2.0, 4.0)
    assert twice.thresholds == pytest.approx(tuple(2 * t for t in m.thresholds), rel=1e-12)
    assert twice.lower == pytest.approx(2 * m.lower, rel=1e-12)
    same = NisMonitor.moment_matched(window, alpha, 1.0, 1.0)
    assert (same.thresholds, same.lower) == (m.thresholds, m.lower)
    for bad in ((0.0, 1.0), (1.0, -1.0), (float("nan"), 1.0)):
        with pytest.raises(ValueError):
            NisMonitor.moment_matched(window, alpha, *bad)
    with pytest.raises(ValueError, match="training windows"):
        nis_moments(test[: window * 29], window)

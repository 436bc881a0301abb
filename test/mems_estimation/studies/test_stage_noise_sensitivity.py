"""Noise sensitivity of the in-situ SF calibration (Chen 2018 Fig. 3.16): the small
analytic pieces of the study."""

import math

import numpy as np
import pytest

from mems_estimation.filters.stage_ekf import FeedthroughCanceller
from mems_estimation.identification.stage_gyro_calibration import Plan, least_squares_eq27
from mems_estimation.studies.stage_noise_sensitivity import (
    cancelled_noise_variance,
    design_sf_ppm,
    eq27_rel_slope_std,
    noise_free_sweep,
    std_interval,
    true_model,
)


def test_eq27_slope_std_matches_monte_carlo():
    """Errors on the reference's peak-to-peak rates: the first-order propagation through
    eq. (27) equals sigma/sqrt(S) for equal errors and agrees with a Monte Carlo of the
    least squares within its sampling error."""
    x = np.linspace(48.0, 62.0, 7)
    k, b = 0.95, 0.3
    sigma = 0.02
    S = float(np.sum((x - x.mean()) ** 2))
    assert eq27_rel_slope_std(x, sigma) == pytest.approx(sigma / math.sqrt(S), rel=1e-12)
    rng = np.random.default_rng(5)
    n = 20000
    sig_i = sigma * (1.0 + 0.5 * np.arange(7) / 6)  # unequal errors
    xs = x + rng.standard_normal((n, 7)) * sig_i
    y = k * x + b
    dx = xs - xs.mean(axis=1, keepdims=True)
    slope = np.sum(dx * (y - y.mean()), axis=1) / np.sum(dx * dx, axis=1)
    # the vectorised slope is eq. (27)'s
    assert slope[0] == pytest.approx(least_squares_eq27(xs[0], y)["scale_factor"], rel=1e-12)
    mc = float(np.std(slope / k - 1.0, ddof=1))
    pred = eq27_rel_slope_std(x, sig_i)
    assert mc == pytest.approx(pred, rel=4.0 / math.sqrt(2 * (n - 1)) + 0.01)


def test_cancelled_noise_variance_matches_the_canceller():
    """White readout noise through the bias on/off cancellation (one period back, linear
    interpolation): per-sample variance sigma^2 (1 + (1 - r)^2 + r^2)."""
    fs, f, sigma = 625e3, 1700.0, 1e-4
    n = int(30 * fs / f)
    ph = np.arange(n) * f / fs
    vb = np.where(np.floor(ph).astype(int) % 2 == 1, 10.0, 0.0)
    rng = np.random.default_rng(7)
    y = rng.standard_normal((n, 40)) * sigma
    out = FeedthroughCanceller(40, fs).step(y, vb, np.full(n, f))
    v = out[np.all(np.isfinite(out), axis=1)]
    assert v.shape[0] > 0.4 * n
    pred = cancelled_noise_variance(sigma, fs, f)
    r = math.ceil(fs / f) - fs / f
    assert pred == pytest.approx(sigma**2 * (1 + (1 - r) ** 2 + r**2))
    assert float(np.mean(v * v)) == pytest.approx(pred, rel=0.02)


def test_std_interval_brackets_and_narrows():
    lo, hi = std_interval(1.0, 10)
    assert lo < 1.0 < hi
    assert (lo, hi) == pytest.approx((0.688, 1.826), abs=2e-3)
    lo, hi = std_interval(1.0, 2001)
    assert (lo, hi) == pytest.approx(
        (1 - 1.96 / math.sqrt(4000), 1 + 1.96 / math.sqrt(4000)), abs=2e-3
    )


def test_noise_free_pipeline_with_the_true_model_is_unbiased():
    """Noise-free calibration sweep, perfectly identified model: the design's steps
    (in-situ correction, EKF with alpha = 1, eq. 27) leave a method bias below 20 ppm."""
    nf = noise_free_sweep(Plan.short())
    ppm, info = design_sf_ppm(true_model(nf.stage, 2e-8), nf.harmonics, nf.yc, nf.rec, nf.sf_ref)
    assert abs(nf.sf_ref - 1.0) < 2e-5  # eq. (27) with the true rate against k_I = 1
    assert abs(ppm) < 20.0
    assert abs(info["model"].wn / nf.stage.wn - 1) < 1e-6

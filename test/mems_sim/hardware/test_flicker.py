"""Flicker noise generator: 1/f spectrum, flat Allan floor, exact analytic figures.

One seeded record of 2^23 samples at fs = 100 Hz (23.3 h) of a gyro-like term (B = 0.0155
deg/s, the ADIS16350 bias instability of Petkov & Slavov, "Stochastic Modeling of MEMS
Inertial Sensors", Sec. 3, here as the flicker coefficient; corners 1e-4 Hz and 50 Hz, two
poles per decade: 13 Gauss-Markov processes) serves the spectrum and Allan tests; the
other tests are short.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from mems_estimation.identification.allan import edf_oavar_greenhall, oadev
from mems_sim.hardware import flicker as fl
from mems_sim.params import ParameterError

FS = 100.0  # Hz
B = 0.0155 * math.pi / 180.0  # rad/s
CFG = fl.FlickerConfig(B, f_low_hz=1.0e-4, f_high_hz=50.0, poles_per_decade=2)
N = 2**23  # samples
SEED = 20261202
NPERSEG = 2**20  # Welch segment, samples (resolution 9.5e-5 Hz)


@pytest.fixture(scope="module")
def record() -> np.ndarray:
    return fl.flicker_noise(N, FS, CFG, np.random.default_rng(SEED))


def _log_slope(f: np.ndarray, s: np.ndarray, f_a: float, f_b: float) -> float:
    """Weighted least-squares slope of log S against log f over [f_a, f_b]: the bins are
    averaged in 10 logarithmic groups per decade, each group weighted by its bin count (the
    variance of a group mean falls as 1/count)."""
    edges = np.geomspace(f_a, f_b, int(round(10 * math.log10(f_b / f_a))) + 1)
    x, y, w = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f >= lo) & (f < hi)
        if sel.any():
            x.append(math.log10(math.sqrt(lo * hi)))
            y.append(math.log10(float(np.mean(s[sel]))))
            w.append(float(sel.sum()))
    slope, _ = np.polyfit(np.array(x), np.array(y), 1, w=np.sqrt(np.array(w)))
    return float(slope)


def test_psd_of_the_record_falls_as_one_over_f_over_three_decades(record):
    """Welch estimate (Hann, 2^20-sample segments, 15 of them with half overlap) of the
    record: its log-log slope over the top three decades of the configured 1/f band is
    -1 +- 0.05, and so is the analytic PSD's; the estimate also matches the analytic PSD
    level (ratio of the averaged estimate within 5 %)."""
    f_lo, f_hi = fl.flicker_band(FS, CFG)
    f_a, f_b = f_hi / 1000.0, f_hi
    assert f_lo <= f_a, (f_lo, f_hi)
    f, s = signal.welch(record, fs=FS, nperseg=NPERSEG)
    data = _log_slope(f, s, f_a, f_b)
    grid = np.geomspace(f_a, f_b, 301)
    model = _log_slope(grid, fl.flicker_psd(grid, FS, CFG), f_a, f_b)
    print(f"band {f_lo:.3g}..{f_hi:.3g} Hz; slope data {data:.4f} model {model:.4f}")
    assert abs(data + 1.0) <= 0.05
    assert abs(model + 1.0) <= 0.05
    sel = (f >= f_a) & (f <= f_b)
    ratio = float(np.mean(s[sel] / fl.flicker_psd(f[sel], FS, CFG)))
    assert abs(ratio - 1.0) < 0.05, ratio


@pytest.fixture(scope="module")
def allan(record):
    """Overlapping Allan deviation of the record at 11 averaging times spread evenly in
    log over two decades from the low end of the flat range."""
    tau_lo, tau_hi = fl.flat_allan_range(FS, CFG)
    m_lo = round(tau_lo * FS)
    m = np.unique(np.round(np.geomspace(m_lo, 100 * m_lo, 11)))
    taus, adev, _, _ = oadev(record, FS, m / FS)
    return tau_lo, tau_hi, taus, adev


def test_allan_deviation_of_the_record_matches_the_analytic_one(allan):
    """Within 2 % of :func:`flicker_adev` over two decades of tau where it is flat.

    Statistics: the overlapping AVAR estimate is chi-square with edf degrees of freedom,
    so ADEV has a relative standard deviation of about 1/sqrt(2 edf). For flicker noise
    (alpha = -1) edf is about 5 N / (4 m) (Howe, Allan & Barnes 1981; here Greenhall &
    Riley 2003, computed); at the largest m = 100 m_lo = 1000 with N = 2^23 it is about
    1e4, so sigma = 0.7 % and 2 % is 2.9 sigma there (and at least 4 sigma at every
    m <= 500, sigma growing as sqrt(m)): a wrong generator level of 2 % is seen, a right
    one fails with a chance of about 0.4 %. The test checks the bound it relies on."""
    tau_lo, tau_hi, taus, adev = allan
    m = np.round(taus * FS).astype(np.int64)
    assert taus[-1] <= tau_hi and taus[-1] / taus[0] >= 99.9, (tau_lo, tau_hi)
    edf = edf_oavar_greenhall(N + 1, m, -1)
    sigma = 1.0 / np.sqrt(2.0 * edf)
    assert np.all(2.8 * sigma < 0.02), sigma
    err = adev / fl.flicker_adev(taus, FS, CFG) - 1.0
    print(f"flat {tau_lo:g}..{tau_hi:g} s; max |err| {np.max(np.abs(err)):.4f}")
    assert np.all(np.abs(err) < 0.02), dict(zip(taus.tolist(), err.tolist()))


def test_flat_level_is_the_flicker_floor(allan):
    """The Allan deviation over the flat range equals B sqrt(2 ln 2 / pi) within the
    ripple: the analytic one at every grid point (by the definition of the range), and
    the record's mean over the tested taus, with its statistical margin (sigma of the mean
    below 0.4 %) inside the ripple."""
    tau_lo, tau_hi, taus, adev = allan
    floor = fl.flicker_floor(B)
    assert floor == pytest.approx(0.6643 * B, rel=1e-4)
    grid = np.unique(np.round(np.geomspace(tau_lo * FS, tau_hi * FS, 200))) / FS
    model = fl.flicker_adev(grid, FS, CFG) / floor - 1.0
    data = float(np.mean(adev)) / floor - 1.0
    print(f"floor error: model max {np.max(np.abs(model)):.4f}, record mean {data:.4f}")
    assert np.all(np.abs(model) <= fl.DEFAULT_RIPPLE)
    assert abs(data) <= fl.DEFAULT_RIPPLE
    assert tau_hi / tau_lo >= 100.0


@pytest.mark.parametrize("m", [1, 3, 30, 1000])
def test_closed_form_allan_variance_is_the_psd_integral(m):
    """The closed-form AVAR of the sampled processes equals the integral of their PSD
    with the Allan transfer function of m-sample averages, 2 sin^4(pi f m dt) / (m^2
    sin^2(pi f dt)) (the discrete counterpart of IEEE Std 952-1997, Annex C, eq. for the
    Allan variance as a PSD integral): two independent routes to the same figure."""
    dt = 1.0 / FS
    x = np.unique(
        np.concatenate([np.geomspace(1e-12, 0.5 / m, 4000), np.linspace(0.5 / m, 0.5, 400 * m)])
    )
    f = x / dt
    h = 2.0 * np.sin(math.pi * x * m) ** 4 / (m * m * np.sin(math.pi * x) ** 2)
    integral = np.trapezoid(fl.flicker_psd(f, FS, CFG) * h, f)
    closed = float(fl.flicker_avar(np.array([m * dt]), FS, CFG)[0])
    assert integral == pytest.approx(closed, rel=1e-4)


def test_the_weights_make_the_band_one_over_f():
    """Equal variances B^2 ln r / pi (and the slowest pole's truncation term) give the 1/f
    level within the ripple across the band; one pole per decade ripples too much for a
    2 % band, and spreads more than two decades at 5 %."""
    f_lo, f_hi = fl.flicker_band(FS, CFG)
    f = np.geomspace(f_lo, f_hi, 400)
    ratio = fl.flicker_psd(f, FS, CFG) / fl.ideal_psd(f, B)
    assert np.max(np.abs(ratio - 1.0)) <= fl.DEFAULT_RIPPLE * (1 + 1e-6)
    assert math.log10(f_hi / f_lo) >= 3.5
    coarse = fl.FlickerConfig(B, 1.0e-4, 50.0, poles_per_decade=1)
    with pytest.raises(ParameterError, match="no decade"):
        fl.flicker_band(FS, coarse)
    lo, hi = fl.flicker_band(FS, coarse, ripple=0.05)
    assert math.log10(hi / lo) >= 2.0


def test_start_is_stationary():
    """The first sample's variance over 1500 seeds is the sum of the pole variances
    (chi-square, 1500 dof: relative sd 3.7 %, tolerance 4 sd)."""
    first = np.array(
        [fl.flicker_noise(1, FS, CFG, np.random.default_rng([SEED, k]))[0] for k in range(1500)]
    )
    expected = float(np.sum(fl.pole_variances(CFG)))
    assert np.mean(first**2) == pytest.approx(expected, rel=0.15)


def test_same_seed_same_bits_and_blocks_continue():
    a = fl.flicker_noise(20_000, FS, CFG, np.random.default_rng(5))
    b = fl.flicker_noise(20_000, FS, CFG, np.random.default_rng(5))
    c = fl.flicker_noise(20_000, FS, CFG, np.random.default_rng(6))
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    rng = np.random.default_rng(5)
    state = fl.initial_state(CFG, rng)
    y0, state = fl.flicker_block(0, FS, CFG, rng, state)
    y1, state = fl.flicker_block(20_000, FS, CFG, rng, state)
    assert y0.shape == (0,) and y1.tobytes() == a.tobytes()
    assert state.shape == (CFG.n_poles,)
    off = fl.flicker_noise(100, FS, fl.FlickerConfig(0.0), np.random.default_rng(5))
    assert not np.any(off)


def test_parameter_table():
    specs = fl.flicker_specs("accel_flicker", "m/s^2", coefficient=3.2e-3, coefficient_max=0.1)
    names = [s.name for s in specs]
    assert names == [
        "accel_flicker_coefficient",
        "accel_flicker_f_low_hz",
        "accel_flicker_f_high_hz",
        "accel_flicker_poles_per_decade",
    ]
    assert specs[0].unit == "m/s^2" and specs[1].unit == specs[2].unit == "Hz"
    for s in specs:
        assert s.source and s.description
        assert s.validate(s.default) == s.default
    cfg = fl.flicker_config({"accel_flicker_f_high_hz": 5.0}, "accel_flicker", specs)
    assert cfg == fl.FlickerConfig(3.2e-3, 1.0e-4, 5.0, 2)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: fl.FlickerConfig(-1.0), "flicker_coefficient"),
        (lambda: fl.FlickerConfig(math.nan), "must be finite"),
        (lambda: fl.FlickerConfig(1.0, f_low_hz=0.0), "flicker_f_low_hz"),
        (lambda: fl.FlickerConfig(1.0, f_high_hz=1.0e6), "flicker_f_high_hz"),
        (lambda: fl.FlickerConfig(1.0, 1.0, 5.0), "f_high >= 10 f_low"),
        (lambda: fl.FlickerConfig(1.0, poles_per_decade=0), "flicker_poles_per_decade"),
        (lambda: fl.FlickerConfig(1.0, poles_per_decade=2.5), "expected an integer"),
        (lambda: fl.flicker_config({"flicker_coefficient": 2.0}), "out of range"),
        (lambda: fl.flicker_config({"flicker_gain": 2.0}), "unknown parameter"),
        (lambda: fl.flicker_config({"flicker_f_low_hz": 1.0}), "f_high >= 10 f_low"),
        (lambda: fl.flicker_noise(10, 1.0, CFG, np.random.default_rng(0)), "Nyquist"),
        (lambda: fl.flicker_noise(10, 0.0, CFG, np.random.default_rng(0)), "sample rate"),
        (lambda: fl.flicker_noise(-1, FS, CFG, np.random.default_rng(0)), "number of samples"),
        (lambda: fl.flicker_avar([0.001], FS, CFG), "below 1/fs"),
        (lambda: fl.flicker_band(FS, fl.FlickerConfig(0.0)), "switched-off"),
        (lambda: fl.flat_allan_range(FS, fl.FlickerConfig(0.0)), "switched-off"),
    ],
)
def test_invalid_values_raise_parameter_error(call, match):
    with pytest.raises(ParameterError, match=match):
        call()

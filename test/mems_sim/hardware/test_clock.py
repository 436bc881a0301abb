"""Tests of the sample clock (mems_sim.hardware.clock): the jitter-limited SNR of a sine
(Kester MT-008), the mean period and the temperature-ramp time error in closed form, the
random-walk phase variance, clock jumps and rate steps, skew, streaming, validation."""

import math

import numpy as np
import pytest

from mems_sim.hardware.clock import (
    CLOCK_SPECS,
    SampleClock,
    clock_values,
    draw_clock_device,
    fractional_frequency,
    jitter_snr_db,
)
from mems_sim.params import ParameterError

#: Every term off: an ideal clock.
IDEAL = {
    "clock_frequency_offset_ppm": 0.0,
    "clock_tempco_ppm_per_k": 0.0,
    "clock_jitter_s": 0.0,
    "clock_phase_diffusion": 0.0,
    "clock_skew_s": 0.0,
}
#: Every term on (and a temperature coefficient that a series exercises).
NOISY = {
    "clock_frequency_offset_ppm": 37.0,
    "clock_tempco_ppm_per_k": -0.6,
    "clock_jitter_s": 2e-9,
    "clock_phase_diffusion": 3e-8,
    "clock_skew_s": 5e-6,
}


def _errors(fs, params, n, seed, temperature=None, sizes=None, faults=()):
    """Time errors of n samples, streamed in blocks of ``sizes`` (default one call)."""
    clock = SampleClock(fs, params)
    for kind, k0, value in faults:
        getattr(clock, kind)(k0, value)
    rng = np.random.default_rng(seed)
    out, i = [], 0
    for m in sizes or [n]:
        temp = None if temperature is None else temperature[i : i + m]
        out.append(clock.instants(np.arange(i, i + m), rng, temp).error_s)
        i += m
    return np.concatenate(out)


def _sine_fit_residual(x, phase):
    """Residual of the three-parameter least-squares sine fit (IEEE Std 1241-2010, the
    sine-fit test) of ``x`` at the nominal phases 2 pi f k / fs."""
    basis = np.column_stack([np.sin(phase), np.cos(phase), np.ones_like(phase)])
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return x - basis @ coef


@pytest.mark.parametrize(
    ("fs", "f", "jitter"),
    [(1.0e6, 99.7e3, 1.0e-10), (1.0e5, 12.34e3, 2.0e-9), (1.0e3, 97.0, 5.0e-7)],
)
def test_white_jitter_limits_the_snr_of_a_sine(fs, f, jitter):
    """A full-scale sine sampled at the jittered instants: SNR = -20 log10(2 pi f sigma_t)
    within 0.5 dB, measured against the ideal samples and by a sine fit."""
    n = 1 << 16
    block = SampleClock(fs, {**IDEAL, "clock_jitter_s": jitter}).instants(
        np.arange(n), np.random.default_rng(7)
    )
    phase = 2.0 * math.pi * f * block.stamps_s
    ideal = np.sin(phase)
    # the ideal sine at t_k = k/fs + e_k, its phase advanced by 2 pi f e_k
    jittered = np.sin(phase + 2.0 * math.pi * f * block.error_s)
    predicted = jitter_snr_db(f, jitter)
    against_ideal = 10 * np.log10(np.mean(ideal**2) / np.mean((jittered - ideal) ** 2))
    fit = 10 * np.log10(np.mean(ideal**2) / np.mean(_sine_fit_residual(jittered, phase) ** 2))
    print(
        f"fs {fs:g} f {f:g} sigma {jitter:g}: predicted {predicted:.3f} dB, "
        f"ideal-ref {against_ideal:.3f} dB, sine fit {fit:.3f} dB"
    )
    assert abs(against_ideal - predicted) < 0.5
    assert abs(fit - predicted) < 0.5
    assert 40.0 < predicted < 110.0  # jitter dominates float rounding by far


@pytest.mark.parametrize(("offset", "tempco", "temp"), [(37.0, 0.0, 25.0), (-48.0, 0.7, 61.5)])
def test_mean_period_is_one_over_the_actual_frequency(offset, tempco, temp):
    """Constant temperature: t_k = k / f_actual exactly with the noise off (relative 1e-12),
    f_actual = fs (1 + 1e-6 (offset + tempco (T - T_ref))); with the noise on the mean
    period over 2e5 samples is within the noise's closed-form bound."""
    fs, n = 800.0, 200_000
    params = {**IDEAL, "clock_frequency_offset_ppm": offset, "clock_tempco_ppm_per_k": tempco}
    f_actual = fs * (1.0 + 1e-6 * (offset + tempco * (temp - 25.0)))
    clock = SampleClock(fs, params)
    t = clock.instants(np.arange(n + 1), np.random.default_rng(1), temp).instants_s
    k = np.arange(n + 1)
    np.testing.assert_allclose(t[1:], k[1:] / f_actual, rtol=1e-12, atol=0)
    mean_period = (t[-1] - t[0]) / n
    assert abs(mean_period * f_actual - 1.0) < 1e-12
    # noise on: the mean period's error is (e_n - e_0) / n, sd sqrt(2 sigma^2 + D^2 n T) / n
    sigma, d = 2e-9, 3e-8
    noisy = {**params, "clock_jitter_s": sigma, "clock_phase_diffusion": d}
    tn = SampleClock(fs, noisy).instants(np.arange(n + 1), np.random.default_rng(2), temp)
    bound = 5 * math.sqrt(2 * sigma**2 + d**2 * n / fs) / n
    mean_noisy = (tn.instants_s[-1] - tn.instants_s[0]) / n
    print(
        f"mean period error: clean {mean_period - 1 / f_actual:.3e} s, noisy "
        f"{mean_noisy - 1 / f_actual:.3e} s (bound {bound:.3e} s)"
    )
    assert abs(mean_noisy - 1.0 / f_actual) < bound


def test_temperature_ramp_gives_the_closed_form_time_error():
    """T_j = T_ref + r j T: y_j = alpha + beta j, and the time error
    x_k = -T sum_{j<k} y_j / (1 + y_j) = -T (S1 - S2) + O(y^3), S1 = sum y_j, S2 = sum y_j^2
    in closed form; the first-order sum alone misses by T S2 (checked to matter)."""
    fs, n = 1000.0, 100_000
    offset, tempco, rate = 20.0, 1.5, 0.4  # ppm, ppm/K, K/s: 40 K over the record
    params = {**IDEAL, "clock_frequency_offset_ppm": offset, "clock_tempco_ppm_per_k": tempco}
    j = np.arange(n + 1)
    temp = 25.0 + rate * j / fs
    x = SampleClock(fs, params).instants(j, np.random.default_rng(0), temp).error_s
    alpha, beta = 1e-6 * offset, 1e-6 * tempco * rate / fs
    k = j.astype(float)
    s1 = k * alpha + beta * k * (k - 1) / 2
    s2 = k * alpha**2 + alpha * beta * k * (k - 1) + beta**2 * (k - 1) * k * (2 * k - 1) / 6
    closed = -(s1 - s2) / fs
    y_max = alpha + beta * n
    bound = k / fs * y_max**3 * 1.01 + 1e-16 * np.abs(closed).max() * k
    print(
        f"ramp: x_n = {x[-1]:.9e} s, closed form {closed[-1]:.9e} s, "
        f"max |diff| {np.abs(x - closed).max():.2e} s, second-order term {s2[-1] / fs:.2e} s"
    )
    assert np.all(np.abs(x - closed) <= bound)
    assert s2[-1] / fs > 100 * bound[-1]  # the second order is resolved
    np.testing.assert_allclose(x[-1], -(n * alpha + beta * n * (n - 1) / 2) / fs, rtol=1e-3)


@pytest.mark.parametrize("jitter", [0.0, 4e-8])
def test_random_walk_phase_variance_grows_linearly(jitter):
    """Over 4000 seeds, Var(e_k) = sigma_t^2 + D^2 k T at k = 50 ... 400, and the increments
    over the disjoint spans [0, 100], [100, 200], [200, 400] have Var = 2 sigma_t^2 +
    D^2 (k2 - k1) T (independent increments: linear growth), each within five standard
    errors of a sample variance (zero mean known: chi-square with M dof, sd sqrt(2/M))."""
    fs, n, d, seeds = 500.0, 401, 2e-6, 4000
    params = {**IDEAL, "clock_jitter_s": jitter, "clock_phase_diffusion": d}
    e = np.array([_errors(fs, params, n, seed) for seed in range(seeds)])
    if jitter == 0.0:
        assert np.all(e[:, 0] == 0.0)  # the walk starts at 0 at the stream's first sample
    rel = 5 * math.sqrt(2 / seeds)
    for kk in (50, 100, 200, 400):
        var, predicted = np.mean(e[:, kk] ** 2), jitter**2 + d**2 * kk / fs
        print(f"k {kk}: Var {var:.4e} s^2, predicted {predicted:.4e} s^2 ({var / predicted:.3f})")
        assert abs(var / predicted - 1) < rel
    for k1, k2 in ((0, 100), (100, 200), (200, 400)):
        var = np.mean((e[:, k2] - e[:, k1]) ** 2)
        predicted = 2 * jitter**2 + d**2 * (k2 - k1) / fs
        print(f"span {k1}-{k2}: Var {var:.4e} s^2, predicted {predicted:.4e} s^2")
        assert abs(var / predicted - 1) < rel


@pytest.mark.parametrize("temperature", [None, "ramp"])
def test_clock_jump_and_rate_step_move_only_later_instants(temperature):
    """A jump J at k0 adds J to e_k for k >= k0, a rate step s at k0 changes the periods from
    k0 on: e_k gains T sum_{j=k0}^{k-1} (1/(1+y_j+s) - 1/(1+y_j)) for k > k0. Before (and for
    the rate step, at) k0 the instants keep every bit; the noise is the same draw."""
    fs, n, k0, jump, step = 1000.0, 3000, 1234, 2.5e-3, 80.0
    temp = None if temperature is None else 20.0 + 0.01 * np.arange(n)
    base = _errors(fs, NOISY, n, 5, temp)
    jumped = _errors(fs, NOISY, n, 5, temp, faults=[("apply_jump", k0, jump)])
    stepped = _errors(fs, NOISY, n, 5, temp, faults=[("apply_rate_step", k0, step)])
    assert np.array_equal(jumped[:k0], base[:k0])
    np.testing.assert_allclose(jumped[k0:] - base[k0:], jump, rtol=0, atol=1e-17)
    assert np.array_equal(stepped[: k0 + 1], base[: k0 + 1])
    values = clock_values(NOISY)
    t_c = np.full(n, 25.0) if temp is None else temp
    y = fractional_frequency(values, t_c[k0:-1])
    expected = np.concatenate(([0.0], np.cumsum(1 / (1 + y + 1e-6 * step) - 1 / (1 + y)) / fs))
    print(f"rate step: e_n moved {stepped[-1] - base[-1]:.6e} s, closed form {expected[-1]:.6e}")
    np.testing.assert_allclose(stepped[k0:] - base[k0:], expected, rtol=1e-9, atol=1e-17)
    assert abs(expected[-1]) > 1e-4  # the step is visible: (n - k0) T 80 ppm


def test_faults_and_temperature_stream_bit_for_bit():
    """Blocks of any size give the one-shot bits, with faults scheduled before the block that
    holds them and a fault scheduled between blocks; same seed same bits, another seed not."""
    fs, n = 250.0, 5000
    temp = 30.0 + 5.0 * np.arange(n) / n
    faults = [("apply_jump", 700, -1e-4), ("apply_rate_step", 2100, -15.0)]
    one = _errors(fs, NOISY, n, 11, temp, faults=faults)
    for sizes in ([1, 699, 1, 1, 2000, 2298], [5000], [333] * 15 + [5]):
        assert np.array_equal(_errors(fs, NOISY, n, 11, temp, sizes, faults), one)
    clock = SampleClock(fs, NOISY)
    rng = np.random.default_rng(11)
    first = clock.instants(np.arange(0, 900), rng, temp[:900])
    with pytest.raises(ParameterError, match="already generated"):
        clock.apply_jump(899, 1e-4)
    clock.apply_jump(900, 0.0)  # the next sample is allowed, and a zero jump changes nothing
    clock.apply_rate_step(2100, -15.0)
    rest = clock.instants(np.arange(900, n), rng, temp[900:])
    streamed = np.concatenate([first.error_s, rest.error_s])
    assert not np.array_equal(streamed, one)  # the jump at 700 was not scheduled here
    expected = _errors(fs, NOISY, n, 11, temp, faults=[("apply_rate_step", 2100, -15.0)])
    assert np.array_equal(streamed, expected)
    assert not np.array_equal(_errors(fs, NOISY, n, 12, temp, faults=faults), one)


def test_skew_delays_the_second_channel_and_ideal_clock_is_the_stamps():
    """The sense channel's instants are the drive channel's plus the skew; an ideal clock's
    instants are the stamps k / fs bit for bit (stamps never move, whatever the clock)."""
    k = np.arange(10, 1010)
    clock = SampleClock(2000.0, NOISY, start_index=10)
    block = clock.instants(k, np.random.default_rng(3))
    np.testing.assert_allclose(block.skewed_instants_s - block.instants_s, 5e-6, atol=1e-15)
    assert np.array_equal(block.stamps_s, k / 2000.0)
    ideal = SampleClock(2000.0, IDEAL, start_index=10).instants(k, np.random.default_rng(3))
    assert np.array_equal(ideal.instants_s, ideal.stamps_s)
    assert np.array_equal(ideal.skewed_instants_s, ideal.stamps_s)


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"clock_jitter_s": -1e-12}, "clock_jitter_s"),
        ({"clock_frequency_offset_ppm": 6e4}, "clock_frequency_offset_ppm"),
        ({"clock_tempco_ppm_per_k": float("nan")}, "finite"),
        ({"clock_phase_diffusion": "1e-9"}, "expected a number"),
        ({"clock_skew_s": 2.0}, "out of range"),
        ({"clock_drift": 1.0}, "unknown parameter"),
    ],
)
def test_invalid_parameters_raise(params, match):
    with pytest.raises(ParameterError, match=match):
        SampleClock(1000.0, params)


def test_invalid_use_raises():
    for fs in (0.0, -5.0, float("inf")):
        with pytest.raises(ParameterError, match="sample_rate_hz"):
            SampleClock(fs)
    clock = SampleClock(1000.0)
    rng = np.random.default_rng(0)
    with pytest.raises(ParameterError, match="clock_jump_s"):
        clock.apply_jump(10, 5e3)
    with pytest.raises(ParameterError, match="clock_rate_step_ppm"):
        clock.apply_rate_step(10, 2e5)
    with pytest.raises(ParameterError, match="integer"):
        clock.apply_jump(1.5, 1e-3)
    with pytest.raises(ValueError, match="consecutive from 0"):
        clock.instants(np.arange(1, 5), rng)
    with pytest.raises(ValueError, match="temperature_c"):
        clock.instants(np.arange(4), rng, np.zeros(3))
    clock.instants(np.arange(4), rng)
    with pytest.raises(ValueError, match="consecutive from 4"):
        clock.instants(np.arange(0, 4), rng)
    with pytest.raises(ValueError, match="temperature_c"):
        SampleClock(1000.0).instants(np.arange(3), rng, np.array([20.0, np.nan, 20.0]))
    with pytest.raises(ValueError, match="temperature_c"):
        SampleClock(1000.0).instants(np.arange(3), rng, -300.0)
    stop = SampleClock(1000.0)
    for _ in range(10):  # ten -10 % steps: 1 + y = 0
        stop.apply_rate_step(2, -1e5)
    with pytest.raises(ParameterError, match="stop the clock"):
        stop.instants(np.arange(5), rng)


def test_batch_spread_stays_within_the_datasheet_stability():
    """Drawn clocks: offsets within +-50 ppm and tempcos within +-0.8 ppm/K, not all equal;
    no seed gives the nominal device; the same seed the same device."""
    values = clock_values()
    draws = [draw_clock_device(values, seed) for seed in range(200)]
    offsets = np.array([d["clock_frequency_offset_ppm"] for d in draws])
    tempcos = np.array([d["clock_tempco_ppm_per_k"] for d in draws])
    assert np.all(np.abs(offsets) <= 50.0) and offsets.std() > 20.0
    assert np.all(np.abs(tempcos) <= 0.8) and tempcos.std() > 0.3
    assert draw_clock_device(values, None) == values
    assert draw_clock_device(values, 4) == draws[4]
    assert all(s.source for s in CLOCK_SPECS)

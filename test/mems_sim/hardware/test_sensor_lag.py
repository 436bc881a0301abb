"""Tests of the lagged temperature sensor (mems_sim.hardware.sensor_lag): the step response
and the ramp lag of the zero-order-hold first-order lag in closed form, offset, noise and
resolution, streaming bit for bit, validation and the batch spread."""

import math

import numpy as np
import pytest

from mems_sim.hardware.sensor_lag import (
    TEMPERATURE_SENSOR_SPECS,
    LaggedTemperatureSensor,
    draw_temperature_sensor,
    lag_coefficient,
    ramp_lag_k,
    temperature_sensor_values,
)
from mems_sim.params import ParameterError

#: Lag only: no offset, noise or rounding.
CLEAN = {"temp_sensor_noise_k": 0.0, "temp_sensor_offset_k": 0.0, "temp_sensor_resolution_k": 0.0}
#: Every term on.
FULL = {
    "temp_sensor_time_constant_s": 2.5,
    "temp_sensor_noise_k": 0.03,
    "temp_sensor_offset_k": -1.7,
    "temp_sensor_resolution_k": 1.0 / 132.48,
    "temp_sensor_zero_code_c": 25.0,
}


def _readings(params, temp, seed, sizes=None, period=0.01):
    sensor = LaggedTemperatureSensor(period, params)
    rng = np.random.default_rng(seed)
    blocks, i = [], 0
    for m in sizes or [temp.size]:
        blocks.append(sensor.measure(temp[i : i + m], rng))
        i += m
    return (
        np.concatenate([b.lagged_c for b in blocks]),
        np.concatenate([b.reading_c for b in blocks]),
        np.concatenate([b.codes for b in blocks]) if blocks[0].codes is not None else None,
    )


@pytest.mark.parametrize(("tau", "period"), [(1.0, 0.01), (0.3, 0.05), (40.0, 1.0)])
def test_step_response_is_the_exponential(tau, period):
    """Element at T0, input T1 from k = 0: y[k] = T1 + (T0 - T1) exp(-k Ts / tau)."""
    t0, t1, n = 20.0, 45.0, 2000
    sensor = LaggedTemperatureSensor(
        period, {**CLEAN, "temp_sensor_time_constant_s": tau}, initial_c=t0
    )
    block = sensor.measure(np.full(n, t1), np.random.default_rng(0))
    k = np.arange(n)
    closed = t1 + (t0 - t1) * np.exp(-k * period / tau)
    err = np.abs(block.lagged_c - closed).max()
    print(f"tau {tau} Ts {period}: max |y - closed form| {err:.2e} K")
    np.testing.assert_allclose(block.lagged_c, closed, rtol=0, atol=1e-12)
    assert np.array_equal(block.reading_c, block.lagged_c)  # nothing else on
    assert block.codes is None
    # the 63 % point is one time constant in
    k_tau = round(tau / period)
    assert abs((block.lagged_c[k_tau] - t0) / (t1 - t0) - (1 - math.exp(-1))) < 1e-9


def test_initial_state_is_the_first_input():
    """Without an initial state the element starts at the first input: a constant input gives
    that temperature throughout; a step after k = 0 responds from T[0]."""
    sensor = LaggedTemperatureSensor(0.01, CLEAN)
    block = sensor.measure(np.full(500, 31.25), np.random.default_rng(0))
    assert block.lagged_c[0] == 31.25
    np.testing.assert_allclose(block.lagged_c, 31.25, rtol=1e-15)
    temp = np.concatenate(([10.0], np.full(300, 20.0)))
    y = LaggedTemperatureSensor(0.01, CLEAN).measure(temp, np.random.default_rng(0)).lagged_c
    a = lag_coefficient(0.01, 1.0)
    assert y[0] == 10.0 and y[1] == 10.0  # y[1] = a T[0] + (1 - a) T[0]
    np.testing.assert_allclose(y[1:], 20.0 - 10.0 * a ** np.arange(300), atol=1e-12)


@pytest.mark.parametrize(("tau", "period", "rate"), [(1.0, 0.01, 0.5), (8.0, 0.1, -0.05)])
def test_ramp_lag_is_tau_times_rate(tau, period, rate):
    """On a ramp T = T0 + r k Ts the steady-state lag T[k] - y[k] is r Ts / (1 - a)
    (the discrete steady state) = r tau + r Ts / 2 within r Ts^2 / (10 tau): the continuous
    lag tau r and half a held sample."""
    n = int(20 * tau / period)
    k = np.arange(n)
    temp = 25.0 + rate * k * period
    y = _readings({**CLEAN, "temp_sensor_time_constant_s": tau}, temp, 0, period=period)[0]
    lag = temp[-1] - y[-1]
    exact = ramp_lag_k(period, tau, rate)
    print(
        f"ramp {rate} K/s, tau {tau} s: lag {lag:.9f} K, r Ts/(1-a) {exact:.9f} K, "
        f"tau r {tau * rate:.6f} K, tau r + r Ts/2 {tau * rate + rate * period / 2:.9f} K"
    )
    # the transient (T0 - y0 = 0, lag 0 at k = 0) has decayed to exp(-20) of the lag
    assert abs(lag - exact) <= 1e-8 * abs(exact) + 3e-9 * abs(rate * tau)
    assert abs(exact - (tau * rate + rate * period / 2)) <= abs(rate) * period**2 / (10 * tau)
    assert abs(lag - tau * rate) > abs(rate) * period / 4  # the half-sample term is resolved


def test_offset_noise_and_resolution():
    """A constant input: the readings' mean is T + offset and their sd the noise (five
    standard errors); readings are T_0 + q codes; without noise the rounding error is within
    half an LSB and the code is round((T + offset - T_0) / q)."""
    n, temp = 40_000, 37.3
    lagged, reading, codes = _readings(FULL, np.full(n, temp), 4)
    q, sigma, offset = 1.0 / 132.48, 0.03, -1.7
    np.testing.assert_array_equal(reading, 25.0 + q * codes)
    err = reading - lagged
    sd_q = math.sqrt(sigma**2 + q**2 / 12)  # rounding adds q^2/12 (noise >> q)
    print(
        f"mean error {err.mean():.5f} K (offset {offset}), sd {err.std():.5f} K "
        f"(predicted {sd_q:.5f} K)"
    )
    assert abs(err.mean() - offset) < 5 * sd_q / math.sqrt(n)
    assert abs(err.std() / sd_q - 1) < 5 / math.sqrt(2 * n)
    quiet = {**FULL, "temp_sensor_noise_k": 0.0}
    ramp = np.linspace(-20.0, 80.0, 5001)
    lagged, reading, codes = _readings(quiet, ramp, 4)
    assert np.all(np.abs(reading - (lagged + offset)) <= q / 2 + 1e-12)
    np.testing.assert_array_equal(codes, np.round((lagged + offset - 25.0) / q).astype(np.int64))


def test_blocks_give_the_bits_of_one_call_and_seeds_repeat():
    """Streaming in blocks of any size equals one call bit for bit (lagged, readings, codes);
    the same seed gives the same bits, another seed other noise; no lag (tau = 0) is the
    input itself."""
    rng = np.random.default_rng(99)
    temp = 25.0 + np.cumsum(rng.normal(0.0, 0.05, 6000))
    one = _readings(FULL, temp, 8)
    for sizes in ([1, 1, 5998], [6000], [777] * 7 + [561], [0, 3000, 0, 3000]):
        for a, b in zip(_readings(FULL, temp, 8, sizes), one):
            assert np.array_equal(a, b)
    again = _readings(FULL, temp, 8)
    assert all(np.array_equal(a, b) for a, b in zip(again, one))
    assert not np.array_equal(_readings(FULL, temp, 9)[1], one[1])
    assert np.array_equal(_readings(FULL, temp, 9)[0], one[0])  # the lag has no noise
    none = {**CLEAN, "temp_sensor_time_constant_s": 0.0}
    for sizes in (None, [100, 5900]):
        lagged, reading, _ = _readings(none, temp, 8, sizes)
        assert np.array_equal(lagged, temp) and np.array_equal(reading, temp)


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"temp_sensor_time_constant_s": -1.0}, "temp_sensor_time_constant_s"),
        ({"temp_sensor_noise_k": -0.1}, "temp_sensor_noise_k"),
        ({"temp_sensor_offset_k": 60.0}, "out of range"),
        ({"temp_sensor_resolution_k": float("inf")}, "finite"),
        ({"temp_sensor_zero_code_c": None}, "expected a number"),
        ({"temp_sensor_lag": 1.0}, "unknown parameter"),
    ],
)
def test_invalid_parameters_raise(params, match):
    with pytest.raises(ParameterError, match=match):
        LaggedTemperatureSensor(0.01, params)


def test_invalid_use_raises():
    for period in (0.0, -1.0, float("nan")):
        with pytest.raises(ParameterError, match="temp_sensor_sample_period_s"):
            LaggedTemperatureSensor(period)
    with pytest.raises(ParameterError, match="initial_c"):
        LaggedTemperatureSensor(0.01, initial_c=-300.0)
    sensor = LaggedTemperatureSensor(0.01)
    rng = np.random.default_rng(0)
    with pytest.raises(ParameterError, match="temperature_c"):
        sensor.measure(np.array([20.0, np.nan]), rng)
    with pytest.raises(ParameterError, match="temperature_c"):
        sensor.measure(np.array([-274.0]), rng)
    with pytest.raises(ValueError, match="1-D"):
        sensor.measure(np.zeros((2, 2)), rng)


def test_batch_spread_stays_within_the_datasheet_offset():
    """Drawn sensors: offsets within the LSM6DSM's +-15 K and lags within +-20 %, spread out;
    no seed gives the nominal sensor, the same seed the same one."""
    values = temperature_sensor_values()
    draws = [draw_temperature_sensor(values, seed) for seed in range(200)]
    offsets = np.array([d["temp_sensor_offset_k"] for d in draws])
    taus = np.array([d["temp_sensor_time_constant_s"] for d in draws])
    assert np.all(np.abs(offsets) <= 15.0) and offsets.std() > 6.0
    assert np.all(np.abs(taus - 1.0) <= 0.2 + 1e-12) and taus.std() > 0.08
    assert draw_temperature_sensor(values, None) == values
    assert draw_temperature_sensor(values, 17) == draws[17]
    assert all(s.source for s in TEMPERATURE_SENSOR_SPECS)

"""Scheduled sensor faults on the accelerometer's readout voltage, inside the
force-rebalance loop, against the fault-free run of the same seed. Open loop, the readout
does not act back on the mass, so every kind is checked sample by sample in codes; closed
loop, the loop answers the faulty readout."""

import numpy as np
import pytest

from mems_sim.devices.accelerometer import ForceRebalanceAccelerometer
from mems_sim.hardware.fault_schedule import parse_schedule
from mems_sim.hardware.sensor_faults import SensorFaultInjector

N = 8000
ON, OFF = 2000, 6000  # the faulty samples [ON, OFF)


def run(entries=(), frame=1000, seed=3, **params):
    d = ForceRebalanceAccelerometer(params, seed=seed)
    if entries:
        sched = parse_schedule({"faults": list(entries)}, ("readout",), ("V",), d.fs)
        d.faults = SensorFaultInjector(sched, d.fs, seed, (d.v_noise_std,))
    out = [d.step(min(frame, N - k)) for k in range(0, N, frame)]
    return np.concatenate([f.code for f in out]), np.concatenate([f.v_f for f in out]), d


def fault(kind, magnitude=None, **extra):
    e = {"kind": kind, "channel": "readout", "start_sample": ON, "duration_samples": OFF - ON}
    if magnitude is not None:
        e["magnitude"] = magnitude
    return e | extra


def untouched_outside(c0, c1):
    np.testing.assert_array_equal(c1[:ON], c0[:ON])
    np.testing.assert_array_equal(c1[OFF:], c0[OFF:])


def test_no_schedule_and_a_fault_after_the_run_are_the_device_bit_for_bit():
    for mode in ("open_loop", "pi_rebalance", "ekf_rebalance"):
        c0, v0, _ = run(mode=mode)
        c1, v1, _ = run([fault("sign_flip") | {"start_sample": N}], mode=mode)
        np.testing.assert_array_equal(c1, c0)
        np.testing.assert_array_equal(v1, v0)


@pytest.mark.parametrize("frame", [1000, 777])
def test_open_loop_bias_step_in_codes(frame):
    c0, _, d = run(mode="open_loop")
    b = 37.3 * d.lsb
    c1, _, _ = run([fault("bias_step", b)], frame=frame, mode="open_loop")
    diff = c1[ON:OFF] - c0[ON:OFF] - b / d.lsb
    assert np.all(np.abs(diff) <= 1)
    assert abs(diff.mean()) < 0.05
    untouched_outside(c0, c1)


def test_open_loop_stuck_scale_sign_and_rail():
    c0, _, d = run(mode="open_loop")
    stuck, _, _ = run([fault("stuck_at")], mode="open_loop", frame=777)
    assert np.all(stuck[ON:OFF] == stuck[ON]) and abs(stuck[ON] - c0[ON]) <= 1
    untouched_outside(c0, stuck)
    scaled, _, _ = run([fault("scale_step", 0.5)], mode="open_loop")
    assert np.all(np.abs(scaled[ON:OFF] - 1.5 * c0[ON:OFF]) <= 1.5)
    flipped, _, _ = run([fault("sign_flip")], mode="open_loop")
    assert np.all(np.abs(flipped[ON:OFF] + c0[ON:OFF]) <= 1)
    rail = 3.0 * d.v_noise_std
    clipped, _, _ = run([fault("saturation", rail)], mode="open_loop")
    assert np.all(np.abs(clipped[ON:OFF]) * d.lsb <= rail + d.lsb)
    inside = np.abs(c0[ON:OFF]) * d.lsb < rail - d.lsb
    np.testing.assert_array_equal(clipped[ON:OFF][inside], c0[ON:OFF][inside])
    assert np.count_nonzero(~inside) > 0


def test_open_loop_noise_burst_and_spikes():
    c0, _, d = run(mode="open_loop")
    noisy, _, _ = run([fault("noise_burst", 4.0)], mode="open_loop")
    extra = (noisy[ON:OFF] - c0[ON:OFF]) * d.lsb
    want = d.v_noise_std * np.sqrt(15.0)
    assert extra.std() == pytest.approx(want, rel=0.05)
    a = 200 * d.lsb
    spiked, _, _ = run([fault("spikes", a, rate_hz=20_000.0)], mode="open_loop", frame=777)
    jumps = np.abs(spiked - c0) * d.lsb > a / 2
    assert not jumps[:ON].any() and not jumps[OFF:].any()
    expected = 20_000.0 / d.fs * (OFF - ON)  # 80 spikes
    assert abs(np.count_nonzero(jumps) - expected) < 4 * np.sqrt(expected)


def test_closed_loop_answers_a_readout_offset():
    """Under PI rebalance the integrator nulls the faulty readout: during a readout offset
    the feedback moves the mass until the code mean is back at zero, so the drive, not the
    code, carries the fault (the physics of an offset inside a force-rebalance loop)."""
    c0, v0, d = run()
    b = 20 * d.v_noise_std
    c1, v1, _ = run([fault("bias_step", b)])
    np.testing.assert_array_equal(c1[:ON], c0[:ON])
    assert np.abs(c1[ON] - c0[ON] - b / d.lsb) <= 1  # the first faulty sample: the offset
    late = slice(OFF - 1000, OFF)
    assert abs((c1[late] - c0[late]).mean() * d.lsb) < 0.2 * b  # nulled by the loop
    assert np.abs(v1[late] - v0[late]).mean() > 0  # through the feedback


def test_loop_terms_compose_like_the_injector():
    """Without rail and hold, the loop's gain y + offset is the injector's own value."""
    entries = [
        fault("bias_step", 1e-4),
        fault("scale_step", -0.3) | {"start_sample": 3000},
        fault("bias_ramp", 2e-3) | {"start_sample": 2500},
        fault("spikes", 5e-4, rate_hz=1e5),
        fault("sign_flip") | {"start_sample": 4000, "duration_samples": 100},
        fault("noise_burst", 3.0) | {"start_sample": 4500},
    ]
    sched = parse_schedule({"faults": entries}, ("readout",), ("V",), 1e6)
    inj = SensorFaultInjector(sched, 1e6, 5, (1e-4,))
    y = np.random.default_rng(1).standard_normal((N, 1)) * 1e-3
    direct = inj.apply(y, 0)[:, 0]
    terms = SensorFaultInjector(sched, 1e6, 5, (1e-4,)).loop_terms(0, N)
    np.testing.assert_allclose(terms.gain * y[:, 0] + terms.offset, direct, rtol=0, atol=1e-18)
    assert np.all(np.isinf(terms.rail)) and not terms.hold.any()

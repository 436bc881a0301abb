"""Sensor faults on blocks of analog values: each kind against its closed form, the same
faulty samples at any block size, and untouched blocks without a schedule."""

import numpy as np
import pytest

from mems_sim.hardware.fault_schedule import parse_schedule
from mems_sim.hardware.sensor_faults import CHUNK, SensorFaultInjector

CHANNELS = ("a", "b", "c")
UNITS = ("V", "V", "V")
FS = 100.0
N = 3 * CHUNK + 123


def injector(*entries, white=(0.2, 0.2, 0.2), seed=4):
    sched = parse_schedule({"faults": list(entries)}, CHANNELS, UNITS, FS)
    return SensorFaultInjector(sched, FS, seed, white)


def signal(seed=1):
    return np.random.default_rng(seed).standard_normal((N, 3))


def run(inj, x, block):
    out = [inj.apply(x[k : k + block], k) for k in range(0, x.shape[0], block)]
    return np.concatenate(out)


def fault(kind, magnitude=None, first=1000, count=5000, channel="b", **extra):
    e = {"kind": kind, "channel": channel, "start_sample": first, "duration_samples": count}
    if magnitude is not None:
        e["magnitude"] = magnitude
    e.update(extra)
    return e


def faulty_and_clean(y, x, first=1000, count=5000, j=1):
    inside = np.zeros(N, bool)
    inside[first : first + count] = True
    clean = np.ones((N, 3), bool)
    clean[inside, j] = False
    np.testing.assert_array_equal(y[clean], x[clean])  # nothing else moves
    return y[inside, j], x[inside, j]


def test_no_fault_returns_the_block_itself():
    x = signal()
    inj = injector()
    assert not inj and inj.apply(x, 0) is x
    late = injector(fault("sign_flip", first=10 * N))
    assert late.apply(x, 0) is x


@pytest.mark.parametrize(
    "kind, magnitude, law",
    [
        ("bias_step", 0.37, lambda x, k: x + 0.37),
        ("bias_ramp", 0.5, lambda x, k: x + 0.5 * (k - 1000) / FS),
        ("scale_step", -0.25, lambda x, k: x * 0.75),
        ("sign_flip", None, lambda x, k: -x),
        ("saturation", 0.8, lambda x, k: np.clip(x, -0.8, 0.8)),
    ],
)
def test_deterministic_kinds_follow_their_law(kind, magnitude, law):
    x = signal()
    y = run(injector(fault(kind, magnitude)), x, 1000)
    got, base = faulty_and_clean(y, x)
    k = np.arange(1000, 6000)
    np.testing.assert_allclose(got, law(base, k), rtol=0, atol=1e-15)
    assert np.any(got != base)


def test_stuck_at_holds_the_onset_value_across_blocks():
    x = signal()
    y = run(injector(fault("stuck_at")), x, 777)
    got, _ = faulty_and_clean(y, x)
    assert np.all(got == x[1000, 1])


def test_noise_burst_raises_the_white_noise_to_k_sigma():
    """White input of sd sigma: inside the burst the sd is k sigma (within 3 standard
    errors of a sample sd over 5000 samples, 1 %)."""
    sigma, k = 0.2, 4.0
    x = sigma * signal(9)
    y = run(injector(fault("noise_burst", k), white=(sigma,) * 3), x, 512)
    got, base = faulty_and_clean(y, x)
    sd = np.std(got)
    assert abs(sd / (k * sigma) - 1) < 3 / np.sqrt(2 * 5000)
    assert abs(np.std(got - base) / (sigma * np.sqrt(k * k - 1)) - 1) < 3 / np.sqrt(2 * 5000)


def test_spikes_at_their_rate_with_their_amplitude():
    rate, a = 10.0, 2.5  # p = 0.1 per sample
    x = signal()
    y = run(injector(fault("spikes", a, count=10_000, rate_hz=rate)), x, 999)
    got, base = faulty_and_clean(y, x, count=10_000)
    d = got - base
    hits = d != 0
    assert np.allclose(np.abs(d[hits]), a, atol=1e-12)
    p = rate / FS
    assert abs(hits.sum() - p * 10_000) < 4 * np.sqrt(10_000 * p * (1 - p))
    assert abs(np.mean(d[hits] > 0) - 0.5) < 4 * 0.5 / np.sqrt(hits.sum())


@pytest.mark.parametrize("kind, extra", [("noise_burst", {}), ("spikes", {"rate_hz": 20.0})])
def test_random_kinds_are_the_same_at_any_block_size(kind, extra):
    x = signal()
    e = fault(kind, 3.0, first=CHUNK - 100, count=2 * CHUNK, **extra)
    a = run(injector(e), x, N)
    for block in (1, 100, 4095, 5000):
        b = run(injector(e), x[: 3 * block] if block == 1 else x, block)
        np.testing.assert_array_equal(b, a[: b.shape[0]])
    other_seed = run(injector(e, seed=5), x, N)
    assert np.any(other_seed != a)


def test_faults_act_in_file_order_and_on_column_slices():
    x = signal()
    inj = injector(fault("bias_step", 1.0, channel="c"), fault("scale_step", 1.0, channel="c"))
    y = inj.apply(x, 0)
    np.testing.assert_allclose(y[1000:6000, 2], (x[1000:6000, 2] + 1.0) * 2.0, atol=1e-15)
    # the same channel seen as column 0 of a slice holding channels c only
    part = injector(fault("bias_step", 1.0, channel="c")).apply(x[:, 2:3], 0, slice(2, 3))
    np.testing.assert_array_equal(
        part[:, 0], np.where((np.arange(N) >= 1000) & (np.arange(N) < 6000), x[:, 2] + 1.0, x[:, 2])
    )
    block = x[:, :2]  # channels a, b: the fault on c does not touch them
    assert injector(fault("bias_step", 1.0, channel="c")).apply(block, 0, slice(0, 2)) is block


def test_noise_burst_needs_a_white_noise_level():
    sched = parse_schedule({"faults": [fault("noise_burst", 2.0)]}, CHANNELS, UNITS, FS)
    with pytest.raises(ValueError, match="no noise_burst"):
        SensorFaultInjector(sched, FS, 0, None)

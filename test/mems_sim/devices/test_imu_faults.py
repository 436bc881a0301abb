"""Scheduled sensor faults in the IMU model, each against the fault-free run of the same
seed: they act on the analog values before the ADC, on their channel and samples only."""

import numpy as np
import pytest

from mems_sim.devices import imu
from mems_sim.hardware.fault_schedule import parse_schedule
from mems_sim.hardware.sensor_faults import SensorFaultInjector

CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3
N, FRAME, SEED = 3000, 128, 6


def codes_of(entries=(), frame=FRAME):
    model = imu.ImuNoiseModel(seed=SEED)
    if entries:
        sched = parse_schedule({"faults": list(entries)}, CHANNELS, UNITS, model.fs)
        model.faults = SensorFaultInjector(sched, model.fs, SEED, model.white_sample_stds())
    out = []
    for k in range(0, N, frame):
        f = model.generate(min(frame, N - k))
        out.append(np.hstack([f.gyro_codes, f.accel_codes]))
    return np.concatenate(out)


def entry(kind, channel, magnitude=None, **extra):
    e = {"kind": kind, "channel": channel, "start_sample": 1000, "duration_samples": 1200}
    if magnitude is not None:
        e["magnitude"] = magnitude
    e.update(extra)
    return e


@pytest.fixture(scope="module")
def clean():
    return codes_of()


def split(codes, clean, j):
    """The faulty part of channel j, after checking everything else is the clean run's."""
    mask = np.zeros(codes.shape, bool)
    mask[1000:2200, j] = True
    np.testing.assert_array_equal(codes[~mask], clean[~mask])
    return codes[1000:2200, j], clean[1000:2200, j]


def test_no_schedule_is_the_device_bit_for_bit(clean):
    """An empty schedule, and a fault that begins after the run, leave every code alone."""
    np.testing.assert_array_equal(codes_of(frame=97), clean)
    late = dict(entry("sign_flip", "gyro_x"), start_sample=N)
    np.testing.assert_array_equal(codes_of([late]), clean)


def test_stuck_axis_gives_constant_codes(clean):
    got, base = split(codes_of([entry("stuck_at", "gyro_y")]), clean, 1)
    assert np.all(got == got[0]) and got[0] == base[0] and np.ptp(base) > 0


def test_bias_step_moves_the_codes_by_its_magnitude_within_one_lsb(clean):
    lsb = imu.imu_values()["accel_lsb"]
    b = 37.3 * lsb
    got, base = split(codes_of([entry("bias_step", "accel_x", b)]), clean, 3)
    assert np.all(np.abs((got - base) - b / lsb) <= 1.0)
    assert abs(np.mean(got - base) - b / lsb) < 0.1


def test_sign_flip_and_saturation(clean):
    got, base = split(codes_of([entry("sign_flip", "accel_z")]), clean, 5)
    assert np.all(np.abs(got + base) <= 1)  # -x quantised: the mirrored code within 1 LSB
    lsb = imu.imu_values()["gyro_lsb"]
    rail = 2.0 * lsb
    got, base = split(codes_of([entry("saturation", "gyro_z", rail)]), clean, 2)
    assert np.all(np.abs(got) <= 2) and np.any(np.abs(base) > 2)


def test_faults_are_the_same_at_any_frame_size():
    e = [entry("spikes", "gyro_x", 0.05, rate_hz=10.0), entry("noise_burst", "accel_y", 5.0)]
    np.testing.assert_array_equal(codes_of(e, frame=FRAME), codes_of(e, frame=1000))

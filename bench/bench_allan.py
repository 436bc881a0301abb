"""Benchmark: our overlapping Allan deviation vs allantools.oadev, and the IMU emulator rate.

Run:  .venv/bin/python bench/bench_allan.py [n_samples]
Prints both oadev times on 1e7 samples (octave taus, same data, one run), the
ratio, the max relative difference, and the emulator's 6-axis samples/s for 1e6
samples.  The numba compile warm-up is done before timing.
"""

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

import allantools

from mems_estimation.identification.allan import oadev, tau_grid
from mems_sim.devices.imu import ImuNoiseModel


def bench_oadev(n: int, fs: float = 100.0) -> None:
    """Time mems_estimation.identification.allan.oadev and allantools.oadev on n white+RW samples."""
    rng = np.random.default_rng(0)
    y = rng.standard_normal(n) + np.cumsum(rng.standard_normal(n)) * 1e-3
    taus = tau_grid(n, fs, "octave")
    oadev(y[:1000], fs, taus[:3])  # numba compile / cache load
    t0 = time.perf_counter()
    ours = oadev(y, fs, taus)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = allantools.oadev(y, rate=fs, data_type="freq", taus=taus)
    t_ref = time.perf_counter() - t0
    assert np.array_equal(ours[0], ref[0]) and np.array_equal(ours[3], ref[3])
    rel = np.max(np.abs(ours[1] / ref[1] - 1.0))
    print(f"oadev on {n:.0e} samples, {taus.size} octave taus:")
    print(f"  mems_estimation.identification.allan.oadev: {t_ours:.3f} s")
    print(f"  allantools.oadev:            {t_ref:.3f} s")
    print(f"  speed-up: {t_ref / t_ours:.2f}x   max relative difference: {rel:.3e}")


def bench_emulator(n: int = 1_000_000, frame: int = 1000) -> None:
    """6-axis samples/s of ImuNoiseModel, one call and in frames of ``frame``."""
    m = ImuNoiseModel({}, seed=1)
    m.generate(10)  # numba compile / cache load
    t0 = time.perf_counter()
    m.generate(n)
    t_one = time.perf_counter() - t0
    m = ImuNoiseModel({}, seed=1)
    t0 = time.perf_counter()
    for _ in range(n // frame):
        m.generate(frame)
    t_frames = time.perf_counter() - t0
    print(
        f"IMU emulator, {n:.0e} 6-axis samples: {n / t_one:,.0f} samples/s in one call, "
        f"{n / t_frames:,.0f} samples/s in frames of {frame}"
    )


if __name__ == "__main__":
    bench_oadev(int(float(sys.argv[1])) if len(sys.argv) > 1 else 10_000_000)
    bench_emulator()

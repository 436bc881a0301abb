"""Benchmark: overlapping Allan deviation vs allantools.oadev, the streaming identification's
memory and time, and the IMU emulator rate.

Run:  .venv/bin/python bench/bench_allan.py [n_samples] [--stream-seconds S]
Streams S seconds (default 1e6 s) of the 6-axis IMU model at 100 Hz into the identifier's
accumulator (StreamingAllan, as imu_noise_identifier_node and identify_noise run it) and
identifies, printing the peak RSS (target < 500 MB) and the time per sample at 1/10 of the
record and at the whole record (linear: equal per-sample times); then both oadev times on
1e7 samples (octave taus, same data, one run) and on 1e5 samples (the "all" grid: every
averaging factor), the ratios and the max relative differences; then the emulator's 6-axis
samples/s for 1e6 samples; then the eq. (2) sum kernel in its fixed order (eight
accumulators written in the source, the same floats on every CPU) against the loop it
replaced, the same sum with fastmath reassociation (the compiler picks the order and the
vector width per CPU), ns per term and their ratio, interleaved (target >= 0.9).
Numba compile warm-up precedes timing.
"""

import os
import resource
import sys
import time

import numba
import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

import allantools

from mems_estimation.identification.allan import (
    _sum_sq_second_diff,
    oadev,
    rate_to_phase,
    tau_grid,
)
from mems_estimation.identification.allan_stream import StreamingAllan
from mems_estimation.identification.imu_noise_fit import identify_stream
from mems_sim.devices.imu import ImuNoiseModel


def bench_oadev(n: int, fs: float = 100.0, kind: str = "octave") -> None:
    """Time mems_estimation.identification.allan.oadev and allantools.oadev on n white+RW
    samples, on the tau grid ``kind`` ("octave" or "all")."""
    rng = np.random.default_rng(0)
    y = rng.standard_normal(n) + np.cumsum(rng.standard_normal(n)) * 1e-3
    taus = tau_grid(n, fs, kind)
    oadev(y[:1000], fs, taus[:3])  # numba compile / cache load
    t0 = time.perf_counter()
    ours = oadev(y, fs, taus)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = allantools.oadev(y, rate=fs, data_type="freq", taus=taus)
    t_ref = time.perf_counter() - t0
    assert np.array_equal(ours[0], ref[0]) and np.array_equal(ours[3], ref[3])
    rel = np.max(np.abs(ours[1] / ref[1] - 1.0))
    print(f"oadev on {n:.0e} samples, {taus.size} {kind} taus:")
    print(f"  mems_estimation.identification.allan.oadev: {t_ours:.3f} s")
    print(f"  allantools.oadev:            {t_ref:.3f} s")
    print(f"  speed-up: {t_ref / t_ours:.2f}x   max relative difference: {rel:.3e}")


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_stream(seconds: float, fs: float = 100.0, block: int = 100_000) -> None:
    """Peak RSS and time per sample of streaming identification of a 6-axis record."""
    model = ImuNoiseModel({}, seed=1)
    st = StreamingAllan(6, fs, "octave")
    st.add(np.zeros((10, 6)))  # compile / cache load
    st = StreamingAllan(6, fs, "octave")
    base = _rss_mb()
    n_total = int(seconds * fs)
    t_gen = t_acc = 0.0
    marks = {}
    done = 0
    while done < n_total:
        k = min(block, n_total - done)
        t0 = time.perf_counter()
        f = model.generate(k)
        y = np.hstack([f.gyro_si, f.accel_si])
        t1 = time.perf_counter()
        st.add(y)
        t_acc += time.perf_counter() - t1
        t_gen += t1 - t0
        done += k
        if done >= n_total // 10 and "tenth" not in marks:
            marks["tenth"] = (done, t_acc)
    t0 = time.perf_counter()
    results = identify_stream(st)
    t_fit = time.perf_counter() - t0
    n10, t10 = marks["tenth"]
    print(
        f"streaming identification of {seconds:.0e} s at {fs:g} Hz x 6 axes ({n_total:.2e} samples):"
    )
    print(
        f"  accumulator state {st.nbytes() / 1e6:.1f} MB, peak RSS {_rss_mb():.0f} MB "
        f"(target < 500; {base:.0f} MB after imports, compile and the accumulator's allocation)"
    )
    print(
        f"  Allan accumulation {t_acc:.1f} s: {1e9 * t10 / n10:.1f} ns/sample over the first "
        f"tenth, {1e9 * t_acc / n_total:.1f} ns/sample over the whole (linear if equal); "
        f"emulator {t_gen:.1f} s; fit of 6 axes {t_fit:.1f} s"
    )
    print(f"  accel_x: B = {results[3][0].B:.4g} m/s^2, T = {results[3][0].T:.4g} s")


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


@numba.njit(nogil=True, fastmath={"reassoc"})  # not cached: a script's function
def _reassociated_sum(phase, m):
    """The loop the fixed-order kernel replaced: 4096-term blocks, reassociated by LLVM."""
    n = phase.shape[0] - 2 * m
    total = 0.0
    k = 0
    while k < n:
        stop = min(k + 4096, n)
        part = 0.0
        for j in range(k, stop):
            d = phase[j + 2 * m] - 2.0 * phase[j + m] + phase[j]
            part += d * d
        total += part
        k = stop
    return total


def bench_sum_order(n: int = 2_000_000, rounds: int = 7) -> None:
    """ns per term of the fixed-order eq. (2) sum and of the reassociated one, interleaved
    over ``rounds`` rounds of every octave m of n samples; medians and their ratio."""
    rng = np.random.default_rng(3)
    phase = rate_to_phase(rng.standard_normal(n), 100.0)
    ms = [2**k for k in range(int(np.log2(n // 3)))]
    terms = sum(phase.shape[0] - 2 * m for m in ms)
    times = {"fixed": [], "reassoc": []}
    for kernel in (_sum_sq_second_diff, _reassociated_sum):
        kernel(phase, 1)  # compile / cache load
    for _ in range(rounds):
        for name, kernel in (("fixed", _sum_sq_second_diff), ("reassoc", _reassociated_sum)):
            t0 = time.perf_counter()
            for m in ms:
                kernel(phase, m)
            times[name].append((time.perf_counter() - t0) / terms * 1e9)
    fixed, reassoc = (float(np.median(times[k])) for k in ("fixed", "reassoc"))
    rel = max(abs(_sum_sq_second_diff(phase, m) / _reassociated_sum(phase, m) - 1.0) for m in ms)
    print(f"eq. (2) sum kernel, {n:.0e} samples, {len(ms)} octave m, {rounds} rounds:")
    print(
        f"  fixed order {fixed:.3f} ns/term, reassociated {reassoc:.3f} ns/term: "
        f"speed ratio {reassoc / fixed:.2f} (target >= 0.9); max relative difference {rel:.1e}"
    )


if __name__ == "__main__":
    args = sys.argv[1:]
    seconds = 1e6
    if "--stream-seconds" in args:
        i = args.index("--stream-seconds")
        seconds = float(args[i + 1])
        del args[i : i + 2]
    bench_stream(seconds)
    bench_oadev(int(float(args[0])) if args else 10_000_000)
    bench_oadev(100_000, kind="all")
    bench_emulator()
    bench_sum_order()

"""Benchmark: sigma-delta resonator device with its in-loop observer, and the observers alone.

Run:  .venv/bin/python bench/bench_sd_resonator.py [n_samples] [--compare] [--check-only]

Prints samples/s and the real-time factor (samples/s / fs) of
SdResonatorDevice at fs = 1 MHz in observer mode (fast = steady-state gain, and
the exact time-varying gain), sub-sample pulse timing (default), frames of 10,000
samples, output noise on; then
samples/s of KalmanObserver alone (time-varying and steady-state) and of
AdaptiveObserver (7 and 8 states).  Numba compile / cache load is done before timing.

``--compare`` (``--check-only``: without the timing): the kernels against the old
reference of test/resonator_oracles.py (:func:`old_kf_run`, :func:`old_ekf_run`, :func:`old_device_run`: the
generic n x n loops of :func:`~mems_sim.kernels.resonator_kf_steps.kf_update`,
:func:`~mems_sim.kernels.resonator_kf_steps.kf_predict`,
:func:`~mems_sim.kernels.resonator_kf_steps.cov_predict` and the full Jacobian products, as
they were before the structured 6-state kernels, with the adaptive observer's f0 Jacobian
column by central difference).  First every output is checked (:func:`check_equal`): equal
bit for bit for the device frames, every field, of the scenario's device cases and more,
several seeds, and the time-varying Kalman observer (exact model and 5 % f0 error) on
those streams, with their carried state and covariance; within :data:`ADAPTIVE_RTOL` of
each output's scale, with the same monitor resets, for the adaptive observer (7 and 8
states, an f0 step with innovation-monitor resets, a reset() and its warm-up again), whose
f0 Jacobian column is analytic now; then the time per 1000-sample frame of each kernel call and of the whole
``step()`` with its per-frame Python, old and new taking turns, best of N (the machine is
shared: ratios within one run).
"""

import math
import os
import sys
import time
from contextlib import contextmanager

import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.abspath(os.path.join(_HERE, "..")))
sys.path.insert(0, os.path.abspath(os.path.join(_HERE, "..", "test")))  # the test oracles

import resonator_oracles as oracles
from resonator_oracles import (
    _NOISY,
    F0,
    FS,
    Q,
    _device_frames,
    check_equal,
    old_device_run,
    old_ekf_run,
    old_kf_step,
)

import mems_estimation.filters.resonator_adaptive_observer as rao
import mems_sim.devices.resonator as rdev
import mems_sim.kernels.resonator_observer as ro
from mems_estimation.filters.resonator_adaptive_observer import AdaptiveObserver
from mems_sim.devices.resonator import SdResonatorDevice
from mems_sim.kernels.resonator_observer import KalmanObserver


# ------------------------------------------------------------------- kernel timing
class _Timed:
    """A kernel wrapped to add up the wall time of its calls."""

    def __init__(self, fn):
        self.fn, self.t = fn, 0.0

    def __call__(self, *args):
        t0 = time.perf_counter()
        self.fn(*args)
        self.t += time.perf_counter() - t0


@contextmanager
def _timed(module, name, fn):
    """``module.name`` replaced by ``fn`` timed (:class:`_Timed`) inside the block."""
    saved = getattr(module, name)
    timed = _Timed(fn)
    setattr(module, name, timed)
    try:
        yield timed
    finally:
        setattr(module, name, saved)


def compare_times(repeats=7, frames=50, frame=1000) -> None:
    """Time per 1000-sample frame, old reference and current kernels taking turns, best of
    ``repeats`` (the graph's resonator: noisy observer loop with the time-varying gain):
    the kernel call alone, and the whole ``step()`` with its per-frame Python (checks,
    noise draws, output arrays)."""
    fr, _ = _device_frames(_NOISY, 1, frames * frame, frame, False)

    def device(old):
        d = SdResonatorDevice(_NOISY, seed=1)
        with _timed(rdev, "_device_run", old_device_run if old else rdev._device_run) as k:
            for _ in range(frames):
                d.step(frame)
        return k.t

    def kf(old, f0):
        ko = KalmanObserver(f0, Q, FS, 0.25, 5e-4)
        target = (oracles, "old_kf_run") if old else (ro, "_kf_run")
        with _timed(*target, getattr(*target)) as k:
            for f in fr:
                args = (f.bits, f.pulses, f.pulse_start, f.pulse_width)
                old_kf_step(ko, *args) if old else ko.step(*args)
        return k.t

    def ekf(old):
        ao = AdaptiveObserver(1.05 * F0, Q, FS, 0.25, 5e-4)
        with _timed(rao, "_ekf_run", old_ekf_run if old else rao._ekf_run) as k:
            for f in fr:
                ao.step(f.bits, f.pulses, f.pulse_start, f.pulse_width)
        return k.t

    cases = {
        "device (observer loop, time-varying gain)": device,
        "Kalman observer, exact model": lambda old: kf(old, F0),
        "Kalman observer, 5 % f0 error": lambda old: kf(old, 1.05 * F0),
        "adaptive observer (7 states)": ekf,
    }
    print(
        f"ms per {frame}-sample frame, best of {repeats}, old and new taking turns "
        "(kernel call | whole step()):"
    )
    tot = np.zeros((2, 2))
    for name, fn in cases.items():
        fn(True), fn(False)  # compile / cache load
        best = np.full((2, 2), math.inf)  # [old, new] x [kernel, step]
        for _ in range(repeats):
            for i, old in enumerate((True, False)):
                t0 = time.perf_counter()
                tk = fn(old)
                best[i] = np.minimum(best[i], [tk / frames, (time.perf_counter() - t0) / frames])
        tot += best
        print(_times_row(name, best))
    print(_times_row("sum (the single-device graph's kernels)", tot))


def _times_row(name, best):
    (ko, so), (kn, sn) = best * 1e3
    return (
        f"  {name:41s} kernel {ko:6.3f} -> {kn:6.3f} ({ko / kn:4.2f}x) | "
        f"step {so:6.3f} -> {sn:6.3f} ({so / sn:4.2f}x)"
    )


# ---------------------------------------------------------------------- throughput
def _rate(fn, n, repeats=3):
    """Best samples/s over ``repeats`` runs (the machine is shared: the best run is the
    least disturbed one)."""
    fn(1000)  # warm-up (numba cache / compile)
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(n)
        best = max(best, n / (time.perf_counter() - t0))
    return best


def bench_device(n: int, fast: bool, frame: int = 10_000) -> float:
    d = SdResonatorDevice({"output_noise_std": 0.5, "fast": fast}, seed=0)

    def run(m):
        for _ in range(max(1, m // frame)):
            d.step(min(frame, m))

    return _rate(run, n)


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if "--compare" in sys.argv or "--check-only" in sys.argv:
        ok = check_equal()
        if "--check-only" not in sys.argv:
            compare_times()
        if not ok:
            raise SystemExit(1)
        return
    n = int(args[0]) if args else 5_000_000
    for fast in (True, False):
        r = bench_device(n if fast else n // 5, fast)
        print(
            f"device, observer in the loop, fast={fast!s:5}: {r / 1e6:7.2f} Msamples/s = "
            f"{r / FS:6.1f} x real time at fs = 1 MHz" + ("  (target >= 10x)" if fast else "")
        )
    fr = SdResonatorDevice({"output_noise_std": 0.5}, seed=1).step(2_000_000)
    io = (fr.bits, fr.pulses, fr.pulse_start, fr.pulse_width)  # sub-sample pulses
    for ss in (False, True):
        ko = KalmanObserver(F0, Q, FS, 0.5, 1e-4, steady_state=ss)
        r = _rate(lambda m: ko.step(*(x[:m] for x in io)), 2_000_000 if ss else 1_000_000)
        print(
            f"KalmanObserver alone, steady_state={ss!s:5}: {r / 1e6:7.2f} Msamples/s "
            f"({r / FS:5.2f} x real time)"
        )
    for eq in (False, True):
        ao = AdaptiveObserver(F0, Q, FS, 0.5, 1e-4, estimate_q=eq)
        r = _rate(lambda m: ao.step(*(x[:m] for x in io)), 500_000)
        print(
            f"AdaptiveObserver alone ({8 if eq else 7} states): {r / 1e6:7.2f} Msamples/s "
            f"({r / FS:5.2f} x real time)"
        )


if __name__ == "__main__":
    main()

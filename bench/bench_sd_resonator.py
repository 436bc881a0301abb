"""Benchmark: sigma-delta resonator device with its in-loop observer, and the observers alone.

Run:  .venv/bin/python bench/bench_sd_resonator.py [n_samples]
Prints samples/s and the real-time factor (samples/s / fs) of
SdResonatorDevice at fs = 1 MHz in observer mode (fast = steady-state gain, and
the exact time-varying gain), sub-sample pulse timing (default), frames of 10,000
samples, output noise on; then
samples/s of KalmanObserver alone (time-varying and steady-state) and of
AdaptiveObserver (7 and 8 states).  Numba compile / cache load is done before timing.
"""

import os
import sys
import time

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation.filters.resonator_adaptive_observer import AdaptiveObserver
from mems_sim.devices.resonator import SdResonatorDevice
from mems_sim.kernels.resonator_observer import KalmanObserver

FS, F0, Q = 1e6, 5e4, 100.0


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
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 5_000_000
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

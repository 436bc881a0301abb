"""Fast mode: every scenario graph's throughput from its first frame to its last.

Run:  .venv/bin/python bench/bench_scenarios_fast.py [NAME ...] [--warm]

Runs each scenario (default: sd_resonator, scanner_shared_electrodes, scanner_threshold,
gyro_calibration, accelerometer_snr) at seed 1, its default duration, as fast as possible,
without plots, in this process, and prints the summary line ``run_scenario`` prints
(:class:`mems_scenarios.delivery.Throughput`): a single device's real-time factor, several
devices' samples emulated per wall second against the sum of their sample rates; start-up
(imports, graph, discovery) and the figures from the MCAP are excluded, loading the
numba kernels from their cache at their first call is not. ``--warm``: run each scenario
once before the measured run (kernels loaded, modules imported), the steady state.
"""

import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

DEFAULT = (
    "sd_resonator",
    "scanner_shared_electrodes",
    "scanner_threshold",
    "gyro_calibration",
    "accelerometer_snr",
)


def run(name: str, out: str) -> tuple[str | None, float]:
    from mems_scenarios import load
    from mems_scenarios.base import ScenarioOptions
    from mems_scenarios.delivery import THROUGHPUT

    THROUGHPUT.reset()
    t0 = time.monotonic()
    load(name).run(ScenarioOptions(seed=1, out=out, progress=False, plots=False))
    return THROUGHPUT.summary(), time.monotonic() - t0


def main() -> None:
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    names = [a for a in sys.argv[1:] if not a.startswith("--")] or DEFAULT
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            if "--warm" in sys.argv:
                run(name, os.path.join(tmp, f"{name}-warm.mcap"))
            line, total = run(name, os.path.join(tmp, f"{name}.mcap"))
            print(f"{name:26s} {line} (whole run with figures {total:.1f} s wall)", flush=True)


if __name__ == "__main__":
    main()

"""Campaign throughput on Dask: 2 workers vs 1, and the machinery's overhead per run.

Runs the same campaign (``--scenario``, default ``imu_noise``; ``--runs`` seeds of
``--duration`` s each, 0 for the scenario's own duration; every run its own ``run_scenario``
process on its own ROS domain) on a local Dask cluster of one and of two workers, and times
``run_scenario`` alone on the same runs (serially, no Dask): throughput ratio 2 workers /
1 worker (runs per wall second), the campaign's overhead per run against ``run_scenario``
alone, and the cores one run uses alone (CPU seconds of the run's processes per wall
second), measured in one run on this machine.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def env() -> dict:
    e = dict(os.environ)
    e.pop("ROS_DOMAIN_ID", None)  # every run leases a domain of its own
    e["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return e


def duration_args(duration: float) -> list[str]:
    """``--duration S``, or nothing for the scenario's own duration (``duration`` 0)."""
    return ["--duration", str(duration)] if duration > 0 else []


def campaign(scenario: str, runs: int, duration: float, workers: int, out: Path) -> float:
    """Wall seconds of one campaign (``--workers``), its runs all ``ok``."""
    start = time.monotonic()
    subprocess.run(
        [str(BIN / "run_campaign"), scenario, "--seeds", f"1-{runs}", *duration_args(duration)]
        + ["--workers", str(workers), "--out", str(out), "--no-progress"],
        env=env(),
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.monotonic() - start


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def alone(scenario: str, runs: int, duration: float, out: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of the same runs as plain ``run_scenario`` processes, one
    after another (CPU: user + system of the runs and every process they started)."""
    start, cpu0 = time.monotonic(), _children_cpu_s()
    for seed in range(1, runs + 1):
        subprocess.run(
            [str(BIN / "run_scenario"), scenario, "--seed", str(seed), *duration_args(duration)]
            + ["--out", str(out / f"{seed}.mcap"), "--no-plots", "--no-progress", "--json"],
            env=env(),
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    return time.monotonic() - start, _children_cpu_s() - cpu0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="imu_noise")
    p.add_argument("--runs", type=int, default=40)
    p.add_argument("--duration", type=float, default=600.0, help="scenario duration [s]")
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        t1 = campaign(a.scenario, a.runs, a.duration, 1, t / "w1")
        t2 = campaign(a.scenario, a.runs, a.duration, 2, t / "w2")
        (t / "alone").mkdir()
        n_alone = max(4, a.runs // 4)
        ta, cpu_alone = alone(a.scenario, n_alone, a.duration, t / "alone")
    per_run_1 = t1 / a.runs
    per_run_alone = ta / n_alone
    what = f"{a.duration:g} s" if a.duration > 0 else "the scenario's duration"
    print(
        f"{a.scenario} campaign, {a.runs} runs of {what}: 1 worker {t1:.1f} s "
        f"({a.runs / t1:.3f} runs/s), 2 workers {t2:.1f} s ({a.runs / t2:.3f} runs/s); "
        f"throughput ratio 2/1 workers {t1 / t2:.2f} (aim >= 1.7 on 2 cores)"
    )
    print(
        f"run_scenario alone: {per_run_alone:.2f} s per run ({n_alone} runs); campaign with 1 "
        f"worker: {per_run_1:.2f} s per run; overhead per run {per_run_1 - per_run_alone:+.2f} s "
        f"(ratio {per_run_1 / per_run_alone:.2f}); one run alone uses {cpu_alone / ta:.2f} cores"
    )


if __name__ == "__main__":
    main()

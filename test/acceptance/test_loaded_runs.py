"""Acceptance (``make acceptance``): every scenario at its default duration, as a user runs
it (``run_scenario NAME``), with a one-core CPU hog running beside it, five times: every
run exits 0 and its recording holds every message of every topic (no frame-index or
sequence gap, no missing tail against the emulators' end-of-stream records).
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from mems_scenarios import SCENARIOS
from mems_sim.bag import info as info_mod

RUNS = 5


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_loaded_runs_lose_nothing(name, cpu_hog, tmp_path, domain_id):
    walls = []
    for k in range(RUNS):
        out = tmp_path / f"{name}-{k}.mcap"
        cmd = [sys.executable, "-m", "mems_scenarios.cli", name, "--seed", str(k + 1)]
        cmd += ["--out", str(out), "--domain-id", str(domain_id), "--no-plots", "--no-progress"]
        t0 = time.monotonic()
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, cwd=tmp_path)
        walls.append(time.monotonic() - t0)
        assert run.returncode == 0, f"run {k}: " + run.stderr[-3000:]
        info = info_mod.bag_info(str(out))
        assert info_mod.losses(info) == [], f"run {k}: {info_mod.losses(info)}"
        announced = {t: v for t, v in info["topics"].items() if "end_of_stream" in v}
        assert announced, f"run {k}: no end-of-stream record"
        for topic, t in announced.items():
            assert t["count"] == t["end_of_stream"]["messages"], (k, topic)
        out.unlink()
    print(f"\n{name}: {RUNS} loaded runs, wall " + ", ".join(f"{w:.1f}" for w in walls) + " s")

"""Scenario summaries fit a 120-column terminal (wide tables wrap their cells, long lines
wrap at spaces); the full data stay in ``--json``. Every scenario at its default duration is
checked by test/acceptance/test_scenario_tables.py; here the one whose table was widest
(sd_resonator: 661 columns) at its shortest duration."""

from __future__ import annotations

import json
import subprocess
import sys

from mems_sim.table import MAX_WIDTH


def test_sd_resonator_summary_fits_120_columns_and_json_keeps_every_figure(
    tmp_path, subprocess_env
):
    cmd = [sys.executable, "-m", "mems_scenarios.cli", "sd_resonator", "--duration", "0.2"]
    cmd += ["--seed", "1", "--no-plots", "--no-progress", "--json"]
    cmd += ["--out", str(tmp_path / "sd.mcap")]
    run = subprocess.run(cmd, capture_output=True, text=True, env=subprocess_env, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    summary = [line for line in run.stderr.splitlines() if not line.startswith("[")]
    assert max(map(len, summary)) <= MAX_WIDTH, max(summary, key=len)
    start = next(k for k, line in enumerate(summary) if line.startswith("recorded "))
    end = next(k for k, line in enumerate(summary) if line.startswith("frame-index gaps"))
    assert end - start > 1  # the recorded line was wider: it wraps, every topic kept
    recorded = " ".join(summary[start:end]).split(": ", 1)[1].split()
    document = json.loads(run.stdout)
    assert len(document["figures"]) > 10
    assert all({"name", "value", "unit", "target"} <= set(f) for f in document["figures"])
    assert "/sd_comparator/adc" in recorded

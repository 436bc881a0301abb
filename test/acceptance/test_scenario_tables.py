"""Acceptance (``make acceptance``): every scenario at seed 1 and its default duration prints
the same table as the reference recorded for it, cell for cell.

The references in ``reference/`` were printed by the scenarios before the package layout
changed (0.1.0), so a move that claims to keep behaviour is checked against the figures
users saw. Lines that depend on the machine (wall time, real-time factor, log lines with
wall-clock stamps, output paths, the number of
diagnostics messages, which go out once per wall-clock second) are left out of the comparison,
and a table's rule of dashes counts as one rule whatever its widths. A change that is meant to
move a figure regenerates the reference with ``MEMS_UPDATE_REFERENCE=1 make acceptance`` and
says so in the changelog.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mems_scenarios import SCENARIOS

HERE = Path(__file__).resolve().parent
REFERENCE = HERE / "reference"
#: lines whose content depends on the host, not on the emulation
VOLATILE = (
    re.compile(r"^\[(INFO|WARN|ERROR|DEBUG)\]"),  # ROS log lines (wall-clock stamps)
    re.compile(r"\bwall\b"),  # wall time and real-time factors
    re.compile(r"^\s*$"),
)


def comparable(text: str) -> list[str]:
    """The lines of a scenario's output that must not depend on the host, cell by cell: runs of
    spaces count as one (a table's column widths follow its widest cell, and the wall-time
    row that is left out can widen them)."""
    out = []
    for line in text.splitlines():
        if any(p.search(line) for p in VOLATILE):
            continue
        line = re.sub(r"(/tmp/\S*/|runs/)", "<out>/", line.rstrip())
        # diagnostics go out once per wall-clock second: their count is the host's
        line = re.sub(r"/diagnostics \d+", "/diagnostics *", line)
        if re.fullmatch(r"[-\s]+", line):
            # a table's rule: its dashes follow the column widths, which the left-out
            # wall-time row can widen
            line = "---"
        out.append(" ".join(line.split()))
    return out


def test_comparable_drops_host_lines():
    text = (
        "[INFO] [1796.1] [a.b]: started\n"
        "scenario x: seed 1, 1.0 s simulated in 2.9 s wall (as fast as possible)\n"
        "  omega RMSE   22.9 C   0.0022 rad/s\n"
        "recorded runs/x-1.mcap: /a 1, /diagnostics 17\n"
    )
    assert comparable(text) == [
        "omega RMSE 22.9 C 0.0022 rad/s",
        "recorded <out>/x-1.mcap: /a 1, /diagnostics *",
    ]
    assert comparable("figure: /tmp/pytest-1/t0/x-1.png") == ["figure: <out>/x-1.png"]
    assert comparable("  -----  ---\n") == ["---"]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_scenario_table_matches_reference(name, tmp_path, domain_id):
    ref = REFERENCE / f"{name}-seed1.txt"
    cmd = [sys.executable, "-m", "mems_scenarios.cli", name, "--seed", "1", "--no-progress"]
    cmd += ["--out", str(tmp_path / f"{name}-1.mcap"), "--domain-id", str(domain_id)]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    got = comparable(run.stdout + run.stderr)
    if os.environ.get("MEMS_UPDATE_REFERENCE") == "1":
        ref.write_text("\n".join(got) + "\n")
    expected = [
        "---" if re.fullmatch(r"[-\s]+", line) else " ".join(line.split())
        for line in ref.read_text().splitlines()
    ]
    assert got == expected

"""Acceptance (``make acceptance``): every scenario at seed 1 and its default duration gives
the figures of the reference recorded for it, by the comparison rule of docs/testing.md.

``reference/NAME-seed1.json`` holds the scenario's ``--json`` records; they are compared by
``reference_rule.figures_difference`` (names, units, targets and verdicts exact, values
within the fitted rule), never as printed text, whose last digit a one-ulp change may round
the other way. The recorded message counts (integers, the ``recorded ...`` lines of the
table) must be equal. ``reference/NAME-seed1.txt`` keeps the printed table for readers
(lines that depend on the host left out); it is rewritten with the JSON, not compared. The
references of 0.1.0 were printed tables; the JSON references were written by a run whose
printed tables equalled them cell for cell. A change that is meant to move a figure
regenerates the references with ``MEMS_UPDATE_REFERENCE=1 make acceptance`` and says so in
the changelog.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from reference_rule import figures_difference

from mems_scenarios import SCENARIOS
from mems_scenarios.figures import JSON_SCHEMA_VERSION, figures_of
from mems_sim.table import MAX_WIDTH

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


def recorded_lines(lines: list[str]) -> list[str]:
    """The ``recorded ...`` lines (message counts per topic) of comparable table lines, each
    joined with its continuation lines (a summary wraps at 120 columns; topic names and
    counts hold no colon, the next line, ``frame-index gaps: ...``, does)."""
    out: list[str] = []
    joining = False
    for line in lines:
        if line.startswith("recorded "):
            out.append(line)
            joining = True
        elif joining and ":" not in line:
            out[-1] += " " + line
        else:
            joining = False
    return out


def test_recorded_lines_join_wrapped_lines():
    one = ["x", "recorded <out>/x-1.mcap: /a 1, /b 2, /c 3", "frame-index gaps: none"]
    wrapped = ["x", "recorded <out>/x-1.mcap: /a 1,", "/b", "2, /c 3", "frame-index gaps: none"]
    assert recorded_lines(one) == recorded_lines(wrapped) == [one[1]]
    assert recorded_lines(wrapped[:3]) != recorded_lines(one)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_scenario_table_matches_reference(name, tmp_path, domain_id):
    ref_json, ref_text = (REFERENCE / f"{name}-seed1.{ext}" for ext in ("json", "txt"))
    cmd = [sys.executable, "-m", "mems_scenarios.cli", name, "--seed", "1", "--no-progress"]
    cmd += ["--out", str(tmp_path / f"{name}-1.mcap"), "--domain-id", str(domain_id), "--json"]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    document = json.loads(run.stdout)
    assert document["schema_version"] == JSON_SCHEMA_VERSION and document["scenario"] == name
    figures = figures_of(document)
    summary = [line for line in run.stderr.splitlines() if not VOLATILE[0].search(line)]
    assert max(map(len, summary)) <= MAX_WIDTH, max(summary, key=len)  # a terminal's width
    text = comparable(run.stderr)
    if os.environ.get("MEMS_UPDATE_REFERENCE") == "1":
        ref_json.write_text(json.dumps(figures, indent=1) + "\n")
        ref_text.write_text("\n".join(text) + "\n")
    found = figures_difference(figures, figures_of(json.loads(ref_json.read_text())))
    assert found is None, found
    expected = [" ".join(line.split()) for line in ref_text.read_text().splitlines()]
    assert recorded_lines(text) == recorded_lines(expected)
    # the scenario contract at the default duration: the recording alone gives the figures
    analyse = [sys.executable, "-m", "mems_scenarios.cli", name, "--analyse"]
    analyse += [str(tmp_path / f"{name}-1.mcap"), "--json", "--no-plots"]
    again = subprocess.run(analyse, capture_output=True, text=True, timeout=1800, cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    assert figures_of(json.loads(again.stdout)) == figures

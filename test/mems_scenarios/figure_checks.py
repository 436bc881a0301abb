"""Shared checks of a scenario result's figures (``result["figures"]``, the records that
``run_scenario --json`` prints) and of its printed table."""

from __future__ import annotations

import json
import re

from mems_scenarios.figures import to_json, valid_source

KEYS = {"name", "value", "unit", "target", "pass", "source", "role"}


def assert_figures(result: dict) -> dict[str, dict]:
    """Check the figures as JSON (seven keys, unique names, ``pass`` true/false/null and
    ``pass`` and ``source`` null exactly where no target applies, a valid source, ``role``
    headline exactly where judged, at least one headline) and the table (no ``nan`` cell, a
    ``NO`` wherever a target is missed); return the records by name."""
    records = json.loads(to_json(result["figures"]))
    assert records and isinstance(records, list)
    for r in records:
        assert set(r) == KEYS, r
        assert r["pass"] in (True, False, None), r
        assert (r["target"] is None) == (r["pass"] is None) == (r["source"] is None), r
        assert r["source"] is None or valid_source(r["source"]), r
        assert r["role"] == ("context" if r["target"] is None else "headline"), r
        assert r["value"] is None or isinstance(r["value"], int | float | str), r
    names = [r["name"] for r in records]
    assert len(set(names)) == len(names)
    assert any(r["role"] == "headline" for r in records), "a scenario with no target"
    table = result["table"]
    assert not re.search(r"\bnan\b", table, re.IGNORECASE), table
    if any(r["pass"] is False for r in records):
        assert re.search(r"\bNO\b", table), table
    return {r["name"]: r for r in records}


def met_of(table: str, row_start: str) -> str:
    """The last cell (``met``) of the table row that starts with ``row_start``."""
    rows = [line for line in table.splitlines() if line.strip().startswith(row_start)]
    assert rows, row_start
    return rows[0].split()[-1]


def verdict(record: dict) -> str:
    """The ``met`` cell a record calls for."""
    return {True: "yes", False: "NO", None: "-"}[record["pass"]]

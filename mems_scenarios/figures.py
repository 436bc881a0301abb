"""A scenario's figures as data: one :class:`Figure` record per reported number.

Every scenario returns its figures as a list of records (``result["figures"]``) besides the
printed table; ``run_scenario --json`` prints one JSON object (:func:`result_json`):
``{"schema_version", "scenario", "figures", "unavailable", "oracle_only"}``, ``figures``
being a list of objects ``{"name", "value", "unit", "target", "pass", "source", "role"}``:

* ``name``: stable and unique within the scenario, dotted (e.g. ``gyro_x.N.rel_error``);
* ``value``: a number, a string or ``null`` (a value that is not finite, NaN or infinite, is
  written as ``null``, never as ``"nan"``);
* ``unit``: the unit the scenario's table prints, except that ratios and percentages are
  plain fractions (unit ``"1"``); ``""`` for counts, flags and text;
* ``target``: the criterion in words and in the figure's unit (``"<= 0.18 deg"``,
  ``"0.8-1.2"``) or ``null`` where none applies;
* ``pass``: ``true`` or ``false`` where a target applies (``false`` whenever the value is not
  finite or missing), ``null`` where none does;
* ``source``: where the target comes from, ``null`` exactly where there is none: a paper and
  its place (``"Chen 2018 Table 5.3"``, ``"Zhang 2010 Table III"``) or ``"this project's
  criterion: "`` and why (:func:`project_criterion`);
* ``role``: ``"headline"`` for a figure judged against a target, ``"context"`` for a figure
  reported to read the headline ones by (no verdict; a paper's number that a drawn device
  cannot be held to, a count, a diagnostic).

A missed target is reported, not an error: it does not change ``run_scenario``'s exit status.
"""

from __future__ import annotations

import json
import math
import numbers
import re
from dataclasses import dataclass

from mems_sim.table import format_table, yes_no

#: Table cell of a value that is not finite (NaN, infinite) or missing.
NOT_FINITE = "n/a (not finite)"


#: The papers a target may cite (the seed documents of the project), each followed by its place.
PAPERS = ("Zhang 2010", "Chen 2018", "Colinet et al.", "Petkov & Slavov")
#: Prefix of a target that is this project's own criterion; the reason follows it.
PROJECT = "this project's criterion: "
_PAPER_PLACE = re.compile(
    "^("
    + "|".join(map(re.escape, PAPERS))
    + r")( (ch\.|Sec\.|Table|Tables|Fig\.|eq\.|eqs\.) \S.*)$"
)


def project_criterion(why: str) -> str:
    """The ``source`` of a target this project sets: :data:`PROJECT` and the reason."""
    return PROJECT + why


def valid_source(source: str) -> bool:
    """True for ``"<paper> <place> ..."`` (a paper of :data:`PAPERS`, then ch., Sec., Table,
    Fig. or eq.) and for ``"this project's criterion: <why>"``."""
    if source.startswith(PROJECT):
        return bool(source[len(PROJECT) :].strip())
    return bool(_PAPER_PLACE.match(source))


@dataclass(frozen=True)
class Figure:
    """One reported figure.

    Attributes:
        name: stable, machine-friendly name, unique within a scenario.
        value: the figure (number, text, or None where it could not be computed).
        unit: unit of ``value`` (``"1"`` for ratios, ``""`` for counts, flags and text).
        target: the criterion in words (e.g. ``"<= 0.18 deg"``), None where none applies.
        passed: whether the target is met; None exactly when there is no target.
        source: where the target comes from (:func:`valid_source`); None exactly when there
            is no target.
    """

    name: str
    value: float | int | str | None
    unit: str
    target: str | None = None
    passed: bool | None = None
    source: str | None = None

    def __post_init__(self) -> None:
        if (self.target is None) != (self.passed is None):
            raise ValueError(
                f"figure {self.name!r}: a target needs a pass/fail and a pass/fail a target "
                f"(target={self.target!r}, passed={self.passed!r})"
            )
        if (self.target is None) != (self.source is None):
            raise ValueError(
                f"figure {self.name!r}: a target needs a source and a source a target "
                f"(target={self.target!r}, source={self.source!r})"
            )
        if self.source is not None and not valid_source(self.source):
            raise ValueError(
                f"figure {self.name!r}: source {self.source!r} is neither a paper and its place "
                f"({', '.join(PAPERS)}) nor {PROJECT!r} and a reason"
            )

    @property
    def role(self) -> str:
        """``"headline"`` for a judged figure, ``"context"`` for one without a target."""
        return "context" if self.target is None else "headline"

    @property
    def finite(self) -> bool:
        """False for a missing value and a number that is NaN or infinite."""
        return is_finite(self.value)

    @property
    def met(self) -> bool | None:
        """The verdict as reported: None without a target, False for a value that is not
        finite, else ``passed``."""
        if self.target is None:
            return None
        return bool(self.passed) and self.finite

    def record(self) -> dict:
        """The JSON object of the figure (``value`` None where not finite)."""
        return {
            "name": self.name,
            "value": json_value(self.value),
            "unit": self.unit,
            "target": self.target,
            "pass": self.met,
            "source": self.source,
            "role": self.role,
        }


def is_finite(value) -> bool:
    """True for text and finite numbers; False for None, NaN and infinities."""
    if value is None:
        return False
    if isinstance(value, str | bool):
        return True
    return isinstance(value, numbers.Real) and math.isfinite(float(value))


def json_value(value):
    """``value`` as a plain JSON scalar: numpy numbers become Python ones, values that are
    not finite become None."""
    if not is_finite(value):
        return None
    if isinstance(value, str | bool):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    return float(value)


def to_json(figures: list[Figure]) -> str:
    """The figures as a JSON list of :meth:`Figure.record` objects
    (strict JSON: no NaN). Raises ValueError for a name used twice."""
    names = [f.name for f in figures]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"figure names used more than once: {', '.join(twice)}")
    return json.dumps([f.record() for f in figures], indent=1, allow_nan=False)


#: Version of the ``run_scenario --json`` object (the scenario contract's schema version).
JSON_SCHEMA_VERSION = 2


def result_json(
    scenario: str,
    figures: list[Figure],
    unavailable: list[tuple[str, str]] = (),
    oracle_only: list[str] = (),
) -> str:
    """The ``run_scenario --json`` object: schema version, scenario, the figures
    (:func:`to_json`'s records), the figures not computed (``{"figures", "reason"}``) and
    the figure groups of the scenario's oracle step."""
    records = json.loads(to_json(figures))
    return json.dumps(
        {
            "schema_version": JSON_SCHEMA_VERSION,
            "scenario": scenario,
            "figures": records,
            "unavailable": [{"figures": w, "reason": r} for w, r in unavailable],
            "oracle_only": list(oracle_only),
        },
        indent=1,
        allow_nan=False,
    )


def figures_of(document) -> list[dict]:
    """The figure records of a parsed ``run_scenario --json`` document (the object of
    :func:`result_json`, or a bare list of records as schema-less references hold).
    Raises ValueError for anything else or another schema version."""
    if isinstance(document, list):
        return document
    if isinstance(document, dict) and document.get("schema_version") == JSON_SCHEMA_VERSION:
        return document["figures"]
    raise ValueError(f"not a run_scenario --json document of schema {JSON_SCHEMA_VERSION}")


def cell(value, spec: str = ".4g", suffix: str = "") -> str:
    """A table cell of a value: ``format(value, spec) + suffix``, or :data:`NOT_FINITE` for a
    value that is missing, NaN or infinite (never ``nan``)."""
    if not is_finite(value):
        return NOT_FINITE
    if isinstance(value, str | bool):
        return str(value)
    return format(value, spec) + suffix


def met_cell(*figures: Figure) -> str:
    """The ``met`` cell of a table row judged by one or more figures: ``-`` where none has a
    target, ``NO`` where any target is missed (or its value is not finite), else ``yes``."""
    verdicts = [f.met for f in figures if f.met is not None]
    if not verdicts:
        return "-"
    return yes_no(all(verdicts))


def figure_table(figures: list[Figure], spec: str = ".4g") -> str:
    """The figures as a plain table: name, value, unit, target, source, met."""
    rows = [
        [f.name, cell(f.value, spec), f.unit or "-", f.target or "-", f.source or "-", met_cell(f)]
        for f in figures
    ]
    return format_table(["figure", "value", "unit", "target", "source", "met"], rows)

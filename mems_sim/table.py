"""Plain-text tables for command-line summaries."""

from __future__ import annotations


def format_table(header: list[str], rows: list[list[str]]) -> str:
    """Plain-text table with right-aligned columns."""
    widths = [max(len(str(r[i])) for r in [header] + rows) for i in range(len(header))]
    line = "  ".join(h.rjust(w) for h, w in zip(header, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(str(c).rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join([line, sep] + body)


def yes_no(met: bool) -> str:
    """A table cell for a criterion: ``yes`` when met, ``NO`` (loud) when missed."""
    return "yes" if met else "NO"

"""Plain-text tables for command-line summaries, at most :data:`MAX_WIDTH` columns wide."""

from __future__ import annotations

import textwrap

#: widest line a summary prints [characters]: a terminal of 120 columns shows it unbroken
MAX_WIDTH = 120
#: narrowest a column is wrapped to [characters]
_MIN_COLUMN = 8


def _column_widths(header: list[str], rows: list[list[str]], max_width: int) -> list[int]:
    """Natural column widths [characters], narrowed until the table (two spaces between
    columns) fits ``max_width``: first the headers wrap (a column narrows, widest first, down
    to its widest body cell and longest header word), then the widest cells."""
    widths = [max(len(str(r[i])) for r in [header] + rows) for i in range(len(header))]
    body = [max([len(str(r[i])) for r in rows] + [0]) for i in range(len(header))]
    words = [max(len(w) for w in (str(h).split() or [""])) for h in header]
    floors = [max(b, w, 1) for b, w in zip(body, words)]
    for floor in (floors, [_MIN_COLUMN] * len(widths)):
        while sum(widths) + 2 * (len(widths) - 1) > max_width:
            narrowable = [k for k in range(len(widths)) if widths[k] > floor[k]]
            if not narrowable:
                break
            widths[max(narrowable, key=widths.__getitem__)] -= 1
    return widths


def _wrapped_row(cells: list[str], widths: list[int], left: list[bool]) -> list[str]:
    """One table row as one or more lines: a cell wider than its column continues on the
    next lines (at spaces where it has them), the other cells stay on the first line;
    columns marked ``left`` are left-aligned, the others right-aligned."""
    parts = [
        textwrap.wrap(str(c), w, break_on_hyphens=False) or [""] for c, w in zip(cells, widths)
    ]
    height = max(len(p) for p in parts)
    align = [str.ljust if lj else str.rjust for lj in left]
    return [
        "  ".join(
            a(p[k] if k < len(p) else "", w) for p, w, a in zip(parts, widths, align)
        ).rstrip()
        for k in range(height)
    ]


def format_table(header: list[str], rows: list[list[str]], max_width: int = MAX_WIDTH) -> str:
    """Plain-text table with right-aligned columns, at most ``max_width`` characters wide:
    a wider table wraps its headers, then its widest cells over continuation lines (every
    word kept); a column whose body cells wrap is left-aligned (wrapped prose reads so)."""
    widths = _column_widths(header, rows, max_width)
    left = [any(len(str(r[i])) > w for r in rows) for i, w in enumerate(widths)]
    sep = "  ".join("-" * w for w in widths)
    lines = _wrapped_row(header, widths, left) + [sep]
    for r in rows:
        lines += _wrapped_row(r, widths, left)
    return "\n".join(lines)


def fit_lines(text: str, max_width: int = MAX_WIDTH) -> str:
    """``text`` with every line longer than ``max_width`` wrapped at spaces, its continuation
    lines indented two spaces more (prose and list lines of a summary; a word is never
    broken, so a single word wider than ``max_width`` stays whole)."""
    out = []
    for line in text.splitlines():
        if len(line) <= max_width:
            out.append(line)
            continue
        indent = " " * (len(line) - len(line.lstrip()))
        out += textwrap.wrap(
            line,
            max_width,
            subsequent_indent=indent + "  ",
            break_on_hyphens=False,
            break_long_words=False,
        )
    return "\n".join(out)


def significant(value: float, digits: int = 3) -> str:
    """``value`` with ``digits`` significant digits, never a fixed number of decimals (which
    prints 0.376 as 0): 0.376 -> ``0.376``, 119.3 -> ``119``, 1234 -> ``1.23e+03``."""
    return f"{value:.{digits}g}"


def yes_no(met: bool) -> str:
    """A table cell for a criterion: ``yes`` when met, ``NO`` (loud) when missed."""
    return "yes" if met else "NO"

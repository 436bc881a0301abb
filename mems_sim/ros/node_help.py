"""``--help`` of the node executables: usage, what the node does, its parameters.

A node executable takes ROS arguments only (``--ros-args -p name:=value -r __ns:=/ns``);
``-h`` or ``--help`` before any ``--ros-args`` prints the text made here from the node
class's attributes (``NODE_NAME``, ``DEFAULT_NAMESPACE``, ``SPECS``,
``RUNTIME_PARAMETERS``, the first paragraph of its docstring) without starting ROS.
"""

from __future__ import annotations

import inspect
import sys
import textwrap
from dataclasses import replace

from mems_sim.params import ParamSpec

HELP_FLAGS = ("-h", "--help")
#: Columns of the parameter table, in order.
COLUMNS = ("name", "unit", "default", "range")


def wants_help(argv: list[str]) -> bool:
    """True if ``-h`` or ``--help`` comes before the first ``--ros-args`` of ``argv``."""
    for arg in argv:
        if arg == "--ros-args":
            return False
        if arg in HELP_FLAGS:
            return True
    return False


def default_text(spec: ParamSpec) -> str:
    """A parameter's default as it would be written after ``-p name:=``, strings quoted."""
    value = spec.default
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def spec_row(spec: ParamSpec) -> tuple[str, str, str, str]:
    """The table cells of one parameter: name, unit, default, range."""
    return spec.name, spec.unit or "-", default_text(spec), spec.range_text()


def description_text(spec: ParamSpec) -> str:
    """A parameter's description, with its default under the ``realistic`` hardware profile
    where that differs (:func:`~mems_sim.params.profile_specs`)."""
    if spec.realistic is None:
        return spec.description
    real = replace(spec, default=spec.realistic)
    return f"{spec.description} (hardware:=realistic: {default_text(real)})"


def executable_name(node_class: type) -> str:
    """The executable of a node class: its module's last name component (``imu_node``)."""
    return node_class.__module__.rsplit(".", 1)[-1]


def first_paragraph(obj: object) -> str:
    """First paragraph of an object's docstring, on one line ("" if it has none)."""
    doc = inspect.getdoc(obj) or ""
    return " ".join(doc.split("\n\n", 1)[0].split())


def summary(node_class: type) -> str:
    """What the node does: the first paragraph of the node class's docstring."""
    return first_paragraph(node_class)


def _wrap(text: str, width: int, indent: str = "") -> list[str]:
    """Lines of at most ``width`` characters; words (and unit strings) are never split."""
    return textwrap.wrap(
        text,
        width,
        initial_indent=indent,
        subsequent_indent=indent,
        break_long_words=False,
        break_on_hyphens=False,
    )


def node_help(node_class: type, width: int = 100) -> str:
    """The ``--help`` text of a node class (see the module doc)."""
    exe = executable_name(node_class)
    namespace = "/" + node_class.DEFAULT_NAMESPACE.strip("/")
    specs = tuple(node_class.SPECS)
    runtime = tuple(getattr(node_class, "RUNTIME_PARAMETERS", ()))
    module = sys.modules.get(node_class.__module__)
    about = [summary(node_class), first_paragraph(module) if module is not None else ""]
    lines = [f"usage: {exe} [-h] [--ros-args -p name:=value ... -r __ns:=/ns]", ""]
    for paragraph in dict.fromkeys(p for p in about if p):
        lines += [*_wrap(paragraph, width), ""]
    notes = (
        f"Node name: {node_class.NODE_NAME}; default namespace: {namespace} "
        "(-r __ns:=/other to change it).",
        "Parameters are set at start with -p name:=value (or --params-file FILE)"
        + (f"; may also change while running: {', '.join(runtime)}" if runtime else "")
        + ". A value outside its range ends the node with exit code 2.",
    )
    for note in notes:
        lines += _wrap(note, width)
    lines.append("")
    rows = [COLUMNS] + [spec_row(s) for s in specs]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COLUMNS))]
    indent = "      "
    for k, row in enumerate(rows):
        lines.append("  " + "  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
        if k == 0:
            lines.append("  " + "  ".join("-" * w for w in widths))
            continue
        lines.extend(_wrap(description_text(specs[k - 1]), width, indent))
    return "\n".join(lines) + "\n"

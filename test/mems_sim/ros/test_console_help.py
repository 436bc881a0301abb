"""Every console script answers --help with exit code 0 and a usage; a node executable
lists every parameter of its node class with its unit, default and range, and does so
without starting ROS."""

import importlib
import importlib.metadata as md
import inspect
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from mems_sim.ros.node_base import MemsNode
from mems_sim.ros.node_help import node_help, spec_row, wants_help

BIN = Path(sys.executable).parent


def console_scripts() -> dict[str, str]:
    """name -> "module:function" of the installed distribution's console scripts."""
    dist = md.distribution("mems_emulator")
    return {ep.name: ep.value for ep in dist.entry_points if ep.group == "console_scripts"}


def node_class(entry_point: str) -> type | None:
    """The node class of a console script's module, None for a command line tool."""
    module = importlib.import_module(entry_point.split(":")[0])
    classes = [
        c
        for _, c in inspect.getmembers(module, inspect.isclass)
        if issubclass(c, MemsNode) and c.__module__ == module.__name__ and c.NODE_NAME
    ]
    assert len(classes) <= 1, classes
    return classes[0] if classes else None


@pytest.fixture(scope="module")
def helps():
    """name -> completed ``<script> --help`` of every console script (two at a time)."""
    scripts = console_scripts()

    def run(name):
        return subprocess.run(
            [str(BIN / name), "--help"], capture_output=True, text=True, timeout=120
        )

    with ThreadPoolExecutor(max_workers=2) as pool:
        return dict(zip(scripts, pool.map(run, scripts)))


def test_every_console_script_answers_help(helps):
    assert len(helps) >= 18
    for name, done in helps.items():
        assert done.returncode == 0, (name, done.stderr[-2000:])
        assert done.stdout.startswith(f"usage: {name} "), (name, done.stdout[:200])


def parameter_table(help_text: str) -> dict[str, tuple[str, str, str]]:
    """name -> (unit, default, range) read from the columns of a node's --help table."""
    lines = help_text.splitlines()
    k = next(
        i
        for i, line in enumerate(lines)
        if line.split()[:4] == ["name", "unit", "default", "range"]
    )
    header = lines[k]
    starts = [header.index(f"  {c}") + 2 for c in ("name", "unit", "default", "range")]
    table = {}
    for line in lines[k + 2 :]:
        if not line.strip() or line.startswith(" " * (starts[0] + 1)):
            continue  # a description line
        cells = [line[a:b].strip() for a, b in zip(starts, [*starts[1:], None])]
        table[cells[0]] = tuple(cells[1:])
    return table


def test_node_help_lists_every_parameter_with_unit_default_and_range(helps):
    nodes = {name: node_class(ep) for name, ep in console_scripts().items()}
    nodes = {name: cls for name, cls in nodes.items() if cls is not None}
    assert len(nodes) >= 13
    for name, cls in nodes.items():
        out = helps[name].stdout
        assert f"default namespace: /{cls.DEFAULT_NAMESPACE}" in out, name
        expected = {s.name: spec_row(s)[1:] for s in cls.SPECS}
        assert parameter_table(out) == expected, name
        for spec in cls.SPECS:
            assert spec.unit and spec_row(spec)[1] == spec.unit, (name, spec.name)
            assert " ".join(spec.description.split()) in " ".join(out.split()), spec.name


def test_help_comes_before_ros_arguments_only():
    assert wants_help(["imu_node", "--help"])
    assert wants_help(["imu_node", "-h", "--ros-args", "-p", "seed:=1"])
    assert not wants_help(["imu_node", "--ros-args", "-p", "seed:=1", "--help"])
    assert not wants_help(["imu_node"])


def test_node_help_does_not_start_ros(capsys):
    """main(["imu_node", "--help"]) in this process: exit code 0, rclpy never initialised."""
    import rclpy

    from mems_sim.nodes import imu_node

    assert imu_node.main(["imu_node", "--help"]) == 0
    assert capsys.readouterr().out == node_help(imu_node.ImuNode)
    assert not rclpy.ok()

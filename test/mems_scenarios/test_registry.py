"""Where scenarios and node classes are found: the entry-point group and the executables."""

from __future__ import annotations

import ast
from importlib.metadata import EntryPoint
from pathlib import Path

import mems_scenarios
from mems_scenarios.contract import NODE_MODULES, node_class

SETUP = Path(__file__).resolve().parents[2] / "setup.py"


def setup_entry_points() -> dict[str, dict[str, str]]:
    """setup.py's entry points: group -> name -> target (read from its source)."""
    tree = ast.parse(SETUP.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "entry_points":
            groups = ast.literal_eval(node.value)
            return {
                g: dict(e.replace(" ", "").split("=", 1) for e in entries)
                for g, entries in groups.items()
            }
    raise AssertionError("setup.py has no entry_points")


def test_builtin_scenarios_are_registered():
    assert setup_entry_points()[mems_scenarios.ENTRY_POINT_GROUP] == mems_scenarios.BUILTIN
    assert list(mems_scenarios.SCENARIOS)[: len(mems_scenarios.BUILTIN)] == list(
        mems_scenarios.BUILTIN
    )


def test_another_package_adds_a_scenario(monkeypatch):
    theirs = [
        EntryPoint("my_bench", "my_pkg.my_bench", mems_scenarios.ENTRY_POINT_GROUP),
        EntryPoint("imu_noise", "my_pkg.shadow", mems_scenarios.ENTRY_POINT_GROUP),
    ]
    import importlib.metadata

    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: theirs)
    found = mems_scenarios._registered()
    assert found["my_bench"] == "my_pkg.my_bench"
    assert found["imu_noise"] == "mems_scenarios.imu_noise"  # ours stays ours


def test_node_modules_are_the_executables():
    scripts = setup_entry_points()["console_scripts"]
    for executable, module in NODE_MODULES.items():
        assert scripts[executable] == f"{module}:main"
        assert node_class(executable).NODE_NAME
    nodes = {e for e, t in scripts.items() if ".nodes." in t}
    assert nodes == set(NODE_MODULES)

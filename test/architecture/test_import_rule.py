"""The import rule of the README's layout section, checked on the source tree (AST walk).

Imports go one way: ``mems_sim`` (devices, kernels, ROS plumbing, emulator nodes, bag
tools) imports nothing from ``mems_estimation`` or ``mems_scenarios``; ``mems_estimation``
imports from ``mems_sim`` only; ``mems_scenarios`` imports both. No module-level import
cycle between modules, and tests and benchmarks import scenarios only through their
public entry (``run``, ``NAME``, ``DESCRIPTION``, ``DEFAULT_DURATION_S``; ``run_graph`` and
the graph layout constants ``INSTANCES``, ``RECORDED``, ``FRAME`` for benchmarks); the
skeleton (``base``), the figure records (``figures``) and the command line are library.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("mems_sim", "mems_estimation", "mems_scenarios")
#: What each layer may import from this project (itself included).
ALLOWED = {
    "mems_sim": {"mems_sim"},
    "mems_estimation": {"mems_sim", "mems_estimation"},
    "mems_scenarios": {"mems_sim", "mems_estimation", "mems_scenarios"},
}
#: What tests and benchmarks may take from a scenario module: its entry, its description and
#: the graph-only entry with the graph's documented layout (benchmarks run the graph alone).
SCENARIO_PUBLIC = {
    "run",
    "NAME",
    "DESCRIPTION",
    "DEFAULT_DURATION_S",
    "run_graph",
    "INSTANCES",
    "RECORDED",
    "FRAME",
}


def module_name(path: Path, root: Path = REPO) -> str:
    """Dotted module name of a source file under ``root``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(source: str, module: str, is_package: bool = False) -> list[tuple[str, int]]:
    """(imported module, line) of every import in ``source`` (relative ones resolved),
    at any depth (imports inside functions count)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = module.split(".") if is_package else module.split(".")[:-1]
                pkg = pkg[: len(pkg) - node.level + 1]
                base = ".".join(pkg + ([base] if base else []))
            found.append((base, node.lineno))
            # "from pkg import submodule" imports the submodule too
            found += [(f"{base}.{alias.name}", node.lineno) for alias in node.names]
    return found


def violations(source: str, module: str, is_package: bool = False) -> list[str]:
    """Imports in ``source`` (the text of ``module``) against the layer rule."""
    layer = module.split(".")[0]
    out = []
    for target, line in imported_modules(source, module, is_package):
        top = target.split(".")[0]
        if top in PACKAGES and top not in ALLOWED[layer]:
            out.append(
                f"{module}:{line} imports {target} ({layer} may import only "
                f"{', '.join(sorted(ALLOWED[layer]))})"
            )
    return out


def package_sources():
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            yield path, module_name(path)


def test_layers_import_one_way():
    found = []
    for path, module in package_sources():
        found += violations(path.read_text(), module, path.name == "__init__.py")
    assert not found, "\n".join(found)


def test_every_project_import_resolves():
    """A moved module leaves no import of its old place behind (relative ones included)."""
    import importlib.util

    def exists(name):
        try:
            return importlib.util.find_spec(name) is not None
        except (ModuleNotFoundError, AttributeError):  # a name inside a module, not a module
            return False

    missing = []
    for path, module in package_sources():
        for target, line in imported_modules(path.read_text(), module, path.name == "__init__.py"):
            if target.split(".")[0] not in PACKAGES:
                continue
            parent = target.rsplit(".", 1)[0]
            if not exists(target) and not exists(parent):
                missing.append(f"{module}:{line} imports {target}")
    assert not missing, "\n".join(missing)


def test_the_rule_catches_a_wrong_import():
    """A device module importing a filter, and a filter importing a scenario, are caught;
    the allowed directions are not."""
    wrong = "import numpy\nfrom mems_estimation.filters import stage_ekf\n"
    assert violations(wrong, "mems_sim.devices.stage") == [
        "mems_sim.devices.stage:2 imports mems_estimation.filters (mems_sim may import only "
        "mems_sim)",
        "mems_sim.devices.stage:2 imports mems_estimation.filters.stage_ekf (mems_sim may "
        "import only mems_sim)",
    ]
    lazy = "def f():\n    from mems_scenarios import base\n"
    assert len(violations(lazy, "mems_estimation.nodes.stage_ekf_node")) == 2
    relative = "from ...mems_estimation import filters\n"
    assert violations(relative, "mems_sim.devices.stage")  # relative imports are resolved
    ok = "from mems_sim.devices import stage\nfrom mems_estimation.filters import stage_ekf\n"
    assert violations(ok, "mems_scenarios.stage_gyro_calibration") == []
    assert violations(ok, "mems_estimation.nodes.stage_ekf_node") == []


def module_graph() -> dict[str, set[str]]:
    """Project-internal module -> modules it imports (any depth), packages resolved to their
    ``__init__`` module name."""
    modules = {module for _, module in package_sources()}
    graph = {}
    for path, module in package_sources():
        deps = set()
        for target, _ in imported_modules(path.read_text(), module, path.name == "__init__.py"):
            if target in modules and target != module:
                deps.add(target)
        graph[module] = deps
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` (as a list of modules), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph.get(node, ())):
            if state.get(dep) == 1:
                return stack[stack.index(dep) :] + [dep]
            if dep not in state:
                cycle = visit(dep)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def is_package_parent(a: str, b: str) -> bool:
    return b.startswith(a + ".") or a.startswith(b + ".")


def test_no_import_cycle():
    graph = module_graph()
    # a package's __init__ importing its own submodule is not a cycle between modules
    graph = {m: {d for d in deps if not is_package_parent(m, d)} for m, deps in graph.items()}
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_detection_works():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


@pytest.mark.parametrize("folder", ["test", "bench"])
def test_tests_and_benches_use_scenarios_only_through_their_entry(folder):
    """Scenario modules are programs: tests and benches run them through ``run`` (or the
    command line) and take anything else from library modules."""
    found = []
    for path in sorted((REPO / folder).rglob("*.py")):
        tree = ast.parse(path.read_text())
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "mems_scenarios"
            ):
                if node.module == "mems_scenarios":
                    for alias in node.names:
                        if alias.name in {"SCENARIOS", "load"}:
                            continue
                        aliases[alias.asname or alias.name] = alias.name
                elif node.module in {
                    "mems_scenarios.base",
                    "mems_scenarios.cli",
                    "mems_scenarios.figures",
                    "mems_scenarios.campaign",
                    "mems_scenarios.container",
                    "mems_scenarios.launch_graph",
                }:
                    # the skeleton, figure records, command lines, campaigns, the node
                    # container, run_graph's launch reader: tools, not scenarios; public
                    continue
                else:
                    bad = [a.name for a in node.names if a.name not in SCENARIO_PUBLIC]
                    if bad:
                        found.append(
                            f"{path.relative_to(REPO)}:{node.lineno} takes {bad} from {node.module}"
                        )
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and node.attr not in SCENARIO_PUBLIC
            ):
                found.append(
                    f"{path.relative_to(REPO)}:{node.lineno} uses "
                    f"{aliases[node.value.id]}.{node.attr}"
                )
    assert not found, "\n".join(found)

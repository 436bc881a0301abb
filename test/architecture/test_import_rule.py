"""The import rule of the README's layout section, checked on the source tree (AST walk).

Imports go one way: ``mems_sim`` (devices, kernels, ROS plumbing, emulator nodes, bag
tools) imports nothing from ``mems_estimation`` or ``mems_scenarios``; ``mems_estimation``
imports from ``mems_sim`` only; ``mems_scenarios`` imports both. No module-level import
cycle between modules, and tests and benchmarks import scenarios only through their
public entry (``run``, ``NAME``, ``DESCRIPTION``, ``DEFAULT_DURATION_S``; the contract's
``graph``, ``analyse``, ``oracle`` and its figure group ``ORACLE``; ``run_graph`` and
the graph layout constants ``INSTANCES``, ``RECORDED``, ``FRAME`` for benchmarks); the
skeleton (``base``, ``delivery``, ``bag_frames``), the contract (``contract``), the figure records (``figures``) and the
command line are library.

Inside a package, sub-packages import one way too (:data:`SUBPACKAGE_RULE`, any depth,
imports inside functions included). The package's top-level modules (``mems_sim.params``,
``bounded_yaml``, ``cli_values``, ``cpu_pins``, ``table``, ``stream_index``, ``views``) are
the base every sub-package may use; they import no sub-package. Then, for ``mems_sim``::

    base < kernels < hardware < devices (the numerical core, ROS-free)
    base < ros < bag                    (ROS plumbing, then the MCAP tools)
    nodes: above devices, kernels, ros and bag

and for ``mems_estimation``::

    filters < identification < studies  (the ROS-free core, then the seeded studies)
    filters, identification < nodes < tools

(``devices`` and ``ros`` do not see each other; ``studies`` and ``nodes`` neither;
``mems_scenarios`` has no sub-packages.) The ROS-free core (:data:`ROS_FREE`:
``mems_sim.devices``, ``mems_sim.hardware``, ``mems_sim.kernels``, ``mems_estimation.filters``,
``mems_estimation.identification``) imports no ROS client library or message package
(:func:`is_ros_module`), neither itself nor through any project module it imports, at any
depth. :func:`test_the_layering_catches_a_wrong_import` feeds deliberate wrong imports (a
kernel importing a device module, a filter importing ``rclpy``) to the checkers.
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
#: The library of mems_scenarios, public to tests and benchmarks: the skeleton, its delivery
#: and frame reading, the contract, figure records, command lines, campaigns, the node
#: container, run_graph's launch reader and the domain leases (tools, not scenarios).
SCENARIO_LIBRARY = {
    "base",
    "delivery",
    "bag_frames",
    "contract",
    "cli",
    "figures",
    "campaign",
    "component_container",
    "run_graph",
    "launch_file",
    "staged_outputs",
    "domain",
}
SCENARIO_PUBLIC = {
    "run",
    "graph",
    "analyse",
    "oracle",
    "ORACLE",
    "NAME",
    "DESCRIPTION",
    "DEFAULT_DURATION_S",
    "run_graph",
    "INSTANCES",
    "RECORDED",
    "FRAME",
}


#: Sub-package -> the sub-packages of its package it may import (itself and the package's
#: top-level modules, "base", always). A module of a package not listed here, or a
#: top-level module, is "base" and may import base modules only.
SUBPACKAGE_RULE = {
    "mems_sim": {
        "kernels": set(),
        "hardware": {"kernels"},
        "devices": {"kernels", "hardware"},
        "ros": set(),
        "bag": {"ros"},
        "nodes": {"kernels", "hardware", "devices", "ros", "bag"},
    },
    "mems_estimation": {
        "filters": set(),
        "identification": {"filters"},
        "studies": {"filters", "identification"},
        "nodes": {"filters", "identification"},
        "tools": {"filters", "identification", "nodes"},
    },
}
#: The ROS-free numerical core: no ROS import, directly or through a project module.
ROS_FREE = (
    "mems_sim.devices",
    "mems_sim.hardware",
    "mems_sim.kernels",
    "mems_estimation.filters",
    "mems_estimation.identification",
)
#: Top-level names of ROS client libraries and message packages (and those of
#: :func:`is_ros_module`'s patterns: ``*_msgs``, ``*_srvs``, ``*_interfaces``, ``rcl*``,
#: ``rosidl*``, ``rosbag2*``).
ROS_PACKAGES = frozenset(
    {
        "rclpy",
        "rosgraph_msgs",
        "sensor_msgs",
        "std_msgs",
        "builtin_interfaces",
        "mems_msgs",
        "diagnostic_msgs",
        "geometry_msgs",
        "rcl_interfaces",
        "launch",
        "launch_ros",
        "ament_index_python",
        "rpyutils",
    }
)


def is_ros_module(name: str) -> bool:
    """True for a module of ROS 2 (client library, message/service package, launch)."""
    top = name.split(".")[0]
    return (
        top in ROS_PACKAGES
        or top.endswith(("_msgs", "_srvs", "_interfaces", "_actions"))
        or top.startswith(("rcl", "rosidl", "rosbag2"))
    )


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


def subpackage(module: str) -> str:
    """The sub-package of a project module ("base" for a top-level module or package)."""
    parts = module.split(".")
    sub = parts[1] if len(parts) > 1 else "base"
    return sub if sub in SUBPACKAGE_RULE.get(parts[0], {}) else "base"


def layering_violations(source: str, module: str, is_package: bool = False) -> list[str]:
    """Imports in ``source`` (the text of ``module``) of a sub-package of its own package
    that :data:`SUBPACKAGE_RULE` does not allow."""
    pkg, sub = module.split(".")[0], subpackage(module)
    if pkg not in SUBPACKAGE_RULE:
        return []
    allowed = {"base", sub} | SUBPACKAGE_RULE[pkg].get(sub, set())
    out, seen = [], set()
    for target, line in imported_modules(source, module, is_package):
        if target.split(".")[0] != pkg or target == pkg:
            continue
        other = subpackage(target)
        if other not in allowed and (line, other) not in seen:  # once per statement
            seen.add((line, other))
            out.append(
                f"{module}:{line} imports {target} ({pkg}.{sub} may import only "
                f"{', '.join(sorted(allowed))} of {pkg})"
            )
    return out


def ros_imports(source: str, module: str, is_package: bool = False) -> list[str]:
    """Direct imports of ROS modules (:func:`is_ros_module`) in ``source``, any depth."""
    return [
        f"{module}:{line} imports {target}"
        for target, line in imported_modules(source, module, is_package)
        if is_ros_module(target)
    ]


def in_ros_free_core(module: str) -> bool:
    return any(module == c or module.startswith(c + ".") for c in ROS_FREE)


def ros_reach(sources: dict[str, tuple[str, bool]]) -> dict[str, list[str]]:
    """For each module of ``sources`` (module -> (text, is_package)): a chain of imports
    (any depth) from it to a ROS import, through project modules of ``sources``, or no
    entry if it reaches none."""
    direct = {m: ros_imports(text, m, pkg) for m, (text, pkg) in sources.items()}
    deps = {
        m: sorted(
            {t for t, _ in imported_modules(text, m, pkg) if t in sources and t != m}
            | {t.rsplit(".", 1)[0] for t, _ in imported_modules(text, m, pkg)}
            & (set(sources) - {m})
        )
        for m, (text, pkg) in sources.items()
    }
    reach: dict[str, list[str]] = {}
    for start in sources:
        seen, queue = {start: [start]}, [start]
        while queue and start not in reach:
            m = queue.pop(0)
            if direct[m]:
                reach[start] = seen[m] + [direct[m][0].split(" imports ")[1]]
                break
            for d in deps[m]:
                if d not in seen:
                    seen[d] = seen[m] + [d]
                    queue.append(d)
    return reach


def package_sources():
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            yield path, module_name(path)


def test_layers_import_one_way():
    found = []
    for path, module in package_sources():
        found += violations(path.read_text(), module, path.name == "__init__.py")
    assert not found, "\n".join(found)


def test_subpackages_import_one_way():
    found = []
    for path, module in package_sources():
        found += layering_violations(path.read_text(), module, path.name == "__init__.py")
    assert not found, "\n".join(found)


def test_the_numerical_core_is_ros_free():
    """No module under devices, kernels, filters or identification imports ROS, neither
    directly nor through the project modules it imports (chain shown)."""
    sources = {
        module: (path.read_text(), path.name == "__init__.py") for path, module in package_sources()
    }
    reach = ros_reach(sources)
    found = [" -> ".join(chain) for m, chain in sorted(reach.items()) if in_ros_free_core(m)]
    assert not found, "\n".join(found)


def test_the_layering_catches_a_wrong_import():
    """A kernel importing a device module, a device importing a node, ROS plumbing
    importing the bag tools, a filter importing a study and a filter importing rclpy (at
    function depth or through a project module) are reported; the allowed directions are
    not."""
    kernel = "import numpy\nfrom mems_sim.devices import resonator\n"
    assert layering_violations(kernel, "mems_sim.kernels.resonator_observer") == [
        "mems_sim.kernels.resonator_observer:2 imports mems_sim.devices (mems_sim.kernels may "
        "import only base, kernels of mems_sim)"
    ]
    lazy = "def f():\n    from ..nodes.stage_node import StageNode\n"  # relative, lazy
    assert layering_violations(lazy, "mems_sim.devices.stage") == [
        "mems_sim.devices.stage:2 imports mems_sim.nodes.stage_node (mems_sim.devices may "
        "import only base, devices, hardware, kernels of mems_sim)"
    ]
    assert layering_violations("from mems_sim.bag.schema import schema_text\n", "mems_sim.ros.x")
    study = "from mems_estimation.studies.scanner_threshold import rmse\n"
    assert layering_violations(study, "mems_estimation.filters.stage_ekf")
    assert layering_violations(study, "mems_estimation.nodes.stage_ekf_node")
    ok = (
        "from mems_sim import params\nfrom mems_sim.kernels import resonator_models\n"
        "from mems_estimation.filters import stage_ekf\n"
    )
    assert layering_violations(ok, "mems_sim.devices.resonator") == []
    assert layering_violations(ok, "mems_estimation.studies.stage_sf_curve") == []
    assert layering_violations("from mems_sim.bag import writer\n", "mems_sim.nodes.x") == []

    rclpy = "import numpy as np\n\n\ndef run():\n    import rclpy.node\n"
    assert ros_imports(rclpy, "mems_estimation.filters.stage_ekf") == [
        "mems_estimation.filters.stage_ekf:5 imports rclpy.node"
    ]
    assert ros_imports("from sensor_msgs.msg import Imu\n", "mems_sim.devices.imu")
    assert ros_imports("from mems_sim.devices import imu\n", "mems_sim.devices.x") == []
    chain = ros_reach(
        {
            "mems_estimation.filters.f": ("from mems_sim.ros import frames\n", False),
            "mems_sim.ros.frames": ("from builtin_interfaces.msg import Time\n", False),
            "mems_sim.kernels.k": ("import numpy\n", False),
        }
    )
    assert chain == {
        "mems_estimation.filters.f": [
            "mems_estimation.filters.f",
            "mems_sim.ros.frames",
            "builtin_interfaces.msg",
        ],
        "mems_sim.ros.frames": ["mems_sim.ros.frames", "builtin_interfaces.msg"],
    }
    assert is_ros_module("mems_msgs.msg") and is_ros_module("rosgraph_msgs.msg")
    assert not is_ros_module("numpy") and not is_ros_module("mems_sim.ros.qos")


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
    assert violations(ok, "mems_scenarios.gyro_calibration") == []
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
                        if alias.name in {"SCENARIOS", "load"} | SCENARIO_LIBRARY:
                            continue
                        aliases[alias.asname or alias.name] = alias.name
                elif node.module.removeprefix("mems_scenarios.") in SCENARIO_LIBRARY:
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

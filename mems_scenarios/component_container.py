"""``component_container``: several nodes in one process, spun by one executor.

Usage::

    component_container [--ros-args ARGS] --node PLUGIN [--ros-args ARGS] [--node ...]

ROS 2's composition runs nodes as components of one process (rclcpp_components'
``component_container``, loaded through the composition_interfaces services); neither it,
launch_ros nor those services are distributed as Python wheels, so this container takes
its nodes on its command line instead, and ``run_graph`` turns a launch file's
``node_container`` with ``composable_node`` entries into that command line. It lives
with ``run_graph`` on the scenarios' side because it loads node classes of both the
device and the estimation side by name.

``PLUGIN`` is a node executable of this package (``resonator_observer_node``: the node
class it runs) or ``MODULE:CLASS`` (any rclpy node class whose constructor takes rclpy
Node's keyword arguments, ``cli_args`` among them). The ``--ros-args`` section after a
``--node PLUGIN`` belongs to that node alone (rcl's node arguments: ``-r __node:=NAME``,
``-r __ns:=/NS``, ``-p P:=V``, ``--params-file F``, ``-r A:=B``); the section before the
first ``--node`` is the process's (``--log-level``, ...), and parameters or remappings
there apply to every node.

Why: with a process per node, the middleware delivers every frame to each process and
each process's executor wakes for it; in one container, one process and one executor
serve all its nodes (each node still takes and deserialises its own message). Measured
with the resonator's three observers on one 1 MHz bit stream at 1.5x real time
(docs/profiles.md): 0.75-0.79x the CPU of three processes. The nodes share one thread.

Behaviour as a node executable's: an invalid parameter of any node ends the process with
exit status 2 and one line naming the node and the parameter; SIGINT or SIGTERM closes
every node (each publishes its final results, e.g. a noise identifier's ``final`` model)
before the process exits with status 0; an unknown plugin or a malformed command line is
one line and exit status 2 before ROS starts.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import sys
from importlib.metadata import PackageNotFoundError, distribution

PROG = "component_container"
#: Distribution whose console scripts are the node executables a plugin may name.
PACKAGE = "mems_emulator"
USAGE = f"""usage: {PROG} [--ros-args ARGS] --node PLUGIN [--ros-args ARGS] [--node PLUGIN ...]

Several nodes in one process and one executor (ROS 2 composition).

  PLUGIN     a node executable of {PACKAGE} (e.g. resonator_observer_node)
             or MODULE:CLASS (an rclpy node class)
  --ros-args after --node PLUGIN: that node's own arguments (-r __node:=NAME,
             -r __ns:=/NS, -p P:=V, --params-file F, -r A:=B); before the
             first --node: the process's (--log-level LEVEL, ...)
"""


class ContainerError(Exception):
    """A malformed command line or a plugin that names no node class."""


def split_command_line(argv: list[str]) -> tuple[list[str], list[tuple[str, list[str]]]]:
    """The container's own arguments and ``(plugin, node arguments)`` per ``--node``.

    Args:
        argv: the command line without the program name.
    """
    own: list[str] = []
    nodes: list[tuple[str, list[str]]] = []
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--node" or arg.startswith("--node="):
            if arg == "--node":
                if i + 1 >= len(argv):
                    raise ContainerError("--node needs a PLUGIN")
                plugin, i = argv[i + 1], i + 2
            else:
                plugin, i = arg.partition("=")[2], i + 1
            if not plugin or plugin.startswith("-"):
                raise ContainerError(f"--node needs a PLUGIN, got {plugin!r}")
            nodes.append((plugin, []))
        else:
            (nodes[-1][1] if nodes else own).append(arg)
            i += 1
    if not nodes:
        raise ContainerError("no --node PLUGIN given")
    for plugin, args in nodes:
        if args and args[0] != "--ros-args":
            raise ContainerError(
                f"--node {plugin}: {args[0]!r} is not a --ros-args section (a node takes "
                "only ROS arguments)"
            )
    if own and own[0] != "--ros-args":
        raise ContainerError(f"unrecognised argument {own[0]!r} (see --help)")
    return own, nodes


def node_label(plugin: str, args: list[str], cls: type | None = None) -> str:
    """How error lines name a node: its fully qualified name as its ``__ns`` and ``__node``
    remappings, or else the class's ``DEFAULT_NAMESPACE`` and ``NODE_NAME``, tell; and its
    plugin."""
    remaps = {}
    for flag, value in zip(args, args[1:]):
        if flag in ("-r", "--remap") and value.startswith(("__node:=", "__ns:=")):
            key, _, v = value.partition(":=")
            remaps[key] = v
    name = remaps.get("__node", getattr(cls, "NODE_NAME", ""))
    ns = remaps.get("__ns", getattr(cls, "DEFAULT_NAMESPACE", ""))
    if name:
        ns = "/" + ns.strip("/") if ns.strip("/") else ""
        return f"node {ns}/{name} ({plugin})"
    return f"node {plugin}"


def _executables() -> dict[str, str]:
    """``{executable: 'module:function'}`` of this package's console scripts."""
    try:
        eps = distribution(PACKAGE).entry_points
    except PackageNotFoundError:  # pragma: no cover - the package runs installed
        return {}
    return {ep.name: ep.value for ep in eps if ep.group == "console_scripts"}


def resolve_plugin(plugin: str) -> type:
    """The node class ``plugin`` names: ``MODULE:CLASS``, or a node executable of this
    package (the one ``MemsNode`` subclass its module defines)."""
    from rclpy.node import Node

    from mems_sim.ros.node_base import MemsNode

    if ":" in plugin:
        module_name, _, class_name = plugin.partition(":")
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise ContainerError(
                f"plugin {plugin!r}: cannot import {module_name!r}: {exc}"
            ) from None
        cls = getattr(module, class_name, None)
        if not (inspect.isclass(cls) and issubclass(cls, Node)):
            raise ContainerError(f"plugin {plugin!r}: {class_name!r} is not a node class")
        return cls
    target = _executables().get(plugin)
    if target is None:
        raise ContainerError(
            f"plugin {plugin!r}: not an executable of {PACKAGE} (give a node executable, "
            "e.g. resonator_observer_node, or MODULE:CLASS)"
        )
    module = importlib.import_module(target.partition(":")[0])
    classes = [
        c
        for c in vars(module).values()
        if inspect.isclass(c) and issubclass(c, MemsNode) and c.__module__ == module.__name__
    ]
    if len(classes) != 1:
        raise ContainerError(f"plugin {plugin!r}: executable {plugin!r} does not run a node")
    return classes[0]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``component_container``."""
    argv = list(sys.argv if argv is None else argv)
    if argv[1:2] in (["-h"], ["--help"]):
        sys.stdout.write(USAGE)
        return 0
    try:
        own, plugins = split_command_line(argv[1:])
        classes = [resolve_plugin(plugin) for plugin, _ in plugins]
    except ContainerError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    from mems_sim.ros.node_main import run_nodes

    factories = [
        (node_label(plugin, args, cls), functools.partial(cls, cli_args=args))
        for (plugin, args), cls in zip(plugins, classes, strict=True)
    ]
    return run_nodes(factories, [argv[0], *own])


if __name__ == "__main__":
    sys.exit(main())

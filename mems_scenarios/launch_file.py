"""The ROS 2 launch-YAML reader of ``run_graph``: the ``launch`` list (``arg``, ``let``,
``node``, ``include``, ``node_container``), its substitutions and checks, into a
:class:`Graph` of node actions with their command lines. The format: docs/graphs.md.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from mems_sim import bounded_yaml
from mems_sim.ros.params_file import ParamsFileError, load_params_file

PROG = "run_graph"


#: Entries of the ``launch`` list and the attributes of each.
TAGS = {
    "arg": {"name", "default", "description"},
    "let": {"name", "value"},
    "node": {"pkg", "exec", "name", "namespace", "param", "remap", "output"},
    "include": {"file", "arg"},
    "node_container": {"pkg", "exec", "name", "namespace", "output", "composable_node"},
}

#: Attributes of a ``composable_node`` of a ``node_container``.
COMPOSABLE = {"pkg", "plugin", "name", "namespace", "param", "remap"}

REQUIRED = {
    "arg": ("name",),
    "let": ("name", "value"),
    "node": ("pkg", "exec"),
    "include": ("file",),
    "node_container": ("pkg", "exec", "name", "composable_node"),
}

OUTPUTS = ("screen", "log")

#: Deepest chain of includes (deeper: an include cycle).
MAX_INCLUDE_DEPTH = 20
#: Most launch files read for one graph, the root and every include counted (a file that
#: includes the next one twice, 20 deep, would read 2**21 files within the depth cap).
MAX_INCLUDE_LOADS = 1000

#: ``$( ... )`` without nested parentheses.
SUBSTITUTION = re.compile(r"\$\(([^()]*)\)")

CLI_ARG = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*):=(.*)$", re.DOTALL)


class GraphError(Exception):
    """A problem with the graph file or the command line, found before anything starts."""


def ros_arguments(
    name: str,
    namespace: str,
    params: list[tuple[str, str]],
    param_files: list[str],
    remaps: list[tuple[str, str]],
) -> list[str]:
    """``--ros-args -r __node:=NAME -r __ns:=NS -p P:=V ... --params-file F ... -r A:=B ...``"""
    args = ["--ros-args"]
    if name:
        args += ["-r", f"__node:={name}"]
    if namespace:
        args += ["-r", f"__ns:={namespace}"]
    for key, value in params:
        args += ["-p", f"{key}:={value}"]
    for path in param_files:
        args += ["--params-file", path]
    for src, dst in remaps:
        args += ["-r", f"{src}:={dst}"]
    return args


@dataclass
class ComposableNode:
    """One ``composable_node`` of a ``node_container``, substituted."""

    pkg: str
    plugin: str
    name: str = ""
    namespace: str = ""
    params: list[tuple[str, str]] = field(default_factory=list)
    param_files: list[str] = field(default_factory=list)
    remaps: list[tuple[str, str]] = field(default_factory=list)

    def arguments(self) -> list[str]:
        """Its part of the container's command line."""
        return ["--node", self.plugin] + ros_arguments(
            self.name, self.namespace, self.params, self.param_files, self.remaps
        )


@dataclass
class NodeAction:
    """One ``node`` (or ``node_container``) entry, substituted and resolved."""

    pkg: str
    exe: str
    executable: str
    name: str = ""
    namespace: str = ""
    output: str = "log"
    params: list[tuple[str, str]] = field(default_factory=list)
    param_files: list[str] = field(default_factory=list)
    remaps: list[tuple[str, str]] = field(default_factory=list)
    #: Extra command-line arguments before ``--ros-args`` (the recorder's options).
    arguments: list[str] = field(default_factory=list)
    #: Extra ROS arguments after the generated ones.
    ros_arguments: list[str] = field(default_factory=list)
    label: str = ""
    #: How messages name the process (default: its node name and executable).
    title: str = ""
    #: The nodes of a ``node_container`` (its name and namespace then only label it).
    composables: list[ComposableNode] = field(default_factory=list)

    def fqn(self) -> str:
        """Fully qualified node name (the executable's name when no name is given)."""
        ns = self.namespace.rstrip("/")
        return f"{ns}/{self.name or self.exe}" if ns else f"/{self.name or self.exe}"

    def command(self) -> list[str]:
        """The process's command line."""
        if self.composables:
            # no __node/__ns of the container's: given to the process, they would rename
            # every node in it
            own = ["--ros-args", *self.ros_arguments] if self.ros_arguments else []
            return [self.executable, *self.arguments, *own] + [
                a for c in self.composables for a in c.arguments()
            ]
        return (
            [self.executable, *self.arguments]
            + ros_arguments(self.name, self.namespace, self.params, self.param_files, self.remaps)
            + self.ros_arguments
        )


@dataclass
class Graph:
    """What a launch file (with its includes) starts, and the arguments it declares."""

    nodes: list[NodeAction] = field(default_factory=list)
    #: name -> (default or None, description), in declaration order.
    arguments: dict[str, tuple[str | None, str]] = field(default_factory=dict)


def resolve_executable(pkg: str, exe: str) -> str:
    """``<prefix of pkg>/lib/pkg/exe`` from the ament index, as ``ros2 run`` finds it."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        prefix = get_package_prefix(pkg)
    except (PackageNotFoundError, ValueError):
        raise GraphError(f"package {pkg!r} not found in the ament index") from None
    path = Path(prefix) / "lib" / pkg / exe
    if "/" in exe or not path.is_file() or not os.access(path, os.X_OK):
        raise GraphError(f"executable {exe!r} not found in package {pkg!r} ({path.parent})")
    return str(path)


def _check_plugin(pkg: str, plugin: str, where: str) -> None:
    """A composable node's plugin: an executable of ``pkg`` (a node executable; the
    container checks that it runs a node), or ``MODULE:CLASS`` of an importable module."""
    import importlib.util

    if ":" in plugin:
        module = plugin.partition(":")[0]
        try:
            found = bool(module) and importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            raise GraphError(f"{where}: module {module!r} of plugin {plugin!r} not found")
        return
    try:
        resolve_executable(pkg, plugin)
    except GraphError as exc:
        raise GraphError(f"{where}: {exc}") from None


def _text(value) -> str:
    """A YAML scalar as launch text (booleans as YAML writes them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return ""
    return str(value)


class _Loader:
    """Walks the entries of a file and its includes, collecting nodes and arguments."""

    def __init__(self, cli: dict[str, str], require: bool = True) -> None:
        self.cli = cli
        self.require = require
        self.graph = Graph()
        #: Launch files read so far (:data:`MAX_INCLUDE_LOADS`).
        self.loads = 0

    def load(self, path: Path, scope: dict[str, str], depth: int = 0) -> None:
        if depth > MAX_INCLUDE_DEPTH:
            raise GraphError(f"{path}: includes nested deeper than {MAX_INCLUDE_DEPTH} (a cycle?)")
        self.loads += 1
        if self.loads > MAX_INCLUDE_LOADS:
            raise GraphError(
                f"{path}: more than {MAX_INCLUDE_LOADS} launch files read for one graph "
                "(includes that fan out?)"
            )
        try:
            text = bounded_yaml.read_text(path)
        except OSError as exc:
            raise GraphError(f"{path}: cannot read: {exc.strerror or exc}") from None
        except yaml.YAMLError as exc:  # not a regular file, too large, not UTF-8
            raise GraphError(str(exc)) from None
        try:
            doc = bounded_yaml.load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise GraphError(f"{where}: YAML syntax error: {problem}") from None
        if not isinstance(doc, dict) or set(doc) != {"launch"}:
            raise GraphError(f"{path}: the document must be a mapping with the one key 'launch'")
        entries = doc["launch"] or []
        if not isinstance(entries, list):
            raise GraphError(f"{path}: 'launch' must be a list of entries")
        for i, entry in enumerate(entries, 1):
            where = f"{path}: entry {i}"
            if not isinstance(entry, dict) or len(entry) != 1:
                raise GraphError(f"{where}: must be a mapping with one tag ({', '.join(TAGS)})")
            ((tag, attrs),) = entry.items()
            if tag not in TAGS:
                raise GraphError(f"{where}: unsupported tag {tag!r} (supported: {', '.join(TAGS)})")
            where = f"{where} ({tag})"
            if not isinstance(attrs, dict):
                raise GraphError(f"{where}: attributes must be a mapping")
            unknown = sorted(set(map(str, attrs)) - TAGS[tag])
            if unknown:
                raise GraphError(
                    f"{where}: unsupported attribute {unknown[0]!r} "
                    f"(supported: {', '.join(sorted(TAGS[tag]))})"
                )
            missing = [a for a in REQUIRED[tag] if attrs.get(a) is None]
            if missing:
                raise GraphError(f"{where}: attribute {missing[0]!r} is required")
            getattr(self, f"_{tag}")(path, where, attrs, scope, depth)

    # -- substitutions

    def sub(self, value, scope: dict[str, str], where: str) -> str:
        """``value`` as text with ``$(var NAME)`` and ``$(find-pkg-share PKG)`` replaced."""
        if isinstance(value, (dict, list)):
            raise GraphError(f"{where}: expected a single value, got a {type(value).__name__}")
        text = _text(value)

        def replace(m: re.Match) -> str:
            words = m.group(1).split()
            if len(words) == 2 and words[0] == "var":
                if words[1] not in scope:
                    raise GraphError(f"{where}: $(var {words[1]}): no such argument or variable")
                return scope[words[1]]
            if len(words) == 2 and words[0] == "find-pkg-share":
                from ament_index_python.packages import (
                    PackageNotFoundError,
                    get_package_share_directory,
                )

                try:
                    return get_package_share_directory(words[1])
                except (PackageNotFoundError, ValueError):
                    raise GraphError(
                        f"{where}: $(find-pkg-share {words[1]}): package not found"
                    ) from None
            raise GraphError(
                f"{where}: unsupported substitution $({m.group(1)}) "
                "(supported: $(var NAME), $(find-pkg-share PACKAGE))"
            )

        if "$(" in SUBSTITUTION.sub("", text):
            raise GraphError(f"{where}: unterminated or nested substitution in {text!r}")
        text = SUBSTITUTION.sub(replace, text)
        if "\0" in text:  # no command line can carry it: refused before anything starts
            raise GraphError(f"{where}: a NUL character in {text!r}")
        return text

    def param_value(self, value, scope: dict[str, str], where: str) -> str:
        """A parameter value as the text after ``-p NAME:=`` (YAML, as the node parses it)."""
        if isinstance(value, dict):
            raise GraphError(f"{where}: nested parameter values are not supported")
        if isinstance(value, list):
            items = [bounded_yaml.load(self.param_value(v, scope, where) or "''") for v in value]
            return yaml.safe_dump(items, default_flow_style=True, width=1 << 30).strip()
        if isinstance(value, float):
            return repr(value)
        text = self.sub(value, scope, where)
        return text if text else "''"

    # -- tags

    def _arg(self, path, where, attrs, scope, depth) -> None:
        name = self.sub(attrs["name"], scope, where)
        default = attrs.get("default")
        default = None if default is None else self.sub(default, scope, where)
        self.graph.arguments.setdefault(
            name, (default, self.sub(attrs.get("description", ""), scope, where))
        )
        if name in scope:
            return
        if default is None and self.require:
            raise GraphError(f"{where}: argument {name!r} is required (give {name}:=VALUE)")
        scope[name] = f"<{name}>" if default is None else default

    def _let(self, path, where, attrs, scope, depth) -> None:
        scope[self.sub(attrs["name"], scope, where)] = self.sub(attrs["value"], scope, where)

    def _include(self, path, where, attrs, scope, depth) -> None:
        target = Path(self.sub(attrs["file"], scope, where))
        if not target.name.endswith((".yaml", ".yml")):
            raise GraphError(f"{where}: only launch YAML files can be included, not {target}")
        items = attrs.get("arg") or []
        if not isinstance(items, list):
            raise GraphError(f"{where}: 'arg' must be a list of name/value entries")
        values = {}
        for item in items:
            if not isinstance(item, dict) or set(item) != {"name", "value"}:
                raise GraphError(f"{where}: each arg needs exactly 'name' and 'value'")
            values[self.sub(item["name"], scope, where)] = self.sub(item["value"], scope, where)
        scope.update(values)  # not scoped: the including file sees them afterwards too
        self.load(target, scope, depth + 1)

    def _namespace(self, attrs, scope, where) -> str:
        """The ``namespace`` attribute, absolute (empty when not given)."""
        ns = self.sub(attrs.get("namespace", ""), scope, where).strip().rstrip("/")
        return ("" if not ns or ns.startswith("/") else "/") + ns

    def _output(self, attrs, scope, where) -> str:
        """The ``output`` attribute (``log`` when not given)."""
        output = self.sub(attrs.get("output", "log"), scope, where)
        if output not in OUTPUTS:
            raise GraphError(f"{where}: output {output!r} is not one of {', '.join(OUTPUTS)}")
        return output

    def _params_remaps(self, node, attrs, scope, where) -> None:
        """The ``param`` and ``remap`` lists of a node or composable node, into ``node``."""
        params = attrs.get("param") or []
        if not isinstance(params, list):
            raise GraphError(f"{where}: 'param' must be a list")
        for item in params:
            if isinstance(item, dict) and set(item) == {"name", "value"}:
                key = self.sub(item["name"], scope, where)
                node.params.append((key, self.param_value(item["value"], scope, f"{where}: {key}")))
            elif isinstance(item, dict) and set(item) == {"from"}:
                file = self.sub(item["from"], scope, where)
                if not Path(file).is_file():
                    raise GraphError(f"{where}: parameter file {file} not found")
                try:  # the node's own parser would fail late, or work unboundedly
                    load_params_file(file)
                except ParamsFileError as exc:
                    raise GraphError(f"{where}: {exc}") from None
                node.param_files.append(file)
            else:
                raise GraphError(f"{where}: each param needs 'name' and 'value', or 'from'")
        remaps = attrs.get("remap") or []
        if not isinstance(remaps, list):
            raise GraphError(f"{where}: 'remap' must be a list")
        for item in remaps:
            if not isinstance(item, dict) or set(item) != {"from", "to"}:
                raise GraphError(f"{where}: each remap needs exactly 'from' and 'to'")
            node.remaps.append(
                (self.sub(item["from"], scope, where), self.sub(item["to"], scope, where))
            )

    def _process(self, pkg: str, exe: str, attrs, scope, where: str) -> NodeAction:
        """The process of a ``node`` or ``node_container`` entry: its executable resolved,
        its namespace and output."""
        try:
            action = NodeAction(pkg=pkg, exe=exe, executable=resolve_executable(pkg, exe))
        except GraphError as exc:
            raise GraphError(f"{where}: {exc}") from None
        action.namespace = self._namespace(attrs, scope, where)
        action.output = self._output(attrs, scope, where)
        return action

    def _node(self, path, where, attrs, scope, depth) -> None:
        pkg = self.sub(attrs["pkg"], scope, where)
        exe = self.sub(attrs["exec"], scope, where)
        where = f"{path}: node {exe!r}"
        node = self._process(pkg, exe, attrs, scope, where)
        node.name = self.sub(attrs.get("name", ""), scope, where)
        self._params_remaps(node, attrs, scope, where)
        self.graph.nodes.append(node)

    def _node_container(self, path, where, attrs, scope, depth) -> None:
        pkg = self.sub(attrs["pkg"], scope, where)
        exe = self.sub(attrs["exec"], scope, where)
        name = self.sub(attrs["name"], scope, where)
        where = f"{path}: node_container {name!r}"
        box = self._process(pkg, exe, attrs, scope, where)
        box.name = name
        items = attrs["composable_node"]
        if not isinstance(items, list) or not items:
            raise GraphError(f"{where}: 'composable_node' must be a non-empty list")
        for k, item in enumerate(items, 1):
            at = f"{where}: composable_node {k}"
            if not isinstance(item, dict):
                raise GraphError(f"{at}: attributes must be a mapping")
            unknown = sorted(set(map(str, item)) - COMPOSABLE)
            if unknown:
                raise GraphError(
                    f"{at}: unsupported attribute {unknown[0]!r} "
                    f"(supported: {', '.join(sorted(COMPOSABLE))})"
                )
            for required in ("pkg", "plugin"):
                if item.get(required) is None:
                    raise GraphError(f"{at}: attribute {required!r} is required")
            node = ComposableNode(
                pkg=self.sub(item["pkg"], scope, at), plugin=self.sub(item["plugin"], scope, at)
            )
            at = f"{where}: composable_node {node.plugin!r}"
            _check_plugin(node.pkg, node.plugin, at)
            node.name = self.sub(item.get("name", ""), scope, at)
            node.namespace = self._namespace(item, scope, at)
            self._params_remaps(node, item, scope, at)
            box.composables.append(node)
        self.graph.nodes.append(box)


def parse_cli_args(items: list[str]) -> dict[str, str]:
    """``name:=value`` items as a dict (GraphError for anything else)."""
    out = {}
    for item in items:
        m = CLI_ARG.match(item)
        if m is None:
            raise GraphError(f"launch arguments are name:=value, got {item!r}")
        out[m.group(1)] = m.group(2)
    return out


def load_graph(path: str | Path, cli: dict[str, str] | None = None, require: bool = True) -> Graph:
    """Read a launch YAML file (and its includes) with the command-line arguments ``cli``.

    Raises GraphError (one line) for anything the module doc refuses. With ``require``
    False a required argument that is not given stands as ``<name>`` (to list the
    arguments).
    """
    cli = dict(cli or {})
    loader = _Loader(cli, require)
    loader.load(Path(path), dict(cli))
    unknown = sorted(set(cli) - set(loader.graph.arguments))
    if unknown:
        declared = ", ".join(loader.graph.arguments) or "none"
        raise GraphError(f"{path}: no argument {unknown[0]!r} is declared (declared: {declared})")
    _label(loader.graph.nodes)
    return loader.graph


def _label(nodes: list[NodeAction]) -> None:
    """A unique label per node (its name without the leading slash, '/' as '.')."""
    seen: dict[str, int] = {}
    for node in nodes:
        base = node.fqn().lstrip("/").replace("/", ".")
        seen[base] = seen.get(base, 0) + 1
        node.label = base if seen[base] == 1 else f"{base}-{seen[base]}"
        if seen[base] == 2:
            print(f"{PROG}: warning: two nodes named {node.fqn()}", file=sys.stderr)

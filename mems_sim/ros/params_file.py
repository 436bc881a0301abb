"""ROS 2 parameter files and ``NODE.PARAM=VALUE`` overrides, matched to nodes as rcl does.

A parameter file is the YAML that ``--ros-args --params-file FILE`` reads (ROS 2
documentation, "Understanding parameters" and "Passing ROS arguments to nodes via the
command-line"): top-level keys are node names, possibly namespaced by nesting
(``ns: {node: {ros__parameters: ...}}``) or by slashes (``/ns/node``), each with a
``ros__parameters`` mapping; nested mappings below it give dotted parameter names
(``a: {b: 1}`` is ``a.b``). A node name without a leading slash is taken from the root
namespace. Wildcards: ``*`` stands for one name token, ``**`` for zero or more, so
``/**`` matches every node and ``/**/imu_noise`` every node named ``imu_noise``. Values are
typed as rcl types them: YAML booleans (``true``, ``yes``, ``on``), integers (also
``0x10``), doubles (also ``1e-3`` and ``inf``, which YAML 1.1 leaves strings), strings,
and lists of one of those types. Where several entries set the same parameter of a node,
the last one in the file wins; later overrides win over earlier ones.

This module is ROS-free (it runs before any node exists) and raises
:class:`ParamsFileError` with one line for anything it cannot read.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from mems_sim import bounded_yaml

#: The key under a node name that holds its parameters.
ROS_PARAMETERS = "ros__parameters"
#: A token of a ROS name (ROS 2 design, "Topic and Service name mapping to DDS"), or a wildcard.
_TOKEN = re.compile(r"^(?:[A-Za-z_~{][\w{}~]*|\*|\*\*)$")
_PARAM = re.compile(r"^[A-Za-z_][\w.]*$")


class ParamsFileError(ValueError):
    """A parameter file or override that cannot be read (one line)."""


class _Loader(yaml.SafeLoader):
    """YAML 1.1 safe loader that also types ``1e-3``, ``inf`` and ``nan`` as doubles, as the
    rcl YAML parser does for plain scalars."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"^(?:[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+"
        r"|[-+]?\.[0-9_]+[eE][-+]?[0-9]+|[-+]?(?:inf|Inf|INF)|nan|NaN|NAN)$"
    ),
    list("-+0123456789.iInN"),
)


def _float(loader, node):
    text = loader.construct_scalar(node).replace("_", "")
    try:
        return float(text)
    except ValueError:
        return yaml.SafeLoader.construct_yaml_float(loader, node)


_Loader.add_constructor("tag:yaml.org,2002:float", _float)
#: :class:`_Loader` with the bounds of every user-supplied YAML (no aliases, depth, size).
_BOUNDED = bounded_yaml.bounded_loader(_Loader)


def parse_value(text: str) -> Any:
    """A parameter value from the text after ``=`` / ``:=``, typed as a YAML scalar or
    flow list the way rcl types it (see the module docstring); refused if it is a mapping,
    null or a list of mixed types."""
    try:
        value = bounded_yaml.load(text, _BOUNDED)
    except yaml.YAMLError as exc:
        raise ParamsFileError(
            f"{text!r} is not a YAML value ({bounded_yaml.problem(exc)})"
        ) from None
    return check_value(value, text)


def check_value(value: Any, what: str) -> Any:
    """``value`` if rcl can hold it as a parameter value, else :class:`ParamsFileError`."""
    if value is None:
        raise ParamsFileError(f"{what!r}: an empty value is not a parameter value")
    if isinstance(value, dict):
        raise ParamsFileError(f"{what!r}: a mapping is not a parameter value")
    if isinstance(value, list):
        if not value:
            raise ParamsFileError(f"{what!r}: an empty list has no parameter type")
        kinds = {type(v) for v in value}
        if len(kinds) != 1 or next(iter(kinds)) not in (bool, int, float, str):
            raise ParamsFileError(
                f"{what!r}: a list parameter holds values of one type (bool, int, float or str)"
            )
    elif not isinstance(value, (bool, int, float, str)):
        raise ParamsFileError(f"{what!r}: not a parameter value")
    return value


def normalise_node(name: str) -> str:
    """A node name (pattern) as rcl keys it: with a leading slash, without a trailing one;
    refused unless every token is a ROS name token or a wildcard."""
    name = "/" + name.strip("/") if name != "/**" else name
    tokens = name.split("/")[1:]
    if not tokens or not all(_TOKEN.match(t) for t in tokens):
        raise ParamsFileError(f"{name!r} is not a node name")
    return name


def node_matches(pattern: str, fqn: str) -> bool:
    """True if the node name ``pattern`` (wildcards ``*``, ``**``) matches the fully
    qualified node name ``fqn``."""
    pat, name = pattern.strip("/").split("/"), fqn.strip("/").split("/")

    def match(i: int, j: int) -> bool:
        if i == len(pat):
            return j == len(name)
        if pat[i] == "**":
            return any(match(i + 1, k) for k in range(j, len(name) + 1))
        return j < len(name) and (pat[i] in ("*", name[j])) and match(i + 1, j + 1)

    return match(0, 0)


def is_wildcard(pattern: str) -> bool:
    """True if ``pattern`` may match more than one node."""
    return "*" in pattern


@dataclass(frozen=True)
class Override:
    """One parameter value for the nodes whose names match ``node``.

    Attributes:
        node: node name pattern, fully qualified (``/imu/imu_noise``, ``/**``).
        name: parameter name.
        value: the value, typed as rcl types it.
        origin: where it was given (``--set`` or the file name), for messages.
        given: the text of a ``--set`` override as the user wrote it.
    """

    node: str
    name: str
    value: Any
    origin: str
    given: str = ""

    def where(self) -> str:
        """The override as the user gave it, for a message: ``--set NODE.PARAM=VALUE`` or
        ``FILE: /node.param``."""
        if self.given:
            return f"{self.origin} {self.given}"
        return f"{self.origin}: {self.node}.{self.name}"

    def text(self) -> str:
        """``NODE.PARAM=VALUE`` as the user gave it (the value as YAML)."""
        value = yaml.safe_dump(self.value, default_flow_style=True, width=1 << 30)
        value = value.strip().removesuffix("...").strip()
        return f"{self.node}.{self.name}={value}"


def _flatten(params: dict, prefix: str, where: str) -> list[tuple[str, Any]]:
    out = []
    for key, value in params.items():
        name = f"{prefix}{key}"
        if not isinstance(key, str) or not _PARAM.match(name):
            raise ParamsFileError(f"{where}: {name!r} is not a parameter name")
        if isinstance(value, dict):
            out += _flatten(value, name + ".", where)
        else:
            out.append((name, check_value(value, f"{where}: {name}")))
    return out


def _entries(doc: dict, prefix: str, where: str) -> list[tuple[str, dict]]:
    """(node name, ros__parameters) of every node of a parameter file's mapping."""
    out = []
    for key, value in doc.items():
        if not isinstance(key, str):
            raise ParamsFileError(f"{where}: {key!r} is not a node name")
        node = f"{prefix}/{key.strip('/')}" if prefix else key
        if not isinstance(value, dict):
            raise ParamsFileError(
                f"{where}: {node!r} holds no mapping (expected {ROS_PARAMETERS}: under it)"
            )
        if ROS_PARAMETERS in value:
            params = value[ROS_PARAMETERS]
            if len(value) != 1:
                others = sorted(str(k) for k in value if k != ROS_PARAMETERS)
                raise ParamsFileError(
                    f"{where}: {node!r} has {', '.join(others)} beside {ROS_PARAMETERS}"
                )
            if params is None:
                params = {}
            if not isinstance(params, dict):
                raise ParamsFileError(f"{where}: {node}.{ROS_PARAMETERS} is not a mapping")
            out.append((normalise_node(node), params))
        else:
            out += _entries(value, node, where)
    return out


def load_params_file(path: str | Path) -> list[Override]:
    """The overrides of a ROS 2 parameter file, in file order.

    Raises:
        ParamsFileError: the file cannot be read, is not YAML, or is not a parameter file.
    """
    where = str(path)
    try:
        text = bounded_yaml.read_text(path)
    except (OSError, yaml.YAMLError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ParamsFileError(f"{where}: cannot read it ({reason})") from None
    try:
        doc = bounded_yaml.load(text, _BOUNDED)
    except yaml.YAMLError as exc:
        raise ParamsFileError(f"{where}: not YAML ({bounded_yaml.problem(exc)})") from None
    if not isinstance(doc, dict) or not doc:
        raise ParamsFileError(
            f"{where}: not a ROS 2 parameter file (NODE: {{{ROS_PARAMETERS}: {{...}}}})"
        )
    out = []
    for node, params in _entries(doc, "", where):
        out += [Override(node, n, v, where) for n, v in _flatten(params, "", where)]
    return out


def parse_set(text: str) -> Override:
    """One ``NODE.PARAM=VALUE`` override. NODE without a slash is a node name in any
    namespace (``/**/NODE``); with one it is a fully qualified name or a pattern
    (``imu/imu_noise`` is ``/imu/imu_noise``). The parameter name is everything after the
    first dot (ROS node names hold no dots)."""
    target, eq, value = text.partition("=")
    node, dot, name = target.partition(".")
    if not eq or not dot or not node or not name:
        raise ParamsFileError(f"--set {text!r}: expected NODE.PARAM=VALUE")
    if not _PARAM.match(name):
        raise ParamsFileError(f"--set {text!r}: {name!r} is not a parameter name")
    try:
        node = normalise_node(node if "/" in node else f"/**/{node}")
    except ParamsFileError as exc:
        raise ParamsFileError(f"--set {text!r}: {exc}") from None
    try:
        typed = parse_value(value)
    except ParamsFileError as exc:
        raise ParamsFileError(f"--set {text!r}: {exc}") from None
    return Override(node, name, typed, "--set", given=text)


def values_for(overrides: list[Override], fqn: str) -> dict[str, Override]:
    """Parameter name -> the override that applies to node ``fqn`` (the last that matches)."""
    out: dict[str, Override] = {}
    for o in overrides:
        if node_matches(o.node, fqn):
            out[o.name] = o
    return out

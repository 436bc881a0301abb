"""A node process's parameter overrides held against what its nodes declare: a ``-p`` name
no node has is refused with the close matches, a malformed ``-p``/``-r`` rule before rcl
parses it, and other undeclared overrides (a wildcard ``/**`` file serves several nodes)
are a warning."""

from __future__ import annotations

import sys

from mems_sim.params import ParameterError


def command_line_parameters(args: list[str]) -> list[tuple[str | None, str]]:
    """``(node name or None, parameter name)`` of every ``-p``/``--param`` rule in the
    ``--ros-args`` sections of ``args`` (``-p NAME:=V``, ``-p NODE:NAME:=V``)."""
    out, ros, k = [], False, 0
    while k < len(args):
        token = args[k]
        if token == "--ros-args":
            ros = True
        elif token == "--":
            ros = False
        elif ros and token in ("-p", "--param", "-r", "--remap"):
            rule = args[k + 1] if k + 1 < len(args) else ""
            if ":=" not in rule or rule.startswith(":="):
                raise ParameterError(f"{token} {rule!r}: a rule is NAME:=VALUE")
            k += 1
            if token in ("-r", "--remap"):
                k += 1
                continue
            key = rule.partition(":=")[0]
            node, _, name = key.rpartition(":")
            out.append((node or None, name))
        k += 1
    return out


def check_parameter_overrides(nodes: list, args: list[str]) -> None:
    """Refuse a ``-p`` name that no node of the process declares (:class:`ParameterError`
    naming the close matches); warn about other overrides no node declares (a wildcard
    ``/**`` parameter file legitimately serves several nodes)."""
    import difflib

    declared = {n.get_name(): set(n._parameters) for n in nodes}
    known = sorted(set().union(*declared.values())) if declared else []
    for node, name in command_line_parameters(args):
        pool = declared.get(node, set()) if node is not None else set(known)
        if node is not None and node not in declared:
            continue  # a rule for a node of another process
        if name not in pool and not name.startswith("qos_overrides."):
            near = difflib.get_close_matches(name, sorted(pool), n=3)
            hint = f" (did you mean {', '.join(near)}?)" if near else ""
            raise ParameterError(f"-p {name}: no node here has a parameter {name!r}{hint}")
    for n in nodes:
        extra = sorted(set(getattr(n, "_parameter_overrides", {})) - declared[n.get_name()])
        extra = [e for e in extra if not e.startswith("qos_overrides.")]
        if extra:
            print(
                f"warning: {n.get_fully_qualified_name()}: parameters given but not declared: "
                + ", ".join(extra),
                file=sys.stderr,
            )

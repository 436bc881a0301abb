"""``run_scenario --faults [NODE=]FILE``: a fault schedule for a scenario's emulators.

The option is the ``fault_schedule`` parameter of the graph's emulators that take one
(docs/faults.md), given without naming them: ``--faults FILE`` sets it on every emulator of
the scenario's graph (:class:`~mems_scenarios.contract.GraphSpec`) whose parameter table
has it, ``--faults NODE=FILE`` on the emulators whose name matches NODE (as in ``--set``).
Each becomes an :class:`~mems_sim.ros.params_file.Override` of origin ``--faults``, so the
run record names it and the node validates the schedule against its channels.
"""

from __future__ import annotations

from pathlib import Path

from mems_sim.ros.params_file import Override, ParamsFileError, node_matches, normalise_node

#: The parameter the option sets.
PARAMETER = "fault_schedule"


def split_faults(text: str) -> tuple[str, Path]:
    """``(node pattern, schedule path)`` of one ``[NODE=]FILE`` (pattern ``/**`` for every
    emulator; a NODE without a slash is a name in any namespace). A missing or unreadable
    file is a ParamsFileError (one line)."""
    node, eq, path = text.partition("=")
    if not eq:
        node, path = "/**", text
    elif not node or not path:
        raise ParamsFileError(f"--faults {text!r}: expected [NODE=]FILE")
    else:
        try:
            node = normalise_node(node if "/" in node else f"/**/{node}")
        except ParamsFileError as exc:
            raise ParamsFileError(f"--faults {text!r}: {exc}") from None
    file = Path(path).expanduser()
    if not file.is_file():
        raise ParamsFileError(f"--faults {text!r}: {path!r} is not a file")
    return node, file.resolve()


def fault_overrides(spec, texts) -> list[Override]:
    """The ``fault_schedule`` overrides of ``--faults`` ``texts`` on the nodes of ``spec``
    (a GraphSpec) whose parameter table has the parameter; a text that matches none is a
    ParamsFileError naming the emulators that would take one."""
    from mems_scenarios.contract import node_class

    takers = [
        e for e in spec.nodes if PARAMETER in {s.name for s in node_class(e.executable).SPECS}
    ]
    out = []
    for text in texts:
        pattern, file = split_faults(text)
        chosen = [e for e in takers if node_matches(pattern, e.fqn)]
        if not chosen:
            which = ", ".join(e.fqn for e in takers) or "none"
            raise ParamsFileError(
                f"--faults {text!r}: no emulator of scenario {spec.scenario} takes it "
                f"(emulators with a fault schedule: {which})"
            )
        out += [Override(e.fqn, PARAMETER, str(file), "--faults", given=text) for e in chosen]
    return out


def fault_topics(entries) -> tuple[str, ...]:
    """The ``faults`` topics of the node entries whose ``fault_schedule`` is given: each
    such emulator publishes ``<its namespace>/faults``."""
    out = []
    for e in entries:
        if e.parameters.get(PARAMETER):
            out.append("/" + "/".join(p for p in (e.namespace.strip("/"), "faults") if p))
    return tuple(out)

"""The scenario contract: a graph as data, a recording that describes itself, figures as an
analysis of the recording.

A scenario module provides ``graph(options) -> GraphSpec`` (:class:`GraphSpec`: the node
entries of a ROS 2 launch file plus the recorder's topics) and ``analyse(bag) ->
ScenarioResult`` (:class:`ScenarioResult`, computed from the MCAP file alone); what needs
the simulation is its named ``oracle`` step. The run records :data:`RUN_INFO_TOPIC`, so
``run_scenario NAME --analyse BAG`` needs no side file. The contract: docs/scenarios.md.
"""

from __future__ import annotations

import importlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import yaml

from mems_scenarios.figures import Figure

#: Version of :class:`ScenarioResult`, of ``run_scenario --json`` and of the run record.
SCHEMA_VERSION = 1
#: The ROS package every executable of this project belongs to (package.xml).
PACKAGE = "mems_emulator"
#: The run record of a scenario's recording: std_msgs/msg/String, one JSON object
#: (:func:`run_info`), reliable and transient-local, so that a recorder that joins late
#: and a replay into another recorder still hold it.
RUN_INFO_TOPIC = "/scenario/run_info"

#: Executable -> module of its node, for the in-process runner (the modules behind the
#: console scripts of setup.py; a test checks the two agree).
NODE_MODULES = {
    "imu_node": "mems_sim.nodes.imu_node",
    "imu_noise_identifier_node": "mems_estimation.nodes.imu_noise_identifier_node",
    "resonator_node": "mems_sim.nodes.resonator_node",
    "resonator_observer_node": "mems_estimation.nodes.resonator_observer_node",
    "accelerometer_node": "mems_sim.nodes.accelerometer_node",
    "accelerometer_ekf_node": "mems_estimation.nodes.accelerometer_ekf_node",
    "stage_node": "mems_sim.nodes.stage_node",
    "stage_ekf_node": "mems_estimation.nodes.stage_ekf_node",
    "stage_average_node": "mems_estimation.nodes.stage_average_node",
    "stage_gyro_calibration_node": "mems_estimation.nodes.stage_gyro_calibration_node",
    "scanner_node": "mems_sim.nodes.scanner_node",
    "scanner_threshold_ekf_node": "mems_estimation.nodes.scanner_threshold_ekf_node",
    "scanner_amdm_node": "mems_sim.nodes.scanner_amdm_node",
    "scanner_amdm_estimator_node": "mems_estimation.nodes.scanner_amdm_estimator_node",
    "imu_calibration_node": "mems_estimation.nodes.imu_calibration_node",
    "imu_corrector_node": "mems_estimation.nodes.imu_corrector_node",
    "view_node": "mems_sim.nodes.view_node",
    "live_view": "mems_sim.nodes.live_view",
}


class AnalysisError(RuntimeError):
    """A recording lacks what a figure needs (one line: the figure and what is missing)."""


def node_class(executable: str) -> type:
    """The node class behind ``executable``: the one rclpy node class its module
    (:data:`NODE_MODULES`) defines. KeyError for an unknown executable."""
    from rclpy.node import Node

    module = importlib.import_module(NODE_MODULES[executable])
    found = [
        c
        for c in vars(module).values()
        if isinstance(c, type) and issubclass(c, Node) and c.__module__ == module.__name__
    ]
    if len(found) != 1:
        raise KeyError(f"{executable}: {module.__name__} defines {len(found)} node classes")
    return found[0]


@dataclass(frozen=True)
class NodeEntry:
    """One node of a graph: the fields of a launch-YAML ``node`` entry.

    Attributes:
        executable: the node's executable (``exec``), e.g. ``imu_node``.
        name: node name (``name``), e.g. ``imu``.
        namespace: namespace without a leading slash (``""``: the root).
        parameters: the scenario's parameter values (``param``), name -> value.
        remaps: topic remappings (``remap``), from -> to.
        package: the ROS package (``pkg``).
        consumers: for an emulator run as a process, the subscriptions its topics need
            before it starts, ``TOPIC:N,...`` (its ``wait_for_subscribers``; the recorder
            counts), e.g. ``adc:2`` for an estimator and the recorder.
    """

    executable: str
    name: str
    namespace: str = ""
    parameters: dict = field(default_factory=dict)
    remaps: dict = field(default_factory=dict)
    package: str = PACKAGE
    consumers: str = ""

    @property
    def fqn(self) -> str:
        """Fully qualified node name, e.g. ``/imu/imu``."""
        return "/" + "/".join(p for p in (self.namespace.strip("/"), self.name) if p)

    def launch_entry(self) -> dict:
        """The entry as a ROS 2 launch-YAML ``node`` mapping."""
        entry = {"pkg": self.package, "exec": self.executable, "name": self.name}
        if self.namespace:
            entry["namespace"] = self.namespace
        entry["output"] = "screen"
        if self.parameters:
            entry["param"] = [{"name": k, "value": v} for k, v in self.parameters.items()]
        if self.remaps:
            entry["remap"] = [{"from": k, "to": v} for k, v in self.remaps.items()]
        return {"node": entry}


@dataclass(frozen=True)
class GraphSpec:
    """A scenario's node graph as data.

    Attributes:
        scenario: the scenario's name.
        nodes: the node entries, emulators first.
        recorded: the topics the recorder writes.
    """

    scenario: str
    nodes: tuple[NodeEntry, ...]
    recorded: tuple[str, ...]

    def node(self, fqn: str) -> NodeEntry:
        """The entry of the node ``fqn`` (KeyError if the graph has none)."""
        for n in self.nodes:
            if n.fqn == fqn:
                return n
        raise KeyError(fqn)

    def as_processes(self, realtime_factor: float, record: str | None = None) -> GraphSpec:
        """The graph for a runner of processes (``run_graph``): every emulator paces itself
        at ``realtime_factor``, starts once its consumers and the recorder are matched
        (``start_when_matched``, its :attr:`NodeEntry.consumers`) and exits once they
        acknowledged its last sample (``exit_when_acknowledged``); every node that reads a
        device's frames exits once its input ended and is done (``exit_when_input_ended``),
        so that the graph ends by itself; ``record``: the path of the run record (JSON),
        published by a ``scenario_run_record`` node."""
        from dataclasses import replace

        nodes = []
        for n in self.nodes:
            if issubclass(node_class(n.executable), _emulator_base()):
                lifecycle = dict(
                    realtime_factor=float(realtime_factor),
                    start_when_matched=True,
                    exit_when_acknowledged=True,
                    wait_for_subscribers=n.consumers,
                )
                n = replace(n, parameters={**n.parameters, **lifecycle})
            elif "exit_when_input_ended" in {s.name for s in node_class(n.executable).SPECS}:
                n = replace(n, parameters={**n.parameters, "exit_when_input_ended": True})
            nodes.append(n)
        if record is not None:
            nodes.append(
                NodeEntry("scenario_run_record", "run_record", "", {"record_file": record})
            )
        return replace(self, nodes=tuple(nodes))

    def to_launch_yaml(self) -> str:
        """The graph as a ROS 2 launch file (YAML) that ``run_graph`` and ``ros2 launch``
        run; the recorder's topics are named in its header comment (``run_graph --record``
        records every topic)."""
        head = (
            f"# Graph of scenario {self.scenario}, written by run_scenario {self.scenario} "
            "--write-launch.\n# Recorded topics: " + ", ".join(self.recorded) + "\n"
        )
        body = yaml.safe_dump(
            {"launch": [n.launch_entry() for n in self.nodes]},
            sort_keys=False,
            default_flow_style=False,
        )
        return head + body


def _emulator_base() -> type:
    from mems_sim.ros.node_base import EmulatorNode

    return EmulatorNode


def full_parameters(entry: NodeEntry, overrides=(), variation: dict | None = None) -> dict:
    """Every parameter value node ``entry`` runs with, without making the node: its
    table's defaults under its hardware profile (``hardware``, as the node takes them:
    :func:`~mems_sim.params.profile_specs`), then :func:`given_parameters`, each validated
    against the table."""
    from mems_sim.params import HARDWARE_SPEC, profile_specs, spec_table

    table = node_class(entry.executable).SPECS
    given = given_parameters(entry, overrides, variation)
    if HARDWARE_SPEC.name in spec_table(table):
        table = profile_specs(table, given.get(HARDWARE_SPEC.name, HARDWARE_SPEC.default))
    specs = spec_table(table)
    values = {name: spec.default for name, spec in specs.items()}
    values.update(given)
    return {name: specs[name].validate(v) if name in specs else v for name, v in values.items()}


def given_parameters(entry: NodeEntry, overrides=(), variation: dict | None = None) -> dict:
    """The parameter values given to node ``entry`` (those a launch file of the run names):
    the entry's values, then ``variation`` (``device_seed``, ``temperature_c``, ``hardware``
    of an emulator) and the matching ``overrides``
    (:class:`~mems_sim.ros.params_file.Override`) that its table has."""
    from mems_sim.params import spec_table
    from mems_sim.ros.params_file import node_matches

    cls = node_class(entry.executable)
    specs = spec_table(cls.SPECS)
    values = dict(entry.parameters)
    if variation and issubclass(cls, _emulator_base()):
        values.update({k: v for k, v in variation.items() if v is not None and k in specs})
    for o in overrides:
        if node_matches(o.node, entry.fqn) and o.name in specs:
            values[o.name] = o.value
    return values


def _jsonable(value):
    """``value`` with numpy scalars and tuples made plain JSON (floats that are not finite
    as strings ``nan``/``inf``, as YAML would print them)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "item") and not isinstance(value, str | bytes):
        value = value.item()
    if isinstance(value, float) and value != value:
        return "nan"
    if isinstance(value, float) and value in (float("inf"), float("-inf")):
        return "inf" if value > 0 else "-inf"
    return value


def run_info(scenario: str, options: dict, nodes: dict[str, dict], **extra) -> str:
    """The run record (JSON) of a scenario run: schema version, scenario, package version,
    the options, and per node (fully qualified name) its executable and the parameter values
    it ran with. ``extra``: further keys a scenario's analysis reads (e.g. a plan)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        package_version = version(PACKAGE)
    except PackageNotFoundError:
        package_version = "unknown"
    record = dict(
        schema_version=SCHEMA_VERSION,
        scenario=scenario,
        package_version=package_version,
        options=options,
        nodes=nodes,
        **extra,
    )
    return json.dumps(_jsonable(record), sort_keys=True)


def bench_record(bench: dict) -> dict:
    """What the run record adds for a bench identification run before the graph: its
    result (``bench``: the identified ``model`` and its ``fit``), which the analysis reads
    from the recording."""
    return dict(bench=dict(model=bench["model"], fit=bench["fit"]))


def read_run_info(path) -> dict | None:
    """The run record of the recording ``path`` (its message on :data:`RUN_INFO_TOPIC`), or
    None when the recording has none (a user's own recording); :class:`AnalysisError` when
    it holds two different ones (it mixes runs)."""
    from mems_sim.bag.player import read_messages

    texts = {msg.data for _, _, _, msg in read_messages(str(path), [RUN_INFO_TOPIC])}
    if not texts:
        return None
    if len(texts) > 1:
        raise AnalysisError(
            f"{path}: {len(texts)} different run records on {RUN_INFO_TOPIC}: the recording "
            "mixes runs (another graph on its ROS domain?)"
        )
    text = texts.pop()
    try:
        record = json.loads(text)
    except ValueError:
        raise AnalysisError(f"{path}: {RUN_INFO_TOPIC} does not hold a JSON run record") from None
    if not isinstance(record, dict) or record.get("schema_version") != SCHEMA_VERSION:
        raise AnalysisError(
            f"{path}: run record of schema {record.get('schema_version')!r}"
            if isinstance(record, dict)
            else f"{path}: {RUN_INFO_TOPIC} is not a run record"
        )
    return record


def node_parameters(record: dict | None, fqn: str, what: str) -> dict:
    """The parameters node ``fqn`` ran with, from the run record; raises
    :class:`AnalysisError` naming ``what`` needs them when the recording has no record of
    that node."""
    if record is None:
        raise AnalysisError(f"{what}: the recording has no run record ({RUN_INFO_TOPIC})")
    try:
        return record["nodes"][fqn]["parameters"]
    except KeyError:
        raise AnalysisError(f"{what}: the run record has no node {fqn}") from None


@dataclass
class ScenarioResult:
    """What a scenario reports: its figures as data, its printed tables and its plots.

    Attributes:
        scenario: the scenario's name.
        figures: every figure computed (``run_scenario --json``).
        table: the printed tables.
        plots: PNG files written.
        unavailable: (figure group, reason) of each figure the recording did not allow.
        oracle_only: figure groups that need the simulation (the scenario's ``oracle``
            step) and that an analysis of a recording alone does not give.
        values: the figures as the scenario's own nested numbers (tests, campaigns).
        schema_version: :data:`SCHEMA_VERSION`.
    """

    scenario: str
    figures: list[Figure]
    table: str
    plots: list[Path] = field(default_factory=list)
    unavailable: list[tuple[str, str]] = field(default_factory=list)
    oracle_only: list[str] = field(default_factory=list)
    values: dict = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    def record(self) -> dict:
        """The result as a JSON-able mapping (figures as :meth:`Figure.record`)."""
        out = asdict(self)
        out["figures"] = [f.record() for f in self.figures]
        out["plots"] = [str(p) for p in self.plots]
        out.pop("values")
        return out

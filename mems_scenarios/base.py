"""Scenario machinery: one process, one rclpy context, emulator + consumers + recorder.

A scenario builds its node graph in a private rclpy context, runs it either
as fast as the machine allows (the runner steps the emulators itself and waits
for every consumer to take each frame, so nothing is dropped and runs are
bit-identical) or paced to the wall clock (``--realtime``, the emulators' own
timers), records it to MCAP, and reports a results table and figures.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
import weakref
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from mems_scenarios.contract import (
    RUN_INFO_TOPIC,
    GraphSpec,
    ScenarioResult,
    node_class,
    run_info,
)
from mems_scenarios.domain import (  # noqa: F401  (DEFAULT_DOMAINS, DomainLease, holder: the lease API, public here)
    DEFAULT_DOMAINS,
    DomainBusy,
    DomainLease,
    holder,
    lease_default_domain,
    lease_domain,
)
from mems_sim.bag.recorder import RecorderNode
from mems_sim.params import ParameterError, spec_table
from mems_sim.ros.env import MAX_DOMAIN_ID, apply_defaults, domain_id_problem
from mems_sim.ros.node_base import EmulatorNode
from mems_sim.ros.pacing import PacedEmulator
from mems_sim.ros.params_file import Override, node_matches
from mems_sim.table import format_table  # noqa: F401  (scenarios print with it)

#: Topics a scenario's recorder leaves out: the estimators' flow-control reports
#: (``~/progress``, for lossless replay into another process) are control, not data.
NOT_RECORDED = r"/progress$"


class ScenarioError(RuntimeError):
    """A scenario could not run (bad option, lost frames, missing result)."""


class IncompleteStream(ScenarioError):
    """A frame topic whose frames jump over sample indices (samples its device declared
    dropped, or loss): an analysis that aligns streams sample by sample cannot use it."""


#: Topics every node has, not data of a scenario (the graph check leaves them out).
IGNORED_TOPICS = frozenset({"/rosout", "/parameter_events"})


@dataclass
class ScenarioOptions:
    """Options common to every scenario (``run_scenario`` command line).

    Attributes:
        duration_s: simulated duration [s] (None: the scenario's default).
        seed: run seed.
        realtime: pace the graph to the wall clock.
        out: MCAP output path (None: ``runs/<scenario>-<seed>.mcap``).
        domain_id: ROS domain of the private context.
        progress: show a progress bar (default: when stderr is a terminal).
        plots: write PNG figures next to the MCAP file.
        overrides: node parameters the user set (``--params-file`` entries, then ``--set``
            ones; later wins): they take precedence over the scenario's own values
            (:meth:`Graph.node`).
        device_seed: ``device_seed`` of every emulator node (None: the nominal devices,
            or the scenario's own); a ``--set`` of it wins.
        temperature_c: ``temperature_c`` of every emulator node [degC] (None: each
            device's reference temperature, or the scenario's own); a ``--set`` wins.
        hardware: ``hardware`` profile of every emulator node, ``ideal`` or ``realistic``
            (None: the nodes' default); a ``--set`` wins.
        applied: filled by the run: (node, parameter) -> (value, origin) of every override
            applied to a node (the run's graphs share it).
        live_view: serve the run to Foxglove on this loopback port (None: no live view).
        cut: fault injection for the tests of the loss reporting: topic -> messages handed
            to the middleware (:class:`Graph`).
        short: the scenario's short plan, where it has one (tests).
        idealised: the scenario's idealised devices, where it has them.
    """

    duration_s: float | None = None
    seed: int = 0
    realtime: bool = False
    out: Path | None = None
    domain_id: int | None = None
    progress: bool | None = None
    plots: bool = True
    overrides: list[Override] = field(default_factory=list)
    applied: dict = field(default_factory=dict)
    device_seed: int | None = None
    temperature_c: float | None = None
    hardware: str | None = None
    live_view: int | None = None
    cut: dict = field(default_factory=dict)
    short: bool = False
    idealised: bool = False


def options_record(options: ScenarioOptions) -> dict:
    """The options of a run as the run record keeps them (JSON-able; the overrides as the
    user wrote them, the output path left out)."""
    out = {}
    for name, value in vars(options).items():
        if name in ("out", "applied", "progress", "domain_id"):
            continue
        if name == "overrides":
            value = [f"{o.node}.{o.name}={o.value!r} ({o.origin})" for o in value]
        out[name] = value
    return out


def default_domain_id() -> int:
    """ROS_DOMAIN_ID from the environment, else a free domain leased for this process
    (:func:`~mems_scenarios.domain.lease_default_domain`: the first of 1..101 without
    61-65, then 0, or of ``$MEMS_FREE_DOMAINS``, that no other graph of this package
    holds). The :class:`Graph` made on
    it keeps the lease; an explicit domain is leased by the Graph (or refused). A value of
    ROS_DOMAIN_ID that rcl would misread or Fast DDS cannot use raises ScenarioError
    (:func:`~mems_sim.ros.env.domain_id_problem`)."""
    env = os.environ.get("ROS_DOMAIN_ID")
    if env:
        problem = domain_id_problem()
        if problem is not None:
            raise ScenarioError(problem)
        return int(env)
    try:
        return lease_default_domain()
    except (DomainBusy, ValueError) as exc:
        raise ScenarioError(str(exc)) from None


def parameters(values: dict) -> list[Parameter]:
    """rclpy parameters (a node's ``parameter_overrides``) from a name -> value mapping."""
    return [Parameter(k, value=v) for k, v in values.items()]


class Graph:
    """A private rclpy context with a single-threaded executor and its nodes.

    Isolation: the graph leases its ROS domain for its lifetime
    (:mod:`mems_scenarios.domain`; another graph of this package on the same domain is
    refused with one line), and :meth:`check_alone` refuses a domain where a publisher
    outside the graph serves one of its topics, so two runs never mix silently.

    Args:
        domain_id: ROS domain (None: :func:`default_domain_id`).
        cut: fault injection for tests of the loss reporting: topic -> messages; an
            emulator added later that publishes the topic hands only that many of its
            messages to the middleware (:meth:`EmulatorNode.cut_topic`).
        overrides: node parameters the user set (:class:`ScenarioOptions`), applied by
            :meth:`node` and :meth:`add_device` on top of the scenario's values and checked
            by :meth:`check_overrides`.
        device_seed, temperature_c, hardware: ``device_seed``, ``temperature_c`` and
            ``hardware`` of every emulator node (None: not set; :class:`ScenarioOptions`),
            applied on top of the scenario's values, under the overrides; a scenario that
            sets one of them itself refuses it.
    """

    def __init__(
        self,
        domain_id: int | None = None,
        *,
        cut: dict | None = None,
        overrides: list[Override] | None = None,
        device_seed: int | None = None,
        temperature_c: float | None = None,
        hardware: str | None = None,
    ) -> None:
        apply_defaults()
        self.overrides = list(overrides or [])
        given = (
            ("device_seed", device_seed),
            ("temperature_c", temperature_c),
            ("hardware", hardware),
        )
        self.variation = {k: v for k, v in given if v is not None}
        #: (node, parameter) -> (value, origin) of every override applied, in order.
        self.applied: dict[tuple[str, str], tuple[object, str]] = {}
        #: Fully qualified name -> class of every node made by :meth:`node`.
        self.node_classes: dict[str, type] = {}
        self._used: set[int] = set()
        if domain_id is None:
            domain_id = default_domain_id()
        if not 0 <= domain_id <= MAX_DOMAIN_ID:
            raise ScenarioError(
                f"domain_id = {domain_id!r} is invalid: allowed [0, {MAX_DOMAIN_ID}]"
            )
        try:
            self.lease = lease_domain(domain_id)
        except DomainBusy as exc:
            raise ScenarioError(str(exc)) from None
        self.domain_id = domain_id
        self.recorders: list = []
        self._cut = dict(cut or {})
        self._alone_checked = False
        _OPEN.add(self)
        self.context = Context()
        try:
            rclpy.init(
                context=self.context,
                domain_id=domain_id,
                signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
            )
        except BaseException:
            self.lease.release()
            raise
        self.executor = SingleThreadedExecutor(context=self.context)
        # the recorder subscribes (and announces each topic) already in its constructor
        rclpy.logging.set_logger_level("mcap_recorder", rclpy.logging.LoggingSeverity.WARN)
        self.nodes: list = []
        self._clock_node = rclpy.create_node("scenario_clock", context=self.context)
        self._clock_pub = self._clock_node.create_publisher(Clock, "/clock", 10)
        self.add(self._clock_node)

    def add(self, node):
        """Add ``node`` to the executor and return it. Its logger is set to WARN: a
        scenario's product is its table, and per-topic INFO lines (the recorder announces
        every topic) would bury it; warnings and errors still print.

        Time: the graph's clock is the emulators' sensor time, epoch 0 (they are its
        source; :meth:`publish_clock` puts it on /clock); every other node gets
        use_sim_time, so that its stamps (diagnostics) are on the same timeline."""
        node.get_logger().set_level(rclpy.logging.LoggingSeverity.WARN)
        if not isinstance(node, PacedEmulator):
            node.set_parameters([Parameter("use_sim_time", value=True)])
        if isinstance(node, RecorderNode):
            self.recorders.append(node)
        for topic, keep in self._cut.items():
            if topic in getattr(node, "streams", {}):
                node.cut_topic(topic, keep)
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def add_device(
        self,
        node_class,
        params: dict,
        *,
        realtime: bool,
        namespace: str | None = None,
        shielded: frozenset[str] = frozenset(),
    ):
        """Add an emulator node of ``node_class`` with parameters ``params``: driven by the
        runner in fast runs, paced by its own timer in real-time runs (started by
        :func:`publish_all` once every consumer is matched, so no frame is lost to discovery).
        ``shielded``: parameters no override reaches on this node (:meth:`overridden`)."""
        return self.node(
            node_class,
            params,
            namespace=namespace,
            shielded=shielded,
            drive_externally=not realtime,
            autostart=False,
        )

    def node(
        self,
        node_class,
        params: dict | None = None,
        *,
        namespace: str | None = None,
        shielded: frozenset[str] = frozenset(),
        **kw,
    ):
        """Create a node of ``node_class`` (a :class:`~mems_sim.ros.node_base.MemsNode`) in
        the graph's context with the scenario's parameters ``params`` and, on top of them, the
        user's overrides whose node name matches it (:meth:`overridden`; none of the
        parameters in ``shielded``); add it and return it. ``kw`` go to the node's
        constructor."""
        if namespace is not None:
            kw["namespace"] = namespace
        values = self.overridden(node_class, namespace, params or {}, shielded)
        if issubclass(node_class, EmulatorNode):
            # the scenario's values are its nominal device; only the user's are fixed
            fqn = self.fqn(node_class, namespace)
            kw.setdefault(
                "fixed_parameters",
                {name for (node, name), (_, origin) in self.applied.items() if node == fqn}
                - set(self.variation),
            )
        node = node_class(context=self.context, parameter_overrides=parameters(values), **kw)
        return self.add(node)

    @staticmethod
    def fqn(node_class, namespace: str | None) -> str:
        """Fully qualified name of a node of ``node_class`` in ``namespace`` (None: the
        class's default namespace)."""
        ns = getattr(node_class, "DEFAULT_NAMESPACE", "") if namespace is None else namespace
        return "/" + "/".join(p for p in (ns.strip("/"), node_class.NODE_NAME) if p)

    def overridden(
        self,
        node_class,
        namespace: str | None,
        params: dict,
        shielded: frozenset[str] = frozenset(),
    ) -> dict:
        """``params`` of a node of ``node_class`` in ``namespace`` (None: the class's
        default) with the overrides that match its fully qualified name, as rcl matches a
        parameter file's node names (:mod:`mems_sim.ros.params_file`), except those of the
        parameters in ``shielded`` (a scenario's reference instance that must stay as it is:
        such an override counts as used only if another node takes it). Each value is checked
        against the node's parameter table first: a value out of range raises
        :class:`ScenarioError` naming the node, the parameter, the value and the range.
        An emulator node gets the graph's ``device_seed`` / ``temperature_c`` / ``hardware``
        first (a scenario that sets one itself refuses it: the scenario is about that
        value)."""
        fqn = self.fqn(node_class, namespace)
        self.node_classes[fqn] = node_class
        specs = spec_table(node_class.SPECS)
        out = dict(params)
        origin = {
            "device_seed": "--device-seed",
            "temperature_c": "--temperature",
            "hardware": "--hardware",
        }
        for name, value in self.variation.items() if issubclass(node_class, EmulatorNode) else ():
            if name in params:
                self.close()
                raise ScenarioError(
                    f"{origin[name]}: this scenario sets {name} of node {fqn} itself "
                    f"({params[name]!r}); {origin[name]} does not apply to it"
                )
            try:
                out[name] = specs[name].validate(value)
            except (KeyError, ParameterError) as exc:
                self.close()
                raise ScenarioError(f"{origin[name]}: node {fqn}: {exc}") from None
            self.applied[(fqn, name)] = (out[name], origin[name])
        for i, o in enumerate(self.overrides):
            if not node_matches(o.node, fqn) or o.name not in specs or o.name in shielded:
                continue
            try:
                value = specs[o.name].validate(o.value)
            except ParameterError as exc:
                self.close()
                raise ScenarioError(f"{o.where()}: node {fqn}: {exc}") from None
            self._used.add(i)
            out[o.name] = value
            self.applied.pop((fqn, o.name), None)
            self.applied[(fqn, o.name)] = (value, o.origin)
        return out

    def check_overrides(self) -> None:
        """Refuse (:class:`ScenarioError`, one line) an override whose node name matches no
        node made by :meth:`node`, or whose parameter no node it matches has. Called by
        :meth:`recorder` (the last node a scenario adds, before the MCAP file is opened) and
        :func:`prepare_delivery`."""
        import difflib

        for i, o in enumerate(self.overrides):
            if i in self._used:
                continue
            nodes = [n for n in self.node_classes if node_matches(o.node, n)]
            if not nodes:
                self.close()
                raise ScenarioError(
                    f"{o.where()}: no node of this scenario matches {o.node}; its nodes are "
                    + ", ".join(sorted(self.node_classes))
                )
            known = sorted({s.name for n in nodes for s in self.node_classes[n].SPECS})
            near = difflib.get_close_matches(o.name, known, n=1)
            hint = f"did you mean '{near[0]}'? " if near else ""
            what = nodes[0] if len(nodes) == 1 else f"none of the {len(nodes)} nodes {o.node}"
            self.close()
            raise ScenarioError(
                f"{o.where()}: {what} has no parameter '{o.name}' ({hint}"
                f"known are {', '.join(known)})"
            )

    def build(
        self, spec: GraphSpec, *, realtime: bool, shielded: dict | None = None
    ) -> dict[str, object]:
        """Create the nodes of ``spec`` in its order (:meth:`add_device` for emulators,
        :meth:`node` for the others, each with the user's overrides on top of the spec's
        parameters); ``shielded``: fully qualified name -> parameters no override reaches
        (:meth:`overridden`). Returns fully qualified name -> node."""
        shielded = shielded or {}
        nodes = {}
        for entry in spec.nodes:
            cls = node_class(entry.executable)
            if cls.NODE_NAME != entry.name or entry.remaps:
                raise ScenarioError(
                    f"graph of {spec.scenario}: {entry.fqn}: the in-process runner names "
                    f"{entry.executable} nodes {cls.NODE_NAME!r} and applies no remaps"
                )
            kw = dict(namespace="/" + entry.namespace.strip("/"))
            kw["shielded"] = frozenset(shielded.get(entry.fqn, ()))
            if issubclass(cls, EmulatorNode):
                nodes[entry.fqn] = self.add_device(cls, entry.parameters, realtime=realtime, **kw)
            else:
                nodes[entry.fqn] = self.node(cls, entry.parameters, **kw)
        return nodes

    def publish_run_info(self, spec: GraphSpec, options, nodes: dict, **extra) -> None:
        """Publish the run record (:func:`~mems_scenarios.contract.run_info`: the options and
        every node's executable and parameter values as it runs with them) on
        :data:`~mems_scenarios.contract.RUN_INFO_TOPIC`, transient-local, for the recorder."""
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        qos = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        entries = {e.fqn: e for e in spec.nodes}
        record = {
            fqn: dict(executable=entries[fqn].executable, parameters=dict(node.p))
            for fqn, node in nodes.items()
        }
        text = run_info(spec.scenario, options_record(options), record, **extra)
        self._run_info_pub = self._clock_node.create_publisher(String, RUN_INFO_TOPIC, qos)
        self._run_info_pub.publish(String(data=text))

    def wait_run_info(self, rec: RecorderNode, timeout_s: float = 20.0) -> None:
        """Wait until ``rec`` holds the run record (before it is closed)."""
        self.spin_until(
            lambda: rec.received(RUN_INFO_TOPIC) >= 1,
            timeout_s,
            "the recorder to take the run record",
        )

    def recorder(self, output: str, **kwargs) -> RecorderNode:
        """Add the scenario's recorder (the last node): :meth:`check_overrides` first, so a
        bad override is refused before the MCAP file is opened."""
        self.check_overrides()
        if kwargs.get("topics") is not None:
            kwargs["topics"] = list(kwargs["topics"]) + [
                t for t in sorted(self.fault_topics()) if t not in kwargs["topics"]
            ]
        return self.add(RecorderNode(output, context=self.context, **kwargs))

    def fault_topics(self) -> set[str]:
        """The ``faults`` topics (labelled truth of a fault schedule) of this graph's
        emulators: recorded with whatever the scenario records."""
        return {
            p.topic_name
            for n in self.nodes
            for p in n.publishers
            if p.topic_name.rsplit("/", 1)[-1] == "faults" and p.msg_type.__name__ == "FaultEvent"
        }

    def publish_clock(self, ns: int) -> None:
        """Publish simulated time on /clock (not again while it has not moved)."""
        if ns == getattr(self, "_clock_ns", None):
            return
        self._clock_ns = ns
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = int(ns // 10**9), int(ns % 10**9)
        self._clock_pub.publish(msg)

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Spin the executor until ``predicate()``; raise ScenarioError after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise ScenarioError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.01)

    def own_publishers(self) -> Counter:
        """Publishers of this graph's nodes per topic."""
        return Counter(p.topic_name for n in self.nodes for p in n.publishers)

    def foreign_publishers(self, topics=None) -> dict[str, int]:
        """Publishers outside this graph per topic, on ``topics`` (default: every topic the
        graph's nodes publish or subscribe to), as the graph has discovered them so far."""
        own = self.own_publishers()
        if topics is None:
            topics = set(own) | {s.topic_name for n in self.nodes for s in n.subscriptions}
        out = {}
        for topic in sorted(set(topics) - IGNORED_TOPICS):
            foreign = len(self._clock_node.get_publishers_info_by_topic(topic)) - own[topic]
            if foreign > 0:
                out[topic] = foreign
        return out

    def check_alone(self) -> None:
        """Refuse (:class:`ScenarioError`, one line) when a publisher outside this graph
        serves one of the graph's topics on its domain: the recording would mix the two.
        Checked once, before the first frame. Discovery of another process takes a moment
        (about 2 s on localhost), so a graph found only later is reported by
        :func:`check_delivery` at the end of the run."""
        if self._alone_checked:
            return
        foreign = self.foreign_publishers()
        if foreign:
            topic, n = next(iter(foreign.items()))
            raise ScenarioError(
                f"ROS domain {self.domain_id} is in use: {topic} has {n} publisher(s) "
                f"outside this run (on {len(foreign)} of its topics), whose messages would "
                "mix with its own; pass another --domain-id, or stop the other graph"
            )
        self._alone_checked = True

    def close(self) -> None:
        """Destroy nodes, shut the context down and end the domain lease (idempotent)."""
        _OPEN.discard(self)
        try:
            for node in self.nodes:
                try:
                    self.executor.remove_node(node)
                    node.destroy_node()
                except Exception:
                    pass
            self.executor.shutdown()
            if self.context.ok():
                rclpy.shutdown(context=self.context)
        finally:
            if getattr(self, "live_view", None) is not None:  # graph_for's, if any
                self.live_view.stop()
            self.lease.release()


#: The Graphs made and not yet closed in this process.
_OPEN: weakref.WeakSet[Graph] = weakref.WeakSet()


@contextmanager
def graphs_closed() -> Iterator[None]:
    """Close, at the end of the block, every Graph made in it and still open: a scenario
    that failed while building its graph (a refused parameter, a device that cannot be
    drawn) leaves no node, context or domain lease behind in a process that goes on."""
    before = set(_OPEN)
    try:
        yield
    finally:
        for graph in [g for g in _OPEN if g not in before]:
            graph.close()


def output_path(out: Path | str, seed: int, suffix: str) -> Path:
    """A file a scenario writes beside its MCAP file ``out`` (a figure, a YAML result),
    named with the run seed so that runs with other seeds never overwrite it:
    ``<stem>-seed<N><suffix>``, the stem being the MCAP file's without a trailing ``-<N>``
    or ``-seed<N>`` (the default ``runs/imu_noise-1.mcap`` gives
    ``runs/imu_noise-seed1-allan.png`` for the suffix ``-allan.png``)."""
    out = Path(out)
    stem = out.stem.removesuffix(f"-seed{seed}").removesuffix(f"-{seed}") or out.stem
    return out.with_name(f"{stem}-seed{seed}{suffix}")


def bench_paths(options: ScenarioOptions, scenario: str, device: str, out=None) -> dict:
    """Where a bench's results go, beside the MCAP file ``out`` (None: the options' ``out``,
    else ``runs/<scenario>-<seed>.mcap``): ``path`` ``<stem>-seed<N>-<device>_params.yaml``
    (the identified model) and ``oracle_path`` ``...-<device>_oracle_params.yaml`` (the
    device's own table's)."""
    out = Path(out or options.out or Path("runs") / f"{scenario}-{options.seed}.mcap")
    return dict(
        path=output_path(out, options.seed, f"-{device}_params.yaml"),
        oracle_path=output_path(out, options.seed, f"-{device}_oracle_params.yaml"),
    )


def outputs_beside(out: Path | str, seed: int) -> list[Path]:
    """The existing entries beside the MCAP file ``out`` that a run of ``seed`` would write
    (:func:`output_path`'s names: ``<stem>-seed<N>`` followed by ``-``, ``.`` or ``_``)."""
    out = Path(out)
    prefix = output_path(out, seed, "").name
    try:
        names = sorted(os.listdir(out.parent))
    except OSError:
        return []
    return [
        out.parent / n
        for n in names
        if n.startswith(prefix) and n[len(prefix) : len(prefix) + 1] in ("-", ".", "_")
    ]


def graph_for(options: ScenarioOptions) -> Graph:
    """The Graph of a scenario run: its domain (None: a free one, leased), the user's
    parameter overrides (recorded as applied in ``options.applied``) and the fault
    injection of ``options.cut`` (topic -> messages, tests only)."""
    graph = Graph(
        options.domain_id,
        cut=options.cut,
        overrides=options.overrides,
        device_seed=options.device_seed,
        temperature_c=options.temperature_c,
        hardware=options.hardware,
    )
    graph.applied = options.applied
    if options.live_view is not None:  # run_scenario --live-view [PORT]
        from mems_scenarios.live import LiveView, LiveViewError

        try:
            graph.live_view = LiveView(graph.domain_id, options.live_view)
        except LiveViewError as exc:
            graph.close()
            raise ScenarioError(str(exc)) from None
    return graph


class Progress:
    """Progress over simulated seconds: a tqdm bar on a terminal, silent otherwise."""

    def __init__(self, total_s: float, enabled: bool | None, label: str) -> None:
        if enabled is None:
            enabled = sys.stderr.isatty()
        self._bar = None
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(
                total=round(total_s, 3),
                unit="sim s",
                desc=label,
                file=sys.stderr,
                dynamic_ncols=True,
                bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} "
                "sim s [{elapsed}<{remaining}, {rate_fmt}]",
            )
        self._done = 0.0

    def update_to(self, done_s: float) -> None:
        """Set the simulated seconds done."""
        if self._bar is not None and done_s > self._done:
            self._bar.update(round(done_s - self._done, 3))
        self._done = max(self._done, done_s)

    def close(self) -> None:
        """Finish the bar."""
        if self._bar is not None:
            self._bar.close()


def run_recorded(
    options: ScenarioOptions,
    *,
    name: str,
    default_duration_s: float,
    check_duration: Callable[[float], None],
    run_graph: Callable[..., dict],
    analyse: Callable[..., ScenarioResult],
    png_suffixes: tuple[str, ...] = ("",),
) -> dict:
    """The common shape of a scenario's ``run``: graph -> MCAP -> ``analyse(MCAP)``.

    Args:
        check_duration: raises :class:`ScenarioError` for a duration the scenario can't use.
        run_graph: ``(options, out, duration, progress) -> dict`` with at least
            ``recorder`` and ``published``; it records the run record
            (:meth:`Graph.publish_run_info`).
        analyse: the scenario's ``analyse(mcap_path, pngs)`` (a pure function of the
            recording, :class:`~mems_scenarios.contract.ScenarioResult`); ``pngs``: one PNG
            path per entry of ``png_suffixes``, named ``<mcap stem>-seed<N><suffix>.png``
            next to the MCAP file (:func:`output_path`), or None without plots.
    Returns:
        dict with ``table``, ``figures`` (the :class:`~mems_scenarios.figures.Figure`
        records), ``values`` (the result's values), ``mcap``, ``figure`` (first PNG),
        ``figure_paths``, ``recorder``, ``published``, ``duration_s``, ``device_seed``,
        ``temperature_c`` and ``hardware`` (the options', None: not set) and ``result`` (the
        :class:`~mems_scenarios.contract.ScenarioResult`).
    """
    duration = default_duration_s if options.duration_s is None else options.duration_s
    check_duration(duration)
    out = Path(options.out or Path("runs") / f"{name}-{options.seed}.mcap")
    out.parent.mkdir(parents=True, exist_ok=True)
    progress = Progress(duration, options.progress, name)
    try:
        ran = run_graph(options, out, duration, progress)
    finally:
        progress.close()
    pngs = None
    if options.plots:
        pngs = tuple(output_path(out, options.seed, s + ".png") for s in png_suffixes)
    try:
        result = analyse_quietly(analyse, out, pngs)
    except IncompleteStream as exc:  # e.g. scheduled dropped samples: the recording stays
        result = ScenarioResult(
            name, [], f"figures not computed: {exc}", unavailable=[("*", str(exc))]
        )
    return dict(
        table=result.table,
        figures=result.figures,
        values=result.values,
        mcap=out,
        figure=pngs[0] if pngs else None,
        figure_paths=pngs,
        recorder=ran["recorder"],
        published=ran["published"],
        duration_s=duration,
        device_seed=options.device_seed,
        temperature_c=options.temperature_c,
        hardware=options.hardware,
        result=result,
    )


def analyse_quietly(analyse: Callable[..., ScenarioResult], *args) -> ScenarioResult:
    """``analyse(*args)`` without matplotlib's warning that placing a "best" legend over
    many points took over a second (it depends on the host's load, not on the figure)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Creating legend with loc")
        return analyse(*args)

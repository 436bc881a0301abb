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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from mems_sim.ros.env import apply_defaults
from mems_sim.ros.frames import index_to_ns
from mems_sim.table import format_table  # noqa: F401  (scenarios print with it)


class ScenarioError(RuntimeError):
    """A scenario could not run (bad option, lost frames, missing result)."""


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
    """

    duration_s: float | None = None
    seed: int = 0
    realtime: bool = False
    out: Path | None = None
    domain_id: int | None = None
    progress: bool | None = None
    plots: bool = True
    extra: dict = field(default_factory=dict)


def default_domain_id() -> int:
    """ROS_DOMAIN_ID from the environment, or one derived from the process id (1..100)."""
    env = os.environ.get("ROS_DOMAIN_ID")
    if env:
        return int(env)
    return 1 + os.getpid() % 100


def parameters(values: dict) -> list[Parameter]:
    """rclpy parameters (a node's ``parameter_overrides``) from a name -> value mapping."""
    return [Parameter(k, value=v) for k, v in values.items()]


class Graph:
    """A private rclpy context with a single-threaded executor and its nodes."""

    def __init__(self, domain_id: int) -> None:
        apply_defaults()
        self.context = Context()
        rclpy.init(
            context=self.context,
            domain_id=domain_id,
            signal_handler_options=rclpy.signals.SignalHandlerOptions.NO,
        )
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
        every topic) would bury it; warnings and errors still print."""
        node.get_logger().set_level(rclpy.logging.LoggingSeverity.WARN)
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def add_device(self, node_class, params: dict, *, realtime: bool, namespace: str | None = None):
        """Add an emulator node of ``node_class`` with parameters ``params``: driven by the
        runner in fast runs, paced by its own timer in real-time runs (started by
        :func:`publish_all` once every consumer is matched, so no frame is lost to discovery)."""
        kwargs = {} if namespace is None else {"namespace": namespace}
        node = node_class(
            context=self.context,
            drive_externally=not realtime,
            autostart=False,
            parameter_overrides=parameters(params),
            **kwargs,
        )
        return self.add(node)

    def publish_clock(self, ns: int) -> None:
        """Publish simulated time on /clock."""
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

    def close(self) -> None:
        """Destroy nodes and shut the context down."""
        for node in self.nodes:
            try:
                self.executor.remove_node(node)
                node.destroy_node()
            except Exception:
                pass
        self.executor.shutdown()
        if self.context.ok():
            rclpy.shutdown(context=self.context)


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


def drive_fast(
    graph: Graph,
    devices: list,
    delivered: Callable[[object], int],
    progress: Progress | None = None,
    window: int = 50,
) -> None:
    """Step every device as fast as its consumers take the frames (lossless, deterministic).

    Args:
        devices: emulator nodes with ``step()``, ``finished``, ``frames_published``,
            ``next_index`` and ``fs``.
        delivered: frames of ``device`` taken by its slowest consumer so far.
        window: frames a device may run ahead of that consumer.
    """
    while not all(d.finished for d in devices):
        for d in devices:
            if not d.finished:
                d.step()
        lead = max(devices, key=lambda d: d.next_index)
        graph.publish_clock(index_to_ns(lead.next_index, lead.fs))

        def caught_up() -> bool:
            return all(d.frames_published - delivered(d) < window for d in devices)

        if not caught_up():
            graph.spin_until(caught_up, 60.0, "consumers to take the emulators' frames")
        graph.executor.spin_once(timeout_sec=0)
        if progress is not None:
            progress.update_to(min(d.next_index / d.fs for d in devices))


def publish_all(
    graph: Graph,
    devices: list,
    delivered: Callable[[object], int],
    progress: Progress | None,
    *,
    realtime: bool,
    realtime_timeout_s: float,
    window: int = 50,
    drain_timeout_s: float = 60.0,
) -> None:
    """Publish every device's data and wait until its consumers took the last frame.

    Real time (``--realtime``): the devices' own wall-clock timers pace them, and the graph
    spins until every device finished (``realtime_timeout_s`` at most). Fast: the runner
    steps the devices as fast as their slowest consumer takes the frames
    (:func:`drive_fast`, lossless and deterministic). Either way the call returns once
    ``delivered(device)`` reached every frame the device published.
    """
    if realtime:
        for d in devices:
            d.start()
        graph.spin_until(
            lambda: all(d.finished for d in devices), realtime_timeout_s, "the devices to finish"
        )
    else:
        drive_fast(graph, devices, delivered, progress, window)
    graph.spin_until(
        lambda: all(delivered(d) >= d.frames_published for d in devices),
        drain_timeout_s,
        "the last frames",
    )


def topic_frames(path, topic: str) -> dict:
    """Concatenate the frames of one topic of an MCAP file into arrays.

    Returns:
        dict with ``first_index`` (first sample index), ``names``, ``units``,
        ``data`` (n, channels) — SignalFrame data, StateEstimate states or AdcFrame
        physical values — and, for StateEstimate, ``variances`` (n, channels).
    """
    import numpy as np

    from mems_sim.bag.player import read_messages
    from mems_sim.ros.frames import adc_physical, signal_data

    chunks, variances, first, names, units = [], [], None, (), ()
    for _, type_name, _, msg in read_messages(str(path), [topic]):
        if first is None:
            first = int(msg.first_sample_index)
        if type_name.endswith("/StateEstimate"):
            k = len(msg.state_names)
            names, units = tuple(msg.state_names), tuple(msg.state_units)
            chunks.append(np.asarray(msg.states).reshape(-1, k))
            variances.append(np.asarray(msg.variances).reshape(-1, k))
        elif type_name.endswith("/AdcFrame"):
            names, units = tuple(msg.channel_names), tuple(msg.channel_units)
            chunks.append(adc_physical(msg))
        else:
            names, units = tuple(msg.channel_names), tuple(msg.channel_units)
            chunks.append(signal_data(msg))
    if not chunks:
        raise ScenarioError(f"{path}: no frames on {topic}")
    out = dict(first_index=first, names=names, units=units, data=np.concatenate(chunks))
    if variances:
        out["variances"] = np.concatenate(variances)
    return out


def run_recorded(
    options: ScenarioOptions,
    *,
    name: str,
    default_duration_s: float,
    check_duration: Callable[[float], None],
    run_graph: Callable[..., dict],
    figures: Callable[[Path, dict, float], dict],
    table: Callable[[dict], str],
    plot: Callable[..., None],
    png_suffixes: tuple[str, ...] = ("",),
) -> dict:
    """The common shape of a scenario's ``run``: graph -> MCAP -> figures -> table and PNGs.

    Args:
        check_duration: raises :class:`ScenarioError` for a duration the scenario can't use.
        run_graph: ``(options, out, duration, progress) -> dict`` with at least
            ``recorder`` and ``published``.
        figures: ``(mcap_path, run_graph_result, duration) -> dict`` (key ``series`` holds
            arrays for the plots only).
        plot: ``(figures, *png_paths)``; one PNG per entry of ``png_suffixes``, named
            ``<mcap stem><suffix>.png`` next to the MCAP file.
    Returns:
        dict with ``table``, ``figures`` (without ``series``), ``mcap``, ``figure`` (first
        PNG), ``figure_paths``, ``recorder``, ``published``, ``duration_s``.
    """
    duration = default_duration_s if options.duration_s is None else options.duration_s
    check_duration(duration)
    out = Path(options.out or Path("runs") / f"{name}-{options.seed}.mcap")
    out.parent.mkdir(parents=True, exist_ok=True)
    progress = Progress(duration, options.progress, name)
    try:
        result = run_graph(options, out, duration, progress)
    finally:
        progress.close()
    f = figures(out, result, duration)
    pngs = None
    if options.plots:
        pngs = tuple(out.with_name(out.stem + s + ".png") for s in png_suffixes)
        plot(f, *pngs)
    return dict(
        table=table(f),
        figures={k: v for k, v in f.items() if k != "series"},
        mcap=out,
        figure=pngs[0] if pngs else None,
        figure_paths=pngs,
        recorder=result["recorder"],
        published=result["published"],
        duration_s=duration,
    )

"""Lossless delivery in the in-process runner: the emulators step as fast as their slowest
consumer takes the frames (:func:`drive_fast`, the flow-control rule of
:mod:`mems_sim.ros.flow`), the recorder is matched before the first frame and checked after
the last (:func:`check_delivery`), and :data:`THROUGHPUT` times the graph. The scenario
contract: docs/scenarios.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from mems_scenarios.base import Graph, Progress, ScenarioError
from mems_sim.ros.flow import may_send, progress_of
from mems_sim.ros.frames import index_to_ns


class Throughput:
    """Samples the devices emulated per wall second from their first frame to the last one
    their consumers took, for the summary line of ``run_scenario``; start-up is excluded:
    building the graph, discovery, the figures, and the first frame (in fast runs the clock
    starts once every consumer took it: the numba kernels are loaded from their cache at
    their first call, which can take longer than the whole run). :func:`drive_fast` and
    :func:`publish_all` call :meth:`begin` and :meth:`end` once the last frame is
    delivered; :data:`THROUGHPUT` holds the runs of the current scenario."""

    def __init__(self) -> None:
        self.runs: list[dict] = []

    def reset(self) -> None:
        self.runs = []

    def begin(self, devices: list) -> None:
        """The clock starts: the samples the devices published so far do not count."""
        self.runs.append(
            dict(
                devices=devices,
                t_first=time.monotonic(),
                t_last=None,
                start=sum(int(d.next_index) for d in devices),
            )
        )

    def end(self, devices: list) -> None:
        """Every frame of ``devices`` published so far is delivered (a later call moves
        the end: the drain after the last frame counts)."""
        for run in reversed(self.runs):
            if run["devices"] is devices:
                run["t_last"] = time.monotonic()
                run["samples"] = sum(int(d.next_index) for d in devices) - run["start"]
                run["rates"] = [float(d.fs) for d in devices]
                return

    def summary(self) -> str | None:
        """A single device's real-time factor (one line), or several devices' samples
        emulated per wall second against the sum of their sample rates (two lines, each
        naming the wall time, under 120 columns); None if no graph ran. Several graphs one
        after the other add up (samples, wall time, and the sum of the rates weighted by each
        graph's wall time)."""
        runs = [r for r in self.runs if r["t_last"] is not None and r["t_last"] > r["t_first"]]
        if not runs:
            return None
        wall = sum(r["t_last"] - r["t_first"] for r in runs)
        samples = sum(r["samples"] for r in runs)
        rate = sum(sum(r["rates"]) * (r["t_last"] - r["t_first"]) for r in runs) / wall
        devices = max(len(r["rates"]) for r in runs)
        if devices == 1:
            return (
                f"graph from its first frame to its last: {samples / rate:.4g} s simulated in "
                f"{wall:.2f} s wall = {samples / wall / rate:.3g} x real time"
            )
        return (
            f"graph from its first frame to its last ({devices} devices): "
            f"{samples / wall:.4g} samples emulated per wall second\n  against {rate:.4g} "
            f"samples/s summed over their sample rates = {samples / wall / rate:.3g} x, "
            f"{wall:.2f} s wall"
        )


#: The graphs of the scenario being run (``run_scenario`` resets it and prints its summary).
THROUGHPUT = Throughput()


def recorded_streams(graph: Graph, devices: list, window: int = 1) -> list[tuple]:
    """``(recorder, account, window)`` for every data topic of ``devices`` that a recorder
    of the graph records; ``window`` is at most half the publisher's history depth (a
    reliable KEEP_LAST publisher overwrites what a reader has not taken beyond it)."""
    out = []
    for d in devices:
        for topic, account in getattr(d, "streams", {}).items():
            for rec in graph.recorders:
                if rec.wants(topic):
                    w = window if account.depth is None else min(window, account.depth // 2)
                    out.append((rec, account, max(1, w)))
    return out


def _end_of_stream_topics(graph: Graph, devices: list) -> list[tuple]:
    """``(recorder, device, topic)`` for every end-of-stream topic a recorder records."""
    out = []
    for d in devices:
        pub = getattr(d, "pub_end_of_stream", None)
        for rec in graph.recorders if pub is not None else ():
            if rec.wants(pub.topic_name):
                out.append((rec, d, pub.topic_name))
    return out


def prepare_delivery(graph: Graph, devices: list, timeout_s: float = 30.0) -> None:
    """Before the first frame: wait until every recorder of the graph subscribes to (and
    has matched) each topic of ``devices`` it selects, end-of-stream records included, so
    that no message is lost to discovery; then :meth:`Graph.check_alone`."""
    topics = [(rec, acc.topic) for rec, acc, _ in recorded_streams(graph, devices)]
    topics += [(rec, t) for rec, _, t in _end_of_stream_topics(graph, devices)]
    graph.check_overrides()
    deadline = time.monotonic() + timeout_s
    while not all(rec.matched(t) for rec, t in topics):
        if time.monotonic() > deadline:
            missing = sorted({t for rec, t in topics if not rec.matched(t)})
            raise ScenarioError(
                f"timed out after {timeout_s:.0f} s waiting for the recorder to subscribe to "
                + ", ".join(missing)
            )
        graph.executor.spin_once(timeout_sec=0.01)
    graph.check_alone()


def _lagging(devices: list, delivered, streams: list) -> str:
    """What has not been delivered yet: per topic the recorder's count, per device the
    frames its other consumers took."""
    parts = [
        f"{acc.topic}: the recorder has {rec.received(acc.topic)} of {acc.sent} messages"
        for rec, acc, _ in streams
        if rec.received(acc.topic) < acc.sent
    ]
    for d in devices:
        n = delivered(d) if delivered is not None else None
        if n is not None and n < d.next_index:
            parts.append(
                f"{d.get_fully_qualified_name()}: its consumers took {n} of {d.next_index} samples"
            )
    return "; ".join(parts) or "nothing outstanding"


def _wait_delivered(graph, predicate, devices, delivered, streams, timeout_s, what) -> None:
    """Spin until ``predicate()``; after ``timeout_s`` raise ScenarioError naming what is
    outstanding."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise ScenarioError(
                f"timed out after {timeout_s:.0f} s waiting for {what}: "
                + _lagging(devices, delivered, streams)
            )
        graph.executor.spin_once(timeout_sec=0.01)


def check_delivery(graph: Graph, devices: list) -> None:
    """Raise :class:`ScenarioError` (one line) when the recording lost or mixed data:
    per data topic of ``devices`` the messages (and samples) the device produced but the
    recorder does not hold, with the missing tail; every loss a recorder saw (frame-index
    and sequence gaps, tails against end-of-stream records, on any topic); messages
    from publishers outside the graph."""
    problems, named = [], set()
    for rec, acc, _ in recorded_streams(graph, devices):
        missing = acc.messages - rec.received(acc.topic)
        if missing <= 0:
            continue
        text = f"{acc.topic}: {missing} of {acc.messages} messages missing"
        if acc.frames:
            recorded = rec.gap_details().get(acc.topic, {}).get("samples", 0)
            tail = rec.tails().get(acc.topic)
            where = f"; the tail from sample {tail['from_index']}" if tail else ""
            text += f" ({acc.samples - recorded} samples{where})"
        problems.append(text)
        named.add(acc.topic)
    own, recorded = graph.own_publishers(), set()
    for rec in graph.recorders:
        problems += [t for t in rec.losses() if t.split(":", 1)[0] not in named]
        recorded |= set(rec.recorded_topics())
        for topic, seq in sorted(rec.sequence_details().items()):
            foreign = seq["publishers"] - own.get(topic, 0)
            if foreign > 0:
                problems.append(
                    f"{topic}: messages of {foreign} publisher(s) outside this run recorded "
                    f"(another graph on ROS domain {graph.domain_id})"
                )
    # topics the graph takes in without recording them (e.g. /clock): any other publisher
    subscribed = {s.topic_name for n in graph.nodes for s in n.subscriptions} - recorded
    for topic, n in graph.foreign_publishers(subscribed).items():
        problems.append(
            f"{topic}: {n} publisher(s) outside this run (another graph on ROS domain "
            f"{graph.domain_id})"
        )
    if problems:
        raise ScenarioError("the recording lost or mixed data: " + "; ".join(problems))


def finish_delivery(graph: Graph, devices: list, delivered=None, timeout_s: float = 60.0) -> None:
    """After the last frame: wait until the consumers (``delivered``) and every recorder
    hold all that ``devices`` published, end-of-stream records included, then
    :func:`check_delivery`."""
    streams = recorded_streams(graph, devices)
    ends = _end_of_stream_topics(graph, devices)

    def done() -> bool:
        if delivered is not None:
            for d in devices:
                n = delivered(d)
                if n is not None and n < d.next_index:
                    return False
        return all(rec.received(acc.topic) >= acc.sent for rec, acc, _ in streams) and all(
            rec.received(t) >= 1 for rec, d, t in ends if d.end_of_stream_sent
        )

    _wait_delivered(graph, done, devices, delivered, streams, timeout_s, "the last frames")
    check_delivery(graph, devices)


def _all_taken(devices: list, delivered, streams: list) -> bool:
    """Every frame the devices published is taken by every consumer and recorder."""
    if delivered is not None:
        for d in devices:
            n = delivered(d)
            if n is not None and n < d.next_index:
                return False
    return all(rec.received(acc.topic) >= acc.sent for rec, acc, _ in streams)


def drive_fast(
    graph: Graph,
    devices: list,
    delivered: Callable[[object], int | None] | None = None,
    progress: Progress | None = None,
    window: int = 50,
) -> None:
    """Step every device as fast as its consumers take the frames (lossless, deterministic).

    Every consumer counts: the recorders of the graph for every topic of every device
    they record (:func:`recorded_streams`, by the recorder's own counts), and the
    consumers ``delivered`` reports. Before the first step the recorders are matched and
    the domain checked (:func:`prepare_delivery`).

    Args:
        devices: emulator nodes with ``step()``, ``finished``, ``frames_published``,
            ``next_index``, ``fs`` and ``streams``.
        delivered: progress of ``device``'s slowest consumer besides the recorders (one
            past the last sample index it finished with, :mod:`mems_sim.ros.flow`; see
            :func:`consumed`), None, or returning None: no such consumer.
        window: frames (messages per topic) a device may run ahead of its consumers.
    """
    prepare_delivery(graph, devices)
    streams = recorded_streams(graph, devices, window)
    first = True

    def caught_up() -> bool:
        if delivered is not None:
            for d in devices:
                n, f = delivered(d), d.p["frame_size"]
                # the next frame is within ``window`` frames of the slowest consumer's
                # progress: the player's credit rule (one flow-control protocol)
                if n is not None and not may_send(d.next_index, f, n, window * f):
                    return False
        return all(acc.sent - rec.received(acc.topic) < w for rec, acc, w in streams)

    while not all(d.finished for d in devices):
        for d in devices:
            if not d.finished:
                d.step()
        lead = max(devices, key=lambda d: d.next_index)
        graph.publish_clock(index_to_ns(lead.next_index, lead.fs))
        if not caught_up():
            _wait_delivered(
                graph, caught_up, devices, delivered, streams, 60.0, "consumers to take frames"
            )
        graph.executor.spin_once(timeout_sec=0)
        if first:  # the throughput's clock starts once every consumer took the first
            # frame (at most 10 s: a consumer that holds a frame back starts it then)
            deadline = time.monotonic() + 10.0
            while not _all_taken(devices, delivered, streams) and time.monotonic() < deadline:
                graph.executor.spin_once(timeout_sec=0.01)
            THROUGHPUT.begin(devices)
            first = False
        if progress is not None:
            progress.update_to(min(d.next_index / d.fs for d in devices))
    THROUGHPUT.end(devices)


def publish_all(
    graph: Graph,
    devices: list,
    delivered: Callable[[object], int | None] | None,
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
    ``delivered(device)`` and the recorders reached every message the device published
    (:func:`finish_delivery`); a loss raises :class:`ScenarioError` naming the topics.
    """
    prepare_delivery(graph, devices)
    if realtime:
        THROUGHPUT.begin(devices)
        for d in devices:
            d.start()

        def finished() -> bool:  # and the graph's clock follows the devices
            lead = max(devices, key=lambda d: d.next_index)
            graph.publish_clock(index_to_ns(lead.next_index, lead.fs))
            return all(d.finished for d in devices)

        graph.spin_until(finished, realtime_timeout_s, "the devices to finish")
    else:
        drive_fast(graph, devices, delivered, progress, window)
    finish_delivery(graph, devices, delivered, drain_timeout_s)
    THROUGHPUT.end(devices)


def consumed(*nodes) -> Callable[[object], int]:
    """``delivered`` of :func:`drive_fast` for consumers ``nodes`` of every device: the
    slowest one's progress in samples (:func:`~mems_sim.ros.flow.progress_of`; 0 before its
    first report)."""

    def delivered(_device) -> int:
        return min(progress_of(n) or 0 for n in nodes)

    return delivered

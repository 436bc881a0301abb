"""MCAP player: ``mcap_play BAG [--rate R | --as-fast-as-possible] [--loop] [--clock [HZ]] ...``.

``BAG`` is an MCAP file or a rosbag2 bag directory (a split recording), played as
one timeline (:func:`iter_raw`). Topics are remapped with ``--remap FROM:=TO`` or
ROS's ``--ros-args -r FROM:=TO``; ``--start-paused`` and the services of
:class:`PlaybackControl` (rosbag2's ``~/pause``, ``~/resume``, ``~/toggle_paused``,
``~/is_paused``, ``~/play_next``, as std_srvs/srv/Trigger) pause and step the replay.

Publishes the serialised bytes stored in the file (no deserialisation) with
publishers created from the file's schemas (``pkg/msg/Type``, imported only
when it is an interface of the ament index: other types are reported and their
topics skipped) and the recorded ``offered_qos_profiles`` (fallback FRAME_QOS),
paced by ``log_time`` scaled by ``--rate``; optionally publishes ``/clock``.
The recorder's log times are sensor time, so ``--rate 1`` replays a 600 s
recording in 600 s and ``--clock`` publishes the time the stamps belong to.

Lossless replay into other processes (``--wait-for-consumer NODE_FQN``, repeatable,
with or without ``--as-fast-as-possible``): flow control at the application level
(:class:`FlowControl`). The consumer reports its progress on ``NODE_FQN/progress``
(std_msgs/UInt64, one past the last sample index it processed, after every frame);
the player keeps at most ``--credit`` samples (``N``) or frames (``Nf``, default 50f)
published ahead of it on each played frame topic it subscribes to, waits at the end
until it has caught up, and reports per topic what was published and acknowledged
and the loss (frames its progress skipped, gaps it reports on /diagnostics, frames
never acknowledged); exit status 3 when anything was lost or a consumer was not
ready, stalled (``--consumer-timeout``) or left.

Files are read through :mod:`mems_sim.bag.reader` (bounded chunk
decompression, CRC, topic-name and QoS checks): a corrupt or hostile file gives
one line on stderr and exit status 2; a truncated one is played up to its last
complete chunk after a warning line.

ROS-free readers for other code:

* :func:`iter_messages` -- ``(topic, type_name, log_time_ns, publish_time_ns, data)``
  in log-time order, also from files whose Summary is missing (crashed recorder).
* :func:`read_messages` -- ``(topic, type_name, log_time_ns, msg)`` with the
  message deserialised into its real Python class (``rclpy.serialization``),
  so equality tests against published messages are exact.
"""

from __future__ import annotations

import argparse
import bisect
import heapq
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import NamedTuple

from mcap.records import Channel, Message, Schema

from mems_sim.bag.reader import (
    BagReadError,
    BagSummary,
    bag_files,
    check_channel,
    closed_pipe_exit,
    one_line,
    open_bag,
    read_chunk_at,
    read_summary,
    shown,
    warn_once,
    warn_truncated,
)
from mems_sim.bag.reader import iter_stream_records as _iter_stream_records
from mems_sim.cli_values import OneLineParser, non_negative, number, positive
from mems_sim.ros.env import apply_defaults, domain_id_problem, install_stop_request
from mems_sim.ros.qos_yaml import playback_profile

__all__ = [
    "BagMessage",
    "BagReadError",
    "Player",
    "bag_start_time_ns",
    "iter_messages",
    "iter_raw",
    "iter_stream_records",
    "open_bag",
    "playable_topics",
    "read_messages",
    "recorded_topics",
]


class BagMessage(NamedTuple):
    """One stored message: topic, type ``pkg/msg/Type``, times [ns] and CDR bytes."""

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes


def iter_stream_records(handle, path: str = "") -> Iterator[tuple[object, bool]]:
    """Yield ``(record, False)`` for every readable record of an MCAP stream, in file order.

    Stops at a truncated file (a writer that was killed) and then yields
    ``(None, True)`` once; raises :class:`BagReadError` for a corrupt record.
    Chunks are decompressed with a bounded size (:mod:`mems_sim.bag.reader`).
    """
    yield from _iter_stream_records(handle, path or getattr(handle, "name", ""))


def _summary(handle, path: str) -> BagSummary | None:
    """The file's Summary with its channels checked, or None when it has none (or a damaged one)."""
    summary = read_summary(handle, path)
    if summary is not None:
        for channel in summary.channels.values():
            check_channel(path, channel)
    return summary


def _iter_indexed(handle, path, summary: BagSummary, topics, start_time_ns, end_time_ns):
    """Messages of an indexed file in log-time order: chunks by start time, merged by a heap."""
    schemas = dict(summary.schemas)
    channels = dict(summary.channels)
    wanted = None
    if topics is not None:
        wanted = {cid for cid, channel in channels.items() if channel.topic in topics}
    unique = {index.chunk_start_offset: index for index in summary.chunk_indexes}  # each once
    indexes = sorted(unique.values(), key=lambda c: (c.message_start_time, c.chunk_start_offset))
    heap: list = []
    seq = 0
    for index in indexes:
        if end_time_ns is not None and index.message_start_time >= end_time_ns:
            continue
        if start_time_ns is not None and index.message_end_time < start_time_ns:
            continue
        if wanted is not None and index.message_index_offsets:
            if not wanted & index.message_index_offsets.keys():
                continue
        while heap and heap[0][0] < index.message_start_time:
            yield heapq.heappop(heap)[2]
        for record in read_chunk_at(handle, index, path):
            if isinstance(record, Schema):
                schemas.setdefault(record.id, record)
            elif isinstance(record, Channel):
                if record.id not in channels:
                    check_channel(path, record)
                    channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or (topics is not None and channel.topic not in topics):
                    continue
                if start_time_ns is not None and record.log_time < start_time_ns:
                    continue
                if end_time_ns is not None and record.log_time >= end_time_ns:
                    continue
                heapq.heappush(
                    heap, (record.log_time, seq, (schemas.get(channel.schema_id), channel, record))
                )
                seq += 1
    while heap:
        yield heapq.heappop(heap)[2]


def iter_raw(
    path: str,
    topics: Iterable[str] | None = None,
    start_time_ns: int | None = None,
    end_time_ns: int | None = None,
    on_truncated: Callable[[str], None] | None = warn_truncated,
) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """``(schema, channel, message)`` of the bag in log-time order (file order without a Summary).

    ``path`` is an MCAP file or a rosbag2 bag directory (:func:`~mems_sim.bag.reader.bag_files`),
    whose files are merged into one log-time ordered timeline (files may overlap in time;
    equal log times keep the files' order).
    Raises :class:`BagReadError` (one line) for a missing, non-MCAP or corrupt file, an
    invalid topic name or absurd QoS metadata; a truncated file is read up to its last
    complete chunk and reported through ``on_truncated(path)`` (default: a warning line).
    """
    topics = None if topics is None else set(topics)
    files = bag_files(path)
    if len(files) == 1:
        yield from _iter_file(files[0], topics, start_time_ns, end_time_ns, on_truncated)
    else:
        yield from _iter_merged(files, topics, start_time_ns, end_time_ns, on_truncated)


def _file_start_ns(path: str) -> int | None:
    """First log time of one file from its Statistics (None: no Statistics or no messages)."""
    handle = open_bag(path)
    with handle:
        summary = _summary(handle, path)
    if summary is not None and summary.statistics is not None and summary.statistics.message_count:
        return summary.statistics.message_start_time
    return None


def _iter_merged(files, topics, start_time_ns, end_time_ns, on_truncated):
    """The files' messages merged by log time. A file is opened only once the timeline
    reaches its first log time (from its Statistics; a file without them at once), so a
    long split recording keeps few files open."""
    starts = []
    for order, path in enumerate(files):
        first = _file_start_ns(path)
        if first is not None and end_time_ns is not None and first >= end_time_ns:
            continue
        starts.append((-1 if first is None else first, order))
    starts.sort()
    heap: list = []
    seq = 0

    def push(order: int, iterator) -> None:
        nonlocal seq
        item = next(iterator, None)
        if item is not None:
            heapq.heappush(heap, (item[2].log_time, order, seq, item, iterator))
            seq += 1

    k = 0
    try:
        while heap or k < len(starts):
            while k < len(starts) and (not heap or starts[k][0] <= heap[0][0]):
                order = starts[k][1]
                push(
                    order,
                    _iter_file(files[order], topics, start_time_ns, end_time_ns, on_truncated),
                )
                k += 1
            if heap:
                _, order, _, item, iterator = heapq.heappop(heap)
                yield item
                push(order, iterator)
    finally:
        for entry in heap:
            entry[4].close()


def _iter_file(path, topics, start_time_ns, end_time_ns, on_truncated):
    """``(schema, channel, message)`` of one MCAP file (see :func:`iter_raw`)."""
    handle = open_bag(path)
    with handle:
        summary = _summary(handle, path)
        if summary is not None and summary.chunk_indexes:
            yield from _iter_indexed(handle, path, summary, topics, start_time_ns, end_time_ns)
            return
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        for record, truncated in _iter_stream_records(handle, path):
            if truncated:
                if on_truncated is not None:
                    on_truncated(path)
                break
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                check_channel(path, record)
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or (topics is not None and channel.topic not in topics):
                    continue
                if start_time_ns is not None and record.log_time < start_time_ns:
                    continue
                if end_time_ns is not None and record.log_time >= end_time_ns:
                    continue
                yield schemas.get(channel.schema_id), channel, record


def bag_start_time_ns(path: str) -> int | None:
    """log_time of the bag's first message [ns] (from Statistics, else by scanning), None if
    empty; of all files of a bag directory."""
    starts = []
    for name in bag_files(path):
        first = _file_start_ns(name)
        if first is None:
            first = next(
                (
                    message.log_time
                    for _, _, message in _iter_file(name, None, None, None, warn_truncated)
                ),
                None,
            )
        if first is not None:
            starts.append(first)
    return min(starts, default=None)


def iter_messages(
    path: str, topics: Iterable[str] | None = None, start_offset_s: float = 0.0
) -> Iterator[BagMessage]:
    """Iterate the stored messages as :class:`BagMessage` in log-time order.

    :param topics: only these topics (None: all).
    :param start_offset_s: skip messages logged earlier than start + offset [s].
    Raises :class:`BagReadError` for a missing, non-MCAP or corrupt file.
    """
    start = None
    if start_offset_s:
        first = bag_start_time_ns(path)
        start = None if first is None else first + int(round(start_offset_s * 1e9))
    for schema, channel, message in iter_raw(path, topics, start_time_ns=start):
        type_name = schema.name if schema is not None else ""
        yield BagMessage(
            channel.topic, type_name, message.log_time, message.publish_time, message.data
        )


def read_messages(
    path: str,
    topics: Iterable[str] | None = None,
    on_unknown: Callable[[str, str, str], None] | None = None,
) -> Iterator[tuple[str, str, int, object]]:
    """Iterate ``(topic, type_name, log_time_ns, msg)`` with ``msg`` deserialised into its real class.

    Uses ``rclpy.serialization.deserialize_message`` (no rclpy.init needed). Messages
    of a type that is not an installed interface (``schema.message_class`` refuses to
    import it) are skipped and reported once per topic through
    ``on_unknown(path, topic, reason)`` (default: a warning line on stderr). A message
    that does not deserialise raises :class:`BagReadError`.
    """
    from rclpy.serialization import deserialize_message

    from mems_sim.bag.schema import SchemaError, message_class

    classes: dict[str, type | None] = {}
    reasons: dict[str, str] = {}
    reported: set[str] = set()
    for item in iter_messages(path, topics):
        if item.type_name not in classes:
            try:
                classes[item.type_name] = message_class(item.type_name)
            except SchemaError as exc:
                classes[item.type_name] = None
                reasons[item.type_name] = str(exc)
        cls = classes[item.type_name]
        if cls is None:
            if item.topic not in reported:
                reported.add(item.topic)
                reason = reasons[item.type_name]
                if on_unknown is not None:
                    on_unknown(path, item.topic, reason)
                else:
                    warn_once(path, f"{shown(item.topic)}: {reason}; skipped")
            continue
        try:
            msg = deserialize_message(item.data, cls)
        except Exception as exc:  # whatever the typesupport raises for bad CDR
            raise BagReadError(
                f"{path}: a message on {shown(item.topic)} (log time {item.log_time_ns}) "
                f"does not deserialise as {item.type_name} ({type(exc).__name__})"
            ) from None
        yield item.topic, item.type_name, item.log_time_ns, msg


def recorded_topics(
    path: str, on_truncated: Callable[[str], None] | None = warn_truncated
) -> dict[str, tuple[str, str]]:
    """``{topic: (type_name, offered_qos_profiles_yaml)}`` of the bag's channels.

    Every channel is checked (topic name, QoS metadata); a file without a Summary is
    scanned completely, so a corrupt chunk raises :class:`BagReadError` here. Of a bag
    directory, the topics of all its files (the first file's QoS of a topic); a topic
    whose type differs between files raises :class:`BagReadError`.
    """
    files = bag_files(path)
    if len(files) == 1:
        return _recorded_topics_file(files[0], on_truncated)
    out: dict[str, tuple[str, str]] = {}
    where: dict[str, str] = {}
    for name in files:
        for topic, (type_name, qos_yaml) in _recorded_topics_file(name, on_truncated).items():
            if topic not in out:
                out[topic], where[topic] = (type_name, qos_yaml), name
            elif out[topic][0] != type_name:
                raise BagReadError(
                    f"{path}: {shown(topic)} is {shown(out[topic][0])} in {where[topic]} "
                    f"but {shown(type_name)} in {name}"
                )
    return out


def _recorded_topics_file(path: str, on_truncated) -> dict[str, tuple[str, str]]:
    """:func:`recorded_topics` of one MCAP file."""
    handle = open_bag(path)
    out: dict[str, tuple[str, str]] = {}
    with handle:
        summary = _summary(handle, path)
        if summary is not None and summary.channels:
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                out[channel.topic] = (
                    schema.name if schema else "",
                    channel.metadata.get("offered_qos_profiles", ""),
                )
            return out
        schemas: dict[int, Schema] = {}
        for record, truncated in _iter_stream_records(handle, path):
            if truncated:
                if on_truncated is not None:
                    on_truncated(path)
                break
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                check_channel(path, record)
                if record.topic not in out:
                    schema = schemas.get(record.schema_id)
                    out[record.topic] = (
                        schema.name if schema else "",
                        record.metadata.get("offered_qos_profiles", ""),
                    )
    return out


def playable_topics(
    path: str, topics: Iterable[str] | None = None
) -> tuple[dict[str, tuple[type, str]], dict[str, str]]:
    """Split the file's topics into playable ``{topic: (message class, qos_yaml)}`` and
    skipped ``{topic: reason}`` (unknown types are never imported)."""
    from mems_sim.bag.schema import SchemaError, message_class

    wanted = None if topics is None else set(topics)
    playable: dict[str, tuple[type, str]] = {}
    skipped: dict[str, str] = {}
    for topic, (type_name, qos_yaml) in recorded_topics(path).items():
        if wanted is not None and topic not in wanted:
            continue
        try:
            playable[topic] = (message_class(type_name), qos_yaml)
        except SchemaError as exc:
            skipped[topic] = str(exc)
    return playable, skipped


# -------------------------------------------------------------------- playback


def parse_remaps(remaps: Iterable[str]) -> dict[str, str]:
    """``['FROM:=TO', ...]`` -> ``{FROM: TO}``; raises ValueError on a malformed entry."""
    out = {}
    for item in remaps or ():
        src, sep, dst = item.partition(":=")
        if not sep or not src or not dst:
            raise ValueError(f"bad remap {item!r} (expected FROM:=TO)")
        out[src] = dst
    return out


class _Timeline:
    """Maps wall-clock time to the bag's log time at a rate, with pause, jump and shift
    (the time controller of rosbag2's player: paused, the log time holds)."""

    def __init__(self, rate: float, bag_ns: int, wall_s: float):
        self.rate = rate
        self.bag_ref = int(bag_ns)  # log time [ns] at wall_ref
        self.wall_ref = wall_s  # monotonic time [s]
        self.paused = False

    def now_ns(self, wall_s: float) -> int:
        """Log time [ns] reached at monotonic time ``wall_s``."""
        if self.paused:
            return self.bag_ref
        return self.bag_ref + int((wall_s - self.wall_ref) * self.rate * 1e9)

    def pause(self, wall_s: float) -> None:
        self.bag_ref = self.now_ns(wall_s)
        self.paused = True

    def resume(self, wall_s: float) -> None:
        self.wall_ref = wall_s
        self.paused = False

    def jump(self, bag_ns: int, wall_s: float) -> None:
        """Move the log time to ``bag_ns`` (held there while paused)."""
        self.bag_ref = int(bag_ns)
        self.wall_ref = wall_s

    def shift(self, seconds: float) -> None:
        """Hold the log time for ``seconds`` of wall time that just passed."""
        if not self.paused:
            self.wall_ref += seconds


#: The player's control services: name (relative to the node, ``~/``) -> what it does.
#: Names are those of rosbag2's player; the types are std_srvs/srv/Trigger, because
#: rosbag2_interfaces is not distributed as a Python wheel.
CONTROL_SERVICES = {
    "pause": "pause playback (the clock holds); success true",
    "resume": "resume playback; success true",
    "toggle_paused": "pause when playing, resume when paused; message: the new state",
    "is_paused": "success: true when paused; message: paused or playing",
    "play_next": "while paused, publish the next message; success false when playing "
    "or at the end of the bag",
}


class PlaybackControl:
    """Pause, resume and play-next of a replay, as rosbag2's player offers them.

    The services (:data:`CONTROL_SERVICES`, on the player's node, ``~/NAME``) are
    std_srvs/srv/Trigger; rosbag2_interfaces' types map onto it so: Pause, Resume,
    TogglePaused -> Trigger (success true; message the state afterwards), IsPaused ->
    Trigger (success = paused), PlayNext -> Trigger (success as PlayNext's: true when the
    player is paused and a message is left; the message is published right after the
    reply). While paused the player publishes nothing and /clock holds.

    :param paused: start paused (``--start-paused``).
    """

    def __init__(self, paused: bool = False):
        self.paused = bool(paused)
        self.next_requests = 0  # play_next calls not served yet
        self.finished = False  # the replay reached its end
        self.services: list = []

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        self.paused = False
        self.next_requests = 0

    def request_next(self) -> tuple[bool, str]:
        """Ask for the next message (paused only); ``(success, message)``."""
        if not self.paused:
            return False, "not paused"
        if self.finished:
            return False, "end of the bag"
        self.next_requests += 1
        return True, "publishing the next message"

    def take_next(self) -> bool:
        """True (once per request) when the player should publish one message now."""
        if self.next_requests > 0:
            self.next_requests -= 1
            return True
        return False

    def state(self) -> str:
        return "paused" if self.paused else "playing"

    def create_services(self, node) -> None:
        """Offer :data:`CONTROL_SERVICES` on ``node`` (std_srvs must be installed)."""
        from std_srvs.srv import Trigger

        def handler(action):
            def call(request, response):
                response.success, response.message = action()
                return response

            return call

        def set_paused(paused: bool):
            def action():
                self.pause() if paused else self.resume()
                return True, self.state()

            return action

        def toggle():
            self.resume() if self.paused else self.pause()
            return True, self.state()

        actions = {
            "pause": set_paused(True),
            "resume": set_paused(False),
            "toggle_paused": toggle,
            "is_paused": lambda: (self.paused, self.state()),
            "play_next": self.request_next,
        }
        for name in CONTROL_SERVICES:
            self.services.append(node.create_service(Trigger, f"~/{name}", handler(actions[name])))


def control_available() -> str | None:
    """None when the control services can be offered, else why not (one line)."""
    try:
        import std_srvs.srv  # noqa: F401  (import check: the services need its Trigger type)
    except ImportError:
        return "the std_srvs interfaces (std_srvs/srv/Trigger) are not installed"
    return None


class Player:
    """Publishes a bag's messages on a node (used by :func:`main`; usable in-process).

    :param node: rclpy node to create publishers on.
    :param path: MCAP file.
    :param topics: topics to play (None: all).
    :param remap: ``{recorded_topic: published_topic}``.
    :param resolved: the result of :func:`playable_topics` when the caller already
        has it (then skipped topics are not reported again on the node's logger).
    :param control: :class:`PlaybackControl` (pause, resume, play next), or None.
    :param executor: an executor of ``node``, spun while the player waits (for the
        control services and flow control); None: the player sleeps while it waits.
    """

    def __init__(
        self,
        node,
        path: str,
        topics: Iterable[str] | None = None,
        remap: dict[str, str] | None = None,
        resolved: tuple[dict[str, tuple[type, str]], dict[str, str]] | None = None,
        control: PlaybackControl | None = None,
        executor=None,
    ):
        self.node = node
        self.control = control
        self.executor = executor
        self.path = path
        self.topics = None if topics is None else list(topics)
        self.remap = dict(remap or {})
        self.publishers: dict[str, object] = {}
        self.published = 0
        #: Messages published per (recorded) topic.
        self.topic_counts: dict[str, int] = {}
        #: Played topics of frame types (sample-indexed: flow control applies to them).
        self.frame_topics: set[str] = set()
        #: Log time [ns] covered by the last :meth:`play` and the wall time [s] it took.
        self.played_log_s = 0.0
        self.played_wall_s = 0.0
        if resolved is None:
            resolved = playable_topics(path, self.topics)
            for topic, reason in resolved[1].items():
                node.get_logger().warning(f"{topic}: not played, {reason}")
        for topic, (cls, qos_yaml) in resolved[0].items():
            if self.topics is not None and topic not in self.topics:
                continue
            self.publishers[topic] = node.create_publisher(
                cls, self.remap.get(topic, topic), playback_profile(qos_yaml)
            )
            self.topic_counts[topic] = 0
            from mems_sim.bag.schema import GAP_CHECKED_TYPES, type_name_of

            if type_name_of(cls) in GAP_CHECKED_TYPES:
                self.frame_topics.add(topic)

    def wait_for_subscribers(self, count: int, timeout_s: float, stop=lambda: False) -> bool:
        """Wait until every publisher has at least ``count`` matched subscriptions; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not stop():
            if all(p.get_subscription_count() >= count for p in self.publishers.values()):
                return True
            self._wait(0.02)
        return all(p.get_subscription_count() >= count for p in self.publishers.values())

    def play(
        self,
        rate: float = 1.0,
        fast: bool = False,
        start_offset_s: float = 0.0,
        duration_s: float | None = None,
        clock_publisher=None,
        clock_hz: float = 0.0,
        stop=lambda: False,
        flow: FlowControl | None = None,
    ) -> int:
        """Publish the messages once, paced by log_time / rate (or as fast as possible).

        The bag's log times are its sensor time, so at rate 1 the replay takes as long as the
        recorded data, and /clock carries the time the stamps belong to.

        :param duration_s: play only this much bag time after the start offset [s].
        :param clock_publisher: publisher of rosgraph_msgs/Clock, published at ``clock_hz``
            [Hz] of wall-clock time with the log time reached (paced: the log time the
            wall clock has reached; as fast as possible: the last published message's), and
            once more with the last message's log time at the end; it never goes back,
            and holds while :attr:`control` is paused.
        :param flow: :class:`FlowControl`: a frame for a named consumer waits for its
            credit; paced playback pauses meanwhile (the time waited does not count).
        Paused (:class:`PlaybackControl`), nothing is published until it resumes, except one
        message per play-next request; the log time then continues from that message.
        Returns the number of messages published.
        """
        from rosgraph_msgs.msg import Clock

        control = self.control
        timeline = None
        clock_period = 1.0 / clock_hz if clock_publisher is not None and clock_hz > 0 else None
        next_clock = time.monotonic()
        next_spin = time.monotonic()
        end_ns = None
        last_ns = None
        count = 0

        clock_ns = None  # the last time published on /clock: it never goes back

        def publish_clock(bag_ns: int):
            nonlocal clock_ns
            clock_ns = int(bag_ns) if clock_ns is None else max(clock_ns, int(bag_ns))
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(clock_ns, 1_000_000_000)
            clock_publisher.publish(msg)

        if control is not None:
            control.finished = False
        for item in iter_messages(self.path, self.publishers.keys(), start_offset_s):
            if stop():
                break
            if timeline is None:
                timeline = _Timeline(rate, item.log_time_ns, time.monotonic())
                timeline.paused = control is not None and control.paused  # held from the start
                started = timeline.wall_ref
                bag0 = item.log_time_ns
                if duration_s is not None:
                    end_ns = bag0 + int(duration_s * 1e9)
            if end_ns is not None and item.log_time_ns > end_ns:
                break
            while not stop():
                now = time.monotonic()
                paused = control is not None and control.paused
                if paused != timeline.paused:
                    (timeline.pause if paused else timeline.resume)(now)
                if fast:
                    shown_ns = last_ns if last_ns is not None else item.log_time_ns
                else:
                    # the time reached, but never past a message not published yet (a late
                    # wake-up on a loaded machine must not carry /clock beyond the data)
                    shown_ns = min(timeline.now_ns(now), item.log_time_ns)
                if clock_period is not None and now >= next_clock:
                    if paused or not fast:
                        publish_clock(shown_ns)
                        next_clock += clock_period
                        if next_clock < now:
                            next_clock = now + clock_period
                    else:
                        publish_clock(item.log_time_ns)
                        next_clock = now + clock_period
                if paused:
                    if control.take_next():
                        timeline.jump(item.log_time_ns, now)  # the clock moves to this message
                        break
                    wake = 0.05 if clock_period is None else next_clock - now
                    self._wait(max(0.0, min(wake, 0.05)))
                    continue
                if fast:
                    if self.executor is not None and now >= next_spin:
                        self.executor.spin_once(timeout_sec=0)  # serve the control services
                        next_spin = now + 0.02
                        continue
                    break
                due_in = (item.log_time_ns - timeline.now_ns(now)) / 1e9 / rate
                if due_in <= 0:
                    break
                wake = due_in if clock_period is None else min(due_in, next_clock - now)
                self._wait(max(0.0, min(wake, 0.05)))
            if stop():
                break
            peek = None
            if flow is not None:
                waited = flow.waited_s
                peek = flow.before(item.topic, item.data, stop)
                timeline.shift(flow.waited_s - waited)  # paused while waiting for credit
                if stop():
                    break
            self._publish(item.topic, item.data)
            if flow is not None:
                flow.after(item.topic, peek)
            self.topic_counts[item.topic] = self.topic_counts.get(item.topic, 0) + 1
            last_ns = item.log_time_ns
            count += 1
        if control is not None:
            control.finished = True
        if clock_period is not None and last_ns is not None and not stop():
            publish_clock(last_ns)
        if timeline is not None and last_ns is not None:
            self.played_log_s = (last_ns - bag0) / 1e9
            self.played_wall_s = time.monotonic() - started
        self.published += count
        return count

    def _wait(self, seconds: float) -> None:
        """Wait up to ``seconds``: serving the node's callbacks when there is an executor."""
        seconds = max(0.0, seconds)  # a negative timeout would make spin_once wait forever
        if self.executor is not None:
            self.executor.spin_once(timeout_sec=seconds)
        else:
            time.sleep(seconds)

    def _publish(self, topic: str, data: bytes) -> None:
        """Publish the serialised bytes on the (possibly remapped) topic."""
        self.publishers[topic].publish(data)

    def wait_acked(self, topic: str | None = None, timeout_s: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published (one topic or all)."""
        from rclpy.duration import Duration

        topics = [topic] if topic is not None else list(self.publishers)
        ok = True
        for name in topics:
            try:
                ok &= bool(self.publishers[name].wait_for_all_acked(Duration(seconds=timeout_s)))
            except Exception:
                pass
        return ok


# -------------------------------------------------------------------- flow control

#: Credit of a consumer unless ``--credit`` says otherwise: frames published ahead of its
#: progress (well within the 1000-frame history of the frame subscriptions).
DEFAULT_CREDIT = "50f"


def parse_credit(text: str) -> tuple[int, str]:
    """``'N'`` (samples) or ``'Nf'`` (frames) -> ``(N, 'samples' | 'frames')``, N >= 1."""
    text = str(text).strip().lower()
    unit = "frames" if text.endswith("f") else "samples"
    number = text[:-1] if unit == "frames" else text
    try:
        value = int(number)
    except ValueError:
        raise ValueError(f"bad credit {text!r} (samples N or frames Nf, N >= 1)") from None
    if value < 1:
        raise ValueError(f"bad credit {text!r} (samples N or frames Nf, N >= 1)")
    return value, unit


def parse_consumer(text: str) -> tuple[str, str | None]:
    """``'/ns/node'`` or ``'/ns/node:/topic'`` -> (node's fully qualified name, topic or None)."""
    fqn, _, topic = str(text).partition(":")
    fqn = fqn if fqn.startswith("/") else "/" + fqn
    tokens = fqn[1:].split("/")
    if not all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", t) for t in tokens):
        raise ValueError(f"bad consumer {text!r} (expected a node name such as /imu/node)")
    if topic and not re.fullmatch(r"/?[A-Za-z_~][A-Za-z0-9_/~{}]*", topic):
        raise ValueError(f"bad consumer {text!r}: {topic!r} is not a topic name")
    return fqn, (topic or None)


def _fqn(namespace: str, name: str) -> str:
    """Fully qualified node name."""
    return f"{namespace.rstrip('/')}/{name}"


class Consumer:
    """A named consumer of replayed frames: its progress and what was sent to it.

    Progress (``NODE_FQN/progress``, std_msgs/UInt64) is one past the last sample index the
    consumer processed (or rejected); it publishes one after every frame. The player keeps
    at most a credit of samples (or frames) published beyond it on each frame topic the
    consumer subscribes to (its input topics, which share one sample index).
    """

    def __init__(self, fqn: str, topic: str | None = None):
        self.fqn = fqn
        self.namespace, _, self.name = fqn.rpartition("/")
        self.namespace = self.namespace or "/"
        self.only_topic = topic
        self.topics: set[str] = set()  # recorded names of the played topics it consumes
        self.progress: int | None = None
        self.progress_msgs = 0
        self.first_sent: int | None = None
        self.outstanding: list[int] = []  # ends (first + num) of frames sent, beyond progress
        self.sent_end: int | None = None
        self.skipped = 0  # frames the progress jumped over (never reported as processed)
        #: True when every progress report reaches the player (the progress publisher keeps
        #: all, or at least :data:`~mems_sim.ros.qos.FRAME_DEPTH`, reports): then a jump over
        #: a frame means the frame was lost; with a shallow history reports may be coalesced.
        self.exact_jumps = False
        self.diag_gaps: int | None = None  # the consumer's own "gaps" count (/diagnostics)
        self.diag_missing: int | None = None  # and its "missing_samples"
        self.diag_at = 0.0  # monotonic time of the last diagnostics status
        self.last_change = time.monotonic()
        self.gave_up = ""  # why the player stopped waiting for it ("" while it does)
        self.subscription = None

    def restart(self) -> None:
        """Forget progress reported before the replay (a latched last value)."""
        self.progress = None
        self.outstanding.clear()
        self.first_sent = self.sent_end = None
        self.skipped = 0
        self.last_change = time.monotonic()

    def lost_frames(self) -> int:
        """Frames lost as far as the player can tell: those its progress jumped over (when
        :attr:`exact_jumps`) and those never acknowledged."""
        return (self.skipped if self.exact_jumps else 0) + len(self.outstanding)

    def on_progress(self, value: int) -> None:
        """A progress report: frames whose end it passes without naming it are skipped."""
        value = int(value)
        self.progress_msgs += 1
        if self.progress is not None and value <= self.progress:
            return
        self.progress = value
        self.last_change = time.monotonic()
        done = bisect.bisect_right(self.outstanding, value)
        if done:
            self.skipped += done - (1 if self.outstanding[done - 1] == value else 0)
            del self.outstanding[:done]

    def allows(self, first: int, num: int, credit: int, unit: str) -> bool:
        """True if the frame [first, first + num) may be published now."""
        if self.gave_up:
            return True
        if unit == "frames":
            # a frame whose partner (same indices, another input topic) is out goes too
            return len(self.outstanding) < credit or first + num in self.outstanding
        base = self.progress if self.progress is not None else self.first_sent
        return base is None or first <= base or first + num <= base + credit

    def sent(self, first: int, num: int) -> None:
        """Record a frame published to it (frames of its paired topics share an end)."""
        end = first + num
        if self.first_sent is None:
            self.first_sent = first
        if self.progress is not None and end <= self.progress:
            return
        if self.sent_end is None or end > self.sent_end:
            self.sent_end = end
        if not self.outstanding or end > self.outstanding[-1]:
            self.outstanding.append(end)
        elif end not in self.outstanding:
            bisect.insort(self.outstanding, end)

    def caught_up(self) -> bool:
        """True once its progress reached the end of everything sent to it."""
        return self.sent_end is None or (
            self.progress is not None and self.progress >= self.sent_end
        )


class FlowControl:
    """Application-level flow control of a replay into named consumers (``--wait-for-consumer``).

    The player subscribes to each consumer's ``progress`` topic (and to /diagnostics for its
    own gap count), publishes a frame on one of its input topics only while the consumer
    has credit (:meth:`Consumer.allows`), and at the end waits until every consumer's
    progress reached the last frame sent. Loss is counted two ways: frames the progress
    jumped over (exact when progress arrives reliably, one report per frame) and the gaps
    the consumer itself reports on /diagnostics. The middleware's acknowledgements and
    message-lost events are not used: a reliable writer reports acknowledgement late and
    even after the reader left, and a reader that falls behind its history loses messages
    without any event.

    :param node: the player's node; :param executor: spun while waiting (progress arrives
        through it); :param consumers: ``[(fqn, topic or None)]``; :param credit: a value
        of :func:`parse_credit`; :param stall_s: give up on a consumer whose progress has
        not moved for this long while frames are outstanding (or that left the graph).
    """

    def __init__(self, node, executor, consumers, credit=(50, "frames"), stall_s: float = 30.0):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.node = node
        self.executor = executor
        self.consumers = [Consumer(fqn, topic) for fqn, topic in consumers]
        self.credit, self.unit = credit
        self.stall_s = float(stall_s)
        self.by_topic: dict[str, list[Consumer]] = {}
        self.topic_ends: dict[str, list[int]] = {}
        self.waited_s = 0.0
        self._last_presence = 0.0
        self._diag_sub = node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            self._on_diagnostics,
            QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT),
        )

    # ------------------------------------------------------------------ discovery

    def _present(self, c: Consumer) -> bool:
        return (c.name, c.namespace) in set(self.node.get_node_names_and_namespaces())

    def _subscribe_progress(self, c: Consumer) -> bool:
        from rclpy.qos import HistoryPolicy
        from std_msgs.msg import UInt64

        from mems_sim.bag.recorder import adapt_qos
        from mems_sim.ros.qos import FRAME_DEPTH

        topic = c.fqn + "/progress"
        offered = [p.qos_profile for p in self.node.get_publishers_info_by_topic(topic)]
        if not offered:
            return False
        c.exact_jumps = all(
            q.history == HistoryPolicy.KEEP_ALL or int(q.depth) >= FRAME_DEPTH for q in offered
        )
        c.subscription = self.node.create_subscription(
            UInt64, topic, lambda msg, c=c: c.on_progress(msg.data), adapt_qos(offered)
        )
        return True

    def wait_ready(self, player: Player, timeout_s: float, stop=lambda: False) -> str | None:
        """Wait until every consumer is in the graph, publishes progress, subscribes to at
        least one played frame topic, and every publisher of those topics is matched with
        all their subscribers; None when ready, else why not (one line)."""
        inverse = {p.topic_name: t for t, p in player.publishers.items()}
        deadline = time.monotonic() + timeout_s
        why = "not ready"
        while time.monotonic() < deadline and not stop():
            self.executor.spin_once(timeout_sec=0.05)
            why = None
            for c in self.consumers:
                if c.subscription is None and not self._subscribe_progress(c):
                    why = f"{c.fqn}: no publisher of {c.fqn}/progress"
                    break
                try:
                    names = self.node.get_subscriber_names_and_types_by_node(c.name, c.namespace)
                except Exception:
                    why = f"{c.fqn}: node not found"
                    break
                subscribed = {inverse[n] for n, _ in names if n in inverse}
                if c.only_topic is not None:
                    wanted = inverse.get(c.only_topic, c.only_topic)
                    subscribed &= {wanted}
                c.topics = {t for t in subscribed if t in player.frame_topics}
                if not c.topics:
                    why = f"{c.fqn}: subscribes to none of the played frame topics"
                    break
                if c.subscription.get_publisher_count() < 1:
                    why = f"{c.fqn}: progress not matched yet"
                    break
            if why is None:
                # every known subscriber matched; near the deadline, the consumers' own
                # suffice (another subscriber may have an incompatible QoS)
                late = time.monotonic() > deadline - min(1.0, timeout_s / 2)
                for topic in {t for c in self.consumers for t in c.topics}:
                    name = player.publishers[topic].topic_name
                    subs = self.node.get_subscriptions_info_by_topic(name)
                    if late:
                        fqns = {c.fqn for c in self.consumers if topic in c.topics}
                        subs = [s for s in subs if _fqn(s.node_namespace, s.node_name) in fqns]
                    if player.publishers[topic].get_subscription_count() < len(subs):
                        why = f"{name}: subscribers not matched yet"
                        break
            if why is None:
                self.by_topic = {}
                for c in self.consumers:
                    for t in c.topics:
                        self.by_topic.setdefault(t, []).append(c)
                settle = time.monotonic() + 0.2  # take a latched last report, then forget it
                while time.monotonic() < settle:
                    self.executor.spin_once(timeout_sec=0.02)
                for c in self.consumers:
                    c.restart()
                return None
        return why or "stopped"

    # ------------------------------------------------------------------ progress

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            for c in self.consumers:
                mine = status.hardware_id == c.fqn or (
                    not status.hardware_id and status.name.split(":", 1)[0] == c.name
                )
                if mine:
                    values = {kv.key: kv.value for kv in status.values}
                    try:
                        c.diag_gaps = int(values.get("gaps", 0))
                        c.diag_missing = int(values.get("missing_samples", 0))
                    except ValueError:
                        pass
                    c.diag_at = time.monotonic()

    def _check_alive(self, c: Consumer) -> None:
        """Give up on a consumer that left the graph or whose progress stalls."""
        if c.gave_up or c.caught_up():
            return
        now = time.monotonic()
        if now - c.last_change > self.stall_s:
            c.gave_up = f"no progress for {self.stall_s:g} s"
        elif now - self._last_presence > 0.5:
            self._last_presence = now
            if not self._present(c):
                c.gave_up = "left the graph"
        if c.gave_up:
            self.node.get_logger().warning(
                f"{c.fqn}: {c.gave_up} (progress {c.progress}, sent up to {c.sent_end}); "
                "no longer waiting for it"
            )

    def before(self, topic: str, data: bytes, stop=lambda: False) -> tuple[int, int] | None:
        """Wait until every consumer of ``topic`` has credit for this frame; return its
        ``(first, num)`` (None: not a gated frame)."""
        consumers = self.by_topic.get(topic)
        if not consumers:
            return None
        from mems_sim.bag.schema import peek_frame_index

        peek = peek_frame_index(data)
        if peek is None:
            return None
        first, num = peek
        self.executor.spin_once(timeout_sec=0)
        t0 = None
        while not stop():
            blocked = [c for c in consumers if not c.allows(first, num, self.credit, self.unit)]
            if not blocked:
                break
            if t0 is None:
                t0 = time.monotonic()
            for c in blocked:
                self._check_alive(c)
            self.executor.spin_once(timeout_sec=0.01)
        if t0 is not None:
            self.waited_s += time.monotonic() - t0
        return peek

    def after(self, topic: str, peek: tuple[int, int] | None) -> None:
        """Account a published frame (``peek`` from :meth:`before`)."""
        if peek is None:
            return
        first, num = peek
        self.topic_ends.setdefault(topic, []).append(first + num)
        for c in self.by_topic.get(topic, ()):
            c.sent(first, num)

    def finish(self, stop=lambda: False, diagnostics_s: float = 2.5) -> None:
        """Wait until every consumer caught up (or was given up), then for one more
        /diagnostics status of each (at most ``diagnostics_s``) for its gap count."""
        while not stop() and not all(c.caught_up() or c.gave_up for c in self.consumers):
            for c in self.consumers:
                self._check_alive(c)
            self.executor.spin_once(timeout_sec=0.02)
        t_end = time.monotonic()
        while not stop() and time.monotonic() - t_end < diagnostics_s:
            if all(c.diag_at > t_end or c.gave_up for c in self.consumers):
                break
            self.executor.spin_once(timeout_sec=0.05)

    # ------------------------------------------------------------------ report

    def acknowledged(self, topic: str) -> int:
        """Frames of ``topic`` whose end every consumer's progress has reached."""
        ends = self.topic_ends.get(topic, [])
        marks = [c.progress for c in self.by_topic.get(topic, ())]
        if not marks or any(m is None for m in marks):
            return 0
        low = min(marks)
        return sum(1 for e in ends if e <= low)

    def lost(self) -> int:
        """Loss seen by the player: per consumer, frames lost (:meth:`Consumer.lost_frames`)
        or, when more, the gaps it reported on /diagnostics itself."""
        return sum(max(c.lost_frames(), c.diag_gaps or 0) for c in self.consumers)

    def report(self, player: Player) -> list[str]:
        """Lines of the end-of-replay report (per topic, then per consumer)."""
        lines = []
        for topic in sorted(player.topic_counts):
            n = player.topic_counts[topic]
            consumers = self.by_topic.get(topic)
            if not consumers:
                lines.append(f"  {topic}: published {n}")
                continue
            names = ", ".join(c.fqn for c in consumers)
            lines.append(
                f"  {topic}: published {n}, acknowledged {self.acknowledged(topic)} by {names}"
            )
        for c in self.consumers:
            state = f"; {c.gave_up}" if c.gave_up else ""
            gaps = (
                "none on /diagnostics"
                if c.diag_gaps is None
                else f"{c.diag_gaps} ({c.diag_missing} samples missing)"
            )
            jumps = "" if c.exact_jumps else " (reports may be coalesced: not counted)"
            lines.append(
                f"  consumer {c.fqn}: progress {c.progress} of {c.sent_end}, "
                f"{c.progress_msgs} reports, frames its progress jumped over {c.skipped}{jumps}, "
                f"unacknowledged {len(c.outstanding)}, gaps it reported {gaps}{state}"
            )
        lost = self.lost()
        lines.append(f"  loss: {'none' if lost == 0 else f'{lost} frames'}")
        return lines


def _parse_args(argv: list[str]) -> argparse.Namespace:
    parser = OneLineParser(prog="mcap_play", description=__doc__.splitlines()[0])
    parser.add_argument(
        "file", nargs="?", metavar="BAG", help="MCAP file or rosbag2 bag directory to play"
    )
    parser.add_argument(
        "--rate",
        "-r",
        type=number(0.0, 1e6, lo_open=True),
        default=1.0,
        help="playback rate factor (> 0)",
    )
    parser.add_argument(
        "--as-fast-as-possible",
        action="store_true",
        help="ignore timing, publish as fast as possible",
    )
    parser.add_argument("--loop", "-l", action="store_true", help="play in a loop")
    parser.add_argument(
        "--clock",
        nargs="?",
        type=number(0.0, 1e4, lo_open=True),
        const=40.0,
        default=None,
        metavar="HZ",
        help="publish /clock at HZ (default 40 Hz)",
    )
    parser.add_argument(
        "--start-offset", type=non_negative, default=0.0, help="skip this much of the bag [s]"
    )
    parser.add_argument(
        "--duration", type=positive, default=None, help="play this much bag time [s]"
    )
    parser.add_argument("--topics", nargs="+", default=None, help="play only these topics")
    parser.add_argument(
        "--remap",
        "-m",
        nargs="+",
        action="extend",
        default=[],
        metavar="FROM:=TO",
        help="topic remaps (also: --ros-args -r FROM:=TO, ROS's remapping rules)",
    )
    parser.add_argument(
        "--start-paused",
        action="store_true",
        help="start paused: ~/resume, ~/toggle_paused and ~/play_next (std_srvs/srv/Trigger "
        "services, rosbag2's names) go on",
    )
    parser.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        metavar="N",
        help="wait until each topic has N subscribers before playing",
    )
    parser.add_argument(
        "--wait-timeout",
        type=number(0.0, 1e6, lo_open=True),
        default=10.0,
        help="give up waiting for subscribers after this long [s]",
    )
    parser.add_argument(
        "--delay", type=number(0.0, 86400.0), default=0.0, help="sleep before playing [s]"
    )
    parser.add_argument(
        "--wait-for-consumer",
        action="append",
        default=[],
        metavar="NODE_FQN[:TOPIC]",
        help="lossless replay into this node (repeatable): wait for it, keep at most --credit "
        "published ahead of the progress it reports on NODE_FQN/progress on each played frame "
        "topic it subscribes to (or TOPIC only), wait for it at the end, report loss",
    )
    parser.add_argument(
        "--credit",
        default=DEFAULT_CREDIT,
        metavar="N|Nf",
        help="samples (N) or frames (Nf) a consumer may be behind (default %(default)s)",
    )
    parser.add_argument(
        "--consumer-timeout",
        type=number(0.0, 1e6, lo_open=True),
        default=30.0,
        metavar="S",
        help="stop waiting for a consumer whose progress has not moved for S seconds [s]",
    )
    args = parser.parse_args(argv)
    if args.file is None:
        # "--remap A:=B BAG" or "--topics T BAG": the bag was taken as one more list item
        if args.remap and ":=" not in args.remap[-1]:
            args.file = args.remap.pop()
        elif args.topics and len(args.topics) > 1 and os.path.exists(args.topics[-1]):
            args.file = args.topics.pop()
        else:
            parser.error("the following arguments are required: BAG")
    if not args.rate > 0 or args.rate == float("inf"):
        parser.error("--rate must be a finite number > 0 (use --as-fast-as-possible)")
    try:
        args.credit = parse_credit(args.credit)
        args.consumers = [parse_consumer(c) for c in args.wait_for_consumer]
    except ValueError as exc:
        parser.error(str(exc))
    if args.consumers and args.loop:
        parser.error("--wait-for-consumer and --loop cannot be combined")
    if not args.consumer_timeout > 0:
        parser.error("--consumer-timeout must be > 0")
    return args


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(own arguments, ROS arguments)``: by rcl's rule, the arguments from each
    ``--ros-args`` up to the next ``--`` (or the end) are ROS's (kept with their
    ``--ros-args``); everything else is the program's, including ``FROM:=TO`` after
    ``--remap``, which rcl alone would also take as a (deprecated) global remapping rule."""
    own: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in argv:
        if inside:
            if arg == "--":
                inside = False
            else:
                ros.append(arg)
        elif arg == "--ros-args":
            inside = True
            ros.append(arg)
        else:
            own.append(arg)
    return own, ros


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_play``; returns the process exit code (2 for a bad file,
    3 for loss in a lossless replay, 141 when stdout's reader went away)."""
    try:
        return _main(argv)
    except BrokenPipeError:
        return closed_pipe_exit()


def _main(argv: list[str] | None) -> int:
    apply_defaults()
    problem = domain_id_problem()
    if problem is not None:
        print(f"mcap_play: error: {problem}", file=sys.stderr)
        return 2
    argv = sys.argv[1:] if argv is None else list(argv)
    own, ros_args = split_ros_args(argv)
    args = _parse_args(own)
    try:
        remap = parse_remaps(args.remap)
        resolved = playable_topics(args.file, args.topics)
    except (BagReadError, ValueError) as exc:
        print(f"mcap_play: error: {one_line(exc)}", file=sys.stderr)
        return 2
    if args.start_paused and control_available() is not None:
        print(f"mcap_play: error: --start-paused: {control_available()}", file=sys.stderr)
        return 2
    playable, skipped = resolved
    if not playable:
        why = "; ".join(f"{shown(t)}: {r}" for t, r in skipped.items())
        print(
            one_line(
                f"mcap_play: error: {args.file}: no playable topics" + (f" ({why})" if why else ""),
                1000,
            ),
            file=sys.stderr,
        )
        return 2
    for topic, reason in skipped.items():
        print(
            one_line(f"mcap_play: warning: {args.file}: {shown(topic)}: {reason}; not played"),
            file=sys.stderr,
        )

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock

    rclpy.init(args=["mcap_play"] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    stop, previous = install_stop_request()
    node = None
    code = 0
    try:
        node = Node("mcap_player")
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        control = PlaybackControl(paused=args.start_paused)
        if control_available() is None:
            control.create_services(node)
        player = Player(
            node,
            args.file,
            args.topics,
            remap,
            resolved=resolved,
            control=control,
            executor=executor,
        )
        clock_pub = node.create_publisher(Clock, "/clock", 10) if args.clock else None
        flow = None
        if args.consumers:
            flow = FlowControl(
                node, executor, args.consumers, args.credit, stall_s=args.consumer_timeout
            )
            why = flow.wait_ready(player, args.wait_timeout, lambda: stop["flag"])
            if why is not None:
                print(one_line(f"mcap_play: error: consumer not ready: {why}"), file=sys.stderr)
                return 3
        if args.wait_for_subscribers > 0 and not player.wait_for_subscribers(
            args.wait_for_subscribers, args.wait_timeout, lambda: stop["flag"]
        ):
            node.get_logger().warning("not every topic has its subscribers; playing anyway")
        delay_end = time.monotonic() + args.delay
        while not stop["flag"] and time.monotonic() < delay_end:
            player._wait(min(0.05, delay_end - time.monotonic()))
        while not stop["flag"]:
            player.play(
                rate=args.rate,
                fast=args.as_fast_as_possible,
                start_offset_s=args.start_offset,
                duration_s=args.duration,
                clock_publisher=clock_pub,
                clock_hz=args.clock or 0.0,
                stop=lambda: stop["flag"],
                flow=flow,
            )
            if not args.loop:
                break
        lines = [f"mcap_play: published {player.published} messages"]
        if player.played_log_s > 0:
            lines[0] += f", {player.played_log_s:.3f} s of log time in {player.played_wall_s:.3f} s"
        if flow is not None:
            flow.finish(lambda: stop["flag"])
            lines += flow.report(player)
            if flow.lost() or any(c.diag_gaps for c in flow.consumers):
                code = 3
        else:
            # deliver the tail before exit (the middleware's acknowledgement: no loss count)
            player.wait_acked(timeout_s=max(1.0, args.wait_timeout))
        print("\n".join(lines), flush=True)
    except BagReadError as exc:
        print(f"mcap_play: error: {one_line(exc)}", file=sys.stderr)
        return 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())

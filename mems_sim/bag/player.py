"""MCAP player: ``mcap_play FILE [--rate R | --as-fast-as-possible] [--loop] [--clock [HZ]] ...``.

Publishes the serialised bytes stored in the file (no deserialisation) with
publishers created from the file's schemas (``pkg/msg/Type``, imported only
when it is an interface of the ament index: other types are reported and their
topics skipped) and the recorded ``offered_qos_profiles`` (fallback FRAME_QOS),
paced by ``log_time`` scaled by ``--rate``; optionally publishes ``/clock``.

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
import heapq
import signal
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import NamedTuple

from mcap.records import Channel, Message, Schema

from mems_sim.bag.reader import (
    BagReadError,
    BagSummary,
    check_channel,
    one_line,
    open_bag,
    read_chunk_at,
    read_summary,
    shown,
    warn_once,
    warn_truncated,
)
from mems_sim.bag.reader import iter_stream_records as _iter_stream_records
from mems_sim.ros.env import apply_defaults, install_stop_request

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
    """``(schema, channel, message)`` of the file in log-time order (file order without a Summary).

    Raises :class:`BagReadError` (one line) for a missing, non-MCAP or corrupt file, an
    invalid topic name or absurd QoS metadata; a truncated file is read up to its last
    complete chunk and reported through ``on_truncated(path)`` (default: a warning line).
    """
    topics = None if topics is None else set(topics)
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
    """log_time of the first message [ns] (from Statistics, else by scanning), None if empty."""
    handle = open_bag(path)
    with handle:
        summary = _summary(handle, path)
    if summary is not None and summary.statistics is not None and summary.statistics.message_count:
        return summary.statistics.message_start_time
    for _, _, message in iter_raw(path):
        return message.log_time
    return None


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
    """``{topic: (type_name, offered_qos_profiles_yaml)}`` of the file's channels.

    Every channel is checked (topic name, QoS metadata); a file without a Summary is
    scanned completely, so a corrupt chunk raises :class:`BagReadError` here.
    """
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


def playback_qos(qos_yaml: str):
    """Publisher QoS from the recorded offered profiles (rosbag2's adaptation); FRAME_QOS if none.

    The first offered profile's reliability and durability are used, with a
    KEEP_LAST history at least FRAME_DEPTH deep.
    """
    from rclpy.qos import HistoryPolicy, QoSProfile

    from mems_sim.bag.schema import qos_profiles_from_yaml
    from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS

    try:
        profiles = qos_profiles_from_yaml(qos_yaml)
    except Exception:
        profiles = []
    if not profiles:
        return FRAME_QOS
    first = profiles[0]
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=max(FRAME_DEPTH, int(first.depth)),
        reliability=first.reliability,
        durability=first.durability,
    )


def parse_remaps(remaps: Iterable[str]) -> dict[str, str]:
    """``['FROM:=TO', ...]`` -> ``{FROM: TO}``; raises ValueError on a malformed entry."""
    out = {}
    for item in remaps or ():
        src, sep, dst = item.partition(":=")
        if not sep or not src or not dst:
            raise ValueError(f"bad remap {item!r} (expected FROM:=TO)")
        out[src] = dst
    return out


class Player:
    """Publishes a bag's messages on a node (used by :func:`main`; usable in-process).

    :param node: rclpy node to create publishers on.
    :param path: MCAP file.
    :param topics: topics to play (None: all).
    :param remap: ``{recorded_topic: published_topic}``.
    :param resolved: the result of :func:`playable_topics` when the caller already
        has it (then skipped topics are not reported again on the node's logger).
    """

    def __init__(
        self,
        node,
        path: str,
        topics: Iterable[str] | None = None,
        remap: dict[str, str] | None = None,
        resolved: tuple[dict[str, tuple[type, str]], dict[str, str]] | None = None,
    ):
        self.node = node
        self.path = path
        self.topics = None if topics is None else list(topics)
        self.remap = dict(remap or {})
        self.publishers: dict[str, object] = {}
        self.published = 0
        if resolved is None:
            resolved = playable_topics(path, self.topics)
            for topic, reason in resolved[1].items():
                node.get_logger().warning(f"{topic}: not played, {reason}")
        for topic, (cls, qos_yaml) in resolved[0].items():
            if self.topics is not None and topic not in self.topics:
                continue
            self.publishers[topic] = node.create_publisher(
                cls, self.remap.get(topic, topic), playback_qos(qos_yaml)
            )

    def wait_for_subscribers(self, count: int, timeout_s: float, stop=lambda: False) -> bool:
        """Wait until every publisher has at least ``count`` matched subscriptions; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not stop():
            if all(p.get_subscription_count() >= count for p in self.publishers.values()):
                return True
            time.sleep(0.02)
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
    ) -> int:
        """Publish the messages once, paced by log_time / rate (or as fast as possible).

        :param duration_s: play only this much bag time after the start offset [s].
        :param clock_publisher: publisher of rosgraph_msgs/Clock, published at ``clock_hz`` [Hz].
        Returns the number of messages published.
        """
        from rosgraph_msgs.msg import Clock

        wall0 = bag0 = None
        clock_period = 1.0 / clock_hz if clock_publisher is not None and clock_hz > 0 else None
        next_clock = time.monotonic()
        end_ns = None
        count = 0

        def publish_clock(bag_ns: int):
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(int(bag_ns), 1_000_000_000)
            clock_publisher.publish(msg)

        for item in iter_messages(self.path, self.publishers.keys(), start_offset_s):
            if stop():
                break
            if wall0 is None:
                wall0, bag0 = time.monotonic(), item.log_time_ns
                if duration_s is not None:
                    end_ns = bag0 + int(duration_s * 1e9)
            if end_ns is not None and item.log_time_ns > end_ns:
                break
            if not fast:
                target = wall0 + (item.log_time_ns - bag0) / 1e9 / rate
                while not stop():
                    now = time.monotonic()
                    if clock_period is not None and now >= next_clock:
                        publish_clock(bag0 + (now - wall0) * rate * 1e9)
                        next_clock += clock_period
                    if now >= target:
                        break
                    wake = target if clock_period is None else min(target, next_clock)
                    time.sleep(max(0.0, min(wake - now, 0.05)))
            elif clock_period is not None and time.monotonic() >= next_clock:
                publish_clock(item.log_time_ns)
                next_clock = time.monotonic() + clock_period
            self._publish(item.topic, item.data)
            count += 1
        self.published += count
        return count

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


def _parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="mcap_play", description=__doc__.splitlines()[0])
    parser.add_argument("file", help="MCAP file to play")
    parser.add_argument("--rate", "-r", type=float, default=1.0, help="playback rate factor (> 0)")
    parser.add_argument(
        "--as-fast-as-possible",
        action="store_true",
        help="ignore timing, publish as fast as possible",
    )
    parser.add_argument("--loop", "-l", action="store_true", help="play in a loop")
    parser.add_argument(
        "--clock",
        nargs="?",
        type=float,
        const=40.0,
        default=None,
        metavar="HZ",
        help="publish /clock at HZ (default 40 Hz)",
    )
    parser.add_argument(
        "--start-offset", type=float, default=0.0, help="skip this much of the bag [s]"
    )
    parser.add_argument("--duration", type=float, default=None, help="play this much bag time [s]")
    parser.add_argument("--topics", nargs="+", default=None, help="play only these topics")
    parser.add_argument("--remap", nargs="+", default=[], metavar="FROM:=TO", help="topic remaps")
    parser.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        metavar="N",
        help="wait until each topic has N subscribers before playing",
    )
    parser.add_argument(
        "--wait-timeout",
        type=float,
        default=10.0,
        help="give up waiting for subscribers after this long [s]",
    )
    parser.add_argument("--delay", type=float, default=0.0, help="sleep before playing [s]")
    args = parser.parse_args(argv)
    if not args.rate > 0 or args.rate == float("inf"):
        parser.error("--rate must be a finite number > 0 (use --as-fast-as-possible)")
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_play``; returns the process exit code (2 for a bad file)."""
    apply_defaults()
    argv = sys.argv[1:] if argv is None else list(argv)
    from rclpy.utilities import remove_ros_args

    args = _parse_args(remove_ros_args(["mcap_play"] + argv)[1:])
    try:
        remap = parse_remaps(args.remap)
        resolved = playable_topics(args.file, args.topics)
    except (BagReadError, ValueError) as exc:
        print(f"mcap_play: error: {one_line(exc)}", file=sys.stderr)
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
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock

    rclpy.init(args=["mcap_play"] + argv, signal_handler_options=SignalHandlerOptions.NO)
    stop, previous = install_stop_request()
    node = None
    try:
        node = Node("mcap_player")
        player = Player(node, args.file, args.topics, remap, resolved=resolved)
        clock_pub = node.create_publisher(Clock, "/clock", 10) if args.clock else None
        if args.wait_for_subscribers > 0 and not player.wait_for_subscribers(
            args.wait_for_subscribers, args.wait_timeout, lambda: stop["flag"]
        ):
            node.get_logger().warning("not every topic has its subscribers; playing anyway")
        if args.delay > 0:
            time.sleep(args.delay)
        while not stop["flag"]:
            player.play(
                rate=args.rate,
                fast=args.as_fast_as_possible,
                start_offset_s=args.start_offset,
                duration_s=args.duration,
                clock_publisher=clock_pub,
                clock_hz=args.clock or 0.0,
                stop=lambda: stop["flag"],
            )
            if not args.loop:
                break
        player.wait_acked(timeout_s=max(1.0, args.wait_timeout))  # deliver the tail before exit
        print(f"mcap_play: published {player.published} messages", flush=True)
    except BagReadError as exc:
        print(f"mcap_play: error: {one_line(exc)}", file=sys.stderr)
        return 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

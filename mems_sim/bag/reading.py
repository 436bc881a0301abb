"""Reading a recorded bag, an MCAP file or a rosbag2 bag directory, as one timeline.

* :func:`iter_raw` -- ``(schema, channel, message)`` records of the selected topics, merged
  over a bag directory's files in log-time order;
* :func:`iter_messages` -- :class:`BagMessage` ``(topic, type_name, log_time_ns,
  publish_time_ns, data)`` in log-time order, also from files whose Summary is missing
  (a crashed recorder);
* :func:`read_messages` -- ``(topic, type_name, log_time_ns, msg)`` with the message
  deserialised into its real Python class (``rclpy.serialization``, imported then), so
  equality tests against published messages are exact;
* :func:`recorded_topics`, :func:`playable_topics` -- the bag's topics, types and QoS.

Files are read through :mod:`mems_sim.bag.reader` (bounded chunk decompression, CRC,
topic-name and QoS checks). Docs: docs/recording.md.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable, Iterator
from typing import NamedTuple

from mcap.records import Channel, Message, Schema

from mems_sim.bag.reader import (
    BagReadError,
    BagSummary,
    bag_files,
    check_channel,
    open_bag,
    read_chunk_at,
    read_summary,
    shown,
    warn_once,
    warn_truncated,
)
from mems_sim.bag.reader import iter_stream_records as _iter_stream_records
from mems_sim.stream_index import DuplicateFilter

__all__ = [
    "BagMessage",
    "BagReadError",
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
    path: str,
    topics: Iterable[str] | None = None,
    start_offset_s: float = 0.0,
    duplicates: DuplicateFilter | None = None,
) -> Iterator[BagMessage]:
    """Iterate the stored messages as :class:`BagMessage` in log-time order.

    :param topics: only these topics (None: all).
    :param start_offset_s: skip messages logged earlier than start + offset [s].
    :param duplicates: if given, a message it has seen (identical topic, log time and
        bytes, and sequence number: a chunk stored twice) is counted there and skipped,
        so each is used once.
    Raises :class:`BagReadError` for a missing, non-MCAP or corrupt file.
    """
    start = None
    if start_offset_s:
        first = bag_start_time_ns(path)
        start = None if first is None else first + int(round(start_offset_s * 1e9))
    for schema, channel, message in iter_raw(path, topics, start_time_ns=start):
        if duplicates is not None and duplicates.seen(
            channel.topic, message.log_time, message.data, message.sequence
        ):
            continue
        type_name = schema.name if schema is not None else ""
        yield BagMessage(
            channel.topic, type_name, message.log_time, message.publish_time, message.data
        )


def read_messages(
    path: str,
    topics: Iterable[str] | None = None,
    on_unknown: Callable[[str, str, str], None] | None = None,
    duplicates: DuplicateFilter | None = None,
) -> Iterator[tuple[str, str, int, object]]:
    """Iterate ``(topic, type_name, log_time_ns, msg)`` with ``msg`` deserialised into its real class.

    Uses ``rclpy.serialization.deserialize_message`` (no rclpy.init needed). Messages
    of a type that is not an installed interface (``schema.message_class`` refuses to
    import it) are skipped and reported once per topic through
    ``on_unknown(path, topic, reason)`` (default: a warning line on stderr). A message
    that does not deserialise raises :class:`BagReadError`. ``duplicates``: as
    :func:`iter_messages`.
    """
    from rclpy.serialization import deserialize_message

    from mems_sim.bag.schema import SchemaError, message_class

    classes: dict[str, type | None] = {}
    reasons: dict[str, str] = {}
    reported: set[str] = set()
    for item in iter_messages(path, topics, duplicates=duplicates):
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

"""``mcap_info BAG``: topics, types, counts, duration, sample rates, frame gaps of an MCAP bag.

``BAG`` is an MCAP file or a rosbag2 bag directory of MCAP files (a split
recording: :func:`mems_sim.bag.reader.bag_files`), described as one recording:
counts, times and loss (frame-index gaps, sequence gaps, end-of-stream tails)
over all its files together, in their recording order.

:func:`bag_info` returns the same as a dict for tests and other code. Message
counts come from the Statistics record when the file has one; frame topics
are always scanned (CDR peek, no deserialisation) for sample rates, total
samples and frame-index gaps. Files without a Summary (a recorder that was
killed) are scanned up to the last complete chunk (``truncated`` = True, and
``mcap_info`` prints a warning line).

Loss: frame topics are checked for frame-index gaps; other topics for gaps of their
publisher's sequence numbers (the MCAP ``sequence``, which this package's recorder
sets to the publication sequence number). When the file holds an emulator's
end-of-stream record (``.../end_of_stream``), every recorded topic it names is
compared with it: fewer messages, or a last frame that ends before the announced end
sample index, is a missing tail. Each loss is on the topic's line and in a warning
line on stderr (exit status 0: the file itself is readable). Samples a device declared
dropped on its ``faults`` topic (a scheduled ``dropped_samples`` fault,
:mod:`mems_sim.ros.device_gaps`) are a device gap, shown on the topic's line and not loss.

Duplicates: a message stored more than once (identical topic, log time, sequence number
and bytes, e.g. every chunk written twice) is counted once in every figure and the copies
are reported per topic (``duplicates``, on the topic's line and in one warning line).

Times are the bag's log times, which the recorder sets to sensor time (header
stamps, else the graph's clock): start, end and duration are the data's, e.g.
from 0 for a fast simulated run. The end includes the extent of the last frame
of each frame topic (its stamp, the time of its first sample, plus num_samples /
sample_rate_hz), so a recording of 2 s of data lasts 2 s, not 2 s less a frame. Records are read by
:mod:`mems_sim.bag.reader`: a corrupt or hostile file gives one line on stderr
and exit status 2. Types that are not installed interfaces are listed (with a
warning line), never imported.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import sys

from mcap.records import Channel, Chunk, Header, Message, Schema

from mems_sim.bag.reader import (
    TRUNCATED_TEXT,
    BagReadError,
    bag_files,
    check_channel,
    closed_pipe_exit,
    iter_stream_records,
    one_line,
    open_bag,
    read_summary,
    shown,
)
from mems_sim.bag.schema import (
    FRAME_LAYOUTS,
    GAP_CHECKED_TYPES,
    interface_problem,
    peek_frame_fields,
    peek_header_stamp_ns,
)
from mems_sim.ros.device_gaps import GapDeclarations
from mems_sim.ros.end_of_stream import (
    describe_tail,
    is_end_of_stream_topic,
    missing_tail,
    parse_end_of_stream,
)
from mems_sim.stream_index import (
    DuplicateFilter,
    SequenceIndex,
    StreamIndex,
    describe_missing_head,
)


def _scan(files: list[str]) -> dict:
    """Scan all records of the files in order: channels, per-topic counts/times, frames,
    sequences, chunk compressions. The accounting runs over the files as one recording
    (a split bag's files in recording order), keyed by topic. A duplicated message
    (:class:`~mems_sim.stream_index.DuplicateFilter`) is counted per file and topic in
    ``file_duplicates`` and left out of every other count, so a bag whose chunks are
    stored twice is described as the bag stored once.

    Raises :class:`BagReadError` for a corrupt record, an invalid topic name or absurd QoS.
    """
    channels: dict[str, Channel] = {}  # the first channel of each topic
    types: dict[str, str] = {}  # topic -> schema name
    origin: dict[str, str] = {}  # topic -> file of its first channel
    file_channels: list[dict[int, Channel]] = []
    file_counts: list[dict[str, int]] = []
    file_times: list[tuple[int | None, int | None]] = []
    file_duplicates: list[dict[str, int]] = []
    duplicates = DuplicateFilter()
    frames: dict[str, StreamIndex] = {}
    declarations = GapDeclarations(lambda t, first, n: frames[t].declare_device_gap(first, n))
    rates: dict[str, set] = {}
    data_ends: dict[str, int] = {}
    sequences: dict[str, SequenceIndex] = {}
    end_records: list[bytes] = []
    compressions = set()
    header = None
    truncated: list[str] = []

    def on_chunk(chunk: Chunk) -> None:
        compressions.add(chunk.compression or "none")

    for path in files:
        schemas: dict[int, Schema] = {}
        by_id: dict[int, Channel] = {}
        counts: dict[str, int] = {}
        before = dict(duplicates.counts)
        start = end = None
        file_header = None
        handle = open_bag(path)
        with handle:
            for item, cut in iter_stream_records(handle, path, on_chunk=on_chunk):
                if cut:
                    truncated.append(path)
                elif isinstance(item, Header):
                    file_header = item
                elif isinstance(item, Schema):
                    schemas[item.id] = item
                elif isinstance(item, Channel):
                    check_channel(path, item)
                    by_id[item.id] = item
                    schema = schemas.get(item.schema_id)
                    _add_channel(path, item, schema.name if schema else "", channels, types, origin)
                elif isinstance(item, Message):
                    channel = by_id.get(item.channel_id)
                    if channel is None or duplicates.seen(
                        channel.topic, item.log_time, item.data, item.sequence
                    ):
                        continue
                    start = item.log_time if start is None else min(start, item.log_time)
                    end = item.log_time if end is None else max(end, item.log_time)
                    topic = channel.topic
                    counts[topic] = counts.get(topic, 0) + 1
                    type_name = types.get(topic, "")
                    declarations.fault(topic, type_name, item.data)
                    _account_frame(item, topic, type_name, frames, rates, data_ends, declarations)
                    _account_sequence(item, topic, type_name, sequences, end_records)
        if file_header is None:
            raise BagReadError(f"{path}: unreadable MCAP header")
        header = header or file_header
        file_channels.append(by_id)
        file_counts.append(counts)
        file_times.append((start, end))
        file_duplicates.append(
            {t: n - before.get(t, 0) for t, n in duplicates.counts.items() if n > before.get(t, 0)}
        )
    return {
        "header": header,
        "channels": channels,
        "types": types,
        "file_channels": file_channels,
        "file_counts": file_counts,
        "file_times": file_times,
        "file_duplicates": file_duplicates,
        "frames": frames,
        "rates": rates,
        "data_ends": data_ends,
        "sequences": sequences,
        "end_records": end_records,
        "compressions": compressions,
        "truncated": truncated,
    }


def _add_channel(path: str, channel: Channel, type_name: str, channels, types, origin) -> None:
    """Keep the first channel of each topic; a topic whose type differs in a later file of
    the bag raises (within one file the first channel's type is kept)."""
    topic = channel.topic
    if topic not in channels:
        channels[topic] = channel
        types[topic] = type_name
        origin[topic] = path
    elif types[topic] != type_name and origin[topic] != path:
        raise BagReadError(
            f"{path}: {shown(topic)} is {shown(type_name)} here but {shown(types[topic])} "
            f"in {origin[topic]}"
        )


def _account_frame(
    message: Message, topic, type_name, frames, rates, data_ends, declarations
) -> None:
    layout = FRAME_LAYOUTS.get(type_name)
    if layout is None:
        return
    fields = peek_frame_fields(message.data, layout)
    if fields is None:
        return
    first, num, rate = fields
    rates.setdefault(topic, set()).add(rate)
    counter = frames.get(topic)
    if counter is None:
        counter = frames[topic] = StreamIndex.recording(start=0)
        declarations.frame_topic(topic)  # the device's declared gaps apply to it
    if type_name in GAP_CHECKED_TYPES:
        counter.update(first, num)
        stamp = peek_header_stamp_ns(message.data)  # time of the frame's first sample
        if stamp is not None and rate > 0 and math.isfinite(rate):
            end = stamp + int(round(num * 1e9 / rate))
            data_ends[topic] = max(data_ends.get(topic, end), end)
    else:
        counter.frames += 1


def _account_sequence(message: Message, topic, type_name, sequences, end_records) -> None:
    """Count gaps of the message sequence numbers per topic; keep end-of-stream records."""
    sequences.setdefault(topic, SequenceIndex()).update(message.sequence)
    if type_name and is_end_of_stream_topic(topic, type_name):
        end_records.append(message.data)


def _end_of_stream(records: list[bytes]) -> dict[str, dict[str, int]]:
    """Per topic, the counts announced by the end-of-stream records of the file (records
    that do not deserialise are skipped: the file is only described, never trusted)."""
    if not records:
        return {}
    try:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.serialization import deserialize_message
    except ImportError:
        return {}
    out: dict[str, dict[str, int]] = {}
    for data in records:
        try:
            out.update(parse_end_of_stream(deserialize_message(data, DiagnosticArray)))
        except Exception:  # a corrupt record announces nothing
            continue
    return out


def _add_losses(topics: dict, scan: dict) -> None:
    """Add sequence gaps (topics that are not frames) and missing tails to ``topics``.

    Sequence numbers are checked on a topic only while they rise (one publisher that
    numbers its messages, as the recorder of this package stores them); numbers that fall
    or repeat (several publishers, or a writer that does not number) leave the topic's
    ``sequence_gaps`` None. A topic named in an end-of-stream record gets ``tail`` (what
    is missing after the last recorded message, :func:`missing_tail`) and
    ``end_of_stream`` (the announced counts).
    """
    for topic, entry in topics.items():
        counter = scan["sequences"].get(topic)
        checkable = counter is not None and counter.resets == 0
        if entry.get("type") not in GAP_CHECKED_TYPES:
            entry["sequence_gaps"] = counter.gaps if checkable else None
            entry["missing_messages"] = counter.missing_messages if checkable else None
    for topic, expected in _end_of_stream(scan["end_records"]).items():
        if topic not in topics:
            continue  # not selected for recording: nothing to compare
        entry = topics[topic]
        counter = scan["sequences"].get(topic)
        if counter is not None and counter.resets == 0 and counter.last is not None:
            seen = counter.last
        else:
            seen = entry.get("count", 0)
        frames = scan["frames"].get(topic)
        end = frames.expected if frames is not None else None
        entry["end_of_stream"] = expected
        entry["tail"] = missing_tail(expected, seen, end)


def losses(info: dict) -> list[str]:
    """One line per topic of :func:`bag_info`'s dict that lost data: frame-index gaps,
    sequence gaps, a missing tail."""
    out = []
    for topic, t in sorted(info["topics"].items()):
        parts = []
        if t.get("missing_head"):
            parts.append(describe_missing_head(t["missing_head"]))
        if t.get("gaps"):
            parts.append(f"{t['gaps']} frame-index gaps ({t['missing_samples']} samples)")
        if t.get("sequence_gaps"):
            parts.append(f"{t['sequence_gaps']} sequence gaps ({t['missing_messages']} messages)")
        tail = t.get("tail")
        if tail and (tail["messages"] or tail.get("samples")):
            parts.append(describe_tail(topic, t["end_of_stream"], tail).split(": ", 1)[1])
        if parts:
            out.append(f"{topic}: " + ", ".join(parts))
    return out


def bag_info(path: str) -> dict:
    """Describe an MCAP bag.

    Returns a dict with ``path``, ``file_size`` [bytes], ``profile``, ``library``,
    ``has_summary``, ``truncated``, ``compression`` (sorted list of chunk
    compressions), ``message_count``, ``start_ns`` and ``end_ns`` (first and last log time,
    i.e. sensor time), ``data_end_ns`` (end of the last sample of the frame topics, None
    without frames), ``duration_s`` [s] (from ``start_ns`` to the later of ``end_ns`` and
    ``data_end_ns``) and ``topics``: ``{topic: {type, message_encoding, count, offered_qos_profiles,
    topic_type_hash, type_problem (why the type is not an installed interface, None if it
    is; such types are only listed, never imported), duplicates (messages stored more than once with identical topic,
    log time and bytes, each counted once in count and every other figure), and for frame
    topics sample_rate_hz [Hz] (None if it varies),
    total_samples, frames, gaps, missing_samples (transport loss), device_gaps and
    device_missing_samples (samples the device declared dropped on its faults topic,
    :mod:`mems_sim.ros.device_gaps`; not loss), resets; for other topics sequence_gaps and
    missing_messages (None when the sequence numbers cannot be checked); for topics named
    in an end-of-stream record end_of_stream (the announced counts) and tail (what is
    missing at the end: messages, and for frames samples and from_index)}}``
    (:func:`losses` lists what a file lost).
    Raises :class:`~mems_sim.bag.reader.BagReadError` (one line) for a missing, non-MCAP
    or corrupt file, an invalid topic name or absurd QoS metadata; a truncated file is
    read up to its last complete chunk (``truncated`` = True).
    """
    files = bag_files(path)
    stats_list = []
    for name in files:
        handle = open_bag(name)
        with handle:
            summary = read_summary(handle, name)
        if summary is not None:
            for channel in summary.channels.values():
                check_channel(name, channel)
        stats_list.append(summary.statistics if summary is not None else None)
    scan = _scan(files)
    header = scan["header"]
    counts: dict[str, int] = {}
    total = 0
    start = end = None
    for stats, by_id, scanned, times, dups in zip(
        stats_list,
        scan["file_channels"],
        scan["file_counts"],
        scan["file_times"],
        scan["file_duplicates"],
    ):
        file_counts = dict(scanned)
        if stats is not None:  # the Statistics count duplicates as stored: counted once here
            for cid, channel in by_id.items():
                if cid in stats.channel_message_counts:
                    stored = stats.channel_message_counts[cid]
                    file_counts[channel.topic] = max(stored - dups.get(channel.topic, 0), 0)
        for topic, n in file_counts.items():
            counts[topic] = counts.get(topic, 0) + n
        if stats is not None and stats.message_count:
            times = (stats.message_start_time, stats.message_end_time)
            total += max(stats.message_count - sum(dups.values()), 0)
        else:
            total += sum(scanned.values())
        if times[0] is not None:
            start = times[0] if start is None else min(start, times[0])
            end = times[1] if end is None else max(end, times[1])
    topics = {}
    for topic, channel in scan["channels"].items():
        type_name = scan["types"][topic]
        entry = {
            "type": type_name,
            "type_problem": interface_problem(type_name) if type_name else None,
            "message_encoding": channel.message_encoding,
            "count": counts.get(topic, 0),
            "duplicates": sum(d.get(topic, 0) for d in scan["file_duplicates"]),
            "offered_qos_profiles": channel.metadata.get("offered_qos_profiles", ""),
            "topic_type_hash": channel.metadata.get("topic_type_hash"),
        }
        if topic in scan["frames"]:
            counter = scan["frames"][topic]
            rates = scan["rates"].get(topic, set())
            entry.update(
                sample_rate_hz=next(iter(rates)) if len(rates) == 1 else None,
                total_samples=counter.samples,
                frames=counter.frames,
                gaps=counter.gaps,
                missing_samples=counter.missing_samples,
                device_gaps=counter.device_gaps,
                device_missing_samples=counter.device_missing_samples,
                missing_head=counter.missing_head,
                resets=counter.resets,
            )
        topics[topic] = entry
    _add_losses(topics, scan)
    data_end = max(scan["data_ends"].values(), default=None)
    last = end if data_end is None or end is None else max(end, data_end)
    return {
        "path": path,
        "files": files,
        "file_size": sum(os.path.getsize(name) for name in files),
        "profile": header.profile,
        "library": header.library,
        "has_summary": all(stats is not None for stats in stats_list),
        "truncated": bool(scan["truncated"]),
        "truncated_files": scan["truncated"],
        "compression": sorted(scan["compressions"]),
        "message_count": total,
        "start_ns": start,
        "end_ns": end,
        "data_end_ns": data_end,
        "duration_s": (last - start) / 1e9 if start is not None else 0.0,
        "topics": topics,
    }


def _printable(text: str) -> str:
    """A string from the file as is when printable, else quoted and escaped (one line)."""
    return text if text.isprintable() else shown(text)


def _end_ns(info: dict) -> int | None:
    """End of the bag's data [ns]: the later of the last log time and the last sample."""
    ends = [t for t in (info["end_ns"], info.get("data_end_ns")) if t is not None]
    return max(ends) if ends else None


def _time_text(ns: int | None) -> str:
    """Sensor time [s] to the nanosecond; with the UTC date when it is a wall-clock time
    (after 2000), as live graphs stamp."""
    if ns is None:
        return "-"
    text = f"{ns // 10**9}.{ns % 10**9:09d} s"
    if ns >= 946_684_800 * 10**9:
        date = datetime.datetime.fromtimestamp(ns / 1e9, tz=datetime.timezone.utc)
        text += f" ({date:%Y-%m-%d %H:%M:%S.%f} UTC)"
    return text


def format_info(info: dict) -> str:
    """Human-readable multi-line text of :func:`bag_info`'s dict."""
    lines = [f"File:        {info['path']}"]
    files = info.get("files", [info["path"]])
    if files != [info["path"]]:
        names = ", ".join(os.path.relpath(name, info["path"]) for name in files)
        lines.append(f"Files:       {len(files)}: " + one_line(names, 1000))
    lines += [
        f"Size:        {info['file_size'] / 1e6:.3f} MB",
        f"Profile:     {_printable(info['profile'])} ({_printable(info['library'])})",
        f"Compression: {', '.join(info['compression']) or 'none'}",
        f"Summary:     {'yes' if info['has_summary'] else 'no'}"
        + (" (file truncated: read up to the last complete chunk)" if info["truncated"] else ""),
        f"Start:       {_time_text(info['start_ns'])}",
        f"End:         {_time_text(_end_ns(info))}",
        f"Duration:    {info['duration_s']:.3f} s",
        f"Messages:    {info['message_count']}",
        "Topics:",
    ]
    for topic, t in sorted(info["topics"].items()):
        line = f"  {topic} [{t['type']}] {t['count']} msgs"
        if t.get("type_problem"):
            line = f"  {topic} [{t['type']!r}, unknown type] {t['count']} msgs"
        if "total_samples" in t:
            rate = "varies" if t["sample_rate_hz"] is None else f"{t['sample_rate_hz']:g} Hz"
            line += (
                f", {t['total_samples']} samples @ {rate}, {t['gaps']} gaps"
                f" ({t['missing_samples']} samples missing)"
            )
            if t.get("device_gaps"):
                line += (
                    f", {t['device_gaps']} device gaps ({t['device_missing_samples']} samples, "
                    "declared by the device)"
                )
            if t.get("missing_head"):
                line += ", " + describe_missing_head(t["missing_head"])
        if t.get("duplicates"):
            line += f", {t['duplicates']} duplicates (stored twice, counted once)"
        if t.get("sequence_gaps"):
            line += (
                f", {t['sequence_gaps']} sequence gaps ({t['missing_messages']} messages missing)"
            )
        tail = t.get("tail")
        if tail and (tail["messages"] or tail.get("samples")):
            line += ", " + describe_tail(topic, t["end_of_stream"], tail).split(": ", 1)[1]
        lines.append(line)
    return "\n".join(lines)


def _warn_duplicates(path: str, info: dict) -> None:
    """One warning line naming the topics with duplicated messages and their counts."""
    listed = [
        f"{t} {v['duplicates']}" for t, v in sorted(info["topics"].items()) if v["duplicates"]
    ]
    if listed:
        text = (
            f"mcap_info: warning: {path}: duplicated messages (identical topic, log time and "
            f"bytes; counted once): {', '.join(listed)}"
        )
        print(one_line(text, 1000), file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_info``; exit code 2 with a one-line error for a bad file, 141
    when stdout is a pipe whose reader closed it (:func:`closed_pipe_exit`)."""
    try:
        return _main(argv)
    except BrokenPipeError:
        return closed_pipe_exit()


def _main(argv: list[str] | None) -> int:
    parser = argparse.ArgumentParser(prog="mcap_info", description=__doc__.splitlines()[0])
    parser.add_argument("file", metavar="BAG", help="MCAP file or rosbag2 bag directory")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    try:
        info = bag_info(args.file)
    except BagReadError as exc:
        print(f"mcap_info: error: {one_line(exc)}", file=sys.stderr)
        return 2
    print(format_info(info), flush=True)
    for name in info["truncated_files"]:
        print(f"mcap_info: warning: {name}: {TRUNCATED_TEXT}", file=sys.stderr, flush=True)
    unknown = {t: v["type"] for t, v in info["topics"].items() if v.get("type_problem")}
    if unknown:
        listed = ", ".join(f"{shown(t)} [{shown(n)}]" for t, n in sorted(unknown.items()))
        print(
            one_line(
                f"mcap_info: warning: {args.file}: unknown types (not installed ROS "
                f"interfaces; listed, not imported): {listed}",
                1000,
            ),
            file=sys.stderr,
        )
    _warn_duplicates(args.file, info)
    for text in losses(info):
        print(
            one_line(f"mcap_info: warning: {args.file}: lost data: {text}", 1000), file=sys.stderr
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

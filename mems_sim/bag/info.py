"""``mcap_info FILE``: topics, types, counts, duration, sample rates, frame gaps of an MCAP bag.

:func:`bag_info` returns the same as a dict for tests and other code. Message
counts come from the Statistics record when the file has one; frame topics
are always scanned (CDR peek, no deserialisation) for sample rates, total
samples and frame-index gaps. Files without a Summary (a recorder that was
killed) are scanned up to the last complete chunk (``truncated`` = True, and
``mcap_info`` prints a warning line). Records are read by
:mod:`mems_sim.bag.reader`: a corrupt or hostile file gives one line on stderr
and exit status 2. Types that are not installed interfaces are listed (with a
warning line), never imported.
"""

from __future__ import annotations

import argparse
import os
import sys

from mcap.records import Channel, Chunk, Header, Message, Schema

from mems_sim.bag.reader import (
    TRUNCATED_TEXT,
    BagReadError,
    check_channel,
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
)
from mems_sim.bag.writer import FrameGapCounter


def _scan(path: str) -> dict:
    """Scan all records in file order: channels, per-channel counts/times, frames, chunk compressions.

    Raises :class:`BagReadError` for a corrupt record, an invalid topic name or absurd QoS.
    """
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    frames: dict[int, FrameGapCounter] = {}
    rates: dict[int, set] = {}
    compressions = set()
    header = None
    start = end = None
    truncated = False

    def on_chunk(chunk: Chunk) -> None:
        compressions.add(chunk.compression or "none")

    handle = open_bag(path)
    with handle:
        for item, cut in iter_stream_records(handle, path, on_chunk=on_chunk):
            if cut:
                truncated = True
            elif isinstance(item, Header):
                header = item
            elif isinstance(item, Schema):
                schemas[item.id] = item
            elif isinstance(item, Channel):
                check_channel(path, item)
                channels[item.id] = item
            elif isinstance(item, Message):
                start = item.log_time if start is None else min(start, item.log_time)
                end = item.log_time if end is None else max(end, item.log_time)
                counts[item.channel_id] = counts.get(item.channel_id, 0) + 1
                _account_frame(item, channels, schemas, frames, rates)
    if header is None:
        raise BagReadError(f"{path}: unreadable MCAP header")
    return {
        "header": header,
        "schemas": schemas,
        "channels": channels,
        "counts": counts,
        "frames": frames,
        "rates": rates,
        "compressions": compressions,
        "start": start,
        "end": end,
        "truncated": truncated,
    }


def _account_frame(message: Message, channels, schemas, frames, rates) -> None:
    channel = channels.get(message.channel_id)
    schema = schemas.get(channel.schema_id) if channel is not None else None
    layout = FRAME_LAYOUTS.get(schema.name) if schema is not None else None
    if layout is None:
        return
    fields = peek_frame_fields(message.data, layout)
    if fields is None:
        return
    first, num, rate = fields
    rates.setdefault(message.channel_id, set()).add(rate)
    counter = frames.setdefault(message.channel_id, FrameGapCounter())
    if schema.name in GAP_CHECKED_TYPES:
        counter.update(first, num)
    else:
        counter.frames += 1


def bag_info(path: str) -> dict:
    """Describe an MCAP bag.

    Returns a dict with ``path``, ``file_size`` [bytes], ``profile``, ``library``,
    ``has_summary``, ``truncated``, ``compression`` (sorted list of chunk
    compressions), ``message_count``, ``start_ns``, ``end_ns``, ``duration_s`` [s]
    and ``topics``: ``{topic: {type, message_encoding, count, offered_qos_profiles,
    topic_type_hash, type_problem (why the type is not an installed interface, None if it
    is; such types are only listed, never imported), and for frame topics sample_rate_hz [Hz] (None if it varies),
    total_samples, frames, gaps, missing_samples, resets}}``.
    Raises :class:`~mems_sim.bag.reader.BagReadError` (one line) for a missing, non-MCAP
    or corrupt file, an invalid topic name or absurd QoS metadata; a truncated file is
    read up to its last complete chunk (``truncated`` = True).
    """
    handle = open_bag(path)
    with handle:
        summary = read_summary(handle, path)
    if summary is not None:
        for channel in summary.channels.values():
            check_channel(path, channel)
    scan = _scan(path)
    header = scan["header"]
    stats = summary.statistics if summary is not None else None
    topics = {}
    for cid, channel in scan["channels"].items():
        schema = scan["schemas"].get(channel.schema_id)
        count = scan["counts"].get(cid, 0)
        if stats is not None:
            count = stats.channel_message_counts.get(cid, count)
        type_name = schema.name if schema else ""
        entry = {
            "type": type_name,
            "type_problem": interface_problem(type_name) if type_name else None,
            "message_encoding": channel.message_encoding,
            "count": count,
            "offered_qos_profiles": channel.metadata.get("offered_qos_profiles", ""),
            "topic_type_hash": channel.metadata.get("topic_type_hash"),
        }
        if cid in scan["frames"]:
            counter = scan["frames"][cid]
            rates = scan["rates"].get(cid, set())
            entry.update(
                sample_rate_hz=next(iter(rates)) if len(rates) == 1 else None,
                total_samples=counter.samples,
                frames=counter.frames,
                gaps=counter.gaps,
                missing_samples=counter.missing_samples,
                resets=counter.resets,
            )
        topics[channel.topic] = entry
    if stats is not None and stats.message_count:
        start, end, total = stats.message_start_time, stats.message_end_time, stats.message_count
    else:
        start, end, total = scan["start"], scan["end"], sum(scan["counts"].values())
    return {
        "path": path,
        "file_size": os.path.getsize(path),
        "profile": header.profile,
        "library": header.library,
        "has_summary": summary is not None and stats is not None,
        "truncated": scan["truncated"],
        "compression": sorted(scan["compressions"]),
        "message_count": total,
        "start_ns": start,
        "end_ns": end,
        "duration_s": (end - start) / 1e9 if start is not None else 0.0,
        "topics": topics,
    }


def _printable(text: str) -> str:
    """A string from the file as is when printable, else quoted and escaped (one line)."""
    return text if text.isprintable() else shown(text)


def format_info(info: dict) -> str:
    """Human-readable multi-line text of :func:`bag_info`'s dict."""
    lines = [
        f"File:        {info['path']}",
        f"Size:        {info['file_size'] / 1e6:.3f} MB",
        f"Profile:     {_printable(info['profile'])} ({_printable(info['library'])})",
        f"Compression: {', '.join(info['compression']) or 'none'}",
        f"Summary:     {'yes' if info['has_summary'] else 'no'}"
        + (" (file truncated: read up to the last complete chunk)" if info["truncated"] else ""),
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
        lines.append(line)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_info``; exit code 2 with a one-line error for a bad file."""
    parser = argparse.ArgumentParser(prog="mcap_info", description=__doc__.splitlines()[0])
    parser.add_argument("file")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    try:
        info = bag_info(args.file)
    except BagReadError as exc:
        print(f"mcap_info: error: {one_line(exc)}", file=sys.stderr)
        return 2
    print(format_info(info), flush=True)
    if info["truncated"]:
        print(f"mcap_info: warning: {args.file}: {TRUNCATED_TEXT}", file=sys.stderr, flush=True)
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
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The recorder's writing cost per storage preset: CPU per second of recorded data, file size.

Run:  .venv/bin/python bench/bench_recorder_presets.py [BAG.mcap] [--repeat N] [--rounds R]
                                                      [--first S]

The messages of a recording (default ``bags/stage.mcap``: the micro-stage's adc, drive,
truth and estimate frames at 625 kHz) are held in memory and written again through
:class:`~mems_sim.bag.writer.McapBagWriter` -- the writer ``mcap_record`` uses, with its
writer thread -- (with ``--first S`` only the messages logged in its first S seconds)
``N`` times over (the data's log times shifted by its span each time, so
the output is N times as long), once per configuration: rosbag2's storage presets and the
zstd levels between them. Configurations take turns for ``R`` rounds; reported is each
one's least process CPU (every thread: the writer thread's chunk building, compression,
CRC and file writes) per second of data, relative to the default (zstd level 1), with the
file size. Every output is read back (mcap's reader) and compared message by message with
the input: the recording stays lossless.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mcap.reader import make_reader

from mems_sim.bag.compression import storage_preset
from mems_sim.bag.writer import McapBagWriter

#: (label, McapBagWriter options) in the order printed
CONFIGS = [
    ("none (zstd 1, default)", storage_preset("none")),
    ("zstd 3 (mcap Python's)", {"compression": "zstd", "compression_level": 3}),
    ("zstd -1", {"compression": "zstd", "compression_level": -1}),
    ("zstd -3", {"compression": "zstd", "compression_level": -3}),
    ("zstd_fast (zstd -5, no CRC)", storage_preset("zstd_fast")),
    ("zstd -5 with CRC", {"compression": "zstd", "compression_level": -5}),
    ("lz4", {"compression": "lz4"}),
    ("fastwrite (none, no CRC)", storage_preset("fastwrite")),
    ("zstd_small (zstd 19, 4 MiB)", storage_preset("zstd_small")),
]


def load(path: str, first_s: float | None = None):
    """Topics (name, type, schema text, metadata) and messages (topic, log, publish, data)."""
    topics, messages = {}, []
    start = end = None
    if first_s is not None:
        # from the first frame (a stamped recording may hold earlier diagnostics)
        with open(path, "rb") as f:
            for _, channel, m in make_reader(f).iter_messages(log_time_order=True):
                if channel.topic.endswith("/adc"):
                    start, end = m.log_time, m.log_time + int(first_s * 1e9)
                    break
    with open(path, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            if start is not None and not start <= m.log_time < end:
                continue
            if channel.topic not in topics:
                topics[channel.topic] = (
                    schema.name,
                    schema.data.decode("utf-8"),
                    dict(channel.metadata),
                )
            messages.append((channel.topic, m.log_time, m.publish_time, bytes(m.data), m.sequence))
    return topics, messages


def cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def write_once(out: str, topics, messages, repeat: int, span_ns: int, options: dict):
    """Write the messages ``repeat`` times; return (CPU s, wall s, bytes)."""
    c0, t0 = cpu_s(), time.perf_counter()
    bag = McapBagWriter(out, **options)
    for name, (type_name, schema, meta) in topics.items():
        bag.add_topic(
            name,
            type_name,
            schema,
            meta.get("offered_qos_profiles", ""),
            meta.get("topic_type_hash"),
        )
    for k in range(repeat):
        shift = k * span_ns
        for topic, log, pub, data, seq in messages:
            bag.write(topic, data, log + shift, pub + shift)
    bag.close()
    return cpu_s() - c0, time.perf_counter() - t0, os.path.getsize(out)


def check(out: str, messages, repeat: int) -> None:
    """The written file holds the same messages (bytes, topics, order within a topic)."""
    expected: dict[str, list[bytes]] = {}
    for topic, _, _, data, _ in messages:
        expected.setdefault(topic, []).append(data)
    seen: dict[str, int] = {}
    with open(out, "rb") as f:
        for _, channel, m in make_reader(f).iter_messages(log_time_order=False):
            i = seen.get(channel.topic, 0)
            ref = expected[channel.topic]
            if m.data != ref[i % len(ref)]:
                raise AssertionError(f"{out}: message {i} of {channel.topic} differs")
            seen[channel.topic] = i + 1
    for topic, ref in expected.items():
        if seen.get(topic, 0) != len(ref) * repeat:
            raise AssertionError(f"{out}: {topic} has {seen.get(topic, 0)} messages")


def main() -> None:
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag", nargs="?", default=os.path.join(here, "..", "bags", "stage.mcap"))
    ap.add_argument("--repeat", type=int, default=25, help="times the messages are written")
    ap.add_argument("--rounds", type=int, default=3, help="turns per configuration")
    ap.add_argument("--first", type=float, default=None, help="only the first S s of the bag")
    args = ap.parse_args()
    topics, messages = load(args.bag, args.first)
    logs = [m[1] for m in messages]
    # span of the data: first to last log time plus one frame period (frames are evenly
    # spaced), so the repeats follow each other without overlap
    distinct = sorted(set(logs))
    step = distinct[1] - distinct[0] if len(distinct) > 1 else 1
    span_ns = distinct[-1] - distinct[0] + step
    seconds = span_ns * args.repeat / 1e9
    raw = sum(len(m[3]) for m in messages) * args.repeat
    print(
        f"{os.path.basename(args.bag)}: {len(messages)} messages x {args.repeat} = "
        f"{seconds:.2f} s of data, {raw / 1e6:.0f} MB of CDR ({raw / seconds / 1e6:.0f} MB/s "
        f"of data); load average {os.getloadavg()[0]:.2f}"
    )
    best: dict[str, tuple[float, float, int]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            for i, (label, options) in enumerate(CONFIGS):
                if label in best and options.get("compression_level", 0) >= 19:
                    continue  # zstd 19 once: ~20 CPU s per s of stage data
                out = os.path.join(tmp, f"c{i}.mcap")
                c, w, size = write_once(out, topics, messages, args.repeat, span_ns, options)
                if label not in best:
                    check(out, messages, args.repeat)
                if label not in best or c < best[label][0]:
                    best[label] = (c, w, size)
                os.unlink(out)
    ref = best[CONFIGS[0][0]][0]
    for label, _ in CONFIGS:
        c, w, size = best[label]
        print(
            f"  {label:28s}: {c / seconds:5.3f} CPU s per s of data ({c / ref:4.2f} x the "
            f"default), file {size / 1e6:6.1f} MB (CDR / file {raw / size:4.2f}), "
            f"lossless"
        )
    print(f"  load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

"""Hostile MCAP files against ``mcap_play``, ``mcap_info`` and ``identify_noise``.

Each tool runs as a subprocess on each file; the expectation is one line on stderr
and exit status 2 (a warning line and exit 0 for a truncated file, read up to its
last complete chunk; a warning line and exit 0 from ``mcap_info`` for a type that is
not installed, which it only lists), a peak RSS under 500 MB, and no import of
anything a file names: a canary module on PYTHONPATH, named by the schemas, writes a
marker file when imported.

Files: (a) schema names that name Python modules, (b) decompression bombs (zstd and
lz4, gigabytes declared or gigabytes actually inside a small payload, with and
without a Summary), (c) corrupt chunks (bytes flipped), (d) invalid topic names,
(e) absurd ``offered_qos_profiles``, (f) a file cut in the middle of its last chunk.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from bagtool_helpers import reference_frames, run_measured

from mems_sim.bag.writer import McapBagWriter

MAGIC = b"\x89MCAP0\r\n"
TOOLS = ("mcap_info", "mcap_play", "identify_noise")
MAX_RSS_MB = 500.0
CANARY = "bagcanary"


def _records(*records) -> bytes:
    from mcap.data_stream import RecordBuilder

    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    return builder.end()


def _frames():
    if not hasattr(_frames, "cache"):
        _frames.cache = reference_frames()
    return _frames.cache


def _write_mcap(path: Path, schema_name: str, topic: str, qos: str | None = None, n: int = 20):
    """A well-formed file (mcap's Writer, Summary included) with arbitrary names."""
    from mcap.writer import Writer

    text, ref_qos, data = _frames()
    with open(path, "wb") as handle:
        writer = Writer(handle)
        writer.start(profile="ros2", library="hostile-test")
        schema_id = writer.register_schema(name=schema_name, encoding="ros2msg", data=text.encode())
        channel_id = writer.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=schema_id,
            metadata={"offered_qos_profiles": ref_qos if qos is None else qos},
        )
        for k, payload in enumerate(data[:n]):
            writer.add_message(channel_id, 1000 + k, payload, 1000 + k, k)
        writer.finish()


def _bomb(path: Path, compression: str, declared: int, actual: int, summary: bool) -> None:
    """Header, Schema, Channel, then one chunk whose payload is small but declares
    ``declared`` bytes and expands to ``actual`` bytes (zeros); optionally a Summary
    whose chunk index points to it."""
    from mcap.records import Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Schema

    text, qos, _ = _frames()
    block = bytes(1 << 20)
    if compression == "zstd":
        import zstandard

        packer = zstandard.ZstdCompressor(level=1).compressobj()
        payload = bytearray()
        for _ in range(actual >> 20):
            payload += packer.compress(block)
        payload += packer.flush()
    else:
        import lz4.frame

        packer = lz4.frame.LZ4FrameCompressor()
        payload = bytearray(packer.begin())
        for _ in range(actual >> 20):
            payload += packer.compress(block)
        payload += packer.flush()
    schema = Schema(id=1, name="mems_msgs/msg/AdcFrame", encoding="ros2msg", data=text.encode())
    channel = Channel(
        id=1,
        topic="/imu/adc",
        message_encoding="cdr",
        schema_id=1,
        metadata={"offered_qos_profiles": qos},
    )
    chunk = Chunk(
        compression=compression,
        data=bytes(payload),
        message_start_time=1,
        message_end_time=2,
        uncompressed_crc=0,
        uncompressed_size=declared,
    )
    head = MAGIC + _records(Header(profile="ros2", library="bomb"), schema, channel)
    chunk_bytes = _records(chunk)
    body = head + chunk_bytes + _records(DataEnd(data_section_crc=0))
    if summary:
        index = ChunkIndex(
            chunk_length=len(chunk_bytes),
            chunk_start_offset=len(head),
            compression=compression,
            compressed_size=len(payload),
            message_end_time=2,
            message_index_length=0,
            message_index_offsets={},
            message_start_time=1,
            uncompressed_size=declared,
        )
        summary_start = len(body)
        body += _records(schema, channel, index)
        body += _records(Footer(summary_start=summary_start, summary_offset_start=0, summary_crc=0))
    else:
        body += _records(Footer(summary_start=0, summary_offset_start=0, summary_crc=0))
    path.write_bytes(body + MAGIC)


def _chunk_spans(path: Path) -> list[tuple[int, int]]:
    """(start offset, length) of every chunk of a well-formed file, from its Summary."""
    from mcap.reader import make_reader

    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    return sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)


def _recorded(path: Path, compression: str, chunk_size: int = 32768) -> None:
    text, qos, data = _frames()
    writer = McapBagWriter(str(path), chunk_size=chunk_size, compression=compression)
    writer.add_topic("/imu/adc", "mems_msgs/msg/AdcFrame", text, qos)
    for k, payload in enumerate(data):
        writer.write("/imu/adc", payload, 1_000_000 + k * 10_000_000, 1_000_000 + k)
    writer.close()


def _flip(path: Path, offset: int, count: int = 32) -> None:
    raw = bytearray(path.read_bytes())
    for i in range(offset, offset + count):
        raw[i] ^= 0x5A
    path.write_bytes(bytes(raw))


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """name -> path of every hostile file (and the canary module directory under 'canary')."""
    root = tmp_path_factory.mktemp("hostile")
    out: dict[str, Path] = {}
    canary_dir = root / "canary"
    canary_dir.mkdir()
    marker = root / "CANARY_IMPORTED"
    (canary_dir / f"{CANARY}.py").write_text(
        f"import pathlib\npathlib.Path({str(marker)!r}).write_text('imported')\n"
    )
    out["canary_dir"], out["marker"] = canary_dir, marker

    # (a) type names that name Python modules
    for name, type_name in {
        "type_unknown_pkg": f"{CANARY}/msg/Canary",
        "type_dotted": f"{CANARY}.sub/msg/Canary",
        "type_dotdot": f"../{CANARY}/msg/Canary",
        "type_short": f"{CANARY}/Canary",
        "type_os": "os/msg/System",
    }.items():
        out[name] = root / f"{name}.mcap"
        _write_mcap(out[name], type_name, "/imu/adc")

    # (b) decompression bombs
    gib = 1 << 30
    for name, args in {
        "bomb_zstd_declared": ("zstd", 8 * gib, 64 << 20, False),
        "bomb_zstd_actual": ("zstd", 1 << 20, 2 * gib, True),
        "bomb_lz4_declared": ("lz4", 8 * gib, 16 << 20, True),
        "bomb_lz4_actual": ("lz4", 1 << 20, gib, False),
    }.items():
        out[name] = root / f"{name}.mcap"
        _bomb(out[name], *args)

    # (c) corrupt chunks: bytes flipped in the middle of the second chunk
    path = out["corrupt_zstd"] = root / "corrupt_zstd.mcap"
    _recorded(path, "zstd")
    start, length = _chunk_spans(path)[1]
    _flip(path, start + length // 2)
    path = out["corrupt_none_no_summary"] = root / "corrupt_none_no_summary.mcap"
    _recorded(path, "none")
    spans = _chunk_spans(path)
    _flip(path, spans[1][0] + spans[1][1] // 2)
    with open(path, "r+b") as handle:  # no Summary: the sequential path
        handle.truncate(spans[3][0] + spans[3][1])
    path = out["corrupt_length"] = root / "corrupt_length.mcap"  # not a truncation: footer there
    _recorded(path, "zstd")
    start, _ = _chunk_spans(path)[1]
    raw = bytearray(path.read_bytes())
    raw[start + 1 : start + 9] = (1 << 40).to_bytes(8, "little")
    path.write_bytes(bytes(raw))

    # (d) invalid topic names
    for name, topic in {
        "topic_double_slash": "/a//b",
        "topic_digit": "1abc",
        "topic_space": "/with space",
        "topic_trailing": "/imu/adc/",
        "topic_newline": "/imu/adc\nmcap_info: fake line",
    }.items():
        out[name] = root / f"{name}.mcap"
        _write_mcap(out[name], "mems_msgs/msg/AdcFrame", topic)

    # (e) absurd QoS
    for name, qos in {
        "qos_depth_1e12": "- history: keep_last\n  depth: 1000000000000\n  reliability: reliable",
        "qos_depth_negative": "- history: keep_last\n  depth: -5\n  reliability: reliable",
        "qos_garbage": "{{{: [ ::: not yaml",
        "qos_not_list": "just a string",
        "qos_bad_policy": "- history: keep_last\n  depth: 10\n  reliability: maybe",
        "qos_negative_duration": "- depth: 10\n  deadline:\n    sec: -1\n    nsec: 0",
        "qos_huge": "- depth: 10\n" + "  x: " + "y" * (100 << 10),
    }.items():
        out[name] = root / f"{name}.mcap"
        _write_mcap(out[name], "mems_msgs/msg/AdcFrame", "/imu/adc", qos=qos)

    # (f) cut in the middle of the last chunk
    path = out["truncated"] = root / "truncated.mcap"
    _recorded(path, "zstd", chunk_size=65536)
    start, length = _chunk_spans(path)[-1]
    with open(path, "r+b") as handle:
        handle.truncate(start + length // 2)
    return out


def _env(subprocess_env, bags) -> dict:
    env = dict(subprocess_env)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(bags["canary_dir"]), env.get("PYTHONPATH", "")) if p
    )
    return env


def _tool_args(tool: str, path: Path) -> list:
    if tool == "mcap_play":
        return [tool, path, "--as-fast-as-possible", "--wait-timeout", "1"]
    return [tool, path]


def test_canary_works(bags, subprocess_env):
    """The canary module does write its marker when something imports it."""
    env = _env(subprocess_env, bags)
    subprocess.run([sys.executable, "-c", f"import {CANARY}"], env=env, check=True)
    assert bags["marker"].exists()
    bags["marker"].unlink()


HOSTILE = [
    "type_unknown_pkg",
    "type_dotted",
    "type_dotdot",
    "type_short",
    "type_os",
    "bomb_zstd_declared",
    "bomb_zstd_actual",
    "bomb_lz4_declared",
    "bomb_lz4_actual",
    "corrupt_zstd",
    "corrupt_none_no_summary",
    "corrupt_length",
    "topic_double_slash",
    "topic_digit",
    "topic_space",
    "topic_trailing",
    "topic_newline",
    "qos_depth_1e12",
    "qos_depth_negative",
    "qos_garbage",
    "qos_not_list",
    "qos_bad_policy",
    "qos_negative_duration",
    "qos_huge",
]

#: Words the one line must contain, per kind of file.
WORDS = {
    "type": "unknown type",
    "bomb": "chunk at offset",
    "corrupt": "at offset",
    "topic": "topic name",
    "qos": "offered_qos_profiles",
}


@pytest.mark.parametrize("tool", TOOLS)
def test_hostile_files(tool, bags, subprocess_env):
    env = _env(subprocess_env, bags)
    failures = []
    for name in HOSTILE:
        path = bags[name]
        run = run_measured(_tool_args(tool, path), env, timeout=60)
        kind = name.split("_")[0]
        expected_code = 0 if (tool == "mcap_info" and kind == "type") else 2
        lines = run.err_lines
        problems = []
        if run.returncode != expected_code:
            problems.append(f"exit {run.returncode}")
        if len(lines) != 1:
            problems.append(f"{len(lines)} stderr lines")
        elif not (str(path) in lines[0] and WORDS[kind] in lines[0]):
            problems.append("line lacks the path or the reason")
        if "Traceback" in run.stderr:
            problems.append("traceback")
        if run.max_rss_mb > MAX_RSS_MB:
            problems.append(f"peak RSS {run.max_rss_mb:.0f} MB")
        if bags["marker"].exists():
            problems.append("the canary was imported")
        if problems:
            failures.append(f"{name}: {', '.join(problems)}: {run.stderr.strip()[:300]!r}")
        print(f"{tool} {name}: exit {run.returncode}, {run.max_rss_mb:.0f} MB, {lines[:1]}")
    assert not failures, "\n".join(failures)


def test_truncated_file(bags, subprocess_env):
    """Cut in the middle of the last chunk: every tool reads the complete chunks,
    says so in one warning line and exits 0."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    path = bags["truncated"]
    complete = 0
    with open(path, "rb") as handle:  # mcap's own streaming reader: up to the torn chunk
        try:
            for record in StreamReader(handle).records:
                complete += isinstance(record, Message)
        except Exception:
            pass
    assert 500 < complete < 600
    env = _env(subprocess_env, bags)
    expect = {
        "mcap_info": f"/imu/adc [mems_msgs/msg/AdcFrame] {complete} msgs",
        "mcap_play": f"published {complete} messages",
        "identify_noise": f"/imu/adc, {complete} frames",
    }
    for tool in TOOLS:
        run = run_measured(_tool_args(tool, path), env, timeout=120)
        assert run.returncode == 0, (tool, run.stderr)
        assert len(run.err_lines) == 1 and "truncated" in run.err_lines[0], (tool, run.stderr)
        assert str(path) in run.err_lines[0]
        assert expect[tool] in run.stdout, (tool, run.stdout)
        assert run.max_rss_mb < MAX_RSS_MB, (tool, run.max_rss_mb)


def test_in_process_readers_never_import(bags, monkeypatch):
    """The library path: unknown types are skipped and reported, never imported."""
    from mems_sim.bag.player import iter_messages, read_messages, recorded_topics
    from mems_sim.bag.schema import SchemaError, message_class

    monkeypatch.syspath_prepend(str(bags["canary_dir"]))
    for name in ("type_unknown_pkg", "type_dotted", "type_dotdot", "type_short"):
        path = str(bags[name])
        type_name = recorded_topics(path)["/imu/adc"][0]
        with pytest.raises(SchemaError, match="unknown type"):
            message_class(type_name)
        skipped = []
        got = list(read_messages(path, on_unknown=lambda p, t, r: skipped.append((t, r))))
        assert got == [] and skipped and skipped[0][0] == "/imu/adc", skipped
        assert len(list(iter_messages(path))) == 20  # raw bytes still readable
    assert CANARY not in sys.modules and not bags["marker"].exists()


def test_reference_bags_still_read(bags):
    """The guards accept what this package and rosbag2-style writers produce."""
    from mems_sim.bag.info import bag_info
    from mems_sim.bag.player import read_messages

    repo = Path(__file__).resolve().parents[3]
    info = bag_info(str(repo / "bags" / "imu.mcap"))
    assert info["has_summary"] and not info["truncated"]
    assert sum(1 for _ in read_messages(str(repo / "bags" / "imu.mcap"), ["/imu/adc"])) == 600

"""Defensive MCAP reading shared by ``mcap_play``, ``mcap_info`` and ``identify_noise``.

A bag is data from elsewhere, so everything a file declares is checked before
it is trusted:

* Records are parsed by this module (with the record layouts of
  :mod:`mcap.records`), never by mcap's readers, whose chunk decompression
  sizes its output buffer from the chunk's declared ``uncompressed_size``.
  Here a chunk may expand to at most :data:`MAX_CHUNK_BYTES`: a larger
  declared size is refused before anything is decompressed, and the
  decompressor is a streaming one that stops one byte past the declared size,
  so a small compressed bomb costs at most that much memory. The
  uncompressed CRC is checked whenever the writer stored one (non-zero).
* A record that ends past the end of the file, or a file that ends without a
  Footer, is *truncated* (a writer that was killed or ran out of disk): it is
  read up to its last complete chunk and reported once. A record that is
  complete but cannot be decoded (bad CRC, undecodable compressed data,
  inner records running past their chunk, bad field encoding, an oversized
  record) is *corrupt*: :class:`BagReadError` with a one-line message.
* Every channel is checked (:func:`check_channel`): the topic must be a fully
  qualified ROS topic name, and the ``offered_qos_profiles`` metadata must be a
  small YAML list of profiles with known policy values, a depth in
  ``[0, MAX_QOS_DEPTH]`` and non-negative durations (rosbag2's layout).
* Type names are only ever imported through
  :func:`mems_sim.bag.schema.message_class`, which accepts nothing but
  interface packages of the ament index (see there).

The Summary section is read by :func:`read_summary` from the Footer's
``summary_start``; a missing or damaged Summary makes the readers fall back to
a sequential scan (:func:`iter_stream_records`).

A bag is a single ``.mcap`` file or a rosbag2 bag directory (a recording split
by size or duration): :func:`bag_files` lists its files in the order of
``relative_file_paths`` in its ``metadata.yaml`` (rosbag2's
``rosbag2_bagfile_information``), or, without one, its ``*.mcap`` files sorted
naturally (``x_2.mcap`` before ``x_10.mcap``). Listed paths must stay inside the
directory; each file is a complete MCAP file, checked as above.
"""

from __future__ import annotations

import io
import os
import re
import signal
import stat
import struct
import sys
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    Schema,
    Statistics,
)

from mems_sim import bounded_yaml

MAGIC = b"\x89MCAP0\r\n"

#: Largest uncompressed chunk accepted [bytes]. rosbag2 writes chunks of about
#: 768 KiB and this package 1 MiB; a chunk only grows past that when a single
#: message is larger.
MAX_CHUNK_BYTES = 256 << 20

#: Largest Message record outside a chunk, and largest Chunk record [bytes].
MAX_DATA_RECORD_BYTES = MAX_CHUNK_BYTES + (1 << 20)

#: Largest Header, Schema, Channel, Statistics or index record [bytes].
MAX_META_RECORD_BYTES = 16 << 20

#: Largest ``offered_qos_profiles`` metadata value [bytes] and number of profiles.
MAX_QOS_YAML_BYTES = 64 << 10
MAX_QOS_PROFILES = 1024

#: Largest history depth accepted in ``offered_qos_profiles``.
MAX_QOS_DEPTH = 100_000

#: Largest topic name [characters].
MAX_TOPIC_LENGTH = 1024

#: Name of a bag directory's metadata file (rosbag2) and the largest one accepted [bytes].
METADATA_NAME = "metadata.yaml"
MAX_METADATA_BYTES = 4 << 20

_HEADER = struct.Struct("<BQ")
_FOOTER_RECORD_SIZE = 9 + 8 + 8 + 4

_PARSERS = {
    Opcode.HEADER: Header.read,
    Opcode.FOOTER: Footer.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.CHUNK_INDEX: ChunkIndex.read,
    Opcode.STATISTICS: Statistics.read,
    Opcode.DATA_END: DataEnd.read,
}
_DATA_OPCODES = (Opcode.CHUNK, Opcode.MESSAGE)


class BagReadError(Exception):
    """The file is missing, unreadable, not MCAP, corrupt or hostile (message is one line)."""


def one_line(text: object, limit: int = 300) -> str:
    """``text`` on one line (whitespace runs collapsed), cut to ``limit`` characters."""
    flat = " ".join(str(text).split())
    return flat if len(flat) <= limit else flat[: limit - 3] + "..."


def shown(value: str, limit: int = 80) -> str:
    """A file-provided string for a one-line message: quoted, escaped, shortened."""
    text = repr(value[:limit])
    return text + ("..." if len(value) > limit else "")


def open_bag(path: str):
    """Open ``path`` for binary reading; raise :class:`BagReadError` (one line) if impossible or not MCAP."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise BagReadError(f"{path}: no such file") from None
    except OSError as exc:
        raise BagReadError(f"{path}: cannot open ({exc.strerror})") from None
    if stat.S_ISDIR(info.st_mode):
        raise BagReadError(f"{path}: is a directory, not an MCAP file")
    if not stat.S_ISREG(info.st_mode):
        raise BagReadError(f"{path}: not a regular file")
    try:
        handle = open(path, "rb")
    except OSError as exc:
        raise BagReadError(f"{path}: cannot open ({exc.strerror})") from None
    magic = handle.read(8)
    handle.seek(0)
    if magic != MAGIC:
        handle.close()
        raise BagReadError(f"{path}: not an MCAP file (bad magic)")
    return handle


def _natural_key(name: str) -> list:
    """Sort key that orders the digit runs of a name by value (``x_2`` before ``x_10``)."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", name) if t]


def bag_metadata(directory: str) -> dict | None:
    """``rosbag2_bagfile_information`` of a bag directory's ``metadata.yaml`` (None: no such
    file), read by :mod:`mems_sim.bounded_yaml` (at most :data:`MAX_METADATA_BYTES`);
    :class:`BagReadError` (one line) for a file that is unreadable, too large or not
    rosbag2's layout. Shared with :mod:`mems_sim.bag.foreign` (sqlite3 bags)."""
    meta = os.path.join(directory, METADATA_NAME)
    try:
        size = os.stat(meta).st_size
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise BagReadError(f"{meta}: cannot open ({exc.strerror})") from None
    if size > MAX_METADATA_BYTES:
        raise BagReadError(f"{meta}: {size} bytes (limit {MAX_METADATA_BYTES})")
    import yaml

    try:
        doc = bounded_yaml.load(bounded_yaml.read_text(meta, MAX_METADATA_BYTES))
    except (OSError, yaml.YAMLError, ValueError, RecursionError) as exc:
        raise BagReadError(f"{meta}: unreadable ({one_line(exc, 120)})") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise BagReadError(f"{meta}: no rosbag2_bagfile_information mapping")
    return info


def _listed_files(directory: str) -> list[str] | None:
    """``relative_file_paths`` of the directory's ``metadata.yaml`` (None: no such file or
    no such list); raises :class:`BagReadError` for a metadata file that
    :func:`bag_metadata` refuses, of another storage than MCAP, or that lists a path
    outside the directory."""
    meta = os.path.join(directory, METADATA_NAME)
    info = bag_metadata(directory)
    if info is None:
        return None
    storage = info.get("storage_identifier")
    if storage is not None and str(storage) != "mcap":
        raise BagReadError(f"{meta}: storage {shown(str(storage))} is not MCAP")
    paths = info.get("relative_file_paths")
    if paths is None:
        return None
    if not isinstance(paths, list) or not all(isinstance(p, str) and p for p in paths):
        raise BagReadError(f"{meta}: relative_file_paths is not a list of file names")
    out = []
    for rel in paths:
        norm = os.path.normpath(rel)
        if os.path.isabs(norm) or norm == ".." or norm.startswith(".." + os.sep):
            raise BagReadError(f"{meta}: {shown(rel)} is outside the bag directory")
        out.append(norm)
    return out


def bag_files(path: str) -> list[str]:
    """The MCAP files of a bag, in recording order.

    A path that is not a directory is the bag itself (``[path]``; :func:`open_bag`
    checks it). A rosbag2 bag directory gives its ``metadata.yaml``'s
    ``relative_file_paths``, or, without that list, its ``*.mcap`` files sorted
    naturally. Raises :class:`BagReadError` (one line) for a bad ``metadata.yaml``
    and for a directory without bag files.
    """
    try:
        info = os.stat(path)
    except OSError:
        return [path]
    if not stat.S_ISDIR(info.st_mode):
        return [path]
    names = _listed_files(path)
    if not names:
        try:
            entries = os.listdir(path)
        except OSError as exc:
            raise BagReadError(f"{path}: cannot list the directory ({exc.strerror})") from None
        names = sorted(
            (n for n in entries if n.endswith(".mcap") and os.path.isfile(os.path.join(path, n))),
            key=_natural_key,
        )
    if not names:
        raise BagReadError(
            f"{path}: a directory without bag files ({METADATA_NAME} lists none, no *.mcap)"
        )
    return [os.path.join(path, n) for n in names]


def _file_size(handle) -> int:
    return os.fstat(handle.fileno()).st_size


def _limit(opcode: int) -> int:
    return MAX_DATA_RECORD_BYTES if opcode in _DATA_OPCODES else MAX_META_RECORD_BYTES


def _parse(opcode: int, body: bytes, path: str, offset: int):
    """Decode one record body; :class:`BagReadError` when it does not decode."""
    stream = ReadDataStream(io.BytesIO(body))
    try:
        if opcode == Opcode.MESSAGE:
            record = Message.read(stream, len(body))
        else:
            record = _PARSERS[opcode](stream)
    except Exception as exc:  # any decoding failure of file data: struct, EOF, UTF-8, ...
        name = Opcode(opcode).name
        raise BagReadError(
            f"{path}: corrupt {name} record at offset {offset} ({one_line(exc, 120)})"
        ) from None
    if stream.count > len(body):  # pragma: no cover - ReadDataStream stops at the end
        raise BagReadError(f"{path}: corrupt {Opcode(opcode).name} record at offset {offset}")
    return record


# ---------------------------------------------------------------- chunks


#: Chunk compressions :func:`expand` decodes: MCAP's (zstd, lz4) and ROS 1's (bz2, lz4).
COMPRESSIONS = ("", "none", "zstd", "lz4", "bz2")


def expand(data: bytes, compression: str, limit: int, where: str) -> bytes:
    """``data`` decompressed, at most ``limit`` bytes of output ever held.

    The decompressor is a streaming one asked for ``limit + 1`` bytes, so a small
    compressed bomb costs at most that much memory; output past ``limit`` raises
    :class:`BagReadError` (``where`` names the chunk or row), as does damaged or
    incomplete input and a compression outside :data:`COMPRESSIONS`. Shared by the MCAP
    chunks of this module and the ROS 1 chunks and sqlite3 rows of
    :mod:`mems_sim.bag.foreign`.
    """
    try:
        if compression in ("", "none"):
            out = bytes(data[: limit + 1])
        elif compression == "zstd":
            out = _expand_zstd(data, limit)
        elif compression in ("lz4", "bz2"):
            out = _expand_incremental(data, compression, limit, where)
        else:
            raise BagReadError(f"{where}: unsupported compression {shown(compression)}")
    except BagReadError:
        raise
    except Exception as exc:  # zstd/lz4/bz2 errors on damaged input
        raise BagReadError(
            f"{where}: {compression} data does not decompress ({one_line(exc, 120)})"
        ) from None
    if len(out) > limit:
        raise BagReadError(f"{where} expands past {limit} bytes (decompression bomb?); refused")
    return out


def _accumulate(read, limit: int) -> bytes:
    """Pieces of at most 1 MiB from ``read(n)`` until it returns nothing or ``limit + 1``
    bytes came. Gathered in a BytesIO, whose ``getvalue`` hands over its buffer without a
    copy: the peak is about 1.1 times the output, not twice (a list joined at the end)."""
    out, total = io.BytesIO(), 0
    while total <= limit:
        part = read(min(limit + 1 - total, 1 << 20))
        if not part:
            break
        out.write(part)
        total += len(part)
    return out.getvalue()


def _expand_zstd(data: bytes, limit: int) -> bytes:
    """The zstd frames of ``data``, up to ``limit + 1`` bytes."""
    import zstandard

    reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True)
    return _accumulate(reader.read, limit)


def _expand_incremental(data: bytes, compression: str, limit: int, where: str) -> bytes:
    """One lz4 frame or bz2 stream of ``data``, up to ``limit + 1`` bytes."""
    if compression == "lz4":
        import lz4.frame

        decompressor = lz4.frame.LZ4FrameDecompressor()
    else:
        import bz2

        decompressor = bz2.BZ2Decompressor()
    pending = [data]

    def read(n: int) -> bytes:
        if decompressor.eof:
            return b""
        return decompressor.decompress(pending.pop() if pending else b"", max_length=n)

    out = _accumulate(read, limit)
    if len(out) <= limit and not decompressor.eof:
        raise BagReadError(f"{where}: {compression} data is incomplete")
    return out


def _decompress(chunk: Chunk, path: str, offset: int) -> bytes:
    """The records bytes of a chunk, never more than its declared size (<= MAX_CHUNK_BYTES)."""
    declared = chunk.uncompressed_size
    where = f"{path}: chunk at offset {offset}"
    if declared > MAX_CHUNK_BYTES:
        raise BagReadError(
            f"{where} declares {declared} uncompressed bytes "
            f"(limit {MAX_CHUNK_BYTES}); refusing to decompress it"
        )
    if chunk.compression == "bz2":  # not an MCAP compression
        raise BagReadError(f"{where}: unsupported compression 'bz2'")
    data = expand(chunk.data, chunk.compression, declared, f"{where} (declared {declared} bytes)")
    if len(data) != declared:
        raise BagReadError(f"{where}: {len(data)} bytes decompressed, {declared} declared")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise BagReadError(f"{where}: CRC mismatch (corrupt chunk)")
    return data


def decode_chunk(chunk: Chunk, path: str = "", offset: int = 0) -> list:
    """Schema, Channel and Message records of a chunk (other inner records are skipped)."""
    data = _decompress(chunk, path, offset)
    view = memoryview(data)
    records, pos, end = [], 0, len(data)
    while pos < end:
        if end - pos < _HEADER.size:
            raise BagReadError(f"{path}: chunk at offset {offset}: torn record inside the chunk")
        opcode, length = _HEADER.unpack_from(view, pos)
        body_start = pos + _HEADER.size
        if length > end - body_start:
            raise BagReadError(
                f"{path}: chunk at offset {offset}: record runs past the end of the chunk"
            )
        if opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
            records.append(
                _parse(opcode, bytes(view[body_start : body_start + length]), path, offset)
            )
        pos = body_start + length
    return records


def read_chunk_at(handle, index: ChunkIndex, path: str = "") -> list:
    """Decoded records of the chunk that a ChunkIndex points to (checked against the file)."""
    size = _file_size(handle)
    offset = index.chunk_start_offset
    if offset < 8 or offset + _HEADER.size > size:
        raise BagReadError(f"{path}: chunk index points outside the file (offset {offset})")
    handle.seek(offset)
    opcode, length = _HEADER.unpack(handle.read(_HEADER.size))
    if opcode != Opcode.CHUNK:
        raise BagReadError(f"{path}: chunk index points to a non-chunk record (offset {offset})")
    if length > MAX_DATA_RECORD_BYTES:
        raise BagReadError(
            f"{path}: chunk at offset {offset} is {length} bytes (limit {MAX_DATA_RECORD_BYTES})"
        )
    if offset + _HEADER.size + length > size:
        raise BagReadError(f"{path}: chunk at offset {offset} runs past the end of the file")
    chunk = _parse(opcode, handle.read(length), path, offset)
    return decode_chunk(chunk, path, offset)


# ---------------------------------------------------------------- summary


@dataclass
class BagSummary:
    """The Summary section: schemas, channels, chunk indexes and statistics (None if absent)."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    statistics: Statistics | None = None


def read_footer(handle) -> Footer | None:
    """The Footer record, or None when the file does not end with Footer + magic."""
    size = _file_size(handle)
    if size < 8 + _FOOTER_RECORD_SIZE + 8:
        return None
    handle.seek(size - _FOOTER_RECORD_SIZE - 8)
    tail = handle.read(_FOOTER_RECORD_SIZE + 8)
    if tail[-8:] != MAGIC:
        return None
    opcode, length = _HEADER.unpack_from(tail, 0)
    if opcode != Opcode.FOOTER or length != _FOOTER_RECORD_SIZE - 9:
        return None
    try:
        return Footer.read(ReadDataStream(io.BytesIO(tail[9:-8])))
    except Exception:
        return None


def read_summary(handle, path: str = "") -> BagSummary | None:
    """The Summary section, or None when the file has none or it does not parse.

    Chunk or Message records inside the Summary section are skipped, never decoded.
    """
    footer = read_footer(handle)
    if footer is None or footer.summary_start == 0:
        return None
    end = _file_size(handle) - _FOOTER_RECORD_SIZE - 8
    if not 8 <= footer.summary_start <= end:
        return None
    summary = BagSummary()
    pos = footer.summary_start
    handle.seek(pos)
    try:
        while pos < end:
            if end - pos < _HEADER.size:
                return None
            opcode, length = _HEADER.unpack(handle.read(_HEADER.size))
            if length > end - pos - _HEADER.size:
                return None
            if opcode in _PARSERS and opcode not in _DATA_OPCODES:
                if length > MAX_META_RECORD_BYTES:
                    return None
                record = _parse(opcode, handle.read(length), path, pos)
                if isinstance(record, Schema):
                    summary.schemas[record.id] = record
                elif isinstance(record, Channel):
                    summary.channels[record.id] = record
                elif isinstance(record, ChunkIndex):
                    summary.chunk_indexes.append(record)
                elif isinstance(record, Statistics):
                    summary.statistics = record
            else:
                handle.seek(length, os.SEEK_CUR)
            pos += _HEADER.size + length
    except BagReadError:
        return None
    return summary


# ---------------------------------------------------------------- sequential scan


def iter_stream_records(
    handle, path: str = "", on_chunk: Callable[[Chunk], None] | None = None
) -> Iterator[tuple[object, bool]]:
    """Yield ``(record, False)`` for the records of an MCAP file in file order, chunks expanded.

    Yields Header, Schema, Channel, Message, Statistics and Footer records (the
    contents of chunks in their place; ``on_chunk`` sees each Chunk before its
    contents). A file that ends inside a record, or without a Footer, was cut
    short: then ``(None, True)`` is yielded once at the end. A corrupt record
    raises :class:`BagReadError`; so does a record running past the end of a file
    that does end with a Footer (its length field is damaged: nothing was cut).
    """
    size = _file_size(handle)
    complete = read_footer(handle) is not None
    handle.seek(0)
    if handle.read(8) != MAGIC:
        raise BagReadError(f"{path}: not an MCAP file (bad magic)")
    pos = 8
    while True:
        head = handle.read(_HEADER.size)
        body_start = pos + _HEADER.size
        opcode, length = _HEADER.unpack(head) if len(head) == _HEADER.size else (0, size)
        if length > size - body_start:
            if complete:
                raise BagReadError(
                    f"{path}: corrupt record at offset {pos} (it runs past the end of the file)"
                )
            yield None, True  # the file was cut inside this record
            return
        if opcode in _PARSERS or opcode == Opcode.MESSAGE:
            if length > _limit(opcode):
                raise BagReadError(
                    f"{path}: {Opcode(opcode).name} record at offset {pos} is {length} bytes "
                    f"(limit {_limit(opcode)})"
                )
            if opcode == Opcode.CHUNK_INDEX:
                handle.seek(length, os.SEEK_CUR)
            else:
                record = _parse(opcode, handle.read(length), path, pos)
                if isinstance(record, Chunk):
                    if on_chunk is not None:
                        on_chunk(record)
                    for inner in decode_chunk(record, path, pos):
                        yield inner, False
                else:
                    yield record, False
                    if isinstance(record, Footer):
                        return
        else:
            handle.seek(length, os.SEEK_CUR)
        pos = body_start + length


# ---------------------------------------------------------------- channel checks

_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_TOPIC_RE = re.compile(rf"/{_TOKEN}(?:/{_TOKEN})*")

_HISTORY = {"system_default": 0, "keep_last": 1, "keep_all": 2, "unknown": 3}
_RELIABILITY = {
    "system_default": 0,
    "reliable": 1,
    "best_effort": 2,
    "unknown": 3,
    "best_available": 4,
}
_DURABILITY = {
    "system_default": 0,
    "transient_local": 1,
    "volatile": 2,
    "unknown": 3,
    "best_available": 4,
}
_LIVELINESS = {
    "system_default": 0,
    "automatic": 1,
    "manual_by_node": 2,
    "manual_by_topic": 3,
    "unknown": 4,
    "best_available": 5,
}
_POLICIES = {
    "history": _HISTORY,
    "reliability": _RELIABILITY,
    "durability": _DURABILITY,
    "liveliness": _LIVELINESS,
}
_DURATIONS = ("deadline", "lifespan", "liveliness_lease_duration")


def topic_name_problem(topic: str) -> str | None:
    """Why ``topic`` is not a fully qualified ROS topic name (rmw's rules), or None.

    ``/`` then tokens of letters, digits and ``_`` separated by single ``/``; no
    token starts with a digit; no trailing ``/``.
    """
    if not isinstance(topic, str) or not topic:
        return "empty topic name"
    if len(topic) > MAX_TOPIC_LENGTH:
        return f"topic name longer than {MAX_TOPIC_LENGTH} characters"
    if _TOPIC_RE.fullmatch(topic) is None:
        return f"invalid topic name {shown(topic)}"
    return None


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def qos_yaml_problem(text: str) -> str | None:
    """Why an ``offered_qos_profiles`` value is unusable, or None (empty means no profiles).

    Accepted: a YAML list of mappings as rosbag2 writes them, policies as names
    (any case) or enum integers, ``depth`` an integer in ``[0, MAX_QOS_DEPTH]``,
    durations ``{sec, nsec}`` with non-negative integers, unknown keys ignored.
    """
    if not text:
        return None
    if len(text) > MAX_QOS_YAML_BYTES:
        return f"offered_qos_profiles is {len(text)} bytes (limit {MAX_QOS_YAML_BYTES})"

    try:
        entries = bounded_yaml.load(text)
    except Exception as exc:  # any YAML error
        return f"offered_qos_profiles is not YAML ({one_line(exc, 80)})"
    if entries is None:
        return None
    if not isinstance(entries, list):
        return "offered_qos_profiles is not a list of QoS profiles"
    if len(entries) > MAX_QOS_PROFILES:
        return f"offered_qos_profiles has {len(entries)} profiles (limit {MAX_QOS_PROFILES})"
    for entry in entries:
        if not isinstance(entry, dict):
            return "offered_qos_profiles entry is not a mapping"
        for key, names in _POLICIES.items():
            if key not in entry:
                continue
            value = entry[key]
            ok = (_is_int(value) and value in names.values()) or (
                isinstance(value, str) and value.lower() in names
            )
            if not ok:
                return f"offered_qos_profiles {key} {shown(str(value), 40)} is not a QoS policy"
        if "depth" in entry:
            depth = entry["depth"]
            if not _is_int(depth) or not 0 <= depth <= MAX_QOS_DEPTH:
                return (
                    f"offered_qos_profiles depth {shown(str(depth), 40)} is absurd "
                    f"(allowed integers 0..{MAX_QOS_DEPTH})"
                )
        for key in _DURATIONS:
            value = entry.get(key)
            if value is None:
                continue
            if not isinstance(value, dict):
                return f"offered_qos_profiles {key} is not {{sec, nsec}}"
            sec, nsec = value.get("sec", 0), value.get("nsec", 0)
            if not (_is_int(sec) and _is_int(nsec) and 0 <= sec < 2**63 and 0 <= nsec < 2**32):
                return f"offered_qos_profiles {key} {shown(str(value), 60)} is absurd"
        avoid = entry.get("avoid_ros_namespace_conventions", False)
        if not isinstance(avoid, bool):
            return "offered_qos_profiles avoid_ros_namespace_conventions is not a boolean"
    return None


def check_channel(path: str, channel: Channel) -> None:
    """Raise :class:`BagReadError` (one line) for an invalid topic name or absurd QoS metadata."""
    problem = topic_name_problem(channel.topic)
    if problem is None:
        metadata = channel.metadata or {}
        problem = qos_yaml_problem(metadata.get("offered_qos_profiles", ""))
        if problem is not None:
            problem = f"channel {shown(channel.topic)}: {problem}"
    else:
        problem = f"channel {channel.id}: {problem}"
    if problem is not None:
        raise BagReadError(f"{path}: {problem}")


# ---------------------------------------------------------------- reporting

_reported: set[tuple[str, str]] = set()


def warn_once(path: str, text: str) -> None:
    """Print ``<program>: warning: <path>: <text>`` on stderr, once per (path, text) and process."""
    key = (str(path), text)
    if key in _reported:
        return
    _reported.add(key)
    program = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "mems_sim"
    print(f"{program}: warning: {path}: {one_line(text)}", file=sys.stderr, flush=True)


TRUNCATED_TEXT = (
    "file is truncated (no Summary, it ends inside or after a record without a Footer): "
    "read up to the last complete chunk"
)


def warn_truncated(path: str) -> None:
    """Default report of a truncated file (one line on stderr, once per path)."""
    warn_once(path, TRUNCATED_TEXT)


def closed_pipe_exit() -> int:
    """Exit status after stdout's reader went away (``mcap_info BAG | head -1``).

    Call it on :class:`BrokenPipeError`.
    As the Python documentation's note on SIGPIPE recommends, stdout is pointed at
    ``os.devnull`` so that the interpreter's final flush does not fail again; the status
    is 128 + SIGPIPE (141), what a shell reports for a program that SIGPIPE ended.
    """
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass
    return 128 + signal.SIGPIPE

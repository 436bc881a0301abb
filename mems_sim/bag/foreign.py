"""Bounded reading of the bags this project reads through rosbags: ROS 1 bags (``.bag``) and
rosbag2 sqlite3 bags (a directory with ``metadata.yaml``, or its ``.db3`` file).

rosbags decompresses without a bound (ROS 1 chunks with ``bz2.decompress`` and
``lz4.frame.decompress``, rosbag2 messages with ``zstd.decompress``, a file-compressed
bag copied out whole), reads record lengths from the file before checking them against
it, and raises many types (``AssertionError``, ``KeyError``, ``apsw`` errors, ...). It has
no hook for a size cap, so this module checks what a file declares before rosbags reads
it and decompresses in its place:

* **ROS 1**: every top-level record (``header_len``, header, ``data_len``, data) is walked
  first (:func:`scan_ros1`): each must lie inside the file; each chunk's ``size`` header
  field (its uncompressed size) at most :data:`~mems_sim.bag.reader.MAX_CHUNK_BYTES`, the
  MCAP path's limit; each chunk-info record must point at a chunk followed by the index
  records it counts, in the 47-byte layout rosbags parses by fixed offsets; ``index_pos``
  at a record. Then each chunk's decompressor in rosbags' reader is replaced by
  :func:`mems_sim.bag.reader.expand` capped at the declared size (output must equal it).
* **sqlite3**: ``metadata.yaml`` is read by :mod:`mems_sim.bounded_yaml` first; the
  listed files must be regular files inside the directory. Per-message compression
  (``compression_mode: message``) is turned off in rosbags' reader after it opened and
  each row is expanded here (at most ``MAX_CHUNK_BYTES``); a file-compressed bag
  (``compression_mode: file``) is expanded here into a temporary bag directory, each file
  at most :data:`MAX_EXPANSION_RATIO` times its size (at least
  :data:`MIN_EXPANDED_FILE_BYTES`, at most :data:`MAX_EXPANDED_FILE_BYTES`), before
  rosbags opens that.

Every read and decode, opening and iteration alike, is inside one error path:
:class:`~mems_sim.bag.reader.BagReadError` with one line (whatever rosbags, sqlite or the
decompressors raise, MemoryError and RecursionError included). Type definitions come
from the bag or from rosbags' typestore; nothing a file names is imported.
"""

from __future__ import annotations

import contextlib
import os
import stat
import struct
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from mems_sim.bag.reader import (
    MAX_CHUNK_BYTES,
    BagReadError,
    bag_metadata,
    expand,
    one_line,
    shown,
)
from mems_sim.stream_index import DuplicateFilter

#: Largest file of a file-compressed rosbag2 bag once expanded [bytes] (written to a
#: temporary directory, never held in memory) ...
MAX_EXPANDED_FILE_BYTES = 4 << 30
#: ... and at most this many times its compressed size (zstd gives a bag 2 to 10), but
#: always up to MIN_EXPANDED_FILE_BYTES, so a small bomb cannot fill the disk.
MAX_EXPANSION_RATIO = 200
MIN_EXPANDED_FILE_BYTES = 256 << 20

ROS1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
_U32 = struct.Struct("<I")
#: ROS 1 record ops.
_OP_CHUNK, _OP_INDEX, _OP_CHUNK_INFO, _OP_BAG_HEADER = 5, 4, 6, 3
#: Header length of an index-data record (op, ver, conn, count), as rosbags parses it.
_INDEX_HEADER_LEN = 47
_ROS1_COMPRESSIONS = ("none", "bz2", "lz4")


def _fail(path: Path, exc: BaseException) -> BagReadError:
    """A one-line error for anything rosbags or the libraries below it raised."""
    if isinstance(exc, BagReadError):
        return exc
    text = one_line(exc, 160) or type(exc).__name__
    return BagReadError(f"{path}: not a bag rosbags can read ({type(exc).__name__}: {text})")


# ---------------------------------------------------------------- ROS 1


@dataclass
class _Ros1Chunk:
    compression: str
    size: int  # uncompressed [bytes]
    indexes: int  # index-data records right after it


def _fields(header: bytes, where: str) -> dict[str, bytes]:
    """The ``name=value`` fields of a ROS 1 record header."""
    fields, pos = {}, 0
    while pos < len(header):
        if len(header) - pos < 4:
            raise BagReadError(f"{where}: torn header field")
        (size,) = _U32.unpack_from(header, pos)
        pos += 4
        if size > len(header) - pos:
            raise BagReadError(f"{where}: header field runs past its header")
        name, sep, value = header[pos : pos + size].partition(b"=")
        if not sep:
            raise BagReadError(f"{where}: header field without '='")
        fields[name.decode("latin-1")] = value
        pos += size
    return fields


def _u(fields: dict[str, bytes], name: str, fmt: str, where: str) -> int:
    value = fields.get(name)
    if value is None or len(value) != struct.calcsize(fmt):
        raise BagReadError(f"{where}: no valid {name!r} field")
    return struct.unpack(fmt, value)[0]


def ros1_records(handle, size: int, path: Path) -> Iterator[tuple[int, int, dict, int, int]]:
    """``(offset, op, fields, header_len, data_len)`` of every top-level record, each
    checked to lie inside the file."""
    pos = len(ROS1_MAGIC)
    while pos < size:
        where = f"{path}: record at offset {pos}"
        handle.seek(pos)
        if size - pos < 4:
            raise BagReadError(f"{where}: torn record (truncated bag)")
        (header_len,) = _U32.unpack(handle.read(4))
        if header_len > size - pos - 8:
            raise BagReadError(f"{where}: header runs past the end of the file")
        fields = _fields(handle.read(header_len), where)
        (data_len,) = _U32.unpack(handle.read(4))
        if data_len > size - pos - 8 - header_len:
            raise BagReadError(f"{where}: data runs past the end of the file")
        op = fields.get("op", b"")
        if len(op) != 1:
            raise BagReadError(f"{where}: no valid 'op' field")
        yield pos, op[0], fields, header_len, data_len
        pos += 8 + header_len + data_len


def scan_ros1(path: Path) -> dict[int, _Ros1Chunk]:
    """Chunks of a ROS 1 bag by offset, after the checks of the module doc (one line,
    :class:`BagReadError`, for a bag that fails one)."""
    try:
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            if handle.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
                raise BagReadError(f"{path}: not a ROS 1 bag (no '#ROSBAG V2.0' line)")
            return _check_ros1(handle, size, path)
    except OSError as exc:
        raise BagReadError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _check_ros1(handle, size: int, path: Path) -> dict[int, _Ros1Chunk]:
    chunks: dict[int, _Ros1Chunk] = {}
    infos: list[tuple[int, int, int]] = []  # (offset, chunk_pos, connections)
    starts_at_index = index_pos = None
    last_chunk = None
    for pos, op, fields, header_len, data_len in ros1_records(handle, size, path):
        where = f"{path}: record at offset {pos}"
        if op == _OP_BAG_HEADER and index_pos is None:
            index_pos = _u(fields, "index_pos", "<Q", where)
        starts_at_index = starts_at_index or pos == index_pos
        if op == _OP_INDEX and last_chunk is not None:
            count = _u(fields, "count", "<I", where)
            if header_len != _INDEX_HEADER_LEN or data_len != 12 * count:
                raise BagReadError(f"{where}: index data of an unexpected layout")
            last_chunk.indexes += 1
            continue
        last_chunk = None
        if op == _OP_CHUNK:
            last_chunk = chunks[pos] = _ros1_chunk(fields, data_len, where)
        elif op == _OP_CHUNK_INFO:
            infos.append(
                (pos, _u(fields, "chunk_pos", "<Q", where), _u(fields, "count", "<I", where))
            )
    if index_pos is None:
        raise BagReadError(f"{path}: no bag header record")
    if chunks and not starts_at_index:
        raise BagReadError(f"{path}: index_pos {index_pos} is not the offset of a record")
    for pos, chunk_pos, connections in infos:
        chunk = chunks.get(chunk_pos)
        if chunk is None or chunk.indexes < connections:
            raise BagReadError(
                f"{path}: chunk info at offset {pos} points to no chunk with {connections} "
                f"index records (offset {chunk_pos})"
            )
    return chunks


def _ros1_chunk(fields: dict, data_len: int, where: str) -> _Ros1Chunk:
    compression = fields.get("compression", b"").decode("latin-1")
    declared = _u(fields, "size", "<I", where)
    if compression not in _ROS1_COMPRESSIONS:
        raise BagReadError(f"{where}: chunk compression {shown(compression)} is not supported")
    if declared > MAX_CHUNK_BYTES:
        raise BagReadError(
            f"{where}: chunk declares {declared} uncompressed bytes (limit {MAX_CHUNK_BYTES}); "
            "refusing to decompress it"
        )
    if compression == "none" and declared != data_len:
        raise BagReadError(f"{where}: uncompressed chunk of {data_len} bytes declares {declared}")
    return _Ros1Chunk(compression, declared, 0)


def _expand_chunk(data: bytes, compression: str, declared: int, where: str) -> bytes:
    """A ROS 1 chunk's records, exactly its declared size."""
    out = expand(data, compression, declared, where)
    if len(out) != declared:
        raise BagReadError(f"{where}: {len(out)} bytes decompressed, {declared} declared")
    return out


def _bound_chunks(reader, chunks: dict[int, _Ros1Chunk], path: Path) -> None:
    """Replace the decompressor of every chunk of rosbags' ROS 1 ``reader`` by a bounded one."""
    for pos, chunk in list(reader.chunks.items()):
        known = chunks[pos]  # scan_ros1 checked every chunk info's position
        bounded = partial(
            _expand_chunk,
            compression=known.compression,
            declared=known.size,
            where=f"{path}: chunk at offset {pos}",
        )
        reader.chunks[pos] = chunk._replace(decompressor=bounded)


# ---------------------------------------------------------------- rosbag2 sqlite3


def _regular_file(path: Path) -> None:
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise BagReadError(f"{path}: cannot open ({exc.strerror})") from None
    if not stat.S_ISREG(mode):
        raise BagReadError(f"{path}: not a regular file")


def rosbag2_metadata(directory: Path) -> dict:
    """``rosbag2_bagfile_information`` of a bag directory's ``metadata.yaml``
    (:func:`mems_sim.bag.reader.bag_metadata`, bounded); BagReadError (one line) if absent."""
    info = bag_metadata(str(directory))
    if info is None:
        raise BagReadError(f"{directory}: no metadata.yaml (not a rosbag2 bag directory)")
    return info


def _sqlite_files(directory: Path, info: dict) -> list[Path]:
    names = info.get("relative_file_paths")
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        raise BagReadError(f"{directory}/metadata.yaml: relative_file_paths is not a list of names")
    files = [directory / Path(n).name for n in names]  # rosbags reads the names only
    for name in files:
        _regular_file(name)
    return files


def _compression_mode(info: dict) -> str:
    mode = str(info.get("compression_mode") or "").lower()
    return "" if mode == "none" else mode


@contextlib.contextmanager
def _expanded_bag(directory: Path, info: dict, files: list[Path]) -> Iterator[Path]:
    """A temporary copy of a file-compressed bag with its files expanded (each at most
    :data:`MAX_EXPANDED_FILE_BYTES`) and ``compression_mode`` none."""
    import yaml
    import zstandard

    with tempfile.TemporaryDirectory(prefix="mems-bag-") as tmp:
        names = []
        for name in files:
            out = Path(tmp, name.stem)  # rosbags' name for the expanded file
            _expand_file(name, out, zstandard)
            names.append(out.name)
        copy = dict(info, relative_file_paths=names, compression_mode="", compression_format="")
        copy["files"] = []
        text = yaml.safe_dump({"rosbag2_bagfile_information": copy})
        Path(tmp, "metadata.yaml").write_text(text)
        yield Path(tmp)


def expanded_file_limit(compressed_bytes: int) -> int:
    """Most bytes a zstd file of ``compressed_bytes`` may expand to (module doc)."""
    ratio = MAX_EXPANSION_RATIO * compressed_bytes
    return min(MAX_EXPANDED_FILE_BYTES, max(MIN_EXPANDED_FILE_BYTES, ratio))


def _expand_file(src: Path, out: Path, zstandard) -> None:
    """``src`` (zstd) expanded into ``out`` in pieces of 1 MiB, up to its limit."""
    total = 0
    with open(src, "rb") as fin, open(out, "wb") as fout:
        limit = expanded_file_limit(os.fstat(fin.fileno()).st_size)
        reader = zstandard.ZstdDecompressor().stream_reader(fin, read_across_frames=True)
        while part := reader.read(1 << 20):
            total += len(part)
            if total > limit:
                raise BagReadError(
                    f"{src}: expands past {limit} bytes (decompression bomb?); refused"
                )
            fout.write(part)


# ---------------------------------------------------------------- one reader for both


def bag_format(path: Path) -> str:
    """``"mcap"``, ``"ros1"`` or ``"sqlite3"``: by a file's magic (a ``.db3`` file stands for
    its directory), by a directory's ``metadata.yaml`` storage, or a directory of
    ``*.mcap`` files; BagReadError (one line) for anything else."""
    if not path.exists():
        raise BagReadError(f"{path}: no such file or directory")
    if path.is_dir():
        if not (path / "metadata.yaml").exists():
            if any(path.glob("*.mcap")):
                return "mcap"
            raise BagReadError(f"{path}: a directory without metadata.yaml or *.mcap files")
        storage = str(rosbag2_metadata(path).get("storage_identifier", ""))
        if storage not in ("mcap", "sqlite3"):
            raise BagReadError(f"{path}: storage {shown(storage)} is neither mcap nor sqlite3")
        return storage
    _regular_file(path)
    with open(path, "rb") as handle:
        magic = handle.read(16)
    if magic.startswith(b"\x89MCAP"):
        return "mcap"
    if magic.startswith(ROS1_MAGIC):
        return "ros1"
    if magic == SQLITE_MAGIC:
        return "sqlite3"
    raise BagReadError(f"{path}: neither MCAP, a ROS 1 bag nor sqlite3 (by its first bytes)")


class ForeignBag:
    """An opened ROS 1 or sqlite3 bag (:func:`open_foreign`): :attr:`topics` and
    :meth:`messages`, every error one line."""

    def __init__(self, path: Path, reader, row_compression: str) -> None:
        self.path = path
        self._reader = reader
        self._rows = row_compression
        #: ``{topic: type name}``.
        self.topics = {c.topic: c.msgtype for c in reader.connections}

    def messages(
        self, topic: str, duplicates: DuplicateFilter | None = None
    ) -> Iterator[tuple[int, object]]:
        """``(log time [ns], message)`` of ``topic`` in the bag's order (log time), each
        deserialised with the bag's type definitions; a message ``duplicates`` has seen is
        skipped (counted there)."""
        reader = self._reader
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            return
        it = reader.messages(connections=conns)
        while True:
            try:
                item = next(it, None)
                if item is None:
                    return
                conn, log_ns, raw = item
                if self._rows:
                    where = f"{self.path}: message on {shown(topic)} at log time {log_ns}"
                    raw = expand(raw, self._rows, MAX_CHUNK_BYTES, where)
                if duplicates is not None and duplicates.seen(topic, log_ns, raw):
                    continue
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # rosbags, apsw, struct, bz2 ...: one line for all
                raise _fail(self.path, exc) from None
            yield int(log_ns), msg


@contextlib.contextmanager
def open_foreign(path: Path) -> Iterator[ForeignBag]:
    """The ROS 1 bag or rosbag2 sqlite3 bag at ``path`` (a ``.db3`` file: its directory),
    opened by rosbags after this module's checks (module doc); closed on exit."""
    with contextlib.ExitStack() as stack:
        try:
            bag = _open(path, stack)
        except Exception as exc:  # checks, expansion and rosbags alike: one line
            raise _fail(path, exc) from None
        yield bag


def _open(path: Path, stack: contextlib.ExitStack) -> ForeignBag:
    kind = bag_format(path)
    if kind == "mcap":
        raise BagReadError(f"{path}: an MCAP bag (read by mems_sim.bag.reading)")
    target, rows, chunks = path, "", None
    if kind == "ros1":
        chunks = scan_ros1(path)
    else:
        target = path.parent if path.is_file() else path
        info = rosbag2_metadata(target)
        files = _sqlite_files(target, info)
        mode = _compression_mode(info)
        if mode == "file":
            target = stack.enter_context(_expanded_bag(target, info, files))
        rows = "zstd" if mode == "message" else ""
    reader = _open_reader(target, kind)
    stack.callback(_close, reader)
    if chunks is not None:
        _bound_chunks(reader.readers[0], chunks, path)
    if rows:  # rosbags would zstd.decompress each row unbounded: ForeignBag does it
        directory = reader.readers[0].storage
        directory.metadata = directory.metadata._replace(compression_mode=None)
    return ForeignBag(path, reader, rows)


def _open_reader(target: Path, kind: str):
    """rosbags' AnyReader of ``target``, opened."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.LATEST)
    reader = AnyReader([target], default_typestore=store)
    reader.open()
    return reader


def _close(reader) -> None:
    with contextlib.suppress(Exception):
        reader.close()

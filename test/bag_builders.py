"""Bags written by rosbags (not by this project) for the tests of ``mems_sim.bag.foreign``:
``sensor_msgs/Imu`` in ROS 1 bags and rosbag2 sqlite3 bags, and a ROS 1 decompression bomb."""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import struct
from pathlib import Path

import numpy as np

from mems_sim.bag import foreign
from mems_sim.bag.reader import MAX_CHUNK_BYTES

TOPIC = "/imu/data_raw"
#: The first stamp and the interval of the written messages [ns] (100 Hz).
T0_NS, DT_NS = 10**9, 10**7


def imu_bag(
    path: Path,
    kind: str,
    n: int = 400,
    compression: str | None = None,
    repeat: int = 1,
    chunk: int = 4096,
) -> Path:
    """``n`` sensor_msgs/Imu messages (seeded white noise, 100 Hz) in a ROS 1 bag
    (``kind`` "ros1", ``compression`` None, "bz2" or "lz4", chunks of ``chunk`` bytes) or a rosbag2
    sqlite3 directory (``compression`` None, "message" or "file", zstd); each message
    written ``repeat`` times (identical topic, log time and bytes)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.LATEST)
    types, imu = store.types, "sensor_msgs/msg/Imu"
    rng = np.random.default_rng(1)
    if ros1:
        writer = Writer1(path)
        if compression:
            writer.set_compression(getattr(Writer1.CompressionFormat, compression.upper()))
        writer.chunk_threshold = chunk
    else:
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
        if compression:
            mode = getattr(CompressionMode, compression.upper())
            writer.set_compression(mode, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection(TOPIC, imu, typestore=store)
        for k in range(n):
            t = T0_NS + k * DT_NS
            sec, nsec = divmod(t, 10**9)
            header = dict(stamp=types["builtin_interfaces/msg/Time"](sec, nsec), frame_id="imu")
            if ros1:
                header["seq"] = k
            v = rng.normal(size=6)
            msg = types[imu](
                header=types["std_msgs/msg/Header"](**header),
                orientation=types["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=types["geometry_msgs/msg/Vector3"](*v[:3]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=types["geometry_msgs/msg/Vector3"](*v[3:]),
                linear_acceleration_covariance=np.zeros(9),
            )
            raw = store.serialize_ros1(msg, imu) if ros1 else store.serialize_cdr(msg, imu)
            for _ in range(repeat):
                writer.write(conn, t, raw)
    return path


def _header_fields(blob: bytes, start: int, length: int) -> dict[str, tuple[int, int]]:
    """Field name -> (offset, length) of the values of a ROS 1 record header at ``start``."""
    out, pos = {}, start
    while pos < start + length:
        (size,) = struct.unpack_from("<I", blob, pos)
        name, _, _ = blob[pos + 4 : pos + 4 + size].partition(b"=")
        out[name.decode()] = (pos + 4 + len(name) + 1, size - len(name) - 1)
        pos += 4 + size
    return out


def ros1_bomb(path: Path, declared: int) -> Path:
    """A ROS 1 bag of one bz2 chunk whose data is 256 bz2 streams of 16 MiB of zeros each
    (4 GiB for ``bz2.decompress``, about 20 KB on disk) and whose ``size`` field declares
    ``declared`` bytes; the bag header's ``index_pos`` follows the new chunk length."""
    import bz2

    imu_bag(path, "ros1", n=10, compression="bz2", chunk=1 << 20)
    blob = bytearray(path.read_bytes())
    (chunk_pos,) = foreign.scan_ros1(path)  # one chunk
    (header_len,) = struct.unpack_from("<I", blob, chunk_pos)
    fields = _header_fields(blob, chunk_pos + 4, header_len)
    size_at = fields["size"][0]
    blob[size_at : size_at + 4] = struct.pack("<I", declared)
    data_at = chunk_pos + 4 + header_len
    (old_len,) = struct.unpack_from("<I", blob, data_at)
    bomb = bz2.compress(bytes(16 << 20), 9) * 256
    blob[data_at : data_at + 4 + old_len] = struct.pack("<I", len(bomb)) + bomb
    (bag_header_len,) = struct.unpack_from("<I", blob, 13)
    index_at = _header_fields(blob, 17, bag_header_len)["index_pos"][0]
    (index_pos,) = struct.unpack_from("<Q", blob, index_at)
    blob[index_at : index_at + 8] = struct.pack("<Q", index_pos + len(bomb) - old_len)
    path.write_bytes(bytes(blob))
    return path


def rechunked_mcap(src: Path, out: Path, group: int = 50, copies: int = 1) -> Path:
    """The messages of the MCAP file ``src`` rewritten by mcap's Writer (zstd) in chunks of
    ``group`` messages in log-time order, each chunk stored ``copies`` times: with
    ``copies=2``, a bag whose chunks are all stored twice (same messages, same chunking)."""
    from mcap.writer import CompressionType, Writer

    from mems_sim.bag.reading import iter_raw

    records = list(iter_raw(str(src)))
    with open(out, "wb") as handle:
        writer = Writer(handle, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="bag_builders")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, _ in records:
            if channel.id not in channels:
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
        writer.flush()
        for start in range(0, len(records), group):
            for _ in range(copies):
                for _, channel, m in records[start : start + group]:
                    writer.add_message(
                        channels[channel.id], m.log_time, m.data, m.publish_time, m.sequence
                    )
                writer.flush()
        writer.finish()
    return out


def _zstd_bomb() -> bytes:
    """256 zstd frames of 16 MiB of zeros each: 4 GiB expanded, about 130 KB."""
    import zstandard

    return zstandard.ZstdCompressor(level=19).compress(bytes(16 << 20)) * 256


def sqlite_row_bomb(path: Path) -> Path:
    """A rosbag2 sqlite3 bag with per-message zstd whose first row expands to 4 GiB."""
    import sqlite3

    imu_bag(path, "sqlite3", n=10, compression="message")
    (db,) = path.glob("*.db3")
    with contextlib.closing(sqlite3.connect(db)) as conn:
        conn.execute(
            "UPDATE messages SET data = ? WHERE id = (SELECT MIN(id) FROM messages)",
            (_zstd_bomb(),),
        )
        conn.commit()
    return path


def sqlite_file_bomb(path: Path) -> Path:
    """A file-compressed rosbag2 sqlite3 bag whose .db3.zstd expands to 4 GiB of zeros."""
    imu_bag(path, "sqlite3", n=10, compression="file")
    (packed,) = path.glob("*.zstd")
    packed.write_bytes(_zstd_bomb())
    return path


#: Values written over length words: edges of u32, the index layout, the chunk cap.
INTERESTING = (0, 1, 4, 47, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, MAX_CHUNK_BYTES + 1)


def _record_fields(path: Path) -> list[int]:
    """Offsets of the length words of every top-level record of a ROS 1 bag and of every
    header field's length word (the bytes rosbags trusts most)."""
    out = []
    with open(path, "rb") as handle:
        size = os.fstat(handle.fileno()).st_size
        for pos, _, _, header_len, _ in foreign.ros1_records(handle, size, path):
            out += [pos, pos + 4 + header_len]
            handle.seek(pos + 4)
            header, k = handle.read(header_len), 0
            while k < header_len:
                out.append(pos + 4 + k)
                k += 4 + struct.unpack_from("<I", header, k)[0]
    return out


def _mutate_bytes(blob: bytearray, rng: random.Random, fields: list[int]) -> bytearray:
    """One seeded mutation: flipped bytes, a cut, or a length word overwritten."""
    kind = rng.randrange(4)
    if kind == 0:
        for _ in range(rng.randint(1, 16)):
            blob[rng.randrange(len(blob))] ^= 1 << rng.randrange(8)
    elif kind == 1:
        del blob[rng.randrange(1, len(blob)) :]
    elif kind == 2 and fields:
        at = rng.choice(fields)
        blob[at : at + 4] = struct.pack("<I", rng.choice(INTERESTING))
    else:
        at = rng.randrange(len(blob) - 4)
        blob[at : at + 4] = struct.pack("<I", rng.choice(INTERESTING))
    return blob


HOSTILE_METADATA = (
    b"a: &a [x, x]\nb: &b [*a, *a]\nc: [*b, *b]\n",  # aliases
    b"[" * 20000,  # deep
    b"\xff\xfe not utf-8",
    b"rosbag2_bagfile_information: 7\n",
    b"rosbag2_bagfile_information: {version: 9, storage_identifier: sqlite3}\n",
)


def _mutate_metadata(text: str, rng: random.Random) -> bytes:
    """metadata.yaml with one seeded change: a hostile document, a line dropped, a value
    replaced, or bytes flipped."""
    kind = rng.randrange(4)
    if kind == 0:
        return rng.choice(HOSTILE_METADATA)
    lines = text.splitlines()
    k = rng.randrange(len(lines))
    if kind == 1:
        del lines[k]
    elif kind == 2 and ":" in lines[k]:
        key = lines[k].split(":", 1)[0]
        lines[k] = f"{key}: {rng.choice(['-1', '99999999999999999999', 'x', '[]', '{}', ''])}"
    else:
        blob = bytearray("\n".join(lines).encode())
        blob[rng.randrange(len(blob))] ^= 1 << rng.randrange(8)
        return bytes(blob)
    return "\n".join(lines).encode()


def fuzz_ros1(src: Path, out: Path, seed: int) -> Path:
    """``out``: the ROS 1 bag ``src`` with one mutation drawn from ``seed``."""
    rng = random.Random(seed)
    blob = _mutate_bytes(bytearray(src.read_bytes()), rng, _record_fields(src))
    out.write_bytes(bytes(blob))
    return out


def fuzz_sqlite(src: Path, out: Path, seed: int) -> Path:
    """``out``: a copy of the sqlite3 bag directory ``src`` with one mutation drawn from
    ``seed`` (of its metadata.yaml or of its data file)."""
    rng = random.Random(seed)
    shutil.copytree(src, out)
    meta = out / "metadata.yaml"
    if rng.random() < 0.3:
        meta.write_bytes(_mutate_metadata(meta.read_text(), rng))
        return out
    (data,) = [p for p in out.iterdir() if p.name != "metadata.yaml"]
    data.write_bytes(bytes(_mutate_bytes(bytearray(data.read_bytes()), rng, [])))
    return out

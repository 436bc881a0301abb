"""``mems_sim.bag.foreign``: ROS 1 and rosbag2 sqlite3 bags written by rosbags, read with
bounded decompression and one error path.

* every variant (ROS 1 uncompressed, bz2, lz4; sqlite3 plain, per-message zstd, file zstd)
  reads back the messages written, in order, each once;
* a bounded fuzz (fixed seeds, 330 corrupt bags from those six: bytes flipped, records'
  lengths and fields overwritten, files cut, metadata.yaml damaged or hostile): every bag
  either reads or raises BagReadError with one line; nothing else escapes, in seconds;
* the decompression caps: a chunk that declares more than MAX_CHUNK_BYTES is refused
  before decompressing, one that expands past its declared size is refused at that size,
  a row or file past its cap too;
* ``identify_noise`` on 4 GiB bombs of 20 to 170 KB (a ROS 1 bz2 chunk declaring 4 GiB,
  one declaring 5000 bytes that expands to 4 GiB, a sqlite3 zstd row and a file-compressed
  .db3 that expand to 4 GiB): one line, exit 2, peak RSS of the process under 500 MB,
  within 30 s.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest
from bag_builders import (
    DT_NS,
    HOSTILE_METADATA,
    T0_NS,
    TOPIC,
    fuzz_ros1,
    fuzz_sqlite,
    imu_bag,
    ros1_bomb,
    sqlite_file_bomb,
    sqlite_row_bomb,
)
from bagtool_helpers import run_measured

from mems_sim.bag import foreign
from mems_sim.bag.reader import MAX_CHUNK_BYTES, BagReadError
from mems_sim.stream_index import DuplicateFilter

N = 60
VARIANTS = (
    ("ros1", None),
    ("ros1", "bz2"),
    ("ros1", "lz4"),
    ("sqlite3", None),
    ("sqlite3", "message"),
    ("sqlite3", "file"),
)


def _name(kind: str, compression: str | None) -> str:
    return f"{kind}_{compression or 'plain'}" + (".bag" if kind == "ros1" else "")


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("foreign")
    return {
        _name(kind, c): imu_bag(root / _name(kind, c), kind, n=N, compression=c)
        for kind, c in VARIANTS
    }


def _read(path: Path, duplicates: DuplicateFilter | None = None) -> list[tuple[int, int]]:
    """(log time, header stamp) of every message of TOPIC."""
    with foreign.open_foreign(path) as bag:
        assert bag.topics == {TOPIC: "sensor_msgs/msg/Imu"}
        out = []
        for log_ns, msg in bag.messages(TOPIC, duplicates):
            stamp = msg.header.stamp
            out.append((log_ns, stamp.sec * 10**9 + stamp.nanosec))
        return out


def test_every_variant_reads_back(bags):
    """Each of the six variants gives the N messages written, in log-time order, with the
    stamps written; ROS 1 bags of 4 KiB chunks have several chunks."""
    expected = [(T0_NS + k * DT_NS,) * 2 for k in range(N)]
    for name, path in bags.items():
        assert _read(path) == expected, name
    assert len(foreign.scan_ros1(bags["ros1_bz2.bag"])) > 3
    assert foreign.bag_format(bags["sqlite3_plain"] / "sqlite3_plain.db3") == "sqlite3"


def test_duplicated_messages_are_used_once(tmp_path):
    """Every message written twice (identical topic, log time and bytes): read once each,
    the second copies counted as duplicates."""
    for kind in ("ros1", "sqlite3"):
        path = imu_bag(tmp_path / _name(kind, "dup"), kind, n=N, repeat=2)
        dups = DuplicateFilter()
        assert _read(path, dups) == [(T0_NS + k * DT_NS,) * 2 for k in range(N)], kind
        assert dups.counts == {TOPIC: N}, kind
        assert len(_read(path)) == 2 * N  # without a filter, as stored


def _one_line_error(path: Path) -> str | None:
    """None if the bag reads completely, else the BagReadError message (one line)."""
    try:
        _read_all(path)
    except BagReadError as exc:
        text = str(exc)
        assert text and "\n" not in text and len(text) < 600, text
        return text
    return None


def _read_all(path: Path) -> None:
    with foreign.open_foreign(path) as bag:
        for topic in bag.topics:
            for _ in bag.messages(topic):
                pass


def test_fuzzed_bags_read_or_fail_in_one_line(bags, tmp_path):
    """330 corrupt bags (55 per variant, seeds 0..54): each reads or raises BagReadError
    with one line; no other exception, every bag in well under a second, all in seconds."""
    outcomes = {"read": 0, "refused": 0}
    t0 = time.monotonic()
    for name, src in bags.items():
        for seed in range(55):
            out = tmp_path / f"{seed}_{name}"
            fuzz = fuzz_ros1 if name.endswith(".bag") else fuzz_sqlite
            path = fuzz(src, out, seed)
            t = time.monotonic()
            error = _one_line_error(path)
            assert time.monotonic() - t < 5.0, (name, seed)
            outcomes["read" if error is None else "refused"] += 1
    assert outcomes["refused"] > 150  # the mutations do break most bags
    assert time.monotonic() - t0 < 60.0


def test_special_files_and_hostile_metadata(bags, tmp_path):
    """A FIFO or a directory where a bag file is listed, /dev/zero as a bag, metadata with
    aliases, 20,000-deep nesting or not UTF-8: one line each, nothing hangs."""
    cases = []
    for k, text in enumerate(HOSTILE_METADATA):
        bag = shutil.copytree(bags["sqlite3_plain"], tmp_path / f"meta{k}")
        (bag / "metadata.yaml").write_bytes(text)
        cases.append(bag)
    fifo = shutil.copytree(bags["sqlite3_plain"], tmp_path / "fifo")
    (fifo / "sqlite3_plain.db3").unlink()
    os.mkfifo(fifo / "sqlite3_plain.db3")
    cases.append(fifo)
    folder = shutil.copytree(bags["sqlite3_plain"], tmp_path / "folder")
    (folder / "sqlite3_plain.db3").unlink()
    (folder / "sqlite3_plain.db3").mkdir()
    cases.append(folder)
    cases += [Path("/dev/zero"), tmp_path / "missing.bag"]
    for path in cases:
        assert _one_line_error(path), path


def test_ros1_chunk_caps(tmp_path):
    """A bz2 chunk declaring 4 GiB is refused before decompressing; one declaring 5000
    bytes whose data expands to 4 GiB stops at 5001 bytes."""
    text = _one_line_error(ros1_bomb(tmp_path / "declared.bag", 0xFFFFFFFF))
    assert "declares 4294967295 uncompressed bytes" in text and str(MAX_CHUNK_BYTES) in text
    t = time.monotonic()
    text = _one_line_error(ros1_bomb(tmp_path / "expands.bag", 5000))
    assert "expands past 5000 bytes" in text and time.monotonic() - t < 2.0


def test_row_and_file_caps(bags, tmp_path, monkeypatch):
    """A per-message zstd row and a file-compressed .db3 are expanded up to their caps only
    (caps lowered here so that the test bags exceed them)."""
    monkeypatch.setattr(foreign, "MAX_CHUNK_BYTES", 100)  # an Imu message is ~300 bytes
    assert "expands past 100 bytes" in _one_line_error(bags["sqlite3_message"])
    monkeypatch.setattr(foreign, "MAX_EXPANDED_FILE_BYTES", 4096)
    monkeypatch.setattr(foreign, "MIN_EXPANDED_FILE_BYTES", 0)
    assert "expands past 4096 bytes" in _one_line_error(bags["sqlite3_file"])


MAX_RSS_MB = 500.0


def test_identify_noise_on_bombs(tmp_path, subprocess_env):
    """identify_noise on each 4 GiB bomb: one line naming the cap, exit 2, peak RSS
    (ru_maxrss of the tool's process) under 500 MB, within 30 s."""
    cases = {
        "declares 4294967295 uncompressed bytes": ros1_bomb(tmp_path / "d.bag", 0xFFFFFFFF),
        "expands past 5000 bytes": ros1_bomb(tmp_path / "e.bag", 5000),
        f"expands past {MAX_CHUNK_BYTES} bytes": sqlite_row_bomb(tmp_path / "row"),
        f"expands past {foreign.MIN_EXPANDED_FILE_BYTES} bytes": sqlite_file_bomb(tmp_path / "f"),
    }
    for words, path in cases.items():
        assert path.stat().st_size < 200_000 or path.is_dir()
        run = run_measured(["identify_noise", path], env=subprocess_env, timeout=30)
        assert run.returncode == 2, (path, run.stderr)
        assert len(run.err_lines) == 1 and words in run.stderr, run.stderr
        assert run.err_lines[0].startswith("identify_noise: error: ")
        assert run.max_rss_mb < MAX_RSS_MB and run.wall_s < 30.0, (path, run)

"""A full disk during a split recording (a bag directory of ``NAME_<n>.mcap`` files and
``metadata.yaml``): the writer's counts (the recorder's summary), what a reader finds in
the files and ``metadata.yaml`` agree, or the one error line says which is short.

* ``mcap_record --max-bag-size`` in a process with ``RLIMIT_FSIZE`` (SIGXFSZ ignored: a
  write past the limit fails with EFBIG, as on a full disk; no mount rights needed);
* the writer with an injected ENOSPC: a disk of a fixed number of bytes shared by the split
  files and ``metadata.yaml`` (which then cannot be updated either), and a disk on which
  only the third split file runs out (``metadata.yaml`` is then complete).
"""

from __future__ import annotations

import errno
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from bagtool_helpers import BIN, reference_frames, start_publisher, stop_process

from mems_sim.bag import bag_metadata
from mems_sim.bag import writer as writer_module
from mems_sim.bag.writer import BagWriteError, McapBagWriter

TOPIC = "/imu/adc"
TYPE = "mems_msgs/msg/AdcFrame"


def files_content(directory: Path) -> dict[str, dict[str, int]]:
    """Per split file: messages per topic a streaming reader finds (up to a torn tail)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    out = {}
    for path in sorted(directory.glob("*.mcap")):
        topics, counts = {}, {}
        with open(path, "rb") as handle:
            try:
                for record in StreamReader(handle).records:
                    if isinstance(record, Channel):
                        topics[record.id] = record.topic
                    elif isinstance(record, Message):
                        topic = topics[record.channel_id]
                        counts[topic] = counts.get(topic, 0) + 1
            except Exception:  # the torn tail of the file the disk filled up in
                pass
        out[path.name] = counts
    return out


def metadata_content(directory: Path) -> tuple[int, dict[str, int], dict[str, int]]:
    """metadata.yaml: (message_count, per topic, per file)."""
    info = yaml.safe_load((directory / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = {
        t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]
    }
    files = {f["path"]: f["message_count"] for f in info["files"]}
    return info["message_count"], topics, files


def _totals(per_file: dict[str, dict[str, int]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for counts in per_file.values():
        for topic, n in counts.items():
            out[topic] = out.get(topic, 0) + n
    return out


def assert_consistent(directory: Path, counts: dict[str, int], error: str) -> None:
    """Summary (``counts``), files and metadata.yaml agree, or ``error`` names the short one."""
    in_files = files_content(directory)
    totals = _totals(in_files)
    assert {t: n for t, n in counts.items() if n} == totals, (counts, totals)
    listed, by_topic, by_file = metadata_content(directory)
    total = sum(totals.values())
    if listed == total:
        assert {t: n for t, n in by_topic.items() if n} == totals
        assert by_file == {name: sum(c.values()) for name, c in in_files.items()}
        assert "metadata.yaml" not in error
    else:
        assert f"metadata.yaml: no space left on device: it lists {listed} of the {total} " in error
    assert len(error.splitlines()) == 1


class _Disk:
    """Injected ENOSPC: ``free`` bytes for the split files (and for metadata.yaml when
    ``metadata``); a write past them writes what fits, then fails as the kernel does."""

    def __init__(self, monkeypatch, free: int, metadata: bool, from_file: int = 0) -> None:
        self.free, self.from_file = free, from_file
        disk = self
        original = writer_module._WriteThroughFile.write

        def write(stream, data):
            if not stream_is_limited(stream):
                return original(stream, data)
            view = memoryview(data)
            if len(view) <= disk.free:
                disk.free -= len(view)
                return original(stream, data)
            os.write(stream._fd, view[: disk.free])  # the part that fits; no position
            disk.free = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def stream_is_limited(stream) -> bool:
            return stream.index >= disk.from_file

        original_init = writer_module._WriteThroughFile.__init__

        def init(stream, path, overwrite=True):
            original_init(stream, path, overwrite)
            stream.index = int(Path(path).stem.rsplit("_", 1)[1])

        monkeypatch.setattr(writer_module._WriteThroughFile, "write", write)
        monkeypatch.setattr(writer_module._WriteThroughFile, "__init__", init)
        if metadata:
            monkeypatch.setattr(bag_metadata, "open", self._open, raising=False)

    def _open(self, path, mode="r", **kwargs):
        handle = open(path, mode, **kwargs)
        disk, write = self, handle.write

        def limited(text):
            if len(text) > disk.free:
                disk.free = 0
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            disk.free -= len(text)
            return write(text)

        handle.write = limited
        return handle


def _record_until_full(bag_dir: Path, frames) -> tuple[McapBagWriter, str]:
    schema, qos, data = frames
    bag = McapBagWriter(str(bag_dir), max_bag_size=40_000, chunk_size=8192)
    bag.add_topic(TOPIC, TYPE, schema, qos)
    k = 0
    while bag.error is None and k < 20_000:
        try:
            bag.write(TOPIC, data[k % len(data)], 1_000_000 * k, 1_000_000 * k, sequence=k + 1)
        except BagWriteError:
            break
        k += 1
        if k % 50 == 0:
            time.sleep(0.001)  # let the writer thread take them
    with pytest.raises(BagWriteError) as err:
        bag.close()
    return bag, str(err.value)


@pytest.fixture(scope="module")
def frames():
    return reference_frames(200)


def test_disk_full_for_files_and_metadata(tmp_path, monkeypatch, frames):
    _Disk(monkeypatch, free=150_000, metadata=True)
    bag, error = _record_until_full(tmp_path / "bag", frames)
    assert "no space left on device" in error, error
    assert len(list((tmp_path / "bag").glob("*.mcap"))) >= 3  # it split before filling up
    assert sum(bag.dropped().values()) > 0  # the torn chunk's messages: not in the summary
    assert_consistent(tmp_path / "bag", bag.counts(), error)
    assert "metadata.yaml" in error  # the disk had no room for it either: said so


def test_third_file_runs_out(tmp_path, monkeypatch, frames):
    _Disk(monkeypatch, free=20_000, metadata=False, from_file=2)
    bag, error = _record_until_full(tmp_path / "bag", frames)
    assert "no space left on device" in error, error
    assert sorted(p.name for p in (tmp_path / "bag").glob("*.mcap")) == [
        "bag_0.mcap",
        "bag_1.mcap",
        "bag_2.mcap",
    ]
    assert_consistent(tmp_path / "bag", bag.counts(), error)
    assert metadata_content(tmp_path / "bag")[0] == sum(bag.counts().values())


def _file_size_limit(limit_bytes: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return apply


def test_mcap_record_split_under_rlimit_fsize(tmp_path, subprocess_env):
    """The first split file reaches RLIMIT_FSIZE (below --max-bag-size): the recorder stops
    by itself with one line, exit 1; its summary, the file and metadata.yaml agree."""
    out = tmp_path / "split"
    # Fast DDS's shared-memory segments are files too, larger than the limit: it says so on
    # stderr (lines of RTPS_*) and talks UDP on the loopback interface instead
    env = subprocess_env
    publisher = start_publisher(subprocess_env, "/full/adc", period_s=0.002)
    try:
        recorder = subprocess.Popen(
            [str(BIN / "mcap_record"), "-o", str(out), "/full/adc", "--chunk-size", "16384"]
            + ["--max-bag-size", "4000000", "--ros-args", "--log-level", "warn"],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=_file_size_limit(256 * 1024),
        )
        try:
            stdout, stderr = recorder.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            recorder.kill()
            stdout, stderr = recorder.communicate()
            raise AssertionError(f"mcap_record did not stop: {stderr[-2000:]}") from None
    finally:
        stop_process(publisher)
    lines = [line for line in stderr.splitlines() if line.strip() and "RTPS_" not in line]
    assert recorder.returncode == 1, (recorder.returncode, stderr, stdout)
    assert len(lines) == 1 and str(out) in lines[0] and "File too large" in lines[0], stderr
    summary = [ln for ln in stdout.splitlines() if ln.strip().startswith("/full/adc [")]
    assert len(summary) == 1, stdout
    recorded = int(summary[0].split("]: ")[1].split(" messages")[0])
    assert recorded > 50
    assert_consistent(out, {"/full/adc": recorded}, lines[0])
    assert metadata_content(out)[0] == recorded  # metadata.yaml is small: it was written


if sys.platform != "linux":  # RLIMIT_FSIZE and SIGXFSZ as Linux has them
    pytestmark = pytest.mark.skip("Linux only")

"""ROS-free MCAP writer for rosbag2-compatible ``ros2`` profile files.

:class:`McapBagWriter` wraps :class:`mcap.writer.Writer`: header profile
``ros2``, schemas ``ros2msg``, channels ``cdr`` with ``offered_qos_profiles``
(and ``topic_type_hash``) metadata; on close the Summary section is written
with a Statistics record (mcap's Writer does that in ``finish()``).

Crash safety: mcap's Writer keeps the open chunk in memory and writes a chunk
(then its message indexes) to the output stream only when the chunk is
complete. The output here is an unbuffered write-through stream
(:class:`_WriteThroughFile`, ``os.write`` on the file descriptor), so every
complete chunk is in the OS the moment it is finished: a SIGKILL of the
process loses at most the chunk in progress (up to ``chunk_size`` bytes) and
the messages still queued for the writer thread (below), and the file reads
back up to the last complete chunk with a streaming reader. (Power loss is
another matter: nothing is fsync'ed except at close.)

Threading: :meth:`McapBagWriter.write` only counts the message and queues it;
a writer thread appends the queued messages to mcap's Writer, which compresses
each finished chunk there. zstd and lz4 release the GIL, so in a one-process
node graph compression runs on another core instead of stalling the executor
(it was ~80 % of the recorder's time). The queue is bounded (``queue_size``
messages): a writer that falls behind blocks the producer rather than growing
without limit. :meth:`McapBagWriter.close` drains the queue before the Summary.

Compression: ``compression`` (zstd, lz4, none), ``compression_level`` (zstd's level, 1 unless
given: the level of rosbag2's MCAP storage; mcap's Python Writer itself takes none and
compresses at zstd's default 3, so the level reaches it through
:class:`~mems_sim.bag.compression._LeveledZstd`) and ``crcs``;
:data:`~mems_sim.bag.compression.STORAGE_PRESETS` maps rosbag2's MCAP storage preset profiles onto them
(``zstd_fast``: level -5 without CRCs, ~0.4 x the CPU of the default and a 1.13 x larger
file on the stage's frames).

Output path: the file is created with ``O_NOFOLLOW`` (and ``O_EXCL`` unless
``overwrite``), so a symbolic link is never followed and its target never
truncated; :func:`output_problem` gives the one-line reason for refusing a
path before anything is opened. Character devices (``/dev/null``,
``/dev/full``) are written without truncation; other special files are refused.

Bounded close: ``close(timeout_s=...)`` lets the writer thread drain the queue
until the deadline; messages still queued then are dropped and counted
(:meth:`McapBagWriter.dropped`), and the Summary is written with what is in
the file, so a stop request finishes in bounded time however busy the
producers were. After a write error (disk full) nothing more is written: the
file keeps the complete chunks written before, and ``close`` raises. The messages of the
chunk that could not be written (and the message being written) then count as dropped,
so that :meth:`McapBagWriter.counts` (the recorder's summary), the messages a reader finds
in the files and a split recording's ``metadata.yaml`` agree; when ``metadata.yaml``
itself cannot be rewritten at close (no room left), the error line says how many messages
it lists against those in the files.

The writer also counts messages per topic and, for frame types
(:data:`~mems_sim.bag.schema.GAP_CHECKED_TYPES`), gaps of the frame index
(``first_sample_index`` of a frame differs from ``first + num_samples`` of the
previous frame on the same topic; :meth:`~mems_sim.stream_index.StreamIndex.recording`),
peeked from the CDR bytes. Messages written with
their publisher's sequence number (the recorder passes the middleware's publication
sequence number) keep it as the MCAP ``sequence``, and gaps of each publisher's
numbers are counted, so a lost message is visible on every topic, frames or not.

Split recordings (``max_bag_size`` / ``max_bag_duration``, rosbag2's ``--max-bag-size`` and
``--max-bag-duration``): the output is a rosbag2 bag directory ``NAME/`` holding
``NAME_0.mcap``, ``NAME_1.mcap``, ... and a ``metadata.yaml`` in rosbag2's format
(``rosbag2_bagfile_information`` version 9, as rosbag2_storage encodes bag metadata).
The writer thread closes a file between two messages: before the message whose log time
is ``max_bag_duration`` past the file's first log time (on the highest log time seen, so
topics on different timelines cannot make it split at every message), or after the message
with which the bytes written to the file reach ``max_bag_size`` (chunks are written whole,
so a file ends at most one chunk past the limit; the chunk size is capped at a quarter of
it). Every file is a complete MCAP file on its own (its Summary with Statistics and footer
written and fsync'ed before the next file is opened) and registers every schema and channel
known so far, as rosbag2 does. ``metadata.yaml`` is rewritten (atomically) at every split
and at close; its ``compression_format``/``compression_mode`` are empty because the MCAP
chunk compression is internal to each file (rosbag2's fields describe its own file or
message compression). Loss accounting (counts, frame-index and sequence gaps) is over the
whole bag, not per file.
"""

from __future__ import annotations

import errno
import os
import queue
import stat
import threading
import time

from mcap.writer import Writer

from mems_sim.bag.bag_metadata import message_count, rosbag2_metadata, write_metadata
from mems_sim.bag.compression import (
    _COMPRESSION,
    _ZSTD,
    DEFAULT_ZSTD_LEVEL,
    MCAP_PY_ZSTD_LEVEL,
    _zstd_level,
)
from mems_sim.bag.output_paths import (
    METADATA_FILE,
    BagWriteError,
    bag_directory_path,
    bag_directory_problem,  # noqa: F401 (re-export)
    bag_file_name,
    describe_error,
    output_problem,  # noqa: F401 (re-export)
    prepare_directory,
)
from mems_sim.bag.schema import GAP_CHECKED_TYPES, normalize_type_name, peek_frame_index
from mems_sim.stream_index import GAP, SequenceIndex, StreamIndex


class _WriteThroughFile:
    """Minimal binary output stream that hands every write straight to the OS.

    Deliberately not an ``io.RawIOBase`` (mcap's Writer would wrap that in a
    ``BufferedWriter``, which is exactly what must not happen here). Opened with
    ``O_NOFOLLOW`` (a symbolic link is refused, its target untouched), ``O_EXCL``
    unless ``overwrite``; character devices are opened without truncation.
    Raises :class:`BagWriteError` (one line naming the path).
    """

    def __init__(self, path: str, overwrite: bool = True):
        flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
        try:
            info = os.lstat(path)
        except OSError:
            info = None
        if info is not None and stat.S_ISCHR(info.st_mode):
            flags &= ~os.O_CREAT
        elif info is not None and stat.S_ISLNK(info.st_mode):
            raise BagWriteError(f"{path}: is a symbolic link; refusing to write through it")
        elif info is not None and stat.S_ISDIR(info.st_mode):
            raise BagWriteError(f"{path}: is a directory")
        elif info is not None and not stat.S_ISREG(info.st_mode):
            raise BagWriteError(f"{path}: not a regular file")
        else:
            flags |= os.O_TRUNC if overwrite else os.O_EXCL
        try:
            self._fd = os.open(path, flags, 0o644)
        except OSError as exc:
            raise BagWriteError(describe_error(path, exc)) from None
        self._pos = 0

    def write(self, data) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
        self._pos += len(data)
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        """Nothing is buffered in user space."""

    def fsync(self) -> None:
        try:
            os.fsync(self._fd)
        except OSError as exc:
            if exc.errno not in (errno.EINVAL, errno.EROFS):  # devices and pipes
                raise

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class McapBagWriter:
    """Write serialised ROS 2 messages into an MCAP file that rosbag2, rosbags,
    Foxglove and PlotJuggler read.

    :param path: output file (``.mcap``); created or truncated.
    :param chunk_size: target uncompressed chunk size [bytes].
    :param compression: ``'zstd'`` (default), ``'lz4'`` or ``'none'``.
    :param compression_level: zstd level (negative: zstd's fast levels; None:
        :data:`DEFAULT_ZSTD_LEVEL`, rosbag2's); only with ``'zstd'``.
    :param crcs: store the CRC of every chunk's uncompressed data (and of the Summary);
        rosbag2's presets ``fastwrite`` and ``zstd_fast`` leave them out.
    :param on_gap: optional callback ``(topic, expected_index, first_index)``
        called when a frame-index gap appears.
    :param queue_size: messages the writer thread may lag behind (module doc).
    :param overwrite: replace an existing regular file (else :class:`BagWriteError`); for a
        bag directory, replace the bag in an existing directory (nothing else is deleted).
    :param max_bag_size: split into a new file once a file has this many bytes (0: never).
    :param max_bag_duration: split into a new file once a file spans this much log time
        [s] (0: never).
    :param directory: write a rosbag2 bag directory (module doc) instead of one file;
        None: when splitting is asked. ``path`` then names the directory (a ``.mcap``
        suffix is dropped, :func:`bag_directory_path`).

    Raises :class:`BagWriteError` (one line naming the path) when the output cannot be
    created or its first bytes cannot be written.
    """

    def __init__(
        self,
        path: str,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        on_gap=None,
        queue_size: int = 256,
        overwrite: bool = True,
        max_bag_size: int = 0,
        max_bag_duration: float = 0.0,
        directory: bool | None = None,
        compression_level: int | None = None,
        crcs: bool = True,
    ):
        if compression not in _COMPRESSION:
            raise ValueError(f"unknown compression {compression!r} (zstd, lz4 or none)")
        if compression_level is not None:
            if compression != "zstd":
                raise ValueError("a compression level needs zstd compression")
            if _ZSTD is None:
                raise ValueError("zstd compression levels need the zstandard package")
            level = int(compression_level)
            if not (-(1 << 17) <= level <= 22):
                raise ValueError(f"zstd level {level} outside -131072..22")
            compression_level = None if level == MCAP_PY_ZSTD_LEVEL else level
        elif compression == "zstd" and _ZSTD is not None:
            compression_level = DEFAULT_ZSTD_LEVEL
        self.compression_level = compression_level
        self.crcs = bool(crcs)
        if max_bag_size < 0 or max_bag_duration < 0:
            raise ValueError("max_bag_size and max_bag_duration must not be negative")
        self.compression = compression or "none"
        self._max_bytes = int(max_bag_size)
        self._max_span_ns = int(round(float(max_bag_duration) * 1e9))
        self._directory = (
            bool(self._max_bytes or self._max_span_ns) if directory is None else bool(directory)
        )
        if self._max_bytes:
            chunk_size = max(1024, min(int(chunk_size), self._max_bytes // 4))
        self._chunk_size = int(chunk_size)
        self._overwrite = overwrite
        # the bag's schemas and channels in registration order: every split file registers
        # them all again (bag channel id = index + 1, the id mcap's Writer gives in one file)
        self._topic_defs: list[tuple[str, str, bytes, dict[str, str]]] = []
        self._done_files: list[dict] = []  # finished split files: path, times, counts
        self._file_index = 0
        self._file_ids: dict[int, int] = {}  # bag channel id -> channel id in the open file
        self._file_schema_ids: dict[str, int] = {}
        self._file_counts: dict[int, int] = {}
        self._file_first: int | None = None  # lowest log time in the open file
        self._file_last: int | None = None  # highest log time in the open file
        self._file_start_hw: int | None = None  # high-water log time at its first message
        self._high_water: int | None = None  # highest log time written to the bag
        self._roll_pending = False
        self._writer = None
        self._stream = None
        self._metadata_listed = 0  # messages the metadata.yaml on disk lists
        self._metadata_problem: str | None = None  # why it could not be updated at close
        if self._directory:
            self.path = bag_directory_path(path)
            prepare_directory(self.path, overwrite)
            self._open_file()
            self._write_metadata()
        else:
            self.path = str(path)
            self._open_file()
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._counts: dict[str, int] = {}
        self._gap_counters: dict[str, StreamIndex] = {}
        self._seq_counters: dict[tuple[str, bytes | None], SequenceIndex] = {}
        self._on_gap = on_gap
        self._closed = False
        self._wlock = threading.Lock()  # serialises every call into mcap's Writer
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, int(queue_size)))
        self._error: BaseException | None = None
        self._deadline: float | None = None  # monotonic time after which queued messages drop
        self._abandon = False
        self._dropped: dict[int, int] = {}
        self._topic_of: dict[int, str] = {}
        self._thread = threading.Thread(target=self._drain, name="mcap-writer", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        """Writer thread: append queued messages until the ``None`` sentinel."""
        while True:
            item = self._queue.get()
            if item is None:
                return
            if (
                self._error is not None
                or self._abandon
                or (self._deadline is not None and time.monotonic() > self._deadline)
            ):
                # keep draining so producers never block; count what is not written
                self._dropped[item[0]] = self._dropped.get(item[0], 0) + 1
                continue
            try:
                with self._wlock:
                    self._add(item)
            except BaseException as exc:
                self._error = exc
                self._lose_unwritten(item)

    # ---------------------------------------------------------------- files

    def _file_path(self) -> str:
        if not self._directory:
            return self.path
        return os.path.join(self.path, bag_file_name(self.path, self._file_index))

    def _open_file(self) -> None:
        """Open the next output file and register the bag's schemas and channels in it."""
        path = self._file_path()
        stream = _WriteThroughFile(path, overwrite=self._overwrite or self._directory)
        try:
            writer = Writer(
                stream,
                chunk_size=self._chunk_size,
                compression=_COMPRESSION[self.compression],
                enable_crcs=self.crcs,
            )
            writer.start(profile="ros2", library="mems_sim.bag/mcap-python")
        except OSError as exc:
            stream.close()
            raise BagWriteError(describe_error(path, exc)) from None
        self._stream, self._writer = stream, writer
        self._file_ids, self._file_schema_ids, self._file_counts = {}, {}, {}
        self._file_first = self._file_last = self._file_start_hw = None
        self._on_disk: tuple[dict[int, int], int | None, int | None] = ({}, None, None)
        for bag_id, (topic, type_name, schema, metadata) in enumerate(self._topic_defs, 1):
            self._register_in_file(bag_id, topic, type_name, schema, metadata)

    def _register_in_file(
        self, bag_id: int, topic: str, type_name: str, schema: bytes, metadata: dict[str, str]
    ) -> None:
        # registering can finish a chunk (schemas and channels go into chunks)
        before = self._stream.tell()
        with _zstd_level(self.compression_level):
            schema_id = self._file_schema_ids.get(type_name)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=type_name, encoding="ros2msg", data=schema
                )
                self._file_schema_ids[type_name] = schema_id
            self._file_ids[bag_id] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema_id, metadata=metadata
            )
        self._note_on_disk(self._stream, before)

    def _add(self, item) -> None:
        """Append one queued message to the open file, splitting first when due (writer
        thread, under the writer lock)."""
        log_time = item[1]
        high_water = log_time if self._high_water is None else max(self._high_water, log_time)
        if self._file_first is not None and (
            self._roll_pending
            or (self._max_span_ns and high_water - self._file_start_hw >= self._max_span_ns)
        ):
            self._roll()
        before = self._stream.tell()
        with _zstd_level(self.compression_level):
            self._writer.add_message(
                channel_id=self._file_ids.get(item[0], item[0]),
                log_time=log_time,
                data=item[2],
                publish_time=item[3],
                sequence=item[4],
            )
        self._high_water = high_water
        if self._file_first is None:
            self._file_first = self._file_last = log_time
            self._file_start_hw = high_water
        else:
            self._file_first = min(self._file_first, log_time)
            self._file_last = max(self._file_last, log_time)
        self._file_counts[item[0]] = self._file_counts.get(item[0], 0) + 1
        self._note_on_disk(self._stream, before)
        if self._max_bytes and self._stream.tell() >= self._max_bytes:
            self._roll_pending = True  # split before the next message: no empty last file

    def _file_info(self) -> dict:
        return {
            "path": os.path.basename(self._file_path()),
            "first": self._file_first,
            "last": self._file_last,
            "counts": dict(self._file_counts),
        }

    def _finish_file(self) -> None:
        """Write the open file's last chunk, Summary and footer, fsync and close it."""
        stream, self._stream = self._stream, None
        before = stream.tell()
        try:
            with _zstd_level(self.compression_level):
                self._writer.finish()
            stream.fsync()
        finally:
            self._note_on_disk(stream, before)
            stream.close()

    def _note_on_disk(self, stream: _WriteThroughFile, before: int) -> None:
        """The open file grew past ``before`` [bytes]: every message added to it so far is
        in complete chunks in the OS (mcap's Writer writes a chunk whole, with the message
        just added, before anything else; a write that failed midway does not count)."""
        if stream.tell() != before:
            self._on_disk = (dict(self._file_counts), self._file_first, self._file_last)

    def _lose_unwritten(self, item) -> None:
        """After a write error: the open file's messages that are not in a complete chunk
        on disk, and ``item`` (the message being written, None: none), count as dropped,
        and the file's counts and times become those on disk, so that :meth:`counts`,
        ``metadata.yaml`` and what a reader finds in the files agree (module doc)."""
        on_disk, first, last = self._on_disk
        for channel_id, n in self._file_counts.items():
            lost = n - on_disk.get(channel_id, 0)
            if lost:
                self._dropped[channel_id] = self._dropped.get(channel_id, 0) + lost
        if item is not None:
            self._dropped[item[0]] = self._dropped.get(item[0], 0) + 1
        self._file_counts, self._file_first, self._file_last = dict(on_disk), first, last

    def _roll(self) -> None:
        """Finish the open split file and open the next one (writer thread)."""
        info = self._file_info()
        self._finish_file()
        self._done_files.append(info)
        self._file_index += 1
        self._roll_pending = False
        self._writer = None
        self._open_file()
        self._write_metadata()

    def _metadata(self) -> dict:
        """rosbag2's ``metadata.yaml`` content for the files written so far."""
        files = list(self._done_files)
        if self._stream is not None or self._writer is not None:
            files.append(self._file_info())
        return rosbag2_metadata(files, self._topic_defs)

    def _write_metadata(self) -> None:
        """Write ``metadata.yaml`` atomically; remember how many messages it lists."""
        metadata = self._metadata()
        write_metadata(self.path, metadata)
        self._metadata_listed = message_count(metadata)

    def files(self) -> list[str]:
        """Paths of the output files so far (one file, or a bag directory's split files)."""
        if not self._directory:
            return [self.path]
        names = [f["path"] for f in self._done_files]
        if self._writer is not None:
            names.append(bag_file_name(self.path, self._file_index))
        return [os.path.join(self.path, n) for n in names]

    @property
    def is_directory(self) -> bool:
        """True when the output is a rosbag2 bag directory of split files."""
        return self._directory

    def size_bytes(self) -> int:
        """Bytes in the output files (all split files of a bag directory)."""
        total = 0
        for path in self.files():
            try:
                total += os.path.getsize(path)
            except OSError:
                pass
        return total

    # ---------------------------------------------------------------- setup

    def has_topic(self, topic: str) -> bool:
        """True once :meth:`add_topic` was called for ``topic``."""
        return topic in self._channels

    def add_topic(
        self,
        topic: str,
        type_name: str,
        schema_text: str,
        qos_yaml: str,
        type_hash: str | None = None,
    ) -> int:
        """Register a topic (channel) and its type's schema; return the channel id.

        ``qos_yaml`` is the ``offered_qos_profiles`` string, ``type_hash`` the
        ``RIHS01_...`` hash (omitted from the metadata when None).
        Registering the same topic again returns the existing channel.
        """
        type_name = normalize_type_name(type_name)
        with self._lock:
            self._check_open()
            if topic in self._channels:
                return self._channels[topic]
            metadata = {"offered_qos_profiles": qos_yaml}
            if type_hash:
                metadata["topic_type_hash"] = type_hash
            with self._wlock:
                self._topic_defs.append((topic, type_name, schema_text.encode("utf-8"), metadata))
                channel_id = len(self._topic_defs)
                if self._writer is not None:  # None only after a failed split
                    self._register_in_file(channel_id, *self._topic_defs[-1])
            self._channels[topic] = channel_id
            self._topic_of[channel_id] = topic
            self._types[topic] = type_name
            self._counts[topic] = 0
            if type_name in GAP_CHECKED_TYPES:
                self._gap_counters[topic] = StreamIndex.recording(start=0)
            return channel_id

    # ---------------------------------------------------------------- data

    def write(
        self,
        topic: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int,
        sequence: int | None = None,
        publisher: bytes | None = None,
    ) -> str | None:
        """Append one serialised (CDR) message of a registered topic; returns the frame's
        event of the loss taxonomy (:data:`~mems_sim.stream_index.EVENTS`, e.g.
        :data:`~mems_sim.stream_index.DEVICE_GAP`), None for a message that is no frame.

        :param log_time_ns: the message's time on the data's timeline [ns] (the recorder
            gives its sensor time: header stamp, else the graph's clock); MCAP readers order
            and pace by it.
        :param publish_time_ns: when the sender published it [ns], as the MCAP
            specification defines (the recorder gives the middleware's source timestamp).
        :param sequence: the publisher's sequence number of the message (1, 2, ...),
            stored as the MCAP message's ``sequence`` (the counter the MCAP format assigns
            to the publisher); None: the writer numbers the topic's messages from 0.
        :param publisher: identity of the publishing endpoint (opaque bytes); with
            ``sequence``, gaps of each publisher's numbers are counted
            (:meth:`sequence_details`).
        """
        with self._lock:
            self._check_open()
            channel_id = self._channels.get(topic)
            if channel_id is None:
                raise KeyError(f"topic {topic} was not added to the bag")
            counter = self._gap_counters.get(topic)
            gap = event = None
            if counter is not None:
                peek = peek_frame_index(data)
                if peek is not None:
                    expected = counter.expected
                    event = counter.update(*peek)[0]
                    if event == GAP:
                        gap = (expected, peek[0])
            if sequence is None:
                sequence = self._counts[topic]
            else:
                key = (topic, publisher)
                seq_counter = self._seq_counters.get(key)
                if seq_counter is None:
                    seq_counter = self._seq_counters[key] = SequenceIndex()
                seq_counter.update(int(sequence))
            self._queue.put(
                (
                    channel_id,
                    int(log_time_ns),
                    bytes(data),
                    int(publish_time_ns),
                    sequence & 0xFFFFFFFF,
                )
            )
            self._counts[topic] += 1
        if gap is not None and self._on_gap is not None:
            self._on_gap(topic, gap[0], gap[1])
        return event

    # ---------------------------------------------------------------- stats

    def counts(self) -> dict[str, int]:
        """Messages written per topic (accepted by :meth:`write`, less those dropped at close)."""
        with self._lock:
            out = dict(self._counts)
        for channel_id, n in dict(self._dropped).items():
            topic = self._topic_of.get(channel_id)
            if topic in out:
                out[topic] -= n
        return out

    def dropped(self) -> dict[str, int]:
        """Messages per topic accepted by :meth:`write` but not written: still queued at the
        close deadline, or after a write error."""
        return {self._topic_of.get(cid, str(cid)): n for cid, n in dict(self._dropped).items() if n}

    @property
    def error(self) -> BaseException | None:
        """The writer thread's error (e.g. disk full), None while writing works."""
        return self._error

    def gaps(self) -> dict[str, int]:
        """Frame-index gaps per frame topic (topics of other types are absent)."""
        with self._lock:
            return {t: c.gaps for t, c in self._gap_counters.items()}

    def gap_details(self) -> dict[str, dict[str, int]]:
        """Per frame topic: gaps, missing_samples (transport loss), device_gaps,
        device_missing_samples (samples its device declared dropped,
        :meth:`declare_device_gap`), resets, frames, samples, missing_head (sample indices
        before the first frame written: a recording that started after its stream, whose
        sample 0 it did not get)."""
        with self._lock:
            return {
                t: {
                    "gaps": c.gaps,
                    "missing_head": c.missing_head,
                    "missing_samples": c.missing_samples,
                    "device_gaps": c.device_gaps,
                    "device_missing_samples": c.device_missing_samples,
                    "resets": c.resets,
                    "frames": c.frames,
                    "samples": c.samples,
                }
                for t, c in self._gap_counters.items()
            }

    def declare_device_gap(self, topic: str, first: int, n: int) -> None:
        """The device of frame topic ``topic`` declares that sample indices ``[first,
        first + n)`` will not come (a scheduled fault): a jump over them is a device gap,
        not transport loss (:meth:`~mems_sim.stream_index.StreamIndex.declare_device_gap`)."""
        with self._lock:
            counter = self._gap_counters.get(topic)
            if counter is not None:
                counter.declare_device_gap(first, n)

    def frame_end(self, topic: str) -> int | None:
        """First sample index after the last frame written on ``topic`` (None: none yet)."""
        with self._lock:
            counter = self._gap_counters.get(topic)
            return None if counter is None else counter.expected

    def sequence_details(self) -> dict[str, dict[str, int]]:
        """Per topic written with publisher sequence numbers: ``publishers`` (endpoints
        seen), ``gaps``, ``missing_messages`` and ``resets`` summed over its publishers,
        and ``last`` (the highest number seen; of one publisher, the count it published)."""
        out: dict[str, dict[str, int]] = {}
        with self._lock:
            for (topic, _), c in self._seq_counters.items():
                d = out.setdefault(
                    topic, {"publishers": 0, "gaps": 0, "missing_messages": 0, "resets": 0}
                )
                d["publishers"] += 1
                d["gaps"] += c.gaps
                d["missing_messages"] += c.missing_messages
                d["resets"] += c.resets
                d["last"] = max(d.get("last", 0), c.last or 0)
        return out

    def topic_types(self) -> dict[str, str]:
        """Type name (``pkg/msg/Type``) per registered topic."""
        return dict(self._types)

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    # ---------------------------------------------------------------- end

    def close(self, timeout_s: float | None = None, abort=None) -> None:
        """Drain the writer thread, write the last chunk and the Summary (with Statistics),
        fsync and close. Idempotent.

        :param timeout_s: drain the queue for at most this long [s] (None: all of it);
            messages still queued then are dropped and counted (:meth:`dropped`).
        :param abort: optional callable; when it returns True the drain stops at once
            (e.g. a second stop signal), as if the deadline had passed.

        After a write error nothing more is written (the file keeps its complete chunks)
        and :class:`BagWriteError` naming the path is raised after closing the file.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if timeout_s is not None:
                self._deadline = time.monotonic() + max(0.0, timeout_s)

            def expired() -> bool:
                return (self._deadline is not None and time.monotonic() > self._deadline) or (
                    abort is not None and bool(abort())
                )

            while True:  # the queue may be full: wait for room, but never past the deadline
                try:
                    self._queue.put(None, timeout=0.05)
                    break
                except queue.Full:
                    if expired():
                        self._abandon = True
            while self._thread.is_alive():
                self._thread.join(timeout=0.05)
                if expired():
                    self._abandon = True
            try:
                if self._error is None and self._stream is not None:
                    try:
                        with self._wlock:
                            self._finish_file()
                        if self._directory:
                            self._write_metadata()
                    except OSError as exc:
                        self._error = exc
                        self._lose_unwritten(None)
            finally:
                if self._stream is not None:
                    self._stream.close()
                    self._stream = None
                if self._directory and self._error is not None:
                    try:  # list what was written (the last file may lack its Summary)
                        self._write_metadata()
                    except OSError as exc:
                        self._metadata_problem = describe_error(METADATA_FILE, exc)
        if self._error is not None:
            raise self._failure() from self._error

    def _failure(self) -> BagWriteError:
        exc = self._error
        if isinstance(exc, BagWriteError):
            text = str(exc)
        elif isinstance(exc, OSError):
            text = describe_error(self.path, exc)
        else:
            text = f"{self.path}: writing failed: {exc}"
        if self._metadata_problem:  # one line: which of the three is short
            text += (
                f"; {self._metadata_problem}: it lists {self._metadata_listed} of the "
                f"{message_count(self._metadata())} messages in the files"
            )
        return exc if text == str(exc) and isinstance(exc, BagWriteError) else BagWriteError(text)

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"bag {self.path} is closed")
        if self._error is not None:
            raise self._failure() from self._error

    def __enter__(self) -> McapBagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def gap_summary(details: dict[str, dict[str, int]]) -> tuple[int, int]:
    """Total (gaps, missing_samples) over all topics of :meth:`McapBagWriter.gap_details`."""
    return (
        sum(d["gaps"] for d in details.values()),
        sum(d["missing_samples"] for d in details.values()),
    )

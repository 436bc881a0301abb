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
file keeps the complete chunks written before, and ``close`` raises.

The writer also counts messages per topic and, for frame types
(:data:`~mems_sim.bag.schema.GAP_CHECKED_TYPES`), gaps of the frame index
(``first_sample_index`` of a frame differs from ``first + num_samples`` of the
previous frame on the same topic), peeked from the CDR bytes. Messages written with
their publisher's sequence number (the recorder passes the middleware's publication
sequence number) keep it as the MCAP ``sequence``, and gaps of each publisher's
numbers are counted, so a lost message is visible on every topic, frames or not.
"""

from __future__ import annotations

import errno
import os
import queue
import stat
import threading
import time

from mcap.writer import CompressionType, Writer

from mems_sim.bag.schema import GAP_CHECKED_TYPES, normalize_type_name, peek_frame_index

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
    "": CompressionType.NONE,
    None: CompressionType.NONE,
}


class BagWriteError(OSError):
    """The output cannot be written (message is one line and names the path)."""


def _describe(path: str, exc: OSError) -> str:
    """One line for an OSError of opening or writing ``path``."""
    reason = {
        errno.EEXIST: "exists (give --overwrite to replace it)",
        errno.ELOOP: "is a symbolic link; refusing to write through it",
        errno.EISDIR: "is a directory",
        errno.ENOENT: "cannot create it (no such file or directory)",
        errno.ENOTDIR: "a part of the path is not a directory",
        errno.ENOSPC: "no space left on device",
        errno.EDQUOT: "disk quota exceeded",
        errno.EROFS: "read-only file system",
    }.get(exc.errno)
    if reason is None:
        reason = exc.strerror or str(exc)
    return f"{path}: {reason}"


def output_problem(path: str, overwrite: bool = False, probe: bool = True) -> str | None:
    """Why ``path`` cannot be used as a bag output, or None (one line naming the path).

    Refused: a symbolic link (never followed), a directory, an existing regular file
    unless ``overwrite``, special files other than character devices, a path whose
    directory is missing or not writable. With ``probe``, a file that does not exist
    yet is created and removed again (the only reliable test for root, to whom
    ``access()`` grants everything, e.g. in ``/proc``); nothing else is modified.
    """
    path = str(path)
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        info = None
    except OSError as exc:
        return _describe(path, exc)
    if info is not None:
        if stat.S_ISLNK(info.st_mode):
            return f"{path}: is a symbolic link; refusing to write through it"
        if stat.S_ISDIR(info.st_mode):
            return f"{path}: is a directory"
        if stat.S_ISCHR(info.st_mode):
            return None
        if not stat.S_ISREG(info.st_mode):
            return f"{path}: not a regular file"
        if not overwrite:
            return f"{path}: exists (give --overwrite to replace it)"
        if not os.access(path, os.W_OK):
            return f"{path}: not writable"
        return None
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        return f"{path}: directory {parent} does not exist"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{path}: directory {parent} is not writable"
    if probe:
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
        except FileExistsError:
            return None  # appeared meanwhile: the real open decides
        except OSError as exc:
            return _describe(path, exc)
        os.close(fd)
        try:
            os.unlink(path)
        except OSError:
            pass
    return None


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
            raise BagWriteError(_describe(path, exc)) from None
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


class FrameGapCounter:
    """Counts frame-index gaps of one frame stream.

    A gap is a frame whose ``first_sample_index`` is larger than the expected
    one (``first + num_samples`` of the previous frame): samples were dropped.
    A smaller index (device restarted, or replayed data) is counted as a
    ``reset``, not a gap.
    """

    def __init__(self):
        self.expected: int | None = None
        self.gaps = 0
        self.missing_samples = 0
        self.resets = 0
        self.frames = 0
        self.samples = 0

    def update(self, first: int, num: int) -> int:
        """Account one frame; return the number of missing samples before it (0 = contiguous)."""
        missing = 0
        if self.expected is not None and first != self.expected:
            if first > self.expected:
                missing = first - self.expected
                self.gaps += 1
                self.missing_samples += missing
            else:
                self.resets += 1
        self.expected = first + num
        self.frames += 1
        self.samples += num
        return missing


class SequenceGapCounter:
    """Counts gaps of one publisher's message sequence numbers.

    Every publisher numbers its messages 1, 2, 3, ...; a number larger than the one
    expected (the previous plus one) is a gap: messages were lost in between. A number
    that is not larger than the previous one (the publisher restarted, or the numbers
    of several publishers are interleaved) is counted as a ``reset``. ``first`` is the
    first number seen (larger than 1 when recording started after the publisher).
    """

    def __init__(self):
        self.first: int | None = None
        self.last: int | None = None
        self.gaps = 0
        self.missing_messages = 0
        self.resets = 0
        self.messages = 0

    def update(self, sequence: int) -> int:
        """Account one message; return the number of messages missing before it."""
        missing = 0
        if self.last is None:
            self.first = sequence
        elif sequence > self.last + 1:
            missing = sequence - self.last - 1
            self.gaps += 1
            self.missing_messages += missing
        elif sequence <= self.last:
            self.resets += 1
        self.last = sequence
        self.messages += 1
        return missing


class McapBagWriter:
    """Write serialised ROS 2 messages into an MCAP file that rosbag2, rosbags,
    Foxglove and PlotJuggler read.

    :param path: output file (``.mcap``); created or truncated.
    :param chunk_size: target uncompressed chunk size [bytes].
    :param compression: ``'zstd'`` (default), ``'lz4'`` or ``'none'``.
    :param on_gap: optional callback ``(topic, expected_index, first_index)``
        called when a frame-index gap appears.
    :param queue_size: messages the writer thread may lag behind (module doc).
    :param overwrite: replace an existing regular file (else :class:`BagWriteError`).

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
    ):
        if compression not in _COMPRESSION:
            raise ValueError(f"unknown compression {compression!r} (zstd, lz4 or none)")
        self.path = str(path)
        self.compression = compression or "none"
        self._stream = _WriteThroughFile(self.path, overwrite=overwrite)
        try:
            self._writer = Writer(
                self._stream, chunk_size=chunk_size, compression=_COMPRESSION[compression]
            )
            self._writer.start(profile="ros2", library="mems_sim.bag/mcap-python")
        except OSError as exc:
            self._stream.close()
            raise BagWriteError(_describe(self.path, exc)) from None
        self._lock = threading.Lock()
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._counts: dict[str, int] = {}
        self._gap_counters: dict[str, FrameGapCounter] = {}
        self._seq_counters: dict[tuple[str, bytes | None], SequenceGapCounter] = {}
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
                    self._writer.add_message(
                        channel_id=item[0],
                        log_time=item[1],
                        data=item[2],
                        publish_time=item[3],
                        sequence=item[4],
                    )
            except BaseException as exc:
                self._error = exc

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
            schema_id = self._schema_ids.get(type_name)
            if schema_id is None:
                with self._wlock:
                    schema_id = self._writer.register_schema(
                        name=type_name, encoding="ros2msg", data=schema_text.encode("utf-8")
                    )
                self._schema_ids[type_name] = schema_id
            metadata = {"offered_qos_profiles": qos_yaml}
            if type_hash:
                metadata["topic_type_hash"] = type_hash
            with self._wlock:
                channel_id = self._writer.register_channel(
                    topic=topic, message_encoding="cdr", schema_id=schema_id, metadata=metadata
                )
            self._channels[topic] = channel_id
            self._topic_of[channel_id] = topic
            self._types[topic] = type_name
            self._counts[topic] = 0
            if type_name in GAP_CHECKED_TYPES:
                self._gap_counters[topic] = FrameGapCounter()
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
    ) -> None:
        """Append one serialised (CDR) message of a registered topic.

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
            gap = None
            if counter is not None:
                peek = peek_frame_index(data)
                if peek is not None:
                    expected = counter.expected
                    if counter.update(*peek):
                        gap = (expected, peek[0])
            if sequence is None:
                sequence = self._counts[topic]
            else:
                key = (topic, publisher)
                seq_counter = self._seq_counters.get(key)
                if seq_counter is None:
                    seq_counter = self._seq_counters[key] = SequenceGapCounter()
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
        """Per frame topic: gaps, missing_samples, resets, frames, samples."""
        with self._lock:
            return {
                t: {
                    "gaps": c.gaps,
                    "missing_samples": c.missing_samples,
                    "resets": c.resets,
                    "frames": c.frames,
                    "samples": c.samples,
                }
                for t, c in self._gap_counters.items()
            }

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
                if self._error is None:
                    try:
                        with self._wlock:
                            self._writer.finish()
                        self._stream.fsync()
                    except OSError as exc:
                        self._error = exc
            finally:
                self._stream.close()
        if self._error is not None:
            raise self._failure() from self._error

    def _failure(self) -> BagWriteError:
        exc = self._error
        if isinstance(exc, BagWriteError):
            return exc
        if isinstance(exc, OSError):
            return BagWriteError(_describe(self.path, exc))
        return BagWriteError(f"{self.path}: writing failed: {exc}")

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

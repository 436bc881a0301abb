"""Sequence accounting of sample streams and message sequences, with one loss taxonomy (ROS-free).

A stream is a run of frames ``[first, first + n)`` of a sample index (``first_sample_index``)
or of messages numbered 1, 2, ... (a publisher's sequence numbers, one index each). Every
frame is classed against the index expected next, by one :class:`StreamIndex` that
estimators, the bag writer, ``mcap_info`` and the player use alike; the loss classes are
:data:`GAP` (transport), :data:`DEVICE_GAP`, :data:`REPEAT`, :data:`OUT_OF_ORDER`,
:data:`RESET`, the missing head (:attr:`StreamIndex.missing_head`) and a stall
(:meth:`StallTimer.stalled`); duplicated messages of a bag (identical topic, log time and
bytes) by :class:`DuplicateFilter`. Also here: a stream's format pin and the pairing of two
streams by index. Docs: docs/recording.md (loss accounting of recordings).
"""

from __future__ import annotations

import hashlib
from collections import deque

#: The first frame of a stream; the frame expected next.
FIRST, NEXT = "first", "next"
#: Samples missing before the frame, lost in transport (not declared by the device).
GAP = "gap"
#: Samples missing before the frame, all declared missing by the device
#: (:meth:`StreamIndex.declare_device_gap`, e.g. a scheduled fault).
DEVICE_GAP = "device_gap"
#: The fault kind by which a device declares a device gap: samples it never delivered
#: (a schedule's ``dropped_samples``, labelled on the device's ``faults`` topic).
DROPPED_SAMPLES = "dropped_samples"
#: A frame whose first index was taken recently (a duplicate).
REPEAT = "repeat"
#: A frame behind the expected index that was not taken (a reordered frame).
OUT_OF_ORDER = "out_of_order"
#: A jump beyond ``max_gap`` either way, or a stream that started again (a restart).
RESET = "reset"
#: Every event :meth:`StreamIndex.update` returns.
EVENTS = (FIRST, NEXT, GAP, DEVICE_GAP, REPEAT, OUT_OF_ORDER, RESET)


class StallTimer:
    """The time of a stream's last change on a clock the caller keeps (monotonic seconds,
    or data time): :meth:`stalled` once it has not changed for longer than a timeout."""

    def __init__(self, now: float | None = None) -> None:
        #: Time of the last change (None: not started).
        self.last_change = now

    def touch(self, now: float) -> None:
        """The stream changed at ``now``."""
        self.last_change = now

    def stalled(self, now: float, timeout: float) -> bool:
        """True if the stream has not changed for more than ``timeout`` before ``now``."""
        return self.last_change is not None and now - self.last_change > timeout


class PublicationStall(StallTimer):
    """Stalls of one publisher, on its own clock (the publication times of its messages
    [s], e.g. the middleware's source timestamps): a silence longer than
    :meth:`bound` after at least :attr:`STEADY` messages (sending steadily) is a stall,
    found when the publisher sends again (:meth:`update`). A silence that ends in a gap the
    device declared (a scheduled device gap) is none. Bounded memory: the last
    :attr:`INTERVALS` intervals.

    :param timeout: least silence that is a stall [s].
    """

    #: Messages before the publisher counts as sending steadily.
    STEADY = 10
    #: A silence shorter than this many times the longest recent interval is no stall.
    FACTOR = 3.0
    #: Recent intervals between messages remembered.
    INTERVALS = 16

    def __init__(self, timeout: float) -> None:
        super().__init__()
        self.timeout = float(timeout)
        self.messages = 0
        #: Stalls found, their total and their longest silence [s].
        self.stalls = 0
        self.stalled_s = self.longest_s = 0.0
        self._intervals: deque[float] = deque(maxlen=self.INTERVALS)

    def bound(self) -> float | None:
        """Silence beyond which the publisher is stalled [s]: the timeout, or
        :attr:`FACTOR` times the longest recent interval if longer; None before it sent
        :attr:`STEADY` messages."""
        if self.messages < self.STEADY or not self._intervals:
            return None
        return max(self.timeout, self.FACTOR * max(self._intervals))

    def update(self, now: float, declared: bool = False) -> float | None:
        """A message published at ``now`` [s] (``declared``: it follows a gap the device
        declared); returns the silence before it [s] if that was a stall, else None. A time
        before the last one (a clock stepped back) is ignored."""
        last, bound = self.last_change, self.bound()
        if last is not None and now < last:
            return None
        self.messages += 1
        self.touch(now)
        if last is None:
            return None
        silence = now - last
        if bound is not None and silence > bound:
            if declared:
                return None
            self.stalls += 1
            self.stalled_s += silence
            self.longest_s = max(self.longest_s, silence)
            return silence
        self._intervals.append(silence)
        return None


class StreamIndex(StallTimer):
    """Sequence accounting of one stream of frames by their first index.

    :meth:`update` classes each frame against :attr:`expected` (``first + n`` of the last
    frame taken):

    * :data:`FIRST`: the first frame; :data:`NEXT`: the expected index;
    * :data:`GAP` / :data:`DEVICE_GAP`: ahead by at most ``max_gap`` (None: any jump ahead);
      a device gap if the device declared every missing sample, else a transport gap;
    * :data:`RESET`: ahead by more than ``max_gap``, behind by more than ``max_gap``, or
      ``restart_frames`` consecutive frames behind the expected index that follow one
      another (a device that started again);
    * :data:`REPEAT`: a frame whose first index is one of the last ``history`` taken;
    * :data:`OUT_OF_ORDER`: any other frame behind the expected index.

    A frame classed first, next, gap or reset is taken (:attr:`expected` moves on); a
    repeated or out-of-order frame is not (its caller drops it). :meth:`recording` gives the
    accounting of a recording, which keeps every frame: history 0 and one frame behind is a
    restart. A declaration may come after the jump it covers (it travels on another topic):
    the samples of a recent transport gap it covers are counted again as a device gap.
    Bounded memory: the last ``history`` first indices, declared device gaps and transport
    gaps.
    """

    #: Consecutive frames behind the expected index, each following the previous one, that
    #: make a stream reset (a device or a replay that started again).
    RESTART_FRAMES = 3
    #: First indices remembered to recognise repeated frames.
    HISTORY = 64
    #: Declared device gaps remembered ahead of the stream.
    MAX_DECLARED = 1024
    #: Recent transport gaps remembered for a declaration that comes after its jump.
    MAX_TRANSPORT_GAPS = 1024

    def __init__(
        self,
        max_gap: int | None = 2**32,
        history: int = HISTORY,
        restart_frames: int = RESTART_FRAMES,
        start: int | None = None,
    ) -> None:
        super().__init__()
        self.max_gap = None if max_gap is None else int(max_gap)
        self.restart_frames = int(restart_frames)
        #: Index the stream begins at (0 for a device's samples, 1 for sequence numbers);
        #: None: unknown (no missing head is counted).
        self.start = start
        self.expected: int | None = None
        #: First index of the first frame (None before it).
        self.first: int | None = None
        #: whether the last stream reset jumped ahead (True) or back (False)
        self.ahead = False
        self.frames = self.samples = 0
        self.gaps = self.missing_samples = 0
        self.device_gaps = self.device_missing_samples = 0
        self.repeats = self.out_of_order = self.resets = 0
        self._recent: deque[int] = deque(maxlen=int(history))
        self._behind_next: int | None = None
        self._behind_run = 0
        self._declared: deque[tuple[int, int]] = deque(maxlen=self.MAX_DECLARED)
        #: Recent jumps with undeclared samples: [undeclared ranges, counted a device gap].
        self._transport: deque[list] = deque(maxlen=self.MAX_TRANSPORT_GAPS)

    @classmethod
    def recording(cls, start: int | None = None) -> StreamIndex:
        """The accounting of a recording, which keeps every frame it gets: any jump ahead is
        a gap, any frame behind a reset (taken, :attr:`expected` follows it)."""
        return cls(max_gap=None, history=0, restart_frames=1, start=start)

    @property
    def missing_head(self) -> int:
        """Indices missing before the first frame (a recording that started after its
        stream): ``first - start``, 0 if unknown or none."""
        if self.first is None or self.start is None:
            return 0
        return max(self.first - self.start, 0)

    def is_repeat(self, first: int) -> bool:
        """True if a frame starting at ``first`` was taken recently."""
        return first in self._recent

    def declare_device_gap(self, first: int, n: int) -> None:
        """The device declares that indices ``[first, first + n)`` will not come: a jump
        over them is a device gap, counted apart from transport loss; a recent jump already
        counted as transport loss over them is counted again (class doc)."""
        first, n = int(first), int(n)
        if n <= 0:
            return
        self._declared.append((first, first + n))
        if self._transport:
            self._reclass(first, first + n)

    def _reclass(self, lo: int, hi: int) -> None:
        """Move the samples of ``[lo, hi)`` in recent transport gaps to device gaps."""
        for jump in self._transport:
            kept, moved = [], 0
            for a, b in jump[0]:
                cut_a, cut_b = max(a, lo), min(b, hi)
                if cut_b <= cut_a:
                    kept.append((a, b))
                    continue
                moved += cut_b - cut_a
                kept += [r for r in ((a, cut_a), (cut_b, b)) if r[1] > r[0]]
            if not moved:
                continue
            jump[0] = kept
            self.missing_samples -= moved
            self.device_missing_samples += moved
            if not jump[1]:
                jump[1] = True
                self.device_gaps += 1
            if not kept:
                self.gaps -= 1
        while self._transport and not self._transport[0][0]:
            self._transport.popleft()

    def _declared_in(self, lo: int, hi: int) -> int:
        """Indices of ``[lo, hi)`` that the device declared missing (ranges may overlap)."""
        cuts = sorted((max(a, lo), min(b, hi)) for a, b in self._declared if a < hi and b > lo)
        total, reach = 0, lo
        for a, b in cuts:
            a = max(a, reach)
            if b > a:
                total, reach = total + b - a, b
        return total

    def update(self, first: int, n: int = 1, now: float | None = None) -> tuple[str, int]:
        """Class (and take, see the class doc) a frame of ``n`` indices at ``first`` (one:
        a message's sequence number), at time ``now`` if the caller keeps one
        (:meth:`stalled`); returns ``(event, indices missing before it)``."""
        first, n = int(first), int(n)
        if now is not None:
            self.last_change = now
        expected, missing = self.expected, 0
        if first == expected:
            event = NEXT
        elif expected is None:
            event = FIRST
            self.first = first
        elif first > expected:
            missing = first - expected
            if self.max_gap is None or missing <= self.max_gap:
                event = self._count_gap(expected, first)
            else:
                event = self._count_reset(first, expected)
        elif first in self._recent:
            self.repeats += 1
            return REPEAT, 0
        elif self.max_gap is not None and expected - first > self.max_gap:
            event = self._count_reset(first, expected)
        else:
            self._behind_run = self._behind_run + 1 if self._behind_next == first else 1
            self._behind_next = first + n
            if self._behind_run < self.restart_frames:
                self.out_of_order += 1
                return OUT_OF_ORDER, 0
            event = self._count_reset(first, expected)
        self.expected = first + n
        self._recent.append(first)
        if self._behind_run:
            self._behind_next, self._behind_run = None, 0
        self.frames += 1
        self.samples += n
        if self._declared:
            while self._declared and self._declared[0][1] <= self.expected:
                self._declared.popleft()
        return event, missing

    def _count_reset(self, first: int, expected: int) -> str:
        self.resets += 1
        self._recent.clear()
        self.ahead = first > expected
        return RESET

    def _count_gap(self, expected: int, first: int) -> str:
        declared = self._declared_in(expected, first) if self._declared else 0
        if declared:
            self.device_gaps += 1
            self.device_missing_samples += declared
        transport = first - expected - declared
        if transport:
            self.gaps += 1
            self.missing_samples += transport
            self._transport.append([self._undeclared(expected, first), bool(declared)])
        return GAP if transport else DEVICE_GAP

    def _undeclared(self, lo: int, hi: int) -> list[tuple[int, int]]:
        """The ranges of ``[lo, hi)`` that no declared device gap covers."""
        return uncovered(self._declared, lo, hi)


def uncovered(ranges, lo: int, hi: int) -> list[tuple[int, int]]:
    """The parts of ``[lo, hi)`` that none of the index ranges ``[a, b)`` of ``ranges``
    covers (they may overlap), in order."""
    out, reach = [], lo
    for a, b in sorted((max(a, lo), min(b, hi)) for a, b in ranges if a < hi and b > lo):
        if a > reach:
            out.append((reach, a))
        reach = max(reach, b)
    if reach < hi:
        out.append((reach, hi))
    return out


class SequenceIndex(StreamIndex):
    """A publisher's message sequence numbers (1, 2, 3, ...) as a recording counts them
    (:meth:`StreamIndex.recording`, one index per message, starting at 1): a number larger
    than the previous plus one is a gap, one not larger a reset."""

    def __init__(self) -> None:
        super().__init__(max_gap=None, history=0, restart_frames=1, start=1)

    @property
    def messages(self) -> int:
        """Messages counted."""
        return self.frames

    @property
    def missing_messages(self) -> int:
        """Messages missing in the gaps."""
        return self.missing_samples

    @property
    def last(self) -> int | None:
        """The last number seen (None before any)."""
        return None if self.expected is None else self.expected - 1


class FormatPin:
    """The format of one stream (a tuple the caller builds, e.g. sample rate and channels):
    the first good frame's; a frame of another format is foreign (rejected) unless
    :attr:`ADOPT_FRAMES` consecutive frames share it, then that format is adopted."""

    #: Consecutive frames of one new format after which it replaces the stream's.
    ADOPT_FRAMES = 3

    def __init__(self) -> None:
        self.format: tuple | None = None
        self._candidate: tuple | None = None
        self._count = 0

    def check(self, fmt: tuple) -> str:
        """``"new"`` (no format yet), ``"same"``, ``"adopt"`` (the new format's
        :attr:`ADOPT_FRAMES`-th consecutive frame) or ``"foreign"``."""
        if self.format is None:
            return "new"
        if fmt == self.format:
            self._candidate, self._count = None, 0
            return "same"
        if fmt == self._candidate:
            self._count += 1
        else:
            self._candidate, self._count = fmt, 1
        return "adopt" if self._count >= self.ADOPT_FRAMES else "foreign"

    def adopt(self, fmt: tuple) -> None:
        """Make ``fmt`` the stream's format."""
        self.format, self._candidate, self._count = fmt, None, 0


class FramePairer:
    """Pairs the frames of two streams (e.g. ADC and drive) that share a first index, in
    index order.

    Frames waiting for their partner are bounded per stream: at most ``max_samples``
    samples (None: no bound) and ``max_frames`` frames; beyond, the oldest (by arrival)
    are dropped and listed in :attr:`overflow` (the caller counts them).
    """

    def __init__(self, kinds: tuple[str, str], max_samples: int | None, max_frames: int) -> None:
        self.kinds = kinds
        self.max_samples = max_samples
        self.max_frames = max_frames
        self.frames: dict[str, dict[int, object]] = {k: {} for k in kinds}
        self._sizes: dict[str, dict[int, int]] = {k: {} for k in kinds}
        self.samples = {k: 0 for k in kinds}
        self.overflow: list[tuple[str, int, int]] = []

    def holds(self, kind: str, first: int) -> bool:
        """True if a frame of ``kind`` at ``first`` waits for its partner."""
        return first in self.frames[kind]

    def add(self, kind: str, first: int, values, n: int):
        """Store one frame of stream ``kind`` (``n`` samples); return the pairs now
        complete, ordered by index as ``(first, values of kinds[0], values of kinds[1])``.
        The frames dropped to respect the bounds are in :attr:`overflow` as ``(kind,
        first, n)`` until the next call."""
        n = int(n)
        self.frames[kind][first] = values
        self._sizes[kind][first] = n
        self.samples[kind] += n
        a, b = (self.frames[k] for k in self.kinds)
        pairs = []
        for k in sorted(set(a) & set(b)):
            pairs.append((k, a.pop(k), b.pop(k)))
            for kk in self.kinds:
                self.samples[kk] -= self._sizes[kk].pop(k)
        self.overflow = []
        store, sizes = self.frames[kind], self._sizes[kind]
        while len(store) > 1 and (
            len(store) > self.max_frames
            or (self.max_samples is not None and self.samples[kind] > self.max_samples)
        ):
            old = next(iter(store))
            del store[old]
            size = sizes.pop(old)
            self.samples[kind] -= size
            self.overflow.append((kind, old, size))
        return pairs

    def drop_before(self, index: int) -> list[tuple[str, int, int]]:
        """Drop the waiting frames that start before ``index`` (they can no longer be
        taken in order); return them as ``(kind, first, n)``."""
        dropped = []
        for kind in self.kinds:
            store = self.frames[kind]
            for first in [f for f in store if f < index]:
                del store[first]
                size = self._sizes[kind].pop(first)
                self.samples[kind] -= size
                dropped.append((kind, first, size))
        return dropped


class DuplicateFilter:
    """Duplicated messages: identical topic, log time [ns] and bytes (a chunk or a file
    stored twice, a writer that wrote a message again), the taxonomy's *duplicate*; where
    the format numbers messages (MCAP's ``sequence``), the same number too, so that a
    publisher that sent the same bytes twice at one time (sim time standing) is not one.

    :meth:`seen` tells a message met before (a duplicate, counted per topic in
    :attr:`counts`; its caller uses it once) from a new one. Bounded memory: the keys
    (topic, log time, a 128-bit BLAKE2b digest of sequence and bytes) of the last ``window``
    messages only. In log-time order duplicates are neighbours (equal log times), and in
    file order a chunk stored twice repeats within its own length, so a window larger than
    the messages of one log time or one chunk sees every duplicate.
    """

    #: Messages remembered (about 16 MB of keys).
    WINDOW = 1 << 16

    def __init__(self, window: int = WINDOW) -> None:
        self.window = int(window)
        #: Duplicates per topic.
        self.counts: dict[str, int] = {}
        self._order: deque[tuple[str, int, bytes]] = deque()
        self._keys: set[tuple[str, int, bytes]] = set()

    @property
    def total(self) -> int:
        """Duplicates of all topics."""
        return sum(self.counts.values())

    def seen(self, topic: str, log_time_ns: int, data: bytes, sequence: int = 0) -> bool:
        """True (and counted) if this message was met within the window, else False (and
        remembered). ``sequence``: the message's number in the file (0: none)."""
        digest = hashlib.blake2b(data, digest_size=16, salt=int(sequence).to_bytes(8, "little"))
        key = (topic, int(log_time_ns), digest.digest())
        if key in self._keys:
            self.counts[topic] = self.counts.get(topic, 0) + 1
            return True
        self._keys.add(key)
        self._order.append(key)
        if len(self._order) > self.window:
            self._keys.discard(self._order.popleft())
        return False


def describe_missing_head(samples: int) -> str:
    """The loss phrase of a missing head of ``samples`` sample indices (recorder summary,
    ``mcap_info``)."""
    return f"missing head ({samples} samples before the first frame)"

"""Input side shared by the estimator nodes: the device's topics, validation of every frame,
sequence accounting, pairing of a device's ADC and drive frames, rejection of bad frames
counted on /diagnostics, and the progress report of lossless replay.

Every estimator node is an :class:`EstimatorNode`. Its device topics (``adc``, ``drive``,
``estimate``, ...) are relative names resolved in the node's namespace, unless the
parameter ``device_namespace`` names another one; so a node started in a device's
namespace (``-r __ns:=/a``) finds that device, and each node class has the usual namespace
of its device as default.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray

from mems_msgs.msg import AdcFrame, SignalFrame
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.device_gaps import (
    FAULT_EVENT_TYPE,
    FAULTS_SUBSCRIPTION_QOS,
    FAULTS_TOPIC,
    MAX_DECLARATIONS,
    declared_gap,
)
from mems_sim.ros.end_of_stream import END_OF_STREAM, END_OF_STREAM_QOS, parse_end_of_stream
from mems_sim.ros.flow import ProgressReporter
from mems_sim.ros.frames import (
    FrameError,
    adc_codes,
    adc_physical,
    code_range,
    frame_format,
    index_to_ns,
    signal_data,
    time_to_ns,
)
from mems_sim.ros.node_base import MemsNode
from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS
from mems_sim.stream_index import (
    DEVICE_GAP,
    GAP,
    OUT_OF_ORDER,
    REPEAT,
    RESET,
    FormatPin,
    FramePairer,
    StreamIndex,
)

#: Parameter of the estimator nodes that read a device's topics.
DEVICE_NAMESPACE = ParamSpec(
    "device_namespace",
    "",
    "-",
    "namespace of the device's topics; empty: the node's own namespace",
    "",
)

#: Limits of the input path of every estimator node (:func:`input_specs` sets the
#: defaults of a node).
INPUT_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "max_frame_samples",
        1_000_000,
        "samples",
        "largest input frame taken; a larger one is rejected and counted",
        "chosen: bounds the memory and time one frame may take",
        min=1,
        max=2**31 - 1,
    ),
    ParamSpec(
        "max_unpaired_samples",
        2_000_000,
        "samples",
        "samples of frames kept per input stream while they wait for their partner frame; "
        "beyond it the oldest are dropped and counted",
        "chosen: bounds the pairing buffers",
        min=1,
        max=2**31 - 1,
    ),
    ParamSpec(
        "exit_when_input_ended",
        False,
        "-",
        "once the primary input's device announced its end (end-of-stream record) and "
        "every sample up to it is done, the node publishes its final results and its "
        "process exits with status 0 (run_graph then ends); false: runs until shut down",
        "",
    ),
    ParamSpec(
        "max_gap_samples",
        2**32,
        "samples",
        "largest forward jump of first_sample_index handled as a gap; a larger jump (or "
        "one back by more) is a stream reset: the estimator starts again (from its prior, "
        "or as its node documents)",
        "chosen: 2^32 samples, over an hour at 1 MHz",
        min=1,
        max=2**62,
    ),
)


def input_specs(paired: bool = True, **defaults) -> tuple[ParamSpec, ...]:
    """:data:`INPUT_SPECS` with some defaults replaced (e.g. ``max_frame_samples=100_000``);
    without ``max_unpaired_samples`` for a node that pairs no frames (``paired=False``)."""
    unknown = set(defaults) - {s.name for s in INPUT_SPECS}
    if unknown:
        raise KeyError(f"not input parameters: {sorted(unknown)}")
    return tuple(
        dataclasses.replace(s, default=defaults[s.name]) if s.name in defaults else s
        for s in INPUT_SPECS
        if paired or s.name != "max_unpaired_samples"
    )


#: One input stream: (topic name relative to the device, message type, decoder). The
#: decoder returns the frame's values (an array of n samples, or a tuple of such arrays)
#: or raises FrameError.
Input = tuple[str, type, Callable[[Any], Any]]


def device_topic(namespace: str, name: str) -> str:
    """Topic ``name`` of the device in ``namespace``; ``''``: relative ``name`` (the node's
    own namespace)."""
    return f"{namespace.rstrip('/')}/{name}" if namespace else name


#: Latest time a builtin_interfaces/Time holds (int32 seconds) [ns].
MAX_STAMP_NS = (2**31 - 1) * 10**9 + 999_999_999


def set_stamp(msg, ns: int) -> None:
    """``msg.header.stamp`` = ``ns`` [ns], saturated to [0, :data:`MAX_STAMP_NS`] (the range
    of builtin_interfaces/Time: a stream index far beyond it has no representable time)."""
    ns = min(max(int(ns), 0), MAX_STAMP_NS)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)


def output_frame(make, *arrays, first: int, fs: float, stamp_ns: int | None = None, **kwargs):
    """``make(*arrays, first, fs, **kwargs)`` (``make_state_estimate`` or
    ``make_signal_frame``) whose header stamp is ``stamp_ns`` [ns] (default: the time of
    sample ``first`` at ``fs``), saturated by :func:`set_stamp`: any uint64 index works."""
    msg = make(*arrays, 0, fs, **kwargs)
    msg.first_sample_index = int(first)
    set_stamp(msg, index_to_ns(first, fs) if stamp_ns is None else stamp_ns)
    return msg


def num_samples(values) -> int:
    """Samples of decoded frame values (an array, or a tuple of arrays of equal length)."""
    return int(np.shape(values[0] if isinstance(values, tuple) else values)[0])


def adc_columns(msg: AdcFrame, cols, codes: np.ndarray | None = None) -> np.ndarray:
    """Physical values (n, len(cols)), C-contiguous, of the channels ``cols`` (indices) of
    an AdcFrame: ``adc_physical(msg)[:, cols]`` bit for bit (each value ``code * lsb +
    offset`` in float64), without converting the other channels. ``codes``: the frame's
    codes from :func:`~mems_sim.ros.frames.adc_codes` if already validated.

    Raises:
        FrameError: as ``adc_physical`` (every channel's conversion checked): malformed
            fields, codes out of range, or a conversion that overflows (``non_finite``).
    """
    if codes is None:
        codes = adc_codes(msg)
    nch = codes.shape[1]
    lsb = np.asarray(msg.lsb, dtype=float)
    offset = np.asarray(msg.offset, dtype=float) if len(msg.offset) else np.zeros(nch)
    # code -> code * lsb + offset rounds monotonically (lsb > 0): finite at both ends of
    # the declared code range, finite for every code of the frame (validated in range)
    lo, hi = code_range(int(msg.bits))
    with np.errstate(over="ignore", invalid="ignore"):
        ends = np.concatenate([lo * lsb + offset, hi * lsb + offset])
    if not np.all(np.isfinite(ends)):
        return np.ascontiguousarray(adc_physical(msg)[:, list(cols)])
    out = np.empty((codes.shape[0], len(cols)))
    for j, c in enumerate(cols):
        col = out[:, j]
        np.multiply(codes[:, c], lsb[c], out=col)
        col += offset[c]
    return out


def adc_channels(msg: AdcFrame, channels, codes: np.ndarray | None = None) -> np.ndarray:
    """Physical values (n, len(channels)), C-contiguous, of the named channels of an
    AdcFrame (:func:`adc_columns`); FrameError as ``adc_physical``, then ``foreign`` when a
    channel is absent."""
    if codes is None:
        codes = adc_codes(msg)
    names = list(msg.channel_names)
    missing = [c for c in channels if c not in names]
    if missing:
        adc_columns(msg, [], codes)  # an overflow is reported first, as adc_physical does
        raise FrameError(
            f"adc frame at {msg.first_sample_index}: channels {missing} absent", "foreign"
        )
    return adc_columns(msg, [names.index(c) for c in channels], codes)


def drive_channels(msg: SignalFrame, channels) -> tuple[np.ndarray, ...]:
    """The named channels of a drive SignalFrame, each a C-contiguous column (values as
    :func:`~mems_sim.ros.frames.signal_data` decodes them); FrameError ``foreign`` naming
    the first absent one."""
    data = signal_data(msg)
    names = list(msg.channel_names)
    for c in channels:
        if c not in names:
            raise FrameError(
                f"drive frame at {msg.first_sample_index}: no '{c}' channel", "foreign"
            )
    return tuple(np.ascontiguousarray(data[:, names.index(c)]) for c in channels)


class EstimatorNode(MemsNode):
    """Base of the estimator nodes: parameters, device topics, diagnostics, frame input.

    Every input frame goes through one path, whose events are counted on /diagnostics
    (counter names in quotes); nothing in it allocates in proportion to an index jump,
    and its buffers are bounded:

    1. Validation (:meth:`take_frame`): a frame without samples (``rejected_empty``), with
       more than ``max_frame_samples`` samples (``rejected_oversized``), with inconsistent
       fields or sizes (``rejected_malformed``), with codes outside the declared bit range
       of an AdcFrame (``rejected_out_of_range``), with non-finite values or a code
       conversion that overflows (``rejected_non_finite``), at another sample rate than
       the model's ``self.fs`` or of another format than its stream's
       (``rejected_foreign``) is rejected: ``rejected_frames`` and a warning. A stream's
       format (sample rate, channel names and units, and an AdcFrame's bits, lsb, offset
       and full scale) is its first good frame's; a stray frame of another format is
       rejected, not adopted; only :attr:`FormatPin.ADOPT_FRAMES` consecutive frames of
       one new format replace it (``format_changes``, :meth:`on_format_change`).
    2. Sequence (:class:`~mems_sim.stream_index.StreamIndex` on ``first_sample_index``,
       the loss taxonomy of :mod:`mems_sim.stream_index`): a repeated frame is
       dropped (``repeated_frames``), a frame behind the stream is dropped
       (``out_of_order_frames``), a forward jump up to ``max_gap_samples`` is a gap
       (``gaps``, ``missing_samples``, warning with :attr:`GAP_NOTE`, then :meth:`on_gap`;
       samples the device declared dropped on its ``faults`` topic,
       :meth:`follow_device_faults`, are ``device_gaps``, ``device_missing_samples``),
       a larger jump (either way) or a stream that started again is a stream reset
       (``stream_resets``, then :meth:`on_stream_reset`, told whether the jump was ahead:
       by default the estimator starts again from its prior, :meth:`reset_estimator`; a
       node may take a jump ahead as a long gap).
    3. Pairing (:meth:`subscribe_pair`): good frames of the two streams are paired by
       ``first_sample_index``; frames waiting for their partner are bounded to
       ``max_unpaired_samples`` samples (and :data:`~mems_sim.ros.qos.FRAME_DEPTH`
       frames) per stream, the oldest dropped beyond (``unpaired_overflow_frames``);
       waiting frames left behind by the stream are dropped (``unpaired_stale_frames``);
       a pair of unequal lengths is rejected (``rejected_malformed``).
    4. Estimation: the pair goes to :meth:`process_pair`, which may raise FrameError
       (rejected) or :class:`Diverged` (the filter's state became non-finite or its
       covariance lost positive definiteness; the node has re-initialised it from its
       prior; ``divergences`` and a warning, the frame's estimates are not published);
       then ``frames_done`` and the ``frames`` counter grow. A single stream
       (:meth:`subscribe_single`) goes the same way to :meth:`process_frame` (the
       ``frames`` counter and ``frames_received``); other streams use :meth:`take_frame`
       and :meth:`sequence`.

    Progress (flow control of lossless replay): after every frame of the primary input
    (the first stream of :meth:`subscribe_pair`, or the single input) that the node has
    finished with -- processed, rejected or dropped --, the node publishes on
    ``~/progress`` (``/<namespace>/<node name>/progress``, std_msgs/msg/UInt64, reliable,
    transient local, depth 1) one past the last sample index of that input it has
    finished with: ``first_sample_index + num_samples``, the largest so far (a rejected
    frame counts at most ``max_frame_samples``; a rejected or dropped frame more than
    ``max_gap_samples`` away from it does not move it); after a stream reset it follows
    the new stream. A player keeps a bounded credit of samples ahead of it.

    End of the input (:meth:`follow_end_of_stream`): a node that holds samples back (a
    smoother's lag, a whole sweep) follows the device's latched end-of-stream record and
    gets :meth:`input_ended` once its progress reaches the announced end of the stream.

    The constructor arguments are :class:`~mems_sim.ros.node_base.MemsNode`'s (every
    parameter is set at start; ``specs`` with :data:`DEVICE_NAMESPACE` and
    :func:`input_specs` if the node reads a device's topics, ``default_namespace`` the
    usual namespace of that device).
    """

    #: Said after "gap of N samples before index K" (what the node does about it).
    GAP_NOTE = ""
    #: Sample rate of the model [Hz]: frames at another rate are rejected (None: any rate).
    fs: float | None = None
    #: Pairs processed.
    frames_done = 0
    #: Frames of the single input received (:meth:`subscribe_single`).
    frames_received = 0
    #: The two paired streams (set by :meth:`subscribe_pair`).
    pairer: FramePairer | None = None
    #: Event of the last frame accounted by :meth:`sequence`.
    last_event = ""

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        self._formats: dict[str, FormatPin] = {}
        self._indices: dict[str, StreamIndex] = {}
        #: Samples the device declared dropped on its faults topic: (first, n).
        self._device_gaps: list[tuple[int, int]] = []
        self._faults_sub = None
        self.primary: str | None = None
        #: (AdcFrame, its validated codes) while :meth:`take_frame` decodes it
        self._adc_checked: tuple | None = None
        #: Progress of the primary input on ``~/progress`` (:mod:`mems_sim.ros.flow`).
        self.progress_reporter = ProgressReporter(self, self._limit("max_gap_samples"))
        #: End sample index of the input announced by the device, until reached.
        self.announced_end: int | None = None
        self._end_topic: str | None = None
        #: True once the announced end of the input was reached (:meth:`input_ended`).
        self.input_done = False

    def follow_end_of_stream(self, name: str = "adc", topic: str | None = None) -> None:
        """Subscribe to the device's end-of-stream record (latched): once the node has
        finished with its primary input up to the end sample index announced for the
        device's topic ``name`` (or ``topic``, its own input topic), :meth:`input_ended` is
        called (once per announcement). Once only: a second call changes nothing."""
        if self._end_topic is not None:
            return
        self._end_topic = self.resolve_topic_name(topic or self.device_topic(name))
        self.create_subscription(
            DiagnosticArray,
            self.device_topic(END_OF_STREAM),
            self._on_end_of_stream,
            END_OF_STREAM_QOS,
        )

    def _on_end_of_stream(self, msg: DiagnosticArray) -> None:
        entry = parse_end_of_stream(msg).get(self._end_topic, {})
        if "end_sample_index" not in entry:
            return
        self.announced_end = int(entry["end_sample_index"])
        self._check_input_end()

    def _check_input_end(self) -> None:
        end = self.announced_end
        if end is not None and self.progress is not None and self.progress >= end:
            self.announced_end = None
            self.input_ended()
            self.input_done = True

    def _end_with_input(self, topic: str) -> None:
        """``exit_when_input_ended``: follow the end of the primary input ``topic``."""
        if self.p.get("exit_when_input_ended"):
            self.follow_end_of_stream(topic=topic)

    def run_ended(self) -> bool:
        """True once the node's process may exit (``exit_when_input_ended`` and the
        announced end of the input reached); the process's main
        (:func:`~mems_sim.ros.node_main.run_nodes`) then closes the node (final results)."""
        return bool(self.p.get("exit_when_input_ended")) and self.input_done

    def input_ended(self) -> None:
        """The input announced as ended is all done (:meth:`follow_end_of_stream`);
        nodes that hold samples back publish them here."""

    def parameter_file(self, name: str, load: Callable[[str], Any]):
        """``load(path)`` of the file the parameter ``name`` names (an identified model's
        YAML); a missing or broken file is refused as the parameter's invalid value
        (ParameterError naming it)."""
        try:
            return load(self.p[name])
        except (FileNotFoundError, ValueError) as exc:
            raise ParameterError(
                f"parameter {name!r} = {self.p[name]!r} is invalid: {exc}"
            ) from None

    def device_topic(self, name: str) -> str:
        """Topic ``name`` of the device (``device_namespace``, or relative)."""
        return device_topic(self.p.get("device_namespace", ""), name)

    def _limit(self, name: str) -> int:
        return int(self.p.get(name, next(s.default for s in INPUT_SPECS if s.name == name)))

    # ------------------------------------------------------------------ progress

    @property
    def progress(self) -> int | None:
        """One past the last sample index of the primary input finished with (None
        before the first frame)."""
        return self.progress_reporter.value

    def report_progress(self, end: int, follow: bool = False) -> None:
        """Publish the progress ``end`` (one past a sample index of the primary input):
        the largest so far, or ``end`` itself if ``follow`` (a stream reset)."""
        self.progress_reporter.report(end, follow)
        if self.announced_end is not None:
            self._check_input_end()

    def _finished(self, kind: str, end: int, follow: bool = False) -> None:
        if kind == self.primary:
            self.report_progress(end, follow)

    # ------------------------------------------------------------------ single frames

    def reject(self, text: str, reason: str = "malformed") -> None:
        """Count a rejected frame (``rejected_frames`` and ``rejected_<reason>``) and warn
        on /diagnostics (the node keeps running)."""
        self.diag.count("rejected_frames")
        self.diag.count(f"rejected_{reason}")
        self.diag.warn(f"rejected frame: {text}")

    def check_rate(self, msg) -> None:
        """FrameError unless the frame's sample rate is the model's ``self.fs`` [Hz]."""
        if self.fs is not None and msg.sample_rate_hz != self.fs:
            raise FrameError(
                f"frame at {msg.first_sample_index}: sample_rate_hz "
                f"{msg.sample_rate_hz} differs from the model's {self.fs} Hz",
                "foreign",
            )

    def take_frame(self, kind: str, msg, decode: Callable[[Any], Any], check_rate: bool = True):
        """Validate a frame of input stream ``kind`` (class doc, step 1) and return
        ``decode(msg)``; None if it was rejected (counted, and reported as progress if
        ``kind`` is the primary input)."""
        pin = self._formats.setdefault(kind, FormatPin())
        verdict = "same"
        try:
            n = int(msg.num_samples)
            if n == 0:
                raise FrameError(f"frame at {msg.first_sample_index}: no samples", "empty")
            if n > self._limit("max_frame_samples"):
                raise FrameError(
                    f"frame at {msg.first_sample_index}: {n} samples, more than "
                    f"max_frame_samples = {self._limit('max_frame_samples')}",
                    "oversized",
                )
            if check_rate:
                self.check_rate(msg)
            if isinstance(msg, AdcFrame):
                self._adc_checked = (msg, adc_codes(msg))
            fmt = frame_format(msg)
            verdict = pin.check(fmt)
            if verdict == "foreign":
                raise FrameError(
                    f"{kind} frame at {msg.first_sample_index}: another sample rate, channel "
                    f"set or format than the stream's ({msg.sample_rate_hz} Hz, "
                    f"{list(getattr(msg, 'channel_names', getattr(msg, 'state_names', [])))})",
                    "foreign",
                )
            values = decode(msg)
        except FrameError as exc:
            self.reject(str(exc), exc.reason)
            n = min(int(msg.num_samples), self._limit("max_frame_samples"))
            self._finished(kind, int(msg.first_sample_index) + n)
            return None
        finally:
            self._adc_checked = None
        if verdict in ("new", "adopt"):
            pin.adopt(fmt)
        if verdict == "adopt":
            self.diag.count("format_changes")
            self.diag.warn(
                f"{kind}: {FormatPin.ADOPT_FRAMES} consecutive frames of a new format "
                f"({msg.sample_rate_hz} Hz) from index {msg.first_sample_index}: adopted"
            )
            self.on_format_change(kind)
        return values

    def checked_codes(self, msg: AdcFrame) -> np.ndarray:
        """The codes (n, channels) of an AdcFrame (:func:`~mems_sim.ros.frames.adc_codes`):
        those :meth:`take_frame` validated if it is decoding ``msg``, else validated now."""
        checked = self._adc_checked
        if checked is not None and checked[0] is msg:
            return checked[1]
        return adc_codes(msg)

    def accept_frame(self, msg, decode: Callable[[Any], Any], check_rate: bool = True):
        """:meth:`take_frame` of the single input stream ``"input"``."""
        return self.take_frame("input", msg, decode, check_rate)

    def index(self, kind: str) -> StreamIndex:
        """Sequence accounting of input stream (or pair) ``kind``."""
        if kind not in self._indices:
            index = self._indices[kind] = StreamIndex(self._limit("max_gap_samples"))
            for first, n in self._device_gaps:
                index.declare_device_gap(first, n)
        return self._indices[kind]

    def follow_device_faults(self) -> None:
        """Subscribe to the device's ``faults`` topic (once): samples it declares dropped
        (a scheduled ``dropped_samples`` fault) are a device gap of every input stream,
        counted as ``device_gaps`` and ``device_missing_samples``, not as loss; a
        declaration that comes after the jump moves the counts of that gap."""
        if self._faults_sub is not None:
            return
        from mems_msgs.msg import FaultEvent

        self._faults_sub = self.create_subscription(
            FaultEvent,
            self.device_topic(FAULTS_TOPIC),
            self._on_device_fault,
            FAULTS_SUBSCRIPTION_QOS,
            raw=True,
        )

    def _on_device_fault(self, data: bytes) -> None:
        topic = self._faults_sub.topic_name
        gap = declared_gap(topic, FAULT_EVENT_TYPE, data)
        if gap is None:
            return
        if len(self._device_gaps) < MAX_DECLARATIONS:
            self._device_gaps.append(gap)
        for index in self._indices.values():
            before = (index.gaps, index.missing_samples, index.device_gaps)
            index.declare_device_gap(*gap)
            moved = before[1] - index.missing_samples
            if moved:  # a jump counted as loss before its declaration came
                self.diag.count("gaps", index.gaps - before[0])
                self.diag.count("missing_samples", -moved)
                self.diag.count("device_gaps", index.device_gaps - before[2])
                self.diag.count("device_missing_samples", moved)

    def sequence(self, kind: str, first: int, n: int, streams: int = 1, hooks: bool = True) -> bool:
        """Account a good frame (or pair of ``streams`` frames) of n samples at ``first``
        (class doc, step 2); True if it is to be processed, False if it was dropped. The
        event (:meth:`StreamIndex.update`) is left in :attr:`last_event`; :meth:`on_gap` and
        :meth:`on_stream_reset` are called only if ``hooks`` (the estimator's main input)."""
        index = self.index(kind)
        expected, lost, declared = (
            index.expected,
            index.missing_samples,
            index.device_missing_samples,
        )
        event, missing = index.update(first, n)
        self.last_event = event
        if event in (REPEAT, OUT_OF_ORDER):
            name = "repeated" if event == REPEAT else "out_of_order"
            self.diag.count(f"{name}_frames", streams)
            self.diag.warn(
                f"dropped {name.replace('_', '-')} frame at {first} (stream at {expected})"
            )
            return False
        if event == RESET:
            self.diag.count("stream_resets")
            self.diag.warn(
                f"stream reset of {kind} at index {first} (stream at {expected}; a jump "
                f"beyond max_gap_samples = {self._limit('max_gap_samples')} or a restart)"
            )
            if hooks:
                self.on_stream_reset(index.ahead)
        elif event in (GAP, DEVICE_GAP):
            self.note_gap(first, index.missing_samples - lost)
            self.note_device_gap(first, index.device_missing_samples - declared)
            if hooks:
                self.on_gap(missing)
        return True

    def note_gap(self, first: int, gap: int) -> None:
        """Count and report ``gap`` samples missing before index ``first`` (if any)."""
        if gap:
            self.diag.count("gaps")
            self.diag.count("missing_samples", int(gap))
            note = f": {self.GAP_NOTE}" if self.GAP_NOTE else ""
            self.diag.warn(f"gap of {gap} samples before index {first}{note}")

    def note_device_gap(self, first: int, gap: int) -> None:
        """Count and report ``gap`` samples before index ``first`` that the device declared
        missing (:meth:`~mems_sim.stream_index.StreamIndex.declare_device_gap`), if any."""
        if gap:
            self.diag.count("device_gaps")
            self.diag.count("device_missing_samples", int(gap))
            self.diag.warn(f"device gap of {gap} samples before index {first} (declared)")

    def note_divergence(self, what: str, first: int) -> None:
        """Count (``divergences``) and report a filter re-initialised from its prior after
        it diverged in the frame at ``first``."""
        self.diag.count("divergences")
        self.diag.warn(
            f"{what} diverged in the frame at {first} (non-finite state or covariance not "
            "positive definite): re-initialised from its prior"
        )

    # ------------------------------------------------------------------ single stream

    def subscribe_single(self, stream: Input, check_rate: bool = True, topic: str | None = None):
        """Subscribe the single input stream (the primary input, named ``"input"``) whose
        good frames go to :meth:`process_frame`; ``topic``: its topic instead of the
        device's topic of the stream's name. Returns the subscription."""
        name, msg_type, decode = stream
        self.primary = "input"
        callback = partial(self._on_single, decode, check_rate)
        topic = self.device_topic(name) if topic is None else topic
        self._end_with_input(topic)
        self.follow_device_faults()
        return self.create_subscription(msg_type, topic, callback, FRAME_QOS)

    def _on_single(self, decode, check_rate: bool, msg) -> None:
        self.frames_received += 1
        first, n = int(msg.first_sample_index), int(msg.num_samples)
        values = self.accept_frame(msg, decode, check_rate)
        if values is None:
            return
        if not self.sequence("input", first, n):
            self.report_progress(first + n)
            return
        follow = self.last_event == RESET
        try:
            self.process_frame(first, time_to_ns(msg.header.stamp), values, msg)
        except FrameError as exc:
            self.reject(str(exc), exc.reason)
            self.report_progress(first + n)
            return
        self.diag.count("frames")
        self.report_progress(first + n, follow)

    # ------------------------------------------------------------------ paired streams

    def subscribe_pair(self, first: Input, second: Input, check_rate: bool = True) -> None:
        """Subscribe the two streams of the device whose pairs go to :meth:`process_pair`;
        the first is the primary input (progress)."""
        self.pairer = FramePairer(
            (first[0], second[0]), self._limit("max_unpaired_samples"), FRAME_DEPTH
        )
        self.primary = first[0]
        self._end_with_input(self.device_topic(first[0]))
        self.follow_device_faults()
        for name, msg_type, decode in (first, second):
            callback = partial(self._on_frame, name, decode, check_rate)
            self.create_subscription(msg_type, self.device_topic(name), callback, FRAME_QOS)

    def _on_frame(self, kind: str, decode, check_rate: bool, msg) -> None:
        first, n = int(msg.first_sample_index), int(msg.num_samples)
        values = self.take_frame(kind, msg, decode, check_rate)
        if values is None:
            return
        if self.index("pair").is_repeat(first) or self.pairer.holds(kind, first):
            self.diag.count("repeated_frames")
            self.diag.warn(f"dropped repeated {kind} frame at {first}")
            self._finished(kind, first + n)
            return
        stamped = (time_to_ns(msg.header.stamp), values)
        pairs = self.pairer.add(kind, first, stamped, n)
        for k, old, size in self.pairer.overflow:
            self.diag.count("unpaired_overflow_frames")
            self.diag.warn(
                f"{k} frame at {old} dropped unpaired: more than max_unpaired_samples = "
                f"{self._limit('max_unpaired_samples')} samples wait for their partner"
            )
            self._finished(k, old + size)
        for first_, (stamp, a), (_, b) in pairs:
            self._on_pair(first_, stamp, a, b)

    def _on_pair(self, first: int, stamp_ns: int, a, b) -> None:
        na, nb = num_samples(a), num_samples(b)
        if na != nb:
            ka, kb = self.pairer.kinds
            self.reject(f"frames at {first}: {na} {ka} samples for {nb} {kb} samples")
            self._finished(self.primary, first + na)
            return
        if not self.sequence("pair", first, na, streams=2):
            self._finished(self.primary, first + na)
            return
        follow = self.last_event == RESET
        try:
            self.process_pair(first, stamp_ns, a, b)
        except Diverged as exc:
            self.note_divergence(str(exc), first)
        except FrameError as exc:
            self.reject(f"frames at {first}: {exc}", exc.reason)
        else:
            self.frames_done += 1
            self.diag.count("frames")
        for kind, old, size in self.pairer.drop_before(first + na):
            self.diag.count("unpaired_stale_frames")
            self._finished(kind, old + size)
        self._finished(self.primary, first + na, follow)

    # ------------------------------------------------------------------ hooks

    def on_gap(self, gap: int) -> None:
        """Called after ``gap`` samples were found missing, before the next pair."""

    def on_stream_reset(self, ahead: bool) -> None:
        """Called at a stream reset, before the frame that starts the new stream; ``ahead``:
        the index jumped ahead by more than ``max_gap_samples`` (the device ran on, unseen),
        else the stream started again (a device or a replay that started again). By
        default both: :meth:`reset_estimator`."""
        self.reset_estimator()

    def on_format_change(self, kind: str) -> None:
        """Called after input stream ``kind`` adopted a new format."""

    def reset_estimator(self) -> None:
        """Re-initialise the estimator from its prior (stream reset, divergence)."""

    def process_frame(self, first: int, stamp_ns: int, values, msg) -> None:
        """Process one good frame ``msg`` of the single input (:meth:`subscribe_single`)
        starting at sample ``first``, stamped ``stamp_ns`` [ns], decoded as ``values``;
        raise FrameError to reject it."""
        raise NotImplementedError

    def process_pair(self, first: int, stamp_ns: int, a, b) -> None:
        """Estimate on one pair of frames starting at sample ``first``, whose first sample
        was stamped ``stamp_ns`` [ns]; raise FrameError to reject it, :class:`Diverged`
        after re-initialising a filter that diverged."""
        raise NotImplementedError


class Diverged(FrameError):
    """A filter diverged in a frame and was re-initialised from its prior (its estimates
    of that frame are not published); the message names the filter."""

    def __init__(self, what: str) -> None:
        super().__init__(what, "diverged")

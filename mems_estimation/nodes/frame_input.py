"""Input side shared by the estimator nodes: the device's topics, pairing of its ADC and
drive frames, rate check, and rejection of bad frames counted on /diagnostics.

Every estimator node is an :class:`EstimatorNode`. Its device topics (``adc``, ``drive``,
``estimate``, ...) are relative names resolved in the node's namespace, unless the
parameter ``device_namespace`` names another one; so a node started in a device's
namespace (``-r __ns:=/a``) finds that device, and each node class has the usual namespace
of its device as default.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from mems_sim.params import ParamSpec
from mems_sim.ros.frames import FrameError, IndexTracker, time_to_ns
from mems_sim.ros.node_base import MemsNode
from mems_sim.ros.qos import FRAME_QOS

#: Parameter of the estimator nodes that read a device's topics.
DEVICE_NAMESPACE = ParamSpec(
    "device_namespace",
    "",
    "-",
    "namespace of the device's topics; empty: the node's own namespace",
    "",
)

#: One input stream: (topic name relative to the device, message type, decoder). The
#: decoder returns the frame's values (an array of n samples, or a tuple of such arrays)
#: or raises FrameError.
Input = tuple[str, type, Callable[[Any], Any]]


def device_topic(namespace: str, name: str) -> str:
    """Topic ``name`` of the device in ``namespace``; ``''``: relative ``name`` (the node's
    own namespace)."""
    return f"{namespace.rstrip('/')}/{name}" if namespace else name


def num_samples(values) -> int:
    """Samples of decoded frame values (an array, or a tuple of arrays of equal length)."""
    return int(np.shape(values[0] if isinstance(values, tuple) else values)[0])


class FramePairer:
    """Pairs the frames of two streams (e.g. ADC and drive) that share a
    ``first_sample_index``, in index order (ROS-free)."""

    def __init__(self, kinds: tuple[str, str] = ("adc", "drive")) -> None:
        self.kinds = kinds
        self.frames: dict[str, dict[int, object]] = {k: {} for k in kinds}

    def add(self, kind: str, first: int, values) -> list[tuple[int, object, object]]:
        """Store one frame of stream ``kind``; return the pairs now complete, ordered by index
        as ``(first_sample_index, values of kinds[0], values of kinds[1])``."""
        self.frames[kind][first] = values
        a, b = (self.frames[k] for k in self.kinds)
        return [(k, a.pop(k), b.pop(k)) for k in sorted(set(a) & set(b))]


class EstimatorNode(MemsNode):
    """Base of the estimator nodes: parameters, device topics, diagnostics, frame input.

    The input path of a node with two streams (:meth:`subscribe_pair`): each frame is
    decoded (rate check against ``self.fs`` unless it is None, then the stream's decoder);
    a bad frame is rejected and counted (``rejected_frames``); good frames are paired by
    ``first_sample_index``; a pair of unequal lengths is rejected; a gap before the pair is
    counted (``gaps``, warning with :attr:`GAP_NOTE`, then :meth:`on_gap`); the pair goes to
    :meth:`process_pair` (which may raise FrameError: rejected), then ``frames_done`` and
    the ``frames`` counter grow. Single streams use :meth:`accept_frame` and
    :meth:`note_gap`.

    The constructor arguments are :class:`~mems_sim.ros.node_base.MemsNode`'s (every
    parameter is set at start; ``specs`` with :data:`DEVICE_NAMESPACE` if the node reads a
    device's topics, ``default_namespace`` the usual namespace of that device).
    """

    #: Said after "gap of N samples before index K" (what the node does about it).
    GAP_NOTE = ""
    #: Sample rate of the model [Hz]: frames at another rate are rejected (None: any rate).
    fs: float | None = None
    #: Pairs processed.
    frames_done = 0
    #: The two paired streams (set by :meth:`subscribe_pair`).
    pairer: FramePairer | None = None

    def device_topic(self, name: str) -> str:
        """Topic ``name`` of the device (``device_namespace``, or relative)."""
        return device_topic(self.p.get("device_namespace", ""), name)

    # ------------------------------------------------------------------ single frames

    def reject(self, text: str) -> None:
        """Count a rejected frame and warn on /diagnostics (the node keeps running)."""
        self.diag.count("rejected_frames")
        self.diag.warn(f"rejected frame: {text}")

    def check_rate(self, msg) -> None:
        """FrameError unless the frame's sample rate is the model's ``self.fs`` [Hz]."""
        if self.fs is not None and msg.sample_rate_hz != self.fs:
            raise FrameError(
                f"frame at {msg.first_sample_index}: sample_rate_hz "
                f"{msg.sample_rate_hz} differs from the model's {self.fs} Hz"
            )

    def accept_frame(self, msg, decode: Callable[[Any], Any], check_rate: bool = True):
        """``decode(msg)`` after the rate check; None (rejected and counted) on FrameError."""
        try:
            if check_rate:
                self.check_rate(msg)
            return decode(msg)
        except FrameError as exc:
            self.reject(str(exc))
            return None

    def note_gap(self, first: int, gap: int) -> None:
        """Count and report ``gap`` samples missing before index ``first`` (if any)."""
        if gap:
            self.diag.count("gaps")
            note = f": {self.GAP_NOTE}" if self.GAP_NOTE else ""
            self.diag.warn(f"gap of {gap} samples before index {first}{note}")

    # ------------------------------------------------------------------ paired streams

    def subscribe_pair(self, first: Input, second: Input, check_rate: bool = True) -> None:
        """Subscribe the two streams of the device whose pairs go to :meth:`process_pair`."""
        self.pairer = FramePairer((first[0], second[0]))
        self.tracker = IndexTracker()
        for name, msg_type, decode in (first, second):
            callback = partial(self._on_frame, name, decode, check_rate)
            self.create_subscription(msg_type, self.device_topic(name), callback, FRAME_QOS)

    def _on_frame(self, kind: str, decode, check_rate: bool, msg) -> None:
        values = self.accept_frame(msg, decode, check_rate)
        if values is None:
            return
        stamped = (time_to_ns(msg.header.stamp), values)
        for first, (stamp, a), (_, b) in self.pairer.add(kind, msg.first_sample_index, stamped):
            self._on_pair(first, stamp, a, b)

    def _on_pair(self, first: int, stamp_ns: int, a, b) -> None:
        na, nb = num_samples(a), num_samples(b)
        if na != nb:
            ka, kb = self.pairer.kinds
            self.reject(f"frames at {first}: {na} {ka} samples for {nb} {kb} samples")
            return
        gap = self.tracker.update(first, na)
        if gap:
            self.note_gap(first, gap)
            self.on_gap(gap)
        try:
            self.process_pair(first, stamp_ns, a, b)
        except FrameError as exc:
            self.reject(f"frames at {first}: {exc}")
            return
        self.frames_done += 1
        self.diag.count("frames")

    def on_gap(self, gap: int) -> None:
        """Called after ``gap`` samples were found missing, before the next pair."""

    def process_pair(self, first: int, stamp_ns: int, a, b) -> None:
        """Estimate on one pair of frames starting at sample ``first``, whose first sample
        was stamped ``stamp_ns`` [ns]; raise FrameError to reject it."""
        raise NotImplementedError

"""An emulator's fault schedule in the node graph: the ``fault_schedule`` parameter, the
injector it builds and the ``faults`` topic of labelled truth.

Each scheduled fault is published once on ``<device>/faults`` as a ``mems_msgs/FaultEvent``
(reliable, transient local, one slot per fault: a late subscriber and the recorder get
every one), in the frame that holds its first sample, stamped in sensor time like the
frames. With no schedule the node has no ``faults`` topic and its device is untouched.

Dropped samples (``dropped_samples``) are samples the device makes but never delivers:
every frame topic of the node except its truth (the ``truth*`` topics stay whole) is cut
around them (:meth:`FaultTopic.attach`), so that the streams jump over exactly those
indices; the fault's FaultEvent, published before the first frame after the gap,
declares them to a recorder or ``mcap_info`` as a device gap, not transport loss.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mems_msgs.msg import FaultEvent
from mems_sim.hardware.fault_schedule import (
    ALL_KINDS,
    FAULT_KINDS,
    FaultEntry,
    FaultKind,
    FaultScheduleError,
    delivered_runs,
    load_schedule,
)
from mems_sim.hardware.sensor_faults import SensorFaultInjector
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.frames import index_to_ns, ns_to_time

FAULT_SCHEDULE_SPEC = ParamSpec(
    "fault_schedule",
    "",
    "-",
    "YAML file of scheduled faults (kind, channel, start, duration, magnitude; docs/faults.md); "
    "'' for none",
    "faults on demand with labelled truth on the 'faults' topic",
)


def load_entries(
    path: str,
    channels: Sequence[str],
    units: Sequence[str],
    fs: float,
    kinds: Mapping[str, FaultKind] = FAULT_KINDS,
) -> tuple[FaultEntry, ...]:
    """The schedule of the ``fault_schedule`` parameter (empty for ''), of the ``kinds``
    the device offers; a bad file is a ParameterError naming the parameter."""
    if not path:
        return ()
    try:
        return load_schedule(path, channels, units, fs, kinds)
    except FaultScheduleError as exc:
        raise ParameterError(f"parameter 'fault_schedule' = {path!r} is invalid: {exc}") from None


def fault_qos(n_faults: int) -> QoSProfile:
    """Reliable, transient local, a slot for every fault of the schedule."""
    return QoSProfile(
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
        history=HistoryPolicy.KEEP_LAST,
        depth=max(1, n_faults),
    )


class FaultTopic:
    """The schedule of one emulator node: its injector and its ``faults`` publisher.

    Args:
        node: the emulator node (an rclpy Node with ``p``, ``fs`` and ``frame_kwargs``).
        channels, units: the device's channel names and SI units.
        fs: sample rate [Hz].
        white_std: per channel, the white-noise standard deviation per sample
            [channel unit] (for ``noise_burst``).
        kinds: the fault kinds the device offers (default: all).
    """

    def __init__(self, node, channels, units, fs: float, white_std=None, kinds=FAULT_KINDS) -> None:
        self.entries = load_entries(node.p["fault_schedule"], channels, units, fs, kinds)
        self.node = node
        self.injector = None
        self.publisher = None
        #: The dropped-samples entries (the streams' gaps).
        self.drops = tuple(e for e in self.entries if ALL_KINDS[e.kind].family == "timing")
        if any(ALL_KINDS[e.kind].family == "sensor" for e in self.entries):
            try:
                self.injector = SensorFaultInjector(self.entries, fs, node.p["seed"], white_std)
            except ValueError as exc:
                raise ParameterError(
                    f"parameter 'fault_schedule' = {node.p['fault_schedule']!r} is invalid: {exc}"
                ) from None
        if self.entries:
            self.publisher = node.create_publisher(
                FaultEvent, "faults", fault_qos(len(self.entries))
            )

    def delivered(self, first: int, n: int) -> list[tuple[int, int]] | None:
        """The parts ``[lo, hi)`` of the block ``[first, first + n)`` (offsets) the device
        delivers; None: all of it (:func:`~mems_sim.hardware.fault_schedule.delivered_runs`)."""
        return delivered_runs(self.drops, first, n) if self.drops else None

    def attach(self, streams) -> None:
        """Cut the frames of every stream account of ``streams`` (topic -> StreamAccount)
        but the truth topics around the dropped samples
        (:meth:`~mems_sim.ros.end_of_stream.StreamAccount.deliver_only`)."""
        if not self.drops:
            return

        def t0() -> int:
            return self.node.frame_kwargs["t0_ns"] or 0

        for topic, account in streams.items():
            if not topic.rsplit("/", 1)[-1].startswith("truth"):
                account.deliver_only(self.delivered, t0)

    def event(self, entry: FaultEntry) -> FaultEvent:
        """The FaultEvent of ``entry``, times in the node's sensor time."""
        kw = self.node.frame_kwargs
        t0, fs = kw["t0_ns"] or 0, self.node.fs
        m = FaultEvent()
        start = ns_to_time(index_to_ns(entry.first, fs, t0))
        m.header.stamp = start
        m.header.frame_id = kw["frame_id"]
        m.kind = entry.kind
        m.channel = entry.channel
        m.first_faulty_sample = entry.first
        m.faulty_samples = 0 if entry.count is None else entry.count
        m.permanent = entry.permanent
        m.start = start
        m.end = start if entry.end is None else ns_to_time(index_to_ns(entry.end, fs, t0))
        m.magnitude = float(entry.magnitude)
        m.magnitude_unit = entry.unit
        m.rate_hz = float(entry.rate_hz)
        m.number = entry.number
        return m

    def publish_starting(self, first: int, n: int) -> None:
        """Publish the faults whose first sample is in ``[first, first + n)``."""
        if self.publisher is None:
            return
        for entry in self.entries:
            if first <= entry.first < first + n:
                self.publisher.publish(self.event(entry))

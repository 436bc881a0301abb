"""Device gaps a device declares on its ``faults`` topic, for the recorder and ``mcap_info``.

An emulator that drops samples of its schedule (``dropped_samples``) publishes the fault's
``mems_msgs/FaultEvent`` on ``<device>/faults`` before the first frame after the gap. A
reader of the graph or of a recording hands every message of such a topic to
:meth:`GapDeclarations.fault`: the dropped indices are declared to the sequence accounting
(:meth:`~mems_sim.stream_index.StreamIndex.declare_device_gap`) of every frame topic in
the device's namespace and below it (``<device>/...``: its own streams, and the estimates
of the estimators that run under it, which carry the same gap), including frame topics met
later, so that the jump over them is a device gap, not transport loss. An estimator in
another namespace is not covered: its gap stays loss. The declaration may arrive
before or after the jump (another topic): the accounting takes either.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mems_sim.stream_index import DROPPED_SAMPLES

#: Type of the faults topic's messages.
FAULT_EVENT_TYPE = "mems_msgs/msg/FaultEvent"
#: Name of a device's faults topic (relative to the device's namespace).
FAULTS_TOPIC = "faults"
#: Declarations remembered per device (the longest schedule an emulator takes).
MAX_DECLARATIONS = 10_000


#: A subscriber's QoS for a faults topic: reliable, transient local (the schedule's events
#: published before it joined reach it too), the last 1000 events.
FAULTS_SUBSCRIPTION_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
)


def namespace(topic: str) -> str:
    """The device of a topic: its name without the last component (``/imu/adc`` -> ``/imu``)."""
    return topic.rsplit("/", 1)[0]


def under(topic: str, device: str) -> bool:
    """True if ``topic`` is in namespace ``device`` or below it."""
    return topic.startswith(device.rstrip("/") + "/")


def declared_gap(topic: str, type_name: str, data: bytes) -> tuple[int, int] | None:
    """``(first, n)`` of the samples a serialised FaultEvent on a faults topic declares
    dropped; None for any other message, fault kind, or bytes that do not deserialise (a
    foreign record is only described, never trusted)."""
    if type_name != FAULT_EVENT_TYPE or topic.rsplit("/", 1)[-1] != FAULTS_TOPIC:
        return None
    from rclpy.serialization import deserialize_message

    from mems_msgs.msg import FaultEvent

    try:
        msg = deserialize_message(bytes(data), FaultEvent)
    except Exception:  # corrupt bytes: no declaration
        return None
    if msg.kind != DROPPED_SAMPLES or msg.permanent or msg.faulty_samples <= 0:
        return None
    return int(msg.first_faulty_sample), int(msg.faulty_samples)


class GapDeclarations:
    """The device gaps declared on the faults topics met so far, handed to ``declare(topic,
    first, n)`` for every frame topic in the device's namespace or below (:func:`under`;
    :meth:`frame_topic` registers one; it gets the declarations made before it too).

    :attr:`declared` counts the declarations per device namespace. Bounded memory:
    :data:`MAX_DECLARATIONS` per device.
    """

    def __init__(self, declare: Callable[[str, int, int], None]) -> None:
        self._declare = declare
        self._frames: list[str] = []
        self._gaps: dict[str, list[tuple[int, int]]] = {}
        #: Declarations taken per device namespace.
        self.declared: dict[str, int] = {}

    def frame_topic(self, topic: str) -> None:
        """Register frame topic ``topic``; the declarations of its device apply to it."""
        if topic in self._frames:
            return
        self._frames.append(topic)
        for device, gaps in self._gaps.items():
            if under(topic, device):
                for first, n in gaps:
                    self._declare(topic, first, n)

    def fault(self, topic: str, type_name: str, data: bytes) -> tuple[int, int] | None:
        """Take one message of ``topic``: a dropped-samples FaultEvent declares its samples
        to the device's frame topics; returns ``(first, n)``, None for other messages."""
        gap = declared_gap(topic, type_name, data)
        if gap is None:
            return None
        ns = namespace(topic)
        kept = self._gaps.setdefault(ns, [])
        if len(kept) < MAX_DECLARATIONS:
            kept.append(gap)
        self.declared[ns] = self.declared.get(ns, 0) + 1
        for frame in self._frames:
            if under(frame, ns):
                self._declare(frame, *gap)
        return gap

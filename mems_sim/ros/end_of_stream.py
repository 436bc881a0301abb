"""Loss accounting of an emulator's output: per-topic counts and the end-of-stream record.

Every data publisher of an emulator node is counted (:class:`StreamAccount`): messages
published and, for frame messages (those with ``first_sample_index`` and
``num_samples``), the sample index after the last frame and the samples published. When
the emulator has published its whole duration it publishes one end-of-stream record on
``<namespace>/end_of_stream`` (:data:`END_OF_STREAM`), latched (reliable,
transient-local, depth 1) so that a recorder that subscribes late still gets it.

The record is a ``diagnostic_msgs/DiagnosticArray`` (an installed interface that every
MCAP tool reads and shows as key/value pairs; no interface of this project needed): its
header stamp is the sensor time after the last sample, and it holds one
``DiagnosticStatus`` per topic, ``name`` the absolute topic name, ``message``
``"end of stream"``, ``hardware_id`` the emulator node and the values ``messages`` (how
many the node published on the topic, which is also the sequence number of its last
message), and for frame topics ``end_sample_index`` (first sample index after the last
frame) and ``samples``. A recorder or ``mcap_info`` compares it with what was recorded:
fewer messages or a smaller index at the end is a missing tail, which gap counting
alone cannot see.

Dropped samples of a fault schedule (:meth:`StreamAccount.deliver_only`): the frames are
cut around samples the device never delivers before they are counted, so the record
counts what the device delivered and a recorder sees the gap the device declared.

Fault injection (tests of the loss reporting): :meth:`StreamAccount.cut` makes the
publisher stop handing messages to the middleware after a number of them while the
account (and so the end-of-stream record) still counts what the device produced, as a
transport that loses a topic's tail would.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import partial

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Topic of the end-of-stream record, relative to the emulator's namespace.
END_OF_STREAM = "end_of_stream"

#: Message type of the end-of-stream record.
END_OF_STREAM_TYPE = "diagnostic_msgs/msg/DiagnosticArray"

#: ``message`` of each status of the record.
END_OF_STREAM_TEXT = "end of stream"

#: Latched: a subscriber that joins after the end still gets the record.
END_OF_STREAM_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
)

#: Topics of a node that are not data streams (graph infrastructure, health, time).
NOT_STREAMS = frozenset({"/diagnostics", "/parameter_events", "/rosout", "/clock"})


def is_end_of_stream_topic(topic: str, type_name: str | None = None) -> bool:
    """True for an end-of-stream topic (name ``.../end_of_stream``, type DiagnosticArray)."""
    if topic.rsplit("/", 1)[-1] != END_OF_STREAM:
        return False
    return type_name is None or type_name == END_OF_STREAM_TYPE


class StreamAccount:
    """Counts what one publisher was given (:meth:`wrap` replaces its ``publish``).

    Attributes:
        topic: absolute topic name.
        messages: messages the node published on the topic.
        sent: messages handed to the middleware (less than ``messages`` only after
            :meth:`cut`).
        refused: messages the middleware refused (a reliable writer whose history stayed
            full of samples a stopped subscriber did not acknowledge): lost at the source,
            counted in the record so a recorder sees them missing.
        end_sample_index: first sample index after the last frame (None: no frame yet or
            not a frame topic).
        samples: samples in the frames published.
        depth: history depth the publisher keeps (KEEP_LAST), None for KEEP_ALL.
    """

    def __init__(self, publisher) -> None:
        self.publisher = publisher
        self.topic: str = publisher.topic_name
        self.messages = 0
        self.sent = 0
        self.refused = 0
        self.end_sample_index: int | None = None
        self.samples = 0
        self.frames = False
        qos = getattr(publisher, "qos_profile", None)
        keep_last = qos is not None and qos.history != HistoryPolicy.KEEP_ALL
        self.depth: int | None = int(qos.depth) if keep_last else None
        self._keep: int | None = None
        self._delivered = None
        self._publish = publisher.publish
        #: Called with the topic at the first refused message (a warning of the node).
        self.on_refused = None

    def wrap(self) -> StreamAccount:
        """Route the publisher's ``publish`` through this account; return self."""
        self.publisher.publish = self.publish
        return self

    def deliver_only(self, delivered, t0_ns) -> None:
        """Publish of each frame only the parts the device delivers: ``delivered(first, n)``
        gives them as offsets ``[(lo, hi), ...]`` (None: the whole frame), each published as
        a frame of its own (:func:`~mems_sim.ros.frames.frame_piece`, stamped from the epoch
        ``t0_ns()`` [ns]); a frame with no part is not published."""
        self._delivered = (delivered, t0_ns)

    def publish(self, msg) -> None:
        """Count ``msg`` (and its samples) and publish it, unless cut (the parts the device
        delivers of a frame, with :meth:`deliver_only`)."""
        if self._delivered is not None and hasattr(msg, "first_sample_index"):
            delivered, t0_ns = self._delivered
            runs = delivered(int(msg.first_sample_index), int(msg.num_samples))
            if runs is not None:
                from mems_sim.ros.frames import frame_piece

                for lo, hi in runs:
                    self._count_and_publish(frame_piece(msg, lo, hi, t0_ns()))
                return
        self._count_and_publish(msg)

    def _count_and_publish(self, msg) -> None:
        self.messages += 1
        first = getattr(msg, "first_sample_index", None)
        num = getattr(msg, "num_samples", None)
        if first is not None and num is not None:
            self.frames = True
            self.end_sample_index = int(first) + int(num)
            self.samples += int(num)
        if self._keep is not None and self.sent >= self._keep:
            return
        self.sent += 1
        try:
            self._publish(msg)
        except _rclpy.RCLError:  # 'cannot publish data': the middleware refused it
            self.sent -= 1
            self.refused += 1
            if self.refused == 1 and self.on_refused is not None:
                self.on_refused(self.topic)

    def cut(self, keep_messages: int) -> None:
        """Fault injection: hand only the first ``keep_messages`` messages to the middleware."""
        self._keep = max(0, int(keep_messages))

    def status_values(self) -> list[tuple[str, str]]:
        """The (key, value) pairs of this topic in the end-of-stream record."""
        values = [("messages", str(self.messages))]
        if self.frames:
            values += [
                ("end_sample_index", str(self.end_sample_index)),
                ("samples", str(self.samples)),
            ]
        return values


def account_publishers(node, skip: Iterable[str] = ()) -> dict[str, StreamAccount]:
    """Wrap every data publisher of ``node`` (not :data:`NOT_STREAMS`, not ``skip``);
    return the accounts by topic."""
    skipped = set(NOT_STREAMS) | set(skip)
    accounts = {}
    for pub in node.publishers:
        topic = pub.topic_name
        if topic in skipped or is_end_of_stream_topic(topic) or topic in accounts:
            continue
        accounts[topic] = StreamAccount(pub).wrap()
        accounts[topic].on_refused = partial(_warn_refused, node)
    return accounts


def _warn_refused(node, topic: str) -> None:
    """One warning of ``node`` at the first message of ``topic`` the middleware refused."""
    node.get_logger().warning(
        f"{topic}: the middleware refused a message (a subscriber's history stayed full); "
        "refused messages are lost at the source and counted in the end-of-stream record"
    )


def end_of_stream_message(accounts: dict[str, StreamAccount], stamp, hardware_id: str):
    """The DiagnosticArray record of ``accounts`` (``stamp``: builtin_interfaces/Time)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = [
        DiagnosticStatus(
            level=DiagnosticStatus.OK,
            name=topic,
            message=END_OF_STREAM_TEXT,
            hardware_id=hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in a.status_values()],
        )
        for topic, a in sorted(accounts.items())
    ]
    return msg


def parse_end_of_stream(msg) -> dict[str, dict[str, int]]:
    """Per topic of an end-of-stream record: ``messages`` and, for frame topics,
    ``end_sample_index`` and ``samples`` (statuses or values that are not numbers are
    skipped)."""
    out: dict[str, dict[str, int]] = {}
    for status in getattr(msg, "status", ()):
        if status.message != END_OF_STREAM_TEXT or not status.name.startswith("/"):
            continue
        values = {}
        for kv in status.values:
            if kv.key in ("messages", "end_sample_index", "samples"):
                try:
                    values[kv.key] = int(kv.value)
                except ValueError:
                    continue
        if "messages" in values:
            out[status.name] = values
    return out


def missing_tail(
    expected: dict[str, int], messages_seen: int, end_seen: int | None
) -> dict[str, int]:
    """What the end of one topic lacks against its end-of-stream entry ``expected``.

    Args:
        messages_seen: the sequence number of the last message recorded from the
            publisher (or, without sequence numbers, the messages recorded).
        end_seen: first sample index after the last recorded frame (None: no frame).
    Returns:
        ``messages`` (missing after the last recorded one) and, for frame topics,
        ``samples`` (missing after the last recorded frame) and ``from_index`` (the first
        missing sample index); all 0 when the tail is complete.
    """
    out = {"messages": max(0, int(expected["messages"]) - int(messages_seen))}
    if "end_sample_index" in expected:
        seen = 0 if end_seen is None else int(end_seen)
        out["samples"] = max(0, int(expected["end_sample_index"]) - seen)
        out["from_index"] = seen
    return out


def describe_tail(topic: str, expected: dict[str, int], tail: dict[str, int]) -> str:
    """One phrase for a missing tail, e.g. ``/imu/truth: missing tail of 2550 of 10000
    messages (255000 samples from sample 745000)``."""
    text = f"{topic}: missing tail of {tail['messages']} of {expected['messages']} messages"
    if tail.get("samples"):
        text += f" ({tail['samples']} samples from sample {tail['from_index']})"
    return text

"""One flow-control protocol between a producer (an emulator stepped in process, a player)
and a lossless consumer (an estimator node, a recorder).

What a consumer reports, its progress: one past the last sample index of its primary
input that it has finished with (processed, rejected or dropped) [samples], the largest
so far (a stream reset starts it again). The producer keeps at most a credit of samples
beyond it (:func:`may_send`). The same number is read two ways:

* in process, from the node itself: :func:`progress_of` (its :class:`ProgressReporter`);
* across processes, from its ``~/progress`` topic (std_msgs/UInt64,
  :data:`~mems_sim.ros.qos.PROGRESS_QOS`): :class:`ProgressSubscriber`.

The module imports ROS only when a reporter or subscriber is made (:func:`may_send` is
plain arithmetic). Lossless replay with this protocol: docs/recording.md ("Lossless
replay into other processes").
"""

from __future__ import annotations

from collections.abc import Callable

#: The topic (relative to the node) a consumer reports its progress on.
PROGRESS_TOPIC = "~/progress"
#: Largest value of the report (std_msgs/UInt64).
_UINT64_MAX = 2**64 - 1


def progress_topic(node_fqn: str) -> str:
    """The progress topic of the consumer node ``node_fqn`` (its ``~/progress``)."""
    return node_fqn.rstrip("/") + "/progress"


class ProgressReporter:
    """The consumer's side: its progress (``value``, None before the first report) and
    the ``~/progress`` publisher of ``node``.

    Args:
        node: the consumer node.
        max_jump: a report more than this many samples away from the progress is not
            taken (a rejected or stray frame far from the stream); None: any report is.
    """

    def __init__(self, node, max_jump: int | None = None) -> None:
        from std_msgs.msg import UInt64

        from mems_sim.ros.qos import PROGRESS_QOS

        self._msg = UInt64
        self.value: int | None = None
        self.max_jump = max_jump
        self.publisher = node.create_publisher(UInt64, PROGRESS_TOPIC, PROGRESS_QOS)

    def report(self, end: int, follow: bool = False) -> int:
        """Finished with the primary input up to sample ``end`` (exclusive): the progress
        becomes the largest so far (``end`` itself if ``follow``: a stream reset, or a
        consumer that reports what it last took), is published and returned."""
        end = int(end)
        if self.value is None or follow:
            self.value = end
        elif self.max_jump is None or abs(end - self.value) <= self.max_jump:
            self.value = max(self.value, end)
        self.publisher.publish(self._msg(data=min(max(self.value, 0), _UINT64_MAX)))
        return self.value


def progress_of(node) -> int | None:
    """In process: the progress of the consumer ``node`` (its ``progress_reporter``);
    None before its first report or for a node that reports none."""
    reporter = getattr(node, "progress_reporter", None)
    return None if reporter is None else reporter.value


class ProgressSubscriber:
    """Across processes: the progress of the consumer ``node_fqn``, subscribed to on
    ``node`` (the producer's node); ``on_progress(value)`` is called for every report.

    Args:
        qos: the subscription's QoS (None: :data:`~mems_sim.ros.qos.PROGRESS_QOS`; a
            player adapts it to the publisher it found).
    """

    def __init__(
        self,
        node,
        node_fqn: str,
        on_progress: Callable[[int], object] | None = None,
        qos=None,
    ) -> None:
        from std_msgs.msg import UInt64

        from mems_sim.ros.qos import PROGRESS_QOS

        self.value: int | None = None
        self.reports = 0
        self.topic = progress_topic(node_fqn)
        self._on_progress = on_progress
        self.subscription = node.create_subscription(
            UInt64, self.topic, self._on_msg, PROGRESS_QOS if qos is None else qos
        )

    def _on_msg(self, msg) -> None:
        self.value = int(msg.data)
        self.reports += 1
        if self._on_progress is not None:
            self._on_progress(self.value)


def may_send(first: int, num: int, progress: int | None, credit: int, start=None) -> bool:
    """True if a frame of samples [first, first + num) may be sent to a consumer that
    reported ``progress`` and is granted ``credit`` samples beyond it: the frame ends
    within the credit, or starts at or before the progress (a repeat, a paired frame).
    Before the first report the credit counts from ``start`` (the first sample sent);
    None: nothing sent yet, any frame may go."""
    base = progress if progress is not None else start
    return base is None or first <= base or first + num <= base + credit

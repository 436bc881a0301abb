"""Health reporting on /diagnostics (diagnostic_msgs/DiagnosticArray).

Every node that consumes or produces frames keeps counters (frames, rejected
frames, gaps, saturated samples) and publishes them here once per period
with a level: OK, WARN when something was rejected, clipped or lost.
"""

from __future__ import annotations

from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy


class DiagnosticsReporter:
    """Counters and messages of one node, published on /diagnostics.

    Published every ``period_s`` of wall-clock time (a timer on the steady clock, so it
    neither floods a fast simulated run nor stops while /clock stands still), stamped with
    ``now_ns()`` (default: the node's ROS clock, i.e. the wall clock or /clock under
    use_sim_time) so that the stamps are on the graph's timeline.
    """

    def __init__(
        self,
        node: Node,
        name: str,
        hardware_id: str = "",
        period_s: float = 1.0,
        now_ns: Callable[[], int] | None = None,
    ):
        self._node = node
        self._now_ns = now_ns or (lambda: node.get_clock().now().nanoseconds)
        self._name = name
        self._hardware_id = hardware_id
        self.counters: dict[str, int | float | str] = {}
        self.warnings: list[str] = []
        self._pub = node.create_publisher(
            DiagnosticArray,
            "/diagnostics",
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        )
        self._timer = (
            node.create_timer(period_s, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))
            if period_s > 0
            else None
        )

    def count(self, key: str, increment: int = 1) -> None:
        """Add ``increment`` to counter ``key``."""
        self.counters[key] = int(self.counters.get(key, 0)) + increment

    def warn(self, text: str) -> None:
        """Record a warning (kept, published with level WARN) and log it."""
        if text not in self.warnings:
            self.warnings.append(text)
            if len(self.warnings) > 20:
                self.warnings.pop(0)
        self._node.get_logger().warning(text)

    def status(self) -> DiagnosticStatus:
        """Current status: WARN if any warning was recorded, OK otherwise."""
        level = DiagnosticStatus.WARN if self.warnings else DiagnosticStatus.OK
        message = self.warnings[-1] if self.warnings else "OK"
        values = [KeyValue(key=k, value=str(v)) for k, v in sorted(self.counters.items())]
        return DiagnosticStatus(
            level=level,
            name=self._name,
            message=message,
            hardware_id=self._hardware_id,
            values=values,
        )

    def publish(self) -> None:
        """Publish the current status on /diagnostics."""
        msg = DiagnosticArray()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(self._now_ns()), 10**9)
        msg.status = [self.status()]
        self._pub.publish(msg)

"""Lossless replay into named consumers (``mcap_play --wait-for-consumer``): application-level
flow control on each consumer's ``~/progress`` (:class:`FlowControl`, :class:`Consumer`),
and the ``--credit`` and ``--wait-for-consumer`` values. Docs: docs/recording.md.
"""

from __future__ import annotations

import bisect
import re
import time

from mems_sim.ros.flow import ProgressSubscriber, may_send, progress_topic
from mems_sim.stream_index import StallTimer

#: Credit of a consumer unless ``--credit`` says otherwise: frames published ahead of its
#: progress (well within the 1000-frame history of the frame subscriptions).
DEFAULT_CREDIT = "50f"


def parse_credit(text: str) -> tuple[int, str]:
    """``'N'`` (samples) or ``'Nf'`` (frames) -> ``(N, 'samples' | 'frames')``, N >= 1."""
    text = str(text).strip().lower()
    unit = "frames" if text.endswith("f") else "samples"
    number = text[:-1] if unit == "frames" else text
    try:
        value = int(number)
    except ValueError:
        raise ValueError(f"bad credit {text!r} (samples N or frames Nf, N >= 1)") from None
    if value < 1:
        raise ValueError(f"bad credit {text!r} (samples N or frames Nf, N >= 1)")
    return value, unit


def parse_consumer(text: str) -> tuple[str, str | None]:
    """``'/ns/node'`` or ``'/ns/node:/topic'`` -> (node's fully qualified name, topic or None)."""
    fqn, _, topic = str(text).partition(":")
    fqn = fqn if fqn.startswith("/") else "/" + fqn
    tokens = fqn[1:].split("/")
    if not all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", t) for t in tokens):
        raise ValueError(f"bad consumer {text!r} (expected a node name such as /imu/node)")
    if topic and not re.fullmatch(r"/?[A-Za-z_~][A-Za-z0-9_/~{}]*", topic):
        raise ValueError(f"bad consumer {text!r}: {topic!r} is not a topic name")
    return fqn, (topic or None)


def _fqn(namespace: str, name: str) -> str:
    """Fully qualified node name."""
    return f"{namespace.rstrip('/')}/{name}"


class Consumer(StallTimer):
    """A named consumer of replayed frames: its progress and what was sent to it.

    Progress (``NODE_FQN/progress``, std_msgs/UInt64) is one past the last sample index the
    consumer processed (or rejected); it publishes one after every frame. The player keeps
    at most a credit of samples (or frames) published beyond it on each frame topic the
    consumer subscribes to (its input topics, which share one sample index).
    """

    def __init__(self, fqn: str, topic: str | None = None):
        super().__init__(time.monotonic())  # a stall: no progress (the player's clock)
        self.fqn = fqn
        self.namespace, _, self.name = fqn.rpartition("/")
        self.namespace = self.namespace or "/"
        self.only_topic = topic
        self.topics: set[str] = set()  # recorded names of the played topics it consumes
        self.progress: int | None = None
        self.progress_msgs = 0
        self.first_sent: int | None = None
        self.outstanding: list[int] = []  # ends (first + num) of frames sent, beyond progress
        self.sent_end: int | None = None
        self.skipped = 0  # frames the progress jumped over (never reported as processed)
        #: True when every progress report reaches the player (the progress publisher keeps
        #: all, or at least :data:`~mems_sim.ros.qos.FRAME_DEPTH`, reports): then a jump over
        #: a frame means the frame was lost; with a shallow history reports may be coalesced.
        self.exact_jumps = False
        self.diag_gaps: int | None = None  # the consumer's own "gaps" count (/diagnostics)
        self.diag_missing: int | None = None  # and its "missing_samples"
        self.diag_at = 0.0  # monotonic time of the last diagnostics status
        self.gave_up = ""  # why the player stopped waiting for it ("" while it does)
        self.subscription = None

    def restart(self) -> None:
        """Forget progress reported before the replay (a latched last value)."""
        self.progress = None
        self.outstanding.clear()
        self.first_sent = self.sent_end = None
        self.skipped = 0
        self.touch(time.monotonic())

    def lost_frames(self) -> int:
        """Frames lost as far as the player can tell: those its progress jumped over (when
        :attr:`exact_jumps`) and those never acknowledged."""
        return (self.skipped if self.exact_jumps else 0) + len(self.outstanding)

    def on_progress(self, value: int) -> None:
        """A progress report: frames whose end it passes without naming it are skipped."""
        value = int(value)
        self.progress_msgs += 1
        if self.progress is not None and value <= self.progress:
            return
        self.progress = value
        self.touch(time.monotonic())
        done = bisect.bisect_right(self.outstanding, value)
        if done:
            self.skipped += done - (1 if self.outstanding[done - 1] == value else 0)
            del self.outstanding[:done]

    def allows(self, first: int, num: int, credit: int, unit: str) -> bool:
        """True if the frame [first, first + num) may be published now."""
        if self.gave_up:
            return True
        if unit == "frames":
            # a frame whose partner (same indices, another input topic) is out goes too
            return len(self.outstanding) < credit or first + num in self.outstanding
        return may_send(first, num, self.progress, credit, self.first_sent)

    def sent(self, first: int, num: int) -> None:
        """Record a frame published to it (frames of its paired topics share an end)."""
        end = first + num
        if self.first_sent is None:
            self.first_sent = first
        if self.progress is not None and end <= self.progress:
            return
        if self.sent_end is None or end > self.sent_end:
            self.sent_end = end
        if not self.outstanding or end > self.outstanding[-1]:
            self.outstanding.append(end)
        elif end not in self.outstanding:
            bisect.insort(self.outstanding, end)

    def caught_up(self) -> bool:
        """True once its progress reached the end of everything sent to it."""
        return self.sent_end is None or (
            self.progress is not None and self.progress >= self.sent_end
        )


class FlowControl:
    """Application-level flow control of a replay into named consumers (``--wait-for-consumer``).

    The player subscribes to each consumer's ``progress`` topic (and to /diagnostics for its
    own gap count), publishes a frame on one of its input topics only while the consumer
    has credit (:meth:`Consumer.allows`), and at the end waits until every consumer's
    progress reached the last frame sent. Loss is counted two ways: frames the progress
    jumped over (exact when progress arrives reliably, one report per frame) and the gaps
    the consumer itself reports on /diagnostics. The middleware's acknowledgements and
    message-lost events are not used: a reliable writer reports acknowledgement late and
    even after the reader left, and a reader that falls behind its history loses messages
    without any event.

    :param node: the player's node; :param executor: spun while waiting (progress arrives
        through it); :param consumers: ``[(fqn, topic or None)]``; :param credit: a value
        of :func:`parse_credit`; :param stall_s: give up on a consumer whose progress has
        not moved for this long while frames are outstanding (or that left the graph).
    """

    def __init__(self, node, executor, consumers, credit=(50, "frames"), stall_s: float = 30.0):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.node = node
        self.executor = executor
        self.consumers = [Consumer(fqn, topic) for fqn, topic in consumers]
        self.credit, self.unit = credit
        self.stall_s = float(stall_s)
        self.by_topic: dict[str, list[Consumer]] = {}
        self.topic_ends: dict[str, list[int]] = {}
        self.waited_s = 0.0
        self._last_presence = 0.0
        self._diag_sub = node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            self._on_diagnostics,
            QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT),
        )

    # ------------------------------------------------------------------ discovery

    def _present(self, c: Consumer) -> bool:
        return (c.name, c.namespace) in set(self.node.get_node_names_and_namespaces())

    def _subscribe_progress(self, c: Consumer) -> bool:
        from rclpy.qos import HistoryPolicy

        from mems_sim.bag.recorder import adapt_qos
        from mems_sim.ros.qos import FRAME_DEPTH

        topic = progress_topic(c.fqn)
        offered = [p.qos_profile for p in self.node.get_publishers_info_by_topic(topic)]
        if not offered:
            return False
        c.exact_jumps = all(
            q.history == HistoryPolicy.KEEP_ALL or int(q.depth) >= FRAME_DEPTH for q in offered
        )
        reader = ProgressSubscriber(self.node, c.fqn, c.on_progress, adapt_qos(offered))
        c.subscription = reader.subscription
        return True

    def wait_ready(self, player, timeout_s: float, stop=lambda: False) -> str | None:
        """Wait until every consumer is in the graph, publishes progress, subscribes to at
        least one played frame topic of ``player`` (a :class:`~mems_sim.bag.player.Player`),
        and every publisher of those topics is matched with all their subscribers; None when
        ready, else why not (one line)."""
        inverse = {p.topic_name: t for t, p in player.publishers.items()}
        deadline = time.monotonic() + timeout_s
        why = "not ready"
        while time.monotonic() < deadline and not stop():
            self.executor.spin_once(timeout_sec=0.05)
            why = None
            for c in self.consumers:
                if c.subscription is None and not self._subscribe_progress(c):
                    why = f"{c.fqn}: no publisher of {c.fqn}/progress"
                    break
                try:
                    names = self.node.get_subscriber_names_and_types_by_node(c.name, c.namespace)
                except Exception:
                    why = f"{c.fqn}: node not found"
                    break
                subscribed = {inverse[n] for n, _ in names if n in inverse}
                if c.only_topic is not None:
                    wanted = inverse.get(c.only_topic, c.only_topic)
                    subscribed &= {wanted}
                c.topics = {t for t in subscribed if t in player.frame_topics}
                if not c.topics:
                    why = f"{c.fqn}: subscribes to none of the played frame topics"
                    break
                if c.subscription.get_publisher_count() < 1:
                    why = f"{c.fqn}: progress not matched yet"
                    break
            if why is None:
                # every known subscriber matched; near the deadline, the consumers' own
                # suffice (another subscriber may have an incompatible QoS)
                late = time.monotonic() > deadline - min(1.0, timeout_s / 2)
                for topic in {t for c in self.consumers for t in c.topics}:
                    name = player.publishers[topic].topic_name
                    subs = self.node.get_subscriptions_info_by_topic(name)
                    if late:
                        fqns = {c.fqn for c in self.consumers if topic in c.topics}
                        subs = [s for s in subs if _fqn(s.node_namespace, s.node_name) in fqns]
                    if player.publishers[topic].get_subscription_count() < len(subs):
                        why = f"{name}: subscribers not matched yet"
                        break
            if why is None:
                self.by_topic = {}
                for c in self.consumers:
                    for t in c.topics:
                        self.by_topic.setdefault(t, []).append(c)
                settle = time.monotonic() + 0.2  # take a latched last report, then forget it
                while time.monotonic() < settle:
                    self.executor.spin_once(timeout_sec=0.02)
                for c in self.consumers:
                    c.restart()
                return None
        return why or "stopped"

    # ------------------------------------------------------------------ progress

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            for c in self.consumers:
                mine = status.hardware_id == c.fqn or (
                    not status.hardware_id and status.name.split(":", 1)[0] == c.name
                )
                if mine:
                    values = {kv.key: kv.value for kv in status.values}
                    try:
                        c.diag_gaps = int(values.get("gaps", 0))
                        c.diag_missing = int(values.get("missing_samples", 0))
                    except ValueError:
                        pass
                    c.diag_at = time.monotonic()

    def _check_alive(self, c: Consumer) -> None:
        """Give up on a consumer that left the graph or whose progress stalls."""
        if c.gave_up or c.caught_up():
            return
        now = time.monotonic()
        if c.stalled(now, self.stall_s):
            c.gave_up = f"no progress for {self.stall_s:g} s"
        elif now - self._last_presence > 0.5:
            self._last_presence = now
            if not self._present(c):
                c.gave_up = "left the graph"
        if c.gave_up:
            self.node.get_logger().warning(
                f"{c.fqn}: {c.gave_up} (progress {c.progress}, sent up to {c.sent_end}); "
                "no longer waiting for it"
            )

    def before(self, topic: str, data: bytes, stop=lambda: False) -> tuple[int, int] | None:
        """Wait until every consumer of ``topic`` has credit for this frame; return its
        ``(first, num)`` (None: not a gated frame)."""
        consumers = self.by_topic.get(topic)
        if not consumers:
            return None
        from mems_sim.bag.schema import peek_frame_index

        peek = peek_frame_index(data)
        if peek is None:
            return None
        first, num = peek
        self.executor.spin_once(timeout_sec=0)
        t0 = None
        while not stop():
            blocked = [c for c in consumers if not c.allows(first, num, self.credit, self.unit)]
            if not blocked:
                break
            if t0 is None:
                t0 = time.monotonic()
            for c in blocked:
                self._check_alive(c)
            self.executor.spin_once(timeout_sec=0.01)
        if t0 is not None:
            self.waited_s += time.monotonic() - t0
        return peek

    def after(self, topic: str, peek: tuple[int, int] | None) -> None:
        """Account a published frame (``peek`` from :meth:`before`)."""
        if peek is None:
            return
        first, num = peek
        self.topic_ends.setdefault(topic, []).append(first + num)
        for c in self.by_topic.get(topic, ()):
            c.sent(first, num)

    def finish(self, stop=lambda: False, diagnostics_s: float = 2.5) -> None:
        """Wait until every consumer caught up (or was given up), then for one more
        /diagnostics status of each (at most ``diagnostics_s``) for its gap count."""
        while not stop() and not all(c.caught_up() or c.gave_up for c in self.consumers):
            for c in self.consumers:
                self._check_alive(c)
            self.executor.spin_once(timeout_sec=0.02)
        t_end = time.monotonic()
        while not stop() and time.monotonic() - t_end < diagnostics_s:
            if all(c.diag_at > t_end or c.gave_up for c in self.consumers):
                break
            self.executor.spin_once(timeout_sec=0.05)

    # ------------------------------------------------------------------ report

    def acknowledged(self, topic: str) -> int:
        """Frames of ``topic`` whose end every consumer's progress has reached."""
        ends = self.topic_ends.get(topic, [])
        marks = [c.progress for c in self.by_topic.get(topic, ())]
        if not marks or any(m is None for m in marks):
            return 0
        low = min(marks)
        return sum(1 for e in ends if e <= low)

    def lost(self) -> int:
        """Loss seen by the player: per consumer, frames lost (:meth:`Consumer.lost_frames`)
        or, when more, the gaps it reported on /diagnostics itself."""
        return sum(max(c.lost_frames(), c.diag_gaps or 0) for c in self.consumers)

    def report(self, player) -> list[str]:
        """Lines of the end-of-replay report of ``player``'s replay (per topic, then per
        consumer)."""
        lines = []
        for topic in sorted(player.topic_counts):
            n = player.topic_counts[topic]
            consumers = self.by_topic.get(topic)
            if not consumers:
                lines.append(f"  {topic}: published {n}")
                continue
            names = ", ".join(c.fqn for c in consumers)
            lines.append(
                f"  {topic}: published {n}, acknowledged {self.acknowledged(topic)} by {names}"
            )
        for c in self.consumers:
            state = f"; {c.gave_up}" if c.gave_up else ""
            gaps = (
                "none on /diagnostics"
                if c.diag_gaps is None
                else f"{c.diag_gaps} ({c.diag_missing} samples missing)"
            )
            jumps = "" if c.exact_jumps else " (reports may be coalesced: not counted)"
            lines.append(
                f"  consumer {c.fqn}: progress {c.progress} of {c.sent_end}, "
                f"{c.progress_msgs} reports, frames its progress jumped over {c.skipped}{jumps}, "
                f"unacknowledged {len(c.outstanding)}, gaps it reported {gaps}{state}"
            )
        lost = self.lost()
        lines.append(f"  loss: {'none' if lost == 0 else f'{lost} frames'}")
        return lines

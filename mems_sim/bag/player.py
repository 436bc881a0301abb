"""Replay of a bag on a node: :class:`Player` publishes the stored bytes on publishers
made from the bag's schemas and recorded QoS, paced by their log time (sensor time) scaled
by a rate, or as fast as possible; with /clock, remaps, pause and play-next
(:mod:`mems_sim.bag.playback_control`) and lossless flow control into named consumers
(:mod:`mems_sim.bag.flow_control`). The command line ``mcap_play`` is
:mod:`mems_sim.bag.play_cli`. The reading API of :mod:`mems_sim.bag.reading` is
re-exported here. Docs: docs/recording.md (``mcap_play``).
"""

from __future__ import annotations

import time
from collections.abc import Iterable

from mems_sim.bag.playback_control import PlaybackControl
from mems_sim.bag.reading import *  # noqa: F403 (the reading API, re-exported)
from mems_sim.bag.reading import __all__ as _READING
from mems_sim.bag.reading import iter_messages, playable_topics
from mems_sim.ros.qos_yaml import playback_profile

__all__ = ["Player", *_READING]


def parse_remaps(remaps: Iterable[str]) -> dict[str, str]:
    """``['FROM:=TO', ...]`` -> ``{FROM: TO}``; raises ValueError on a malformed entry."""
    out = {}
    for item in remaps or ():
        src, sep, dst = item.partition(":=")
        if not sep or not src or not dst:
            raise ValueError(f"bad remap {item!r} (expected FROM:=TO)")
        out[src] = dst
    return out


class _Timeline:
    """Maps wall-clock time to the bag's log time at a rate, with pause, jump and shift
    (the time controller of rosbag2's player: paused, the log time holds)."""

    def __init__(self, rate: float, bag_ns: int, wall_s: float):
        self.rate = rate
        self.bag_ref = int(bag_ns)  # log time [ns] at wall_ref
        self.wall_ref = wall_s  # monotonic time [s]
        self.paused = False

    def now_ns(self, wall_s: float) -> int:
        """Log time [ns] reached at monotonic time ``wall_s``."""
        if self.paused:
            return self.bag_ref
        return self.bag_ref + int((wall_s - self.wall_ref) * self.rate * 1e9)

    def pause(self, wall_s: float) -> None:
        self.bag_ref = self.now_ns(wall_s)
        self.paused = True

    def resume(self, wall_s: float) -> None:
        self.wall_ref = wall_s
        self.paused = False

    def jump(self, bag_ns: int, wall_s: float) -> None:
        """Move the log time to ``bag_ns`` (held there while paused)."""
        self.bag_ref = int(bag_ns)
        self.wall_ref = wall_s

    def shift(self, seconds: float) -> None:
        """Hold the log time for ``seconds`` of wall time that just passed."""
        if not self.paused:
            self.wall_ref += seconds


class Player:
    """Publishes a bag's messages on a node (used by :func:`main`; usable in-process).

    :param node: rclpy node to create publishers on.
    :param path: MCAP file.
    :param topics: topics to play (None: all).
    :param remap: ``{recorded_topic: published_topic}``.
    :param resolved: the result of :func:`playable_topics` when the caller already
        has it (then skipped topics are not reported again on the node's logger).
    :param control: :class:`PlaybackControl` (pause, resume, play next), or None.
    :param executor: an executor of ``node``, spun while the player waits (for the
        control services and flow control); None: the player sleeps while it waits.
    """

    def __init__(
        self,
        node,
        path: str,
        topics: Iterable[str] | None = None,
        remap: dict[str, str] | None = None,
        resolved: tuple[dict[str, tuple[type, str]], dict[str, str]] | None = None,
        control: PlaybackControl | None = None,
        executor=None,
    ):
        self.node = node
        self.control = control
        self.executor = executor
        self.path = path
        self.topics = None if topics is None else list(topics)
        self.remap = dict(remap or {})
        self.publishers: dict[str, object] = {}
        self.published = 0
        #: Messages published per (recorded) topic.
        self.topic_counts: dict[str, int] = {}
        #: Played topics of frame types (sample-indexed: flow control applies to them).
        self.frame_topics: set[str] = set()
        #: Log time [ns] covered by the last :meth:`play` and the wall time [s] it took.
        self.played_log_s = 0.0
        self.played_wall_s = 0.0
        if resolved is None:
            resolved = playable_topics(path, self.topics)
            for topic, reason in resolved[1].items():
                node.get_logger().warning(f"{topic}: not played, {reason}")
        for topic, (cls, qos_yaml) in resolved[0].items():
            if self.topics is not None and topic not in self.topics:
                continue
            self.publishers[topic] = node.create_publisher(
                cls, self.remap.get(topic, topic), playback_profile(qos_yaml)
            )
            self.topic_counts[topic] = 0
            from mems_sim.bag.schema import GAP_CHECKED_TYPES, type_name_of

            if type_name_of(cls) in GAP_CHECKED_TYPES:
                self.frame_topics.add(topic)

    def wait_for_subscribers(self, count: int, timeout_s: float, stop=lambda: False) -> bool:
        """Wait until every publisher has at least ``count`` matched subscriptions; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not stop():
            if all(p.get_subscription_count() >= count for p in self.publishers.values()):
                return True
            self._wait(0.02)
        return all(p.get_subscription_count() >= count for p in self.publishers.values())

    def play(
        self,
        rate: float = 1.0,
        fast: bool = False,
        start_offset_s: float = 0.0,
        duration_s: float | None = None,
        clock_publisher=None,
        clock_hz: float = 0.0,
        stop=lambda: False,
        flow=None,
    ) -> int:
        """Publish the messages once, paced by log_time / rate (or as fast as possible).

        The bag's log times are its sensor time, so at rate 1 the replay takes as long as the
        recorded data, and /clock carries the time the stamps belong to.

        :param duration_s: play only this much bag time after the start offset [s].
        :param clock_publisher: publisher of rosgraph_msgs/Clock, published at ``clock_hz``
            [Hz] of wall-clock time with the log time reached (paced: the log time the
            wall clock has reached; as fast as possible: the last published message's), and
            once more with the last message's log time at the end; it never goes back,
            and holds while :attr:`control` is paused.
        :param flow: :class:`~mems_sim.bag.flow_control.FlowControl`: a frame for a named consumer waits for its
            credit; paced playback pauses meanwhile (the time waited does not count).
        Paused (:class:`PlaybackControl`), nothing is published until it resumes, except one
        message per play-next request; the log time then continues from that message.
        Returns the number of messages published.
        """
        from rosgraph_msgs.msg import Clock

        control = self.control
        timeline = None
        clock_period = 1.0 / clock_hz if clock_publisher is not None and clock_hz > 0 else None
        next_clock = time.monotonic()
        next_spin = time.monotonic()
        end_ns = None
        last_ns = None
        count = 0

        clock_ns = None  # the last time published on /clock: it never goes back

        def publish_clock(bag_ns: int):
            nonlocal clock_ns
            clock_ns = int(bag_ns) if clock_ns is None else max(clock_ns, int(bag_ns))
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(clock_ns, 1_000_000_000)
            clock_publisher.publish(msg)

        if control is not None:
            control.finished = False
        for item in iter_messages(self.path, self.publishers.keys(), start_offset_s):
            if stop():
                break
            if timeline is None:
                timeline = _Timeline(rate, item.log_time_ns, time.monotonic())
                timeline.paused = control is not None and control.paused  # held from the start
                started = timeline.wall_ref
                bag0 = item.log_time_ns
                if duration_s is not None:
                    end_ns = bag0 + int(duration_s * 1e9)
            if end_ns is not None and item.log_time_ns > end_ns:
                break
            while not stop():
                now = time.monotonic()
                paused = control is not None and control.paused
                if paused != timeline.paused:
                    (timeline.pause if paused else timeline.resume)(now)
                if fast:
                    shown_ns = last_ns if last_ns is not None else item.log_time_ns
                else:
                    # the time reached, but never past a message not published yet (a late
                    # wake-up on a loaded machine must not carry /clock beyond the data)
                    shown_ns = min(timeline.now_ns(now), item.log_time_ns)
                if clock_period is not None and now >= next_clock:
                    if paused or not fast:
                        publish_clock(shown_ns)
                        next_clock += clock_period
                        if next_clock < now:
                            next_clock = now + clock_period
                    else:
                        publish_clock(item.log_time_ns)
                        next_clock = now + clock_period
                if paused:
                    if control.take_next():
                        timeline.jump(item.log_time_ns, now)  # the clock moves to this message
                        break
                    wake = 0.05 if clock_period is None else next_clock - now
                    self._wait(max(0.0, min(wake, 0.05)))
                    continue
                if fast:
                    if self.executor is not None and now >= next_spin:
                        self.executor.spin_once(timeout_sec=0)  # serve the control services
                        next_spin = now + 0.02
                        continue
                    break
                due_in = (item.log_time_ns - timeline.now_ns(now)) / 1e9 / rate
                if due_in <= 0:
                    break
                wake = due_in if clock_period is None else min(due_in, next_clock - now)
                self._wait(max(0.0, min(wake, 0.05)))
            if stop():
                break
            peek = None
            if flow is not None:
                waited = flow.waited_s
                peek = flow.before(item.topic, item.data, stop)
                timeline.shift(flow.waited_s - waited)  # paused while waiting for credit
                if stop():
                    break
            self._publish(item.topic, item.data)
            if flow is not None:
                flow.after(item.topic, peek)
            self.topic_counts[item.topic] = self.topic_counts.get(item.topic, 0) + 1
            last_ns = item.log_time_ns
            count += 1
        if control is not None:
            control.finished = True
        if clock_period is not None and last_ns is not None and not stop():
            publish_clock(last_ns)
        if timeline is not None and last_ns is not None:
            self.played_log_s = (last_ns - bag0) / 1e9
            self.played_wall_s = time.monotonic() - started
        self.published += count
        return count

    def _wait(self, seconds: float) -> None:
        """Wait up to ``seconds``: serving the node's callbacks when there is an executor."""
        seconds = max(0.0, seconds)  # a negative timeout would make spin_once wait forever
        if self.executor is not None:
            self.executor.spin_once(timeout_sec=seconds)
        else:
            time.sleep(seconds)

    def _publish(self, topic: str, data: bytes) -> None:
        """Publish the serialised bytes on the (possibly remapped) topic."""
        self.publishers[topic].publish(data)

    def wait_acked(self, topic: str | None = None, timeout_s: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published (one topic or all)."""
        from rclpy.duration import Duration

        topics = [topic] if topic is not None else list(self.publishers)
        ok = True
        for name in topics:
            try:
                ok &= bool(self.publishers[name].wait_for_all_acked(Duration(seconds=timeout_s)))
            except Exception:
                pass
        return ok

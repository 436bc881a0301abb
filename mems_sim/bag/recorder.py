"""MCAP recorder node: ``mcap_record -o FILE.mcap [-a | TOPIC ...] [-e RE] [-x RE] [-b BYTES] [-d S]``.

The command line follows ``ros2 bag record`` (rosbag2, Jazzy/Rolling) where an option
exists there: ``-s/--storage`` (``mcap`` only), ``--topics``, ``-a/--all``, ``-e/--regex``,
``-x/--exclude-regex``, ``--include-hidden-topics``, ``-b/--max-bag-size``,
``-d/--max-bag-duration``, ``--qos-profile-overrides-path``, ``--compression-format``,
``--storage-preset-profile`` (``none``, ``fastwrite``, ``zstd_fast``, ``zstd_small``:
:data:`~mems_sim.bag.writer.STORAGE_PRESETS`).
``--duration`` (rosbag2 has no such option) ends recording after that much wall-clock
time. With ``-b`` or ``-d`` the output is a rosbag2 bag directory of split MCAP files and a
``metadata.yaml`` (:class:`~mems_sim.bag.writer.McapBagWriter`); without them ``-o`` names
one ``.mcap`` file.

:class:`RecorderNode` discovers topics periodically, subscribes with
``raw=True`` (the serialised CDR bytes go to the file untouched, no
deserialise/serialise round trip) and a QoS adapted to the publishers
(rosbag2's rule: reliable only if every publisher offers reliable,
transient-local only if every publisher offers it; depth at least
:data:`~mems_sim.ros.qos.FRAME_DEPTH`). It records the publishers' offered QoS as
``offered_qos_profiles``. Frame-index gaps of frame topics are counted (and
logged as warnings when they appear).

Loss on every topic: each message is written with its publisher's publication
sequence number (from the middleware's message info) as the MCAP ``sequence``, and
gaps of each publisher's numbers are counted, so a lost message shows on topics that
are not frames too. An emulator's end-of-stream record (``.../end_of_stream``,
:mod:`mems_sim.ros.end_of_stream`) tells how many messages and samples it published
per topic; :meth:`RecorderNode.tails` compares that with what was recorded, so a
missing tail is seen as well as a gap (:meth:`RecorderNode.losses` lists both).

Times: the bag is on the data's timeline. ``log_time`` is the message's sensor
time: its ``header.stamp`` when the type starts with a ``std_msgs/Header`` (for
``rosgraph_msgs/Clock`` the clock value), otherwise the graph's clock when it
arrives (:meth:`RecorderNode.graph_time_ns`: the last /clock received, else the
node's ROS clock). ``publish_time`` is when the sender published the message,
as the MCAP specification defines: the middleware's source timestamp (wall
clock), or the receive time when the middleware gives none. So a fast simulated
run, whose stamps start at 0, gives a bag that starts at 0 and lasts as long as
its data, and a live graph stamped from the wall clock gives wall-clock log times.

In-process users (the scenario runner) create a RecorderNode with their own
context and executor and use :meth:`RecorderNode.received` to throttle. An executor
takes one message per subscription per wait; each recorder callback takes up to
:data:`TAKE_BATCH` more of its topic, so that a topic many publishers feed
(``/diagnostics``) does not queue up behind a busy graph, and :meth:`RecorderNode.close`
first takes what the middleware already delivered (:meth:`RecorderNode.take_pending`).

Stopping (``mcap_record``): a stop request (SIGINT or SIGTERM, as ``ros2 launch``
and ``docker stop`` send before a SIGKILL) ends recording in bounded time, live
publishers or not. Messages that arrive within :data:`STOP_GRACE_S` of the
request are still taken and written; then the subscriptions are destroyed, the
writer thread drains its queue until :data:`STOP_FINALISE_S` after the request
(what is still queued then is dropped and counted in the summary), and the
Summary, Statistics and footer are written; exit status 0. A second signal
skips the rest of the grace window and of the drain. Output problems (an
existing file without ``--overwrite``, a symbolic link, a directory, a missing
directory, a full disk) give one line on stderr naming the path and exit status
1 (2 for a path refused before recording).
"""

from __future__ import annotations

import argparse
import re
import signal
import sys
import time
from collections.abc import Iterable
from functools import partial

from rclpy.clock import Clock as RclpyClock
from rclpy.clock import ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import UInt64

from mems_sim.bag.schema import (
    SchemaError,
    has_header,
    message_class,
    normalize_type_name,
    peek_frame_index,
    peek_header_stamp_ns,
    qos_profiles_yaml,
    schema_text,
    type_hash,
)
from mems_sim.bag.writer import (
    STORAGE_PRESETS,
    BagWriteError,
    McapBagWriter,
    bag_directory_path,
    bag_directory_problem,
    gap_summary,
    output_problem,
    storage_preset,
)
from mems_sim.cli_values import OneLineParser, non_negative, positive
from mems_sim.ros.end_of_stream import (
    describe_tail,
    is_end_of_stream_topic,
    missing_tail,
    parse_end_of_stream,
)
from mems_sim.ros.env import STOP_SIGNALS, apply_defaults, domain_id_problem
from mems_sim.ros.qos import FRAME_DEPTH, PROGRESS_QOS
from mems_sim.ros.qos_yaml import load_overrides

_BEST_EFFORT = ReliabilityPolicy.BEST_EFFORT

#: Topics skipped unless listed explicitly.
DEFAULT_EXCLUDED = ("/rosout", "/parameter_events")

#: After a stop request, messages arriving within this time are still recorded [s].
STOP_GRACE_S = 0.4

#: After a stop request the file is finalised by this time at the latest [s]
#: (queued messages not written by then are dropped and counted).
STOP_FINALISE_S = 1.0

#: After ``--duration`` the writer queue is drained for at most this long before the
#: Summary is written [s] (what is still queued then is dropped and counted).
DURATION_FINALISE_S = 0.3

#: Messages a recorder callback takes from its subscription after the one the executor
#: handed it (:meth:`RecorderNode._take_waiting`): an executor takes one message per
#: subscription per wait, so a topic many publishers feed (``/diagnostics``: one status a
#: second from every node) would otherwise queue up in the reader behind the graph's work.
TAKE_BATCH = 100

#: :meth:`RecorderNode.close` takes what the middleware already delivered to the
#: subscriptions for at most this long [s] (publishers of other processes may go on).
CLOSE_TAKE_S = 5.0


def is_hidden_topic(topic: str) -> bool:
    """True for a hidden topic: a name token starts with an underscore (the ROS 2 rule
    ``ros2 topic list`` and rosbag2 apply)."""
    return any(token.startswith("_") for token in topic.split("/"))


def adapt_qos(offered: list[QoSProfile], keep_all: bool = True) -> QoSProfile:
    """Subscription QoS that matches every offered publisher QoS (rosbag2's rule).

    Reliable if all offer reliable, else best effort; transient-local if all
    offer it, else volatile. History: KEEP_ALL for reliable topics (with
    ``keep_all``), so that a recorder that falls behind applies back-pressure
    through DDS flow control instead of dropping from a full KEEP_LAST reader
    history; otherwise KEEP_LAST with depth max(FRAME_DEPTH, offered depths).
    """
    reliable = bool(offered) and all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    latched = bool(offered) and all(
        q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered
    )
    depth = max(
        [FRAME_DEPTH] + [int(q.depth) for q in offered if q.history == HistoryPolicy.KEEP_LAST]
    )
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if (reliable and keep_all) else HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def _publication(info) -> tuple[int | None, bytes | None]:
    """(publication sequence number, publisher gid) from rclpy's message info, when the
    middleware gives them."""
    if not info:
        return None, None
    sequence = info.get("publication_sequence_number")
    gid = info.get("publisher_gid") or {}
    data = gid.get("data") if isinstance(gid, dict) else None
    return sequence, (bytes(data) if data is not None else None)


class RecorderNode(Node):
    """Record topics into an MCAP file (rosbag2-compatible ``ros2`` profile).

    :param output: path of the ``.mcap`` file to write (truncated if present).
    :param topics: topic names to record (recorded even if in DEFAULT_EXCLUDED).
    :param all_topics: record every discovered topic (except DEFAULT_EXCLUDED).
    :param regex: also record topics whose name matches this regular expression.
    :param exclude: never record topics matching this regular expression.
    :param discovery_period_s: period of the topic discovery timer [s].
    :param compression: chunk compression ``'zstd'``, ``'lz4'`` or ``'none'``.
    :param chunk_size: uncompressed chunk size [bytes].
    :param storage_preset_profile: rosbag2's MCAP storage preset (``none``, ``fastwrite``,
        ``zstd_fast``, ``zstd_small``; :func:`~mems_sim.bag.writer.storage_preset`): its
        compression, zstd level, chunk size and CRC setting replace ``compression`` and
        ``chunk_size`` (``mcap_record`` lets explicit options override the preset).
    :param writer_options: more :class:`~mems_sim.bag.writer.McapBagWriter` options
        (``compression_level``, ``crcs``), applied last.
    :param node_name: ROS node name.
    :param overwrite: replace an existing output file (the ``mcap_record`` CLI passes
        ``--overwrite``; a symbolic link is refused either way).
    :param max_bag_size: split into a new file at this many bytes (0: never); with a split
        the output is a rosbag2 bag directory (:class:`~mems_sim.bag.writer.McapBagWriter`).
    :param max_bag_duration: split into a new file at this much log time [s] (0: never).
    :param qos_overrides: topic -> QoSProfile used for that topic's subscription instead of
        the adapted one (rosbag2's ``--qos-profile-overrides-path``).
    :param include_hidden_topics: with ``all_topics`` or ``regex``, record hidden topics
        too (listed topics always are); the ``mcap_record`` CLI defaults to False as rosbag2.
    :param progress_topic: a recorded frame topic whose progress the recorder reports on
        ``~/progress`` (one past the last sample index written, after each frame of that
        topic), so that a player's ``--wait-for-consumer NODE_FQN:TOPIC`` flow control can
        replay into the recorder without loss; None: no progress topic.
    :param kwargs: passed to ``rclpy.node.Node`` (e.g. ``context=ctx``).

    The constructor arguments can be overridden by ROS parameters of the same
    names (``output``, ``topics``, ``all``, ``regex``, ``exclude``).
    """

    def __init__(
        self,
        output: str = "",
        topics: Iterable[str] = (),
        all_topics: bool = False,
        regex: str | None = None,
        exclude: str | None = None,
        discovery_period_s: float = 0.25,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
        node_name: str = "mcap_recorder",
        storage_preset_profile: str | None = None,
        writer_options: dict | None = None,
        overwrite: bool = True,
        max_bag_size: int = 0,
        max_bag_duration: float = 0.0,
        qos_overrides: dict[str, QoSProfile] | None = None,
        include_hidden_topics: bool = True,
        progress_topic: str | None = None,
        **kwargs,
    ):
        super().__init__(node_name, **kwargs)
        output = self.declare_parameter("output", str(output)).value
        topics = list(self.declare_parameter("topics", list(topics) or [""]).value or [])
        all_topics = bool(self.declare_parameter("all", bool(all_topics)).value)
        regex = self.declare_parameter("regex", regex or "").value or None
        exclude = self.declare_parameter("exclude", exclude or "").value or None
        if not output:
            raise ValueError("RecorderNode needs an output path")
        self._explicit = {t for t in topics if t}
        self._all = all_topics
        self._regex = re.compile(regex) if regex else None
        self._exclude = re.compile(exclude) if exclude else None
        self._hidden = bool(include_hidden_topics)
        self._qos_overrides = dict(qos_overrides or {})
        options = {"chunk_size": chunk_size, "compression": compression}
        options.update(storage_preset(storage_preset_profile))
        options.update(writer_options or {})
        self._bag = McapBagWriter(
            output,
            **options,
            on_gap=self._log_gap,
            overwrite=overwrite,
            max_bag_size=max_bag_size,
            max_bag_duration=max_bag_duration,
        )
        self._topic_subs: dict[str, object] = {}
        self._unusable: dict[str, str] = {}
        self._rx_counts: dict[str, int] = {}
        self._stamped: dict[str, bool] = {}
        self._eos_topics: set[str] = set()
        self._end_of_stream: dict[str, dict[str, int]] = {}
        self._rec_closed = False
        self._graph_clock_ns: int | None = None
        self._progress_topic = progress_topic
        self._progress_pub = (
            self.create_publisher(UInt64, "~/progress", PROGRESS_QOS) if progress_topic else None
        )
        self._clock_sub = self.create_subscription(
            Clock, "/clock", self._on_clock, QoSProfile(depth=10, reliability=_BEST_EFFORT)
        )
        # on the steady clock: neither run at every step of a fast simulated run nor stop
        # while /clock stands still (under use_sim_time)
        self._discovery_timer = self.create_timer(
            discovery_period_s, self.discover, clock=RclpyClock(clock_type=ClockType.STEADY_TIME)
        )
        self.discover()

    # ---------------------------------------------------------------- selection

    def wants(self, topic: str) -> bool:
        """True when ``topic`` is selected by the topic list / all / regex and not excluded."""
        if topic in self._explicit:
            return True
        if self._exclude is not None and self._exclude.search(topic):
            return False
        if topic in DEFAULT_EXCLUDED:
            return False
        if not self._hidden and is_hidden_topic(topic):
            return False
        if self._all:
            return True
        return bool(self._regex is not None and self._regex.search(topic))

    # ---------------------------------------------------------------- discovery

    def discover(self) -> None:
        """Subscribe to newly appeared selected topics that have at least one publisher."""
        if self._rec_closed:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self._topic_subs or topic in self._unusable or not self.wants(topic):
                continue
            if len(types) != 1:
                self._mark_unusable(topic, f"has {len(types)} types {types}; not recorded")
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: try again when a publisher appears
            self._subscribe(topic, types[0], [p.qos_profile for p in publishers])

    def _subscribe(self, topic: str, type_name: str, offered: list[QoSProfile]) -> None:
        try:
            type_name = normalize_type_name(type_name)
            msg_type = message_class(type_name)
            text = schema_text(type_name)
            stamped = has_header(type_name)
        except SchemaError as exc:
            self._mark_unusable(topic, str(exc))
            return
        self._bag.add_topic(
            topic, type_name, text, qos_profiles_yaml(offered), type_hash(type_name)
        )
        self._rx_counts[topic] = 0
        if is_end_of_stream_topic(topic, type_name):
            self._eos_topics.add(topic)
        # a Clock message starts with its time, laid out as a header's stamp
        self._stamped[topic] = stamped or type_name == "rosgraph_msgs/msg/Clock"
        qos = self._qos_overrides.get(topic) or adapt_qos(offered)
        self._topic_subs[topic] = self.create_subscription(
            msg_type, topic, partial(self._on_message, topic), qos, raw=True
        )
        self.get_logger().info(
            f"recording {topic} [{type_name}] ({qos.reliability.name.lower()}, "
            f"{qos.durability.name.lower()}, depth {qos.depth})"
        )

    def _mark_unusable(self, topic: str, reason: str) -> None:
        self._unusable[topic] = reason
        self.get_logger().warning(f"{topic}: {reason}")

    # ---------------------------------------------------------------- data

    def _on_clock(self, msg) -> None:
        self._graph_clock_ns = int(msg.clock.sec) * 1_000_000_000 + int(msg.clock.nanosec)

    def graph_time_ns(self) -> int:
        """The graph's clock [ns]: the last /clock received, else the node's ROS clock (the
        wall clock, or /clock under use_sim_time); the log time of unstamped messages."""
        if self._graph_clock_ns is not None:
            return self._graph_clock_ns
        return self.get_clock().now().nanoseconds

    def _on_message(self, topic: str, data: bytes, info) -> None:
        # ``info`` has no default: rclpy passes the message info (publication sequence
        # number, publisher, source timestamp) only to a callback that requires it
        if self._rec_closed:
            return
        self._record(topic, data, info)
        self._take_waiting(topic, TAKE_BATCH)

    def _take_waiting(self, topic: str, limit: int | None, deadline: float | None = None) -> int:
        """Take and record what the middleware already holds for ``topic``'s subscription:
        at most ``limit`` messages (None: all), until ``deadline`` (monotonic) if given.
        Returns the number taken."""
        sub = self._topic_subs.get(topic)
        taken = 0
        if sub is None:
            return 0
        while limit is None or taken < limit:
            if deadline is not None and time.monotonic() >= deadline:
                break
            try:
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:  # destroyed meanwhile
                break
            if got is None:
                break
            self._record(topic, got[0], got[1])
            taken += 1
        return taken

    def take_pending(self, timeout_s: float | None = CLOSE_TAKE_S) -> int:
        """Take and record every message the middleware already delivered to the
        subscriptions but the executor has not taken yet (for at most ``timeout_s``
        seconds; None: no limit). Returns the number taken. :meth:`close` calls it, so
        that an in-process recorder closed right after the graph's last publish (or while
        its executor lags behind a busy topic) loses nothing already delivered."""
        if self._rec_closed:
            return 0
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        return sum(self._take_waiting(t, None, deadline) for t in list(self._topic_subs))

    def _record(self, topic: str, data: bytes, info) -> None:
        """Write one message taken from ``topic``'s subscription."""
        stamp = peek_header_stamp_ns(data) if self._stamped[topic] else None
        log_time = self.graph_time_ns() if stamp is None else stamp
        sent = info.get("source_timestamp") if info else None
        sequence, publisher = _publication(info)
        self._bag.write(
            topic, data, log_time, sent or time.time_ns(), sequence=sequence, publisher=publisher
        )
        self._rx_counts[topic] += 1
        if self._progress_pub is not None and topic == self._progress_topic:
            peek = peek_frame_index(data)
            if peek is not None:
                self._progress_pub.publish(UInt64(data=peek[0] + peek[1]))
        if topic in self._eos_topics:
            self._take_end_of_stream(topic, data)

    def _take_end_of_stream(self, topic: str, data: bytes) -> None:
        """Keep the per-topic counts of an emulator's end-of-stream record."""
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.serialization import deserialize_message

        try:
            entries = parse_end_of_stream(deserialize_message(data, DiagnosticArray))
        except Exception as exc:  # a foreign or corrupt record is only reported
            self.get_logger().warning(f"{topic}: unreadable end-of-stream record: {exc}")
            return
        self._end_of_stream.update(entries)

    def _log_gap(self, topic: str, expected: int, first: int) -> None:
        self.get_logger().warning(
            f"{topic}: frame-index gap, expected first_sample_index {expected}, got {first} "
            f"({first - expected} samples missing)"
        )

    # ---------------------------------------------------------------- queries

    def received(self, topic: str) -> int:
        """Messages received (and written) on ``topic`` so far (0 if not subscribed)."""
        return self._rx_counts.get(topic, 0)

    def counts(self) -> dict[str, int]:
        """Messages written per recorded topic."""
        return self._bag.counts()

    def gaps(self) -> dict[str, int]:
        """Frame-index gaps per recorded frame topic."""
        return self._bag.gaps()

    def gap_details(self) -> dict[str, dict[str, int]]:
        """Per frame topic: gaps, missing_samples, resets, frames, samples."""
        return self._bag.gap_details()

    def sequence_details(self) -> dict[str, dict[str, int]]:
        """Per topic: ``publishers`` seen, publication-sequence ``gaps``,
        ``missing_messages``, ``resets`` and ``last`` (highest sequence number)."""
        return self._bag.sequence_details()

    def publishers_seen(self, topic: str) -> int:
        """Distinct publishers whose messages were recorded on ``topic``."""
        return self._bag.sequence_details().get(topic, {}).get("publishers", 0)

    def end_of_stream(self) -> dict[str, dict[str, int]]:
        """Per data topic, the counts of the end-of-stream records received so far
        (``messages``; ``end_sample_index`` and ``samples`` for frames)."""
        return dict(self._end_of_stream)

    def tails(self) -> dict[str, dict[str, int]]:
        """Per topic announced in an end-of-stream record and recorded short of it: the
        missing tail (``messages``; ``samples`` and ``from_index`` for frames)."""
        details, seqs, counts = self.gap_details(), self.sequence_details(), self.counts()
        out = {}
        for topic, expected in self._end_of_stream.items():
            if topic not in counts:
                continue  # not selected for recording
            seq = seqs.get(topic, {})
            seen = seq["last"] if seq.get("publishers") == 1 else counts.get(topic, 0)
            end = None
            if topic in details and details[topic]["frames"]:
                end = self._bag.frame_end(topic)
            tail = missing_tail(expected, seen, end)
            if tail["messages"] or tail.get("samples"):
                out[topic] = tail
        return out

    def losses(self) -> list[str]:
        """One phrase per recorded topic that lost data: frame-index gaps, gaps of a
        publisher's sequence numbers (topics that are not frames), a missing tail."""
        out = []
        details, seqs, tails = self.gap_details(), self.sequence_details(), self.tails()
        for topic in sorted(set(details) | set(seqs) | set(tails)):
            parts = []
            d = details.get(topic)
            if d and d["gaps"]:
                parts.append(f"{d['gaps']} frame-index gaps ({d['missing_samples']} samples)")
            s = seqs.get(topic)
            if s and s["gaps"] and topic not in details:
                parts.append(f"{s['gaps']} sequence gaps ({s['missing_messages']} messages)")
            if topic in tails:
                text = describe_tail(topic, self._end_of_stream[topic], tails[topic])
                parts.append(text.split(": ", 1)[1])
            if parts:
                out.append(f"{topic}: " + ", ".join(parts))
        return out

    def matched(self, topic: str) -> bool:
        """True when the recorder subscribes to ``topic`` and has matched a publisher."""
        sub = self._topic_subs.get(topic)
        return sub is not None and sub.get_publisher_count() > 0

    def recorded_topics(self) -> dict[str, str]:
        """Type name per recorded topic."""
        return self._bag.topic_types()

    def dropped(self) -> dict[str, int]:
        """Messages per topic received but not written (still queued at a bounded close)."""
        return self._bag.dropped()

    @property
    def write_error(self) -> BaseException | None:
        """The writer's error (e.g. disk full), None while writing works."""
        return self._bag.error

    @property
    def output(self) -> str:
        """Path of the MCAP file (of the bag directory when splitting)."""
        return self._bag.path

    def output_files(self) -> list[str]:
        """The MCAP files written so far (one, or the split files of the bag directory)."""
        return self._bag.files()

    # ---------------------------------------------------------------- end

    def stop_taking(self) -> None:
        """Stop discovery and destroy the subscriptions: nothing more is received."""
        self._rec_closed = True
        self._discovery_timer.cancel()
        for sub in self._topic_subs.values():
            self.destroy_subscription(sub)
        self._topic_subs.clear()

    def close(self, timeout_s: float | None = None, abort=None) -> None:
        """Stop recording and finalise the file (Summary, Statistics). Idempotent.

        First the messages the middleware already delivered to the subscriptions but the
        executor has not taken are taken and written (:meth:`take_pending`, at most
        :data:`CLOSE_TAKE_S`): an in-process recorder closed right after the graph's last
        publish, or behind a busy topic, keeps them.

        :param timeout_s: drain the writer queue for at most this long [s] (None: all);
            what is still queued then is dropped and counted (:meth:`dropped`).
        :param abort: callable; True ends the drain at once (e.g. a second signal).
        Raises :class:`~mems_sim.bag.writer.BagWriteError` after a write error.
        """
        if self._bag.closed:
            return
        if self._bag.error is None:
            # what the executor has not taken yet (stop_taking already destroyed the
            # subscriptions of the command line's recorder: nothing then)
            try:
                self.take_pending(
                    CLOSE_TAKE_S if timeout_s is None else min(timeout_s, CLOSE_TAKE_S)
                )
            except BagWriteError:
                pass  # raised again by the writer's close below
        self._rec_closed = True
        self._discovery_timer.cancel()
        self._bag.close(timeout_s=timeout_s, abort=abort)

    def summary(self) -> str:
        """Multi-line human-readable summary: topics, counts, gaps, file size."""
        counts, details = self.counts(), self.gap_details()
        size = self._bag.size_bytes()
        files = f", {len(self.output_files())} files" if self._bag.is_directory else ""
        lines = [
            f"{self.output}: {sum(counts.values())} messages, {len(counts)} topics, "
            f"{size / 1e6:.3f} MB{files}"
        ]
        for topic, type_name in sorted(self.recorded_topics().items()):
            line = f"  {topic} [{type_name}]: {counts.get(topic, 0)} messages"
            if topic in details:
                d = details[topic]
                line += f", {d['samples']} samples, {d['gaps']} gaps ({d['missing_samples']} samples missing)"
            lines.append(line)
        total_gaps, missing = gap_summary(details)
        lines.append(f"  frame-index gaps: {total_gaps} ({missing} samples missing)")
        lines += [f"  lost: {text}" for text in self.losses()]
        dropped = self.dropped()
        if dropped:
            lines.append(
                f"  received but not written (stop deadline or write error): "
                f"{sum(dropped.values())} messages ("
                + ", ".join(f"{t} {n}" for t, n in sorted(dropped.items()))
                + ")"
            )
        return "\n".join(lines)

    def destroy_node(self) -> None:
        """Close the file, then destroy the node."""
        try:
            self.close()
        finally:
            super().destroy_node()


# -------------------------------------------------------------------- CLI


#: Exit status of ``mcap_record --fail-on-loss`` when a recorded topic lost data.
LOSS_STATUS = 3
#: Smallest split size of ``-b`` [bytes]: below it every message would start a file.
MIN_SPLIT_BYTES = 16384


def _byte_count(text: str) -> int:
    """A number of bytes: an integer, or a number with a k/M/G suffix (powers of 1000)."""
    scale = {"k": 10**3, "K": 10**3, "M": 10**6, "G": 10**9}.get(text[-1:], 1)
    number = text[:-1] if scale != 1 else text
    try:
        value = float(number) * scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of bytes") from None
    if not (0 <= value < 2**63) or value != int(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be a whole number of bytes >= 0")
    return int(value)


def _storage(text: str) -> str:
    if text != "mcap":
        raise argparse.ArgumentTypeError(f"{text!r}: only 'mcap' is supported")
    return text


def _regex(text: str) -> str:
    try:
        re.compile(text)
    except re.error as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not a regular expression: {exc}") from None
    return text


def _parse_args(argv: list[str]) -> argparse.Namespace:
    parser = OneLineParser(
        prog="mcap_record",
        description=__doc__.splitlines()[0],
        epilog="Without -b/-d, -o names one MCAP file. With -b or -d, -o names a rosbag2 bag "
        "directory (a .mcap suffix is dropped) holding NAME_0.mcap, NAME_1.mcap, ... and "
        "metadata.yaml; an existing directory is refused unless --overwrite (which replaces "
        "only a bag directory).",
    )
    parser.add_argument("topics", nargs="*", help="topics to record")
    parser.add_argument(
        "--topics",
        dest="more_topics",
        nargs="+",
        default=[],
        metavar="TOPIC",
        help="topics to record (as rosbag2; the same as positional topics)",
    )
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        help="output: FILE.mcap, or the bag directory with -b/-d",
    )
    parser.add_argument(
        "-s", "--storage", type=_storage, default="mcap", help="storage identifier: mcap only"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the output file (bag directory) if it exists",
    )
    parser.add_argument("-a", "--all", action="store_true", help="record all topics")
    parser.add_argument(
        "-e", "--regex", type=_regex, default=None, help="record topics matching this regex"
    )
    parser.add_argument(
        "-x",
        "--exclude-regex",
        "--exclude",
        dest="exclude",
        metavar="REGEX",
        type=_regex,
        default=None,
        help="exclude topics matching this regex (--exclude: old name)",
    )
    parser.add_argument(
        "--include-hidden-topics",
        action="store_true",
        help="with -a/-e, record hidden topics (a name token starting with '_') too",
    )
    parser.add_argument(
        "--qos-profile-overrides-path",
        default=None,
        metavar="FILE.yaml",
        help="YAML file of topic -> QoS profile (history, depth, reliability, durability, "
        "deadline, lifespan, liveliness, liveliness_lease_duration, "
        "avoid_ros_namespace_conventions) used for those subscriptions",
    )
    parser.add_argument(
        "-b",
        "--max-bag-size",
        type=_byte_count,
        default=0,
        metavar="BYTES",
        help="split the bag into a new file at this size [bytes; k/M/G suffixes] (0: never)",
    )
    parser.add_argument(
        "-d",
        "--max-bag-duration",
        type=non_negative,
        default=0.0,
        metavar="SECONDS",
        help="split the bag into a new file at this much log (sensor) time [s] (0: never)",
    )
    parser.add_argument(
        "--duration",
        type=positive,
        default=None,
        metavar="SECONDS",
        help="stop after this much wall-clock time from the start of recording [s]",
    )
    parser.add_argument(
        "--compression-format",
        "--compression",
        dest="compression",
        choices=["zstd", "lz4", "none"],
        default=None,
        help="MCAP chunk compression (default zstd, or the preset's; --compression: old name)",
    )
    parser.add_argument(
        "--chunk-size",
        type=_byte_count,
        default=None,
        help="MCAP chunk size [bytes] (default 1 MiB, or the preset's)",
    )
    parser.add_argument(
        "--storage-preset-profile",
        choices=list(STORAGE_PRESETS),
        default="none",
        metavar="PROFILE",
        help="rosbag2's MCAP writer presets: none (default: zstd level 1, 1 MiB chunks, "
        "CRCs), fastwrite (no compression, no CRCs), zstd_fast (zstd level -5, no CRCs), "
        "zstd_small (zstd level 19, 4 MiB chunks); --compression-format and --chunk-size "
        "override the preset's",
    )
    parser.add_argument(
        "--fail-on-loss",
        action="store_true",
        help=f"exit with status {LOSS_STATUS} (after the summary, with one line naming the "
        "topics) when a recorded topic lost data (run_graph sets it)",
    )
    parser.add_argument(
        "--report-progress",
        metavar="TOPIC",
        default=None,
        help="publish ~/progress (one past the last sample index written) after each frame "
        "of this recorded frame topic, so that mcap_play --wait-for-consumer NODE:TOPIC "
        "replays into the recorder without loss",
    )
    args = parser.parse_args(argv)
    args.writer_options = storage_preset(args.storage_preset_profile)
    if args.compression is not None:
        args.writer_options["compression"] = args.compression
        if args.compression != "zstd":
            args.writer_options.pop("compression_level", None)
    if args.chunk_size is not None:
        args.writer_options["chunk_size"] = args.chunk_size
    args.compression = args.writer_options.get("compression", "zstd")
    args.chunk_size = args.writer_options.get("chunk_size", 1 << 20)
    args.topics = list(args.topics) + list(args.more_topics)
    if not (args.topics or args.all or args.regex):
        parser.error("give topics, -a/--all or -e/--regex")
    if args.chunk_size < 1:
        parser.error("argument --chunk-size: must be at least 1 byte")
    if 0 < args.max_bag_size < MIN_SPLIT_BYTES:
        parser.error(f"argument -b/--max-bag-size: at least {MIN_SPLIT_BYTES} bytes (0: never)")
    args.split = bool(args.max_bag_size or args.max_bag_duration)
    if args.split:
        args.output = bag_directory_path(args.output)
    args.qos_overrides = {}
    if args.qos_profile_overrides_path:
        try:
            args.qos_overrides = load_overrides(args.qos_profile_overrides_path)
        except ValueError as exc:
            parser.error(f"argument --qos-profile-overrides-path: {exc}")
    return args


def drain(
    executor,
    recorder: RecorderNode,
    idle_s: float = 0.3,
    limit_s: float = 10.0,
    stop=lambda: False,
) -> None:
    """Write what the middleware already delivered before stopping.

    Messages acknowledged by the subscription but not yet taken by the
    executor would be lost on an immediate stop; spin until nothing has
    arrived for ``idle_s`` seconds, at most ``limit_s`` seconds, or until
    ``stop()`` (a second signal) or a write error.
    """
    deadline = time.monotonic() + limit_s
    last_total, last_change = -1, time.monotonic()
    while time.monotonic() < deadline and not stop() and recorder.write_error is None:
        executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))
        total = sum(recorder._rx_counts.values())
        if total != last_total:
            last_total, last_change = total, time.monotonic()
        elif time.monotonic() - last_change >= idle_s:
            return


class _StopRequest:
    """The stop signals (SIGINT, SIGTERM, SIGHUP) as a counter the main loop polls (the
    handler only records)."""

    def __init__(self):
        self.count = 0
        self.first_at: float | None = None
        self.first_name = ""
        self.previous = {}

    def _handle(self, signum, _frame) -> None:
        self.count += 1
        if self.first_at is None:
            self.first_at = time.monotonic()
            self.first_name = signal.Signals(signum).name

    def install(self) -> None:
        for sig in STOP_SIGNALS:
            self.previous[sig] = signal.signal(sig, self._handle)

    def restore(self) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        self.previous = {}


def _error(text: str, code: int) -> int:
    print(f"mcap_record: error: {' '.join(str(text).split())}", file=sys.stderr, flush=True)
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_record``; returns the process exit code.

    0 after a stop request or ``--duration``; 2 for an output path refused before
    recording; 1 when writing fails (disk full), with one line naming the path.
    """
    stop = _StopRequest()
    stop.install()  # before rclpy starts: a signal from now on finalises the file
    try:
        return _run(argv, stop)
    finally:
        stop.restore()


def _run(argv: list[str] | None, stop: _StopRequest) -> int:
    apply_defaults()
    problem = domain_id_problem()
    if problem is not None:
        return _error(problem, 2)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    argv = sys.argv[1:] if argv is None else list(argv)
    args = _parse_args(remove_ros_args(["mcap_record"] + argv)[1:])
    check = bag_directory_problem if args.split else output_problem
    problem = check(args.output, overwrite=args.overwrite)
    if problem is not None:
        return _error(problem, 2)

    rclpy.init(args=["mcap_record"] + argv, signal_handler_options=SignalHandlerOptions.NO)
    recorder = None
    code = 0
    try:
        try:
            recorder = RecorderNode(
                args.output,
                topics=args.topics,
                all_topics=args.all,
                regex=args.regex,
                exclude=args.exclude,
                compression=args.compression,
                chunk_size=args.chunk_size,
                writer_options={
                    k: v
                    for k, v in args.writer_options.items()
                    if k in ("compression_level", "crcs")
                },
                overwrite=args.overwrite,
                max_bag_size=args.max_bag_size,
                max_bag_duration=args.max_bag_duration,
                qos_overrides=args.qos_overrides,
                include_hidden_topics=args.include_hidden_topics,
                progress_topic=args.report_progress,
            )
        except BagWriteError as exc:
            return _error(exc, 1)
        executor = SingleThreadedExecutor()
        executor.add_node(recorder)
        # --duration: wall-clock time from here (the file is open, discovery has run once)
        started = time.monotonic()
        deadline = None if args.duration is None else started + args.duration
        timed_out = False
        try:
            while not stop.count and recorder.write_error is None:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    timed_out = True
                    break
                wait = 0.1 if deadline is None else min(0.1, deadline - now)
                executor.spin_once(timeout_sec=wait)
            if recorder.write_error is None and not timed_out:
                if stop.count:  # bounded: grace window, then a drain deadline
                    t0 = stop.first_at
                    drain(
                        executor,
                        recorder,
                        idle_s=0.1,
                        limit_s=max(0.0, t0 + STOP_GRACE_S - time.monotonic()),
                        stop=lambda: stop.count > 1,
                    )
                else:
                    drain(executor, recorder, idle_s=0.3, limit_s=2.0)
        except BagWriteError:
            pass  # a write raised inside a callback: reported below
        recorder.stop_taking()
        timeout = None
        if stop.count:
            timeout = max(0.0, stop.first_at + STOP_FINALISE_S - time.monotonic())
        elif timed_out:  # end on time: what the writer has not taken by then is counted
            timeout = DURATION_FINALISE_S
        try:
            recorder.close(timeout_s=timeout, abort=lambda: stop.count > 1)
        except BagWriteError as exc:
            code = _error(
                f"{exc} (the file keeps the chunks completed before the error)",
                1,
            )
        if code == 0 and stop.first_at is not None:
            print(
                f"mcap_record: {stop.first_name}: file finalised "
                f"{time.monotonic() - stop.first_at:.3f} s after the stop request",
                flush=True,
            )
        elif code == 0 and timed_out:
            print(
                f"mcap_record: --duration {args.duration:g} s: file finalised "
                f"{time.monotonic() - deadline:.3f} s after it "
                f"({time.monotonic() - started:.3f} s of recording)",
                flush=True,
            )
        print(recorder.summary(), flush=True)
        if code == 0 and args.fail_on_loss and recorder.losses():
            code = _error("lost data: " + "; ".join(recorder.losses()), LOSS_STATUS)
    finally:
        if recorder is not None:
            try:
                recorder.destroy_node()
            except BagWriteError:
                pass  # already reported
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())

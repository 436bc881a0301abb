"""MCAP recorder node, :class:`RecorderNode`; its command line, ``mcap_record``, is
:mod:`mems_sim.bag.record_cli`.

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
Samples a device declares dropped on its ``faults`` topic (a scheduled
``dropped_samples`` fault, :mod:`mems_sim.ros.device_gaps`) are a device gap of its
frame topics, counted apart (:meth:`RecorderNode.device_gaps`), neither loss nor a stall.

Stalls (with ``stall_timeout_s``): each publisher of a data topic is timed on its own
clock, the middleware's source timestamps of its messages
(:class:`~mems_sim.stream_index.PublicationStall`): a publisher that had been sending
steadily and then sent nothing for longer than the timeout (or three times its longest
recent interval) while it stayed in the graph is stalled, seen when it sends again
(:meth:`RecorderNode.stalls`). A stopped recorder stalls no publisher (their timestamps
run on), and a frame after a gap its device declared (a scheduled device gap) ends no
stall. Not timed: ``/diagnostics``, ``/rosout``, ``/parameter_events``, ``/clock`` and
end-of-stream records, which are not data streams.

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
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterable
from functools import partial

from rclpy.clock import Clock as RclpyClock
from rclpy.clock import ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from mems_sim.bag.compression import storage_preset
from mems_sim.bag.schema import (
    GAP_CHECKED_TYPES,
    SchemaError,
    has_header,
    message_class,
    normalize_type_name,
    peek_frame_index,
    peek_header_stamp_ns,
    schema_text,
    type_hash,
)
from mems_sim.bag.writer import (
    BagWriteError,
    McapBagWriter,
    gap_summary,
)
from mems_sim.ros.device_gaps import FAULT_EVENT_TYPE, GapDeclarations, namespace, under
from mems_sim.ros.end_of_stream import (
    NOT_STREAMS,
    describe_tail,
    is_end_of_stream_topic,
    missing_tail,
    parse_end_of_stream,
)
from mems_sim.ros.flow import ProgressReporter
from mems_sim.ros.qos import FRAME_DEPTH
from mems_sim.ros.qos_yaml import profiles_yaml
from mems_sim.stream_index import DEVICE_GAP, PublicationStall, describe_missing_head

_BEST_EFFORT = ReliabilityPolicy.BEST_EFFORT

#: Topics skipped unless listed explicitly.
DEFAULT_EXCLUDED = ("/rosout", "/parameter_events")

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
        ``zstd_fast``, ``zstd_small``; :func:`~mems_sim.bag.compression.storage_preset`): its
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
    :param stall_timeout_s: a publisher of a data topic silent for longer than this [s]
        after sending steadily is stalled (:meth:`stalls`); None: stalls are not timed.
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
        stall_timeout_s: float | None = None,
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
        #: Faults topics (their dropped samples declare device gaps).
        self._fault_topics: set[str] = set()
        self._taking_faults = False
        self._declarations = GapDeclarations(self._bag.declare_device_gap)
        #: End-of-stream topics without a record whose publishers had all left when the
        #: subscriptions were destroyed (:meth:`stop_taking`); None before.
        self._silent_ends: set[str] | None = None
        self._end_of_stream: dict[str, dict[str, int]] = {}
        self._rec_closed = False
        self._graph_clock_ns: int | None = None
        self._progress_topic = progress_topic
        self._stall_timeout_s = stall_timeout_s
        #: (topic, publisher) -> its stall accounting (with ``stall_timeout_s``).
        self._publication: dict[tuple[str, bytes | None], PublicationStall] = {}
        #: ``~/progress`` of ``progress_topic`` (:mod:`mems_sim.ros.flow`); None without one.
        self.progress_reporter = ProgressReporter(self) if progress_topic else None
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
        self._bag.add_topic(topic, type_name, text, profiles_yaml(offered), type_hash(type_name))
        self._rx_counts[topic] = 0
        if is_end_of_stream_topic(topic, type_name):
            self._eos_topics.add(topic)
        if type_name in GAP_CHECKED_TYPES:
            self._declarations.frame_topic(topic)
        elif type_name == FAULT_EVENT_TYPE:
            self._fault_topics.add(topic)
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
        if self._fault_topics and topic not in self._fault_topics:
            self._take_device_faults(topic)
        if topic in self._fault_topics:
            gap = self._declarations.fault(topic, FAULT_EVENT_TYPE, data)
            if gap is not None:
                self.get_logger().info(
                    f"{topic}: the device declares samples {gap[0]}..{gap[0] + gap[1] - 1} "
                    f"dropped ({gap[1]} samples): a device gap, not loss"
                )
        stamp = peek_header_stamp_ns(data) if self._stamped[topic] else None
        log_time = self.graph_time_ns() if stamp is None else stamp
        sent = info.get("source_timestamp") if info else None
        sequence, publisher = _publication(info)
        sent = sent or time.time_ns()
        event = self._bag.write(topic, data, log_time, sent, sequence=sequence, publisher=publisher)
        self._rx_counts[topic] += 1
        if self._stall_timeout_s is not None and topic not in self._eos_topics:
            self._time_publication(topic, publisher, sent, event == DEVICE_GAP)
        if self.progress_reporter is not None and topic == self._progress_topic:
            peek = peek_frame_index(data)
            if peek is not None:  # what it last wrote (a replay that loops starts again)
                self.progress_reporter.report(peek[0] + peek[1], follow=True)
        if topic in self._eos_topics:
            self._take_end_of_stream(topic, data)

    def _take_device_faults(self, topic: str) -> None:
        """Record first what the middleware already holds of the faults topics of the
        devices ``topic`` is under: a FaultEvent published before a frame declares its gap
        before the frame is judged (another topic's callback may be scheduled later)."""
        if self._taking_faults:
            return
        self._taking_faults = True
        try:
            for faults in self._fault_topics:
                if under(topic, namespace(faults)):
                    self._take_waiting(faults, None)
        finally:
            self._taking_faults = False

    def _time_publication(self, topic: str, publisher, sent_ns: int, declared: bool) -> None:
        """Stall accounting of ``topic``'s ``publisher`` with a message sent at ``sent_ns``
        (``declared``: a frame after a device gap its device declared)."""
        if topic in NOT_STREAMS:
            return
        watch = self._publication.get((topic, publisher))
        if watch is None:
            watch = self._publication[(topic, publisher)] = PublicationStall(self._stall_timeout_s)
        silence = watch.update(sent_ns * 1e-9, declared)
        if silence is not None:
            self.get_logger().warning(f"{topic}: stalled, {silence:.1f} s without data")

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
        declarable = any(under(topic, namespace(f)) for f in self._fault_topics)
        self.get_logger().warning(
            f"{topic}: frame-index gap, expected first_sample_index {expected}, got {first} "
            f"({first - expected} samples missing"
            + ("; a device gap instead if its device declares them dropped)" if declarable else ")")
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
        """Per frame topic: gaps, missing_samples (transport loss), device_gaps,
        device_missing_samples (declared by the device), resets, frames, samples."""
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

    def silent_ends(self) -> set[str]:
        """End-of-stream topics whose emulators left without their record reaching the
        recorder: subscribed (a publisher was there), no record received, no publisher
        left. An emulator publishes its record before it exits, latched; missing, the
        recording cannot show whether the streams' tails arrived (a recorder stopped long
        enough for the emulator's participant to drop it receives nothing more, so no gap
        shows either). A live emulator (the recorder stopped first) is not counted."""
        if self._silent_ends is not None:
            return set(self._silent_ends)
        return {
            t
            for t in self._eos_topics
            if self._rx_counts.get(t) == 0
            and t in self._topic_subs
            and self._topic_subs[t].get_publisher_count() == 0
        }

    def losses(self) -> list[str]:
        """One phrase per recorded topic that lost data: a missing head (a frame topic whose
        first recorded frame is after sample 0: the recorder joined late), frame-index gaps,
        gaps of a publisher's sequence numbers (topics that are not frames), a missing
        tail, an end-of-stream record that never came (:meth:`silent_ends`)."""
        out = []
        details, seqs, tails = self.gap_details(), self.sequence_details(), self.tails()
        silent = self.silent_ends()
        for topic in sorted(set(details) | set(seqs) | set(tails) | silent):
            parts = []
            if topic in silent:
                parts.append(
                    "the emulator left without its end-of-stream record reaching the "
                    "recorder (its streams' tails are unverified)"
                )
            d = details.get(topic)
            if d and d["missing_head"]:
                parts.append(describe_missing_head(d["missing_head"]))
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

    def stalls(self) -> list[str]:
        """One line per topic a publisher of which stalled (class doc):
        ``stalled: TOPIC (N s without data)``, with the number of stalls if more than one
        (the longest silence then)."""
        found: dict[str, list[PublicationStall]] = {}
        for (topic, _), watch in self._publication.items():
            if watch.stalls:
                found.setdefault(topic, []).append(watch)
        out = []
        for topic, watches in sorted(found.items()):
            count = sum(w.stalls for w in watches)
            longest = max(w.longest_s for w in watches)
            times = f"{count} stalls, longest " if count > 1 else ""
            out.append(f"stalled: {topic} ({times}{longest:.1f} s without data)")
        return out

    def report(self, counts: dict[str, int] | None = None, text: bool = False) -> dict:
        """What a run reports of its recording: ``counts`` (messages per topic; the
        caller's selection if given), ``gaps`` (:meth:`gaps`), ``losses``, ``device_gaps``
        and, with ``text``, the :meth:`summary`."""
        out = dict(
            counts=self.counts() if counts is None else counts,
            gaps=self.gaps(),
            losses=self.losses(),
            device_gaps=self.device_gaps(),
        )
        if text:
            out["text"] = self.summary()
        return out

    def device_gaps(self) -> list[str]:
        """One line per frame topic with samples its device declared dropped:
        ``TOPIC: N device gaps (M samples, declared by the device)``."""
        return [
            f"{topic}: {d['device_gaps']} device gaps ({d['device_missing_samples']} samples, "
            "declared by the device)"
            for topic, d in sorted(self.gap_details().items())
            if d["device_gaps"]
        ]

    def declare_device_gap(self, topic: str, first: int, n: int) -> None:
        """Frame topic ``topic``'s device declares sample indices ``[first, first + n)``
        missing (a scheduled fault): a device gap, neither transport loss nor a stall."""
        self._bag.declare_device_gap(topic, first, n)

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
        self._silent_ends = self.silent_ends()
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
        lines += [f"  device gap: {text}" for text in self.device_gaps()]
        lines += [f"  lost: {text}" for text in self.losses()]
        lines += [f"  {text}" for text in self.stalls()]
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

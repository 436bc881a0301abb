"""``live_view``: the graph's topics, live, in Foxglove (a Foxglove WebSocket server).

:class:`LiveViewNode` discovers the graph's topics periodically and offers each on a
Foxglove WebSocket server (the ``foxglove-sdk`` package) as a channel with message encoding
``cdr`` and the ``ros2msg`` schema text that rosbag2 writes into MCAP files (the ``.msg``
definition followed by its dependencies), so the Foxglove app decodes the messages without
the project's message packages. Messages go out as the middleware delivers them, serialized
CDR bytes untouched, with their sensor time as log time: the ``header.stamp`` of stamped
types, else the latest stamp forwarded on any topic (the wall clock before the first).

It does not slow the graph: a topic is subscribed in ROS only while a Foxglove client
subscribes to its channel (best-effort, shallow history: the publishers never wait for the
live view, reliable ones included), and each channel forwards at most ``max_rate_hz``
messages per second; messages above that rate are dropped. A live view is not lossless
(the recorder is): frame topics of fast devices are decimated.

Clients reach a front end (:mod:`mems_sim.nodes.foxglove_front`), not the SDK's server,
which listens on a private port of 127.0.0.1: the front end checks each handshake's
``Origin`` (:mod:`mems_sim.nodes.foxglove_origin`; others added with ``allowed_origins``),
admits at most ``max_clients`` clients and bounds what waits for each client to
``client_queue_bytes``, dropping the oldest messages of a client that does not read
(counted and logged). It binds to 127.0.0.1 unless ``host`` says otherwise; ``port`` 0 takes
a free port. Once it listens, one line
``live_view: Foxglove WebSocket server on ws://HOST:PORT`` goes to standard output. SIGINT
or SIGTERM stops the server and the node.
"""

from __future__ import annotations

import re
import sys
import time
from dataclasses import dataclass

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from mems_sim.bag.schema import (
    SchemaError,
    has_header,
    message_class,
    normalize_type_name,
    peek_header_stamp_ns,
    schema_text,
)
from mems_sim.nodes.foxglove_front import FrontEnd, FrontStats
from mems_sim.nodes.foxglove_origin import OriginError, OriginPolicy, parse_origins
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.node_main import run_node
from mems_sim.ros.params import declare_specs

#: Topics never offered unless listed in ``topics``: every node's log and parameter events,
#: and the steps of a fast run's clock (thousands per second, no use in a plot).
DEFAULT_EXCLUDED = ("/rosout", "/parameter_events", "/clock")

#: Subscription of a live topic: best effort (matches reliable and best-effort publishers,
#: and a reader that falls behind never holds a publisher back), a short history.
LIVE_QOS = QoSProfile(
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
)

#: Subscription of a latched topic (every publisher transient-local, e.g. a calibration
#: result): reliable and transient-local, so the last result reaches a late client.
LATCHED_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
)

#: Period of the check of the clients' subscriptions [s].
SYNC_PERIOD_S = 0.1

#: Messages the SDK's server holds for each of the front end's connections (its
#: ``message_backlog_size``, 1024 by default): it only fills when the front end's thread is
#: starved of CPU, and its oldest message data is dropped beyond.
SDK_BACKLOG_MESSAGES = 32

SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "host",
        "127.0.0.1",
        "-",
        "address the WebSocket server binds to; 127.0.0.1 keeps it on this machine (0.0.0.0 "
        "serves every network interface: opt in only on a trusted network)",
    ),
    ParamSpec(
        "port",
        8765,
        "-",
        "TCP port of the WebSocket server (8765 is the Foxglove app's default); 0: any free "
        "port, printed at start",
        min=0,
        max=65535,
    ),
    ParamSpec(
        "topics",
        "",
        "-",
        "comma-separated topic names to offer (offered even if excluded by default); with "
        "neither topics nor regex every topic is offered",
    ),
    ParamSpec(
        "allowed_origins",
        "",
        "-",
        "comma-separated web origins (scheme://host[:port]) allowed besides the defaults: no "
        "Origin, null, file://, loopback http(s) hosts and https://app.foxglove.dev",
    ),
    ParamSpec(
        "max_clients",
        16,
        "-",
        "most WebSocket clients connected at once; one more is refused (HTTP 503)",
        min=1,
        max=1024,
    ),
    ParamSpec(
        "client_queue_bytes",
        2 * 1024 * 1024,
        "B",
        "bound of what waits to be sent to one client; beyond it the client's oldest "
        "messages are dropped (counted)",
        min=64 * 1024,
        max=1024 * 1024 * 1024,
    ),
    ParamSpec("regex", "", "-", "offer the topics whose name matches this regular expression"),
    ParamSpec("exclude", "", "-", "never offer topics matching this regular expression"),
    ParamSpec(
        "max_rate_hz",
        30.0,
        "Hz",
        "most messages per second forwarded per channel (a faster topic is decimated: the "
        "live view is not lossless); 0: no limit",
        min=0.0,
        max=1.0e6,
    ),
    ParamSpec(
        "discovery_period_s",
        0.5,
        "s",
        "period of the search for new topics",
        min=0.05,
        max=60.0,
    ),
)


@dataclass
class LiveChannel:
    """One offered topic: its Foxglove channel, its ROS subscription while a client
    subscribes, and the forwarding counters."""

    topic: str
    type_name: str
    channel: object
    msg_type: type
    stamped: bool
    latched: bool
    subscription: object = None
    next_ns: int = 0
    forwarded: int = 0
    decimated: int = 0


class LiveViewNode(Node):
    """Foxglove WebSocket server offering the graph's topics as ``cdr`` channels with
    ``ros2msg`` schemas; forwards a topic only while a client subscribes, at most
    ``max_rate_hz`` messages per second per channel.

    Args:
        **node_kwargs: passed to rclpy's Node (context, parameter_overrides, namespace).

    Raises:
        ParameterError: a parameter out of range, an invalid regular expression, or a
            server that cannot listen on ``host:port`` (e.g. the port is in use).
    """

    NODE_NAME = "live_view"
    DEFAULT_NAMESPACE = ""
    SPECS = SPECS
    RUNTIME_PARAMETERS = ("max_rate_hz",)

    def __init__(self, **node_kwargs) -> None:
        node_kwargs.setdefault("namespace", self.DEFAULT_NAMESPACE)
        super().__init__(self.NODE_NAME, **node_kwargs)
        self.p = declare_specs(self, self.SPECS, runtime=self.RUNTIME_PARAMETERS)
        self._explicit = {t.strip() for t in self.p["topics"].split(",") if t.strip()}
        self._regex = self._compile("regex")
        self._exclude = self._compile("exclude")
        self._channels: dict[str, LiveChannel] = {}
        self._unusable: set[str] = set()
        self._last_stamp_ns: int | None = None
        self._closed = False

        self._start_servers()
        host = self.p["host"]
        self.url = f"ws://[{host}]:{self.port}" if ":" in host else f"ws://{host}:{self.port}"
        if self.p["host"] not in ("127.0.0.1", "localhost", "::1"):
            self.get_logger().warning(
                f"the live view serves {self.p['host']}: it is reachable from the network"
            )
        print(f"live_view: Foxglove WebSocket server on {self.url}", flush=True)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._discovery_timer = self.create_timer(
            self.p["discovery_period_s"], self.discover, clock=steady
        )
        self._sync_timer = self.create_timer(SYNC_PERIOD_S, self.sync_subscriptions, clock=steady)
        self.discover()

    def _start_servers(self) -> None:
        """The SDK's server on a private loopback port, the front end on ``host:port``."""
        import foxglove

        try:
            policy = OriginPolicy(parse_origins(self.p["allowed_origins"]))
        except OriginError as exc:
            raise ParameterError(f"parameter 'allowed_origins' is invalid: {exc}") from None
        self._foxglove_context = foxglove.Context()
        self.server = foxglove.start_server(
            name="mems_emulator live view",
            host="127.0.0.1",
            port=0,
            context=self._foxglove_context,
            message_backlog_size=SDK_BACKLOG_MESSAGES,
        )
        self.front = FrontEnd(
            int(self.server.port),
            self.p["host"],
            self.p["port"],
            policy,
            self.p["max_clients"],
            self.p["client_queue_bytes"],
            log=self.get_logger().warning,
        )
        try:
            self.port = self.front.start()
        except OSError as exc:
            self.server.stop()
            raise ParameterError(
                f"parameter 'port' = {self.p['port']}: the WebSocket server cannot listen "
                f"on {self.p['host']}:{self.p['port']} ({' '.join(str(exc).split())})"
            ) from None

    def _compile(self, name: str):
        text = self.p[name]
        if not text:
            return None
        try:
            return re.compile(text)
        except re.error as exc:
            raise ParameterError(
                f"parameter '{name}' = {text!r} is invalid: not a regular expression ({exc})"
            ) from None

    # ---------------------------------------------------------------- selection

    def wants(self, topic: str) -> bool:
        """True when ``topic`` is offered: listed, or (not excluded and) every topic when
        neither ``topics`` nor ``regex`` is set, else matching ``regex``."""
        if topic in self._explicit:
            return True
        if topic in DEFAULT_EXCLUDED:
            return False
        if self._exclude is not None and self._exclude.search(topic):
            return False
        if self._regex is not None:
            return bool(self._regex.search(topic))
        return not self._explicit

    # ---------------------------------------------------------------- discovery

    def discover(self) -> None:
        """Offer newly appeared selected topics that have a publisher."""
        if self._closed:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self._channels or topic in self._unusable or not self.wants(topic):
                continue
            if len(types) != 1:
                self._unusable.add(topic)
                self.get_logger().warning(f"{topic} has {len(types)} types {types}: not offered")
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if publishers:
                self._offer(topic, types[0], publishers)

    def _offer(self, topic: str, type_name: str, publishers) -> None:
        import foxglove

        try:
            type_name = normalize_type_name(type_name)
            msg_type = message_class(type_name)
            schema = schema_text(type_name)
            stamped = has_header(type_name) or type_name == "rosgraph_msgs/msg/Clock"
        except SchemaError as exc:
            self._unusable.add(topic)
            self.get_logger().warning(f"{topic}: {exc}; not offered")
            return
        channel = foxglove.Channel(
            topic,
            schema=foxglove.Schema(name=type_name, encoding="ros2msg", data=schema.encode()),
            message_encoding="cdr",
            context=self._foxglove_context,
        )
        latched = all(
            p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers
        )
        self._channels[topic] = LiveChannel(topic, type_name, channel, msg_type, stamped, latched)
        self.get_logger().info(f"offering {topic} [{type_name}]")

    # ---------------------------------------------------------------- subscriptions

    def sync_subscriptions(self) -> None:
        """Subscribe in ROS to the topics whose channel has a client (the SDK's
        ``has_sinks``: a WebSocket client subscribed to it); unsubscribe from the others."""
        if self._closed:
            return
        for topic, live in self._channels.items():
            wanted = live.channel.has_sinks()
            if wanted and live.subscription is None:
                live.next_ns = 0
                live.subscription = self.create_subscription(
                    live.msg_type,
                    topic,
                    lambda data, live=live: self._forward(live, data),
                    LATCHED_QOS if live.latched else LIVE_QOS,
                    raw=True,
                )
                self.get_logger().info(f"forwarding {topic}")
            elif not wanted and live.subscription is not None:
                self.destroy_subscription(live.subscription)
                live.subscription = None
                self.get_logger().info(f"no client on {topic}: not forwarded")

    # ---------------------------------------------------------------- data

    def _forward(self, live: LiveChannel, data: bytes) -> None:
        now = time.monotonic_ns()
        rate = self.p["max_rate_hz"]
        if rate > 0:
            if now < live.next_ns:
                live.decimated += 1
                return
            period = int(1e9 / rate)
            # at most one message per period on average; a pause does not earn a burst
            live.next_ns = max(live.next_ns + period, now)
        stamp = peek_header_stamp_ns(data) if live.stamped else None
        if stamp is not None:
            self._last_stamp_ns = stamp
        elif self._last_stamp_ns is not None:
            stamp = self._last_stamp_ns
        else:
            stamp = time.time_ns()
        live.channel.log(bytes(data), log_time=stamp)
        live.forwarded += 1

    # ---------------------------------------------------------------- queries

    def offered(self) -> dict[str, str]:
        """Type name per offered topic."""
        return {t: c.type_name for t, c in self._channels.items()}

    def forwarding(self) -> list[str]:
        """Topics subscribed in ROS now (a client subscribes to their channel)."""
        return sorted(t for t, c in self._channels.items() if c.subscription is not None)

    def counts(self) -> dict[str, tuple[int, int]]:
        """Per offered topic: (messages forwarded, messages dropped by the rate limit)."""
        return {t: (c.forwarded, c.decimated) for t, c in self._channels.items()}

    def client_stats(self) -> FrontStats:
        """The front end's counters: clients now, accepted, refused (origin, full), messages
        dropped for clients that did not read, clients disconnected for reading nothing."""
        return self.front.stats

    # ---------------------------------------------------------------- end

    def close(self) -> None:
        """Stop the server and the subscriptions (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._discovery_timer.cancel()
        self._sync_timer.cancel()
        for live in self._channels.values():
            if live.subscription is not None:
                self.destroy_subscription(live.subscription)
                live.subscription = None
        self.front.stop()
        self.server.stop()
        for live in self._channels.values():
            live.channel.close()
        forwarded = sum(c.forwarded for c in self._channels.values())
        decimated = sum(c.decimated for c in self._channels.values())
        stats = self.front.stats
        self.get_logger().info(
            f"stopped: {forwarded} messages forwarded, {decimated} dropped by the rate limit; "
            f"{stats.accepted} clients served, {stats.dropped} messages dropped for clients "
            f"that did not read, {stats.refused_origin + stats.refused_full} clients refused"
        )


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``live_view`` (ROS arguments only: ``--ros-args -p port:=0``)."""
    return run_node(LiveViewNode, argv)


if __name__ == "__main__":
    sys.exit(main())

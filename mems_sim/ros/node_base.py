"""Bases of the emulator and estimator nodes and their parameters.

* :class:`MemsNode`: every node (default namespace, ParamSpec parameters, diagnostics);
* :class:`EmulatorNode`: every emulator node (device, frame publishers, ``step``; one device
  of a batch at a temperature: ``device_seed``, ``temperature_c``, :func:`variation_specs`;
  in a graph of processes: ``start_when_matched``, ``exit_when_acknowledged``); its sensor
  time and pacing: :class:`~mems_sim.ros.pacing.PacedEmulator`.

The ``main()`` of the node executables is :mod:`mems_sim.ros.node_main`; the estimator
nodes' base, ``EstimatorNode``, is in ``mems_estimation.nodes.frame_input``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from sensor_msgs.msg import Temperature

from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.params import (
    HARDWARE_SPEC,
    ParameterError,
    ParamSpec,
    draw_device,
    profile_specs,
    spec_table,
)
from mems_sim.ros.diagnostics import DiagnosticsReporter
from mems_sim.ros.end_of_stream import (
    END_OF_STREAM,
    END_OF_STREAM_QOS,
    account_publishers,
    end_of_stream_message,
)
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.pacing import PacedEmulator
from mems_sim.ros.params import declare_specs
from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS

#: Parameters every emulator node has, besides its device table (``hardware``: the
#: profile of the defaults, :func:`~mems_sim.params.profile_specs`).
EMULATOR_SPECS: tuple[ParamSpec, ...] = (
    HARDWARE_SPEC,
    ParamSpec(
        "seed",
        0,
        "-",
        "run seed of every random source of the device",
        "deterministic: every random source is seeded from the run seed",
        min=0,
        max=2**62,
    ),
    ParamSpec(
        "frame_size",
        10,
        "samples",
        "samples per published frame",
        "frames of consecutive samples; a jump in the first sample index is a drop",
        min=1,
        max=1_000_000,
    ),
    ParamSpec(
        "realtime_factor",
        1.0,
        "-",
        "pacing of the standalone node: simulated seconds per wall-clock second "
        "(not used while it follows /clock under use_sim_time)",
        "",
        min=0.0,
        max=1.0e6,
        min_exclusive=True,
    ),
    ParamSpec(
        "duration_s",
        0.0,
        "s",
        "simulated duration after which the node stops publishing; 0 runs until shut down",
        "",
        min=0.0,
        max=1.0e9,
    ),
    ParamSpec(
        "stamp_origin",
        "auto",
        "-",
        "epoch, the time of sample 0: 'zero' (0, bit-identical runs), 'wall' (the graph's "
        "time at start: the wall clock, or /clock when use_sim_time is true), 'auto' ('wall' "
        "when the node paces itself from start, as its executable does; 'zero' when its "
        "owner steps or starts it, as the scenario runner does)",
        "sensor time: sample k is stamped epoch + k / fs",
        choices=("auto", "zero", "wall"),
    ),
    ParamSpec(
        "publish_clock",
        0.0,
        "Hz",
        "publish the node's sensor time on /clock this many times per wall-clock second "
        "(the node is then the graph's clock source); 0: off",
        "rosgraph_msgs/Clock, the time that nodes with use_sim_time follow",
        min=0.0,
        max=1000.0,
    ),
    ParamSpec("frame_id", "imu_link", "-", "frame_id of published headers", "REP-103/105"),
    ParamSpec(
        "start_when_matched",
        False,
        "-",
        "a node that paces itself starts publishing only once every data topic has "
        "min_subscribers matched subscriptions and every topic of wait_for_subscribers its "
        "count (a recorder subscribes only after it has seen the publishers: frames "
        "published before are lost to discovery)",
        "",
    ),
    ParamSpec(
        "min_subscribers",
        1,
        "-",
        "with start_when_matched: matched subscriptions each data topic of the node needs",
        "",
        min=0,
        max=1000,
    ),
    ParamSpec(
        "wait_for_subscribers",
        "",
        "-",
        "with start_when_matched: more topics to wait for, 'TOPIC:N,TOPIC:N' (a relative "
        "name is in the node's namespace): N subscriptions each, e.g. an estimator's output "
        "so that the device starts once the chain is up (the node's own topics: matched "
        "subscriptions; others: the graph's count)",
        "",
    ),
    ParamSpec(
        "exit_when_acknowledged",
        True,
        "-",
        "once the duration (or the device's schedule) is published and every subscriber "
        "acknowledged its samples, the process exits with status 0 (1 if they are not "
        "acknowledged within 30 s); a node without an end (duration_s 0, no schedule) runs "
        "until shut down (given explicitly as true, it is refused); false: idles until "
        "shut down",
        "",
    ),
    ParamSpec(
        "consumers",
        "",
        "-",
        "flow control: nodes 'NODE,NODE' (a relative name is in the node's namespace) "
        "whose ~/progress gates publishing: a frame goes out only within "
        "CONSUMER_CREDIT_FRAMES frames of the slowest one's progress (the pacing then "
        "falls behind instead of losing samples)",
        "the progress protocol of mems_sim.ros.flow",
    ),
)

#: Frames an emulator with ``consumers`` may publish beyond the slowest consumer's
#: progress: half the subscription's queue (FRAME_QOS depth), so none is overwritten.
CONSUMER_CREDIT_FRAMES = FRAME_DEPTH // 2


#: Reference temperature [degC] of a device table whose source gives none (assumption:
#: the values were identified at room temperature).
ROOM_TEMPERATURE_C = 25.0


def variation_specs(
    reference_c: float = ROOM_TEMPERATURE_C, device_specs: Iterable[ParamSpec] = ()
) -> tuple[ParamSpec, ...]:
    """``device_seed`` and ``temperature_c`` of an emulator node (:class:`EmulatorNode`):
    which device of a batch it emulates and at which temperature, ``reference_c`` [degC]
    being the temperature of the device table's values. A name the device's own table
    ``device_specs`` already has (the stage's) is left out: the device keeps its meaning."""
    have = {s.name for s in device_specs}
    specs = (
        ParamSpec(
            "device_seed",
            -1,
            "-",
            "which device of the batch: every parameter of the device table with a "
            "manufacturing spread is drawn from this seed and its name; -1: the nominal "
            "device (nothing drawn). A parameter set explicitly is not drawn",
            "deterministic: independent of the run seed (the noise); one seed, one device",
            min=-1,
            max=2**62,
        ),
        ParamSpec(
            "temperature_c",
            float(reference_c),
            "degC",
            "device temperature: every parameter of the device table with a temperature "
            f"coefficient moves linearly from its value at {reference_c:g} C (the table's "
            "reference); can be changed while the node runs, and follows "
            "sensor_msgs/Temperature on the node's temperature input (from the next frame)",
            f"reference {reference_c:g} C: the temperature of the device table's values",
            min=-60.0,
            max=150.0,
        ),
    )
    return tuple(s for s in specs if s.name not in have)


def emulator_specs(**defaults) -> tuple[ParamSpec, ...]:
    """:data:`EMULATOR_SPECS` with some defaults replaced (e.g. ``frame_size=10000``)."""
    unknown = set(defaults) - {s.name for s in EMULATOR_SPECS}
    if unknown:
        raise KeyError(f"not emulator parameters: {sorted(unknown)}")
    return tuple(
        dataclasses.replace(s, default=defaults[s.name]) if s.name in defaults else s
        for s in EMULATOR_SPECS
    )


class MemsNode(Node):
    """Base of every emulator and estimator node: default namespace, parameters declared
    from ParamSpec tables (:func:`~mems_sim.ros.params.declare_specs`: ranges, validation,
    runtime guard), ``self.p`` with their values and ``self.diag`` on /diagnostics.

    A node class states what it is in four class attributes and needs no constructor of its
    own unless it builds more: :attr:`NODE_NAME`, :attr:`DEFAULT_NAMESPACE`, :attr:`SPECS`
    and :attr:`DIAGNOSTICS_TITLE`.

    Args:
        **node_kwargs: passed to rclpy's Node (context, namespace, parameter_overrides);
            without ``namespace`` the node starts in :attr:`DEFAULT_NAMESPACE`.
    """

    #: ROS node name (the device's name stem).
    NODE_NAME: str = ""
    #: Namespace unless one is given (the usual namespace of the device the node emulates
    #: or reads); ``__ns:=`` on the command line overrides it.
    DEFAULT_NAMESPACE: str = ""
    #: The node's parameter table(s).
    SPECS: tuple[ParamSpec, ...] = ()
    #: What the node does, on /diagnostics after the node name: a string or a function of
    #: the parameter values.
    DIAGNOSTICS_TITLE: str | Callable[[dict], str] = ""
    #: Parameters that may be changed while the node runs (the others are set at start).
    RUNTIME_PARAMETERS: tuple[str, ...] = ()
    #: The node's fully qualified name as hardware_id of its diagnostics status (the
    #: status name starts with the node's plain name, the same for e.g. the estimators of
    #: two devices: the hardware_id tells them apart in a recording).
    DIAGNOSTICS_HARDWARE_ID = True

    def __init__(self, **node_kwargs) -> None:
        node_kwargs.setdefault("namespace", self.DEFAULT_NAMESPACE)
        super().__init__(self.NODE_NAME, **node_kwargs)
        self.p = declare_specs(
            self,
            self.declared_specs(),
            runtime=self.RUNTIME_PARAMETERS,
            on_change=self.parameter_changed,
        )
        title = self.DIAGNOSTICS_TITLE
        title = title if isinstance(title, str) else title(self.p)
        hardware_id = self.get_fully_qualified_name() if self.DIAGNOSTICS_HARDWARE_ID else ""
        self.diag = DiagnosticsReporter(
            self, f"{self.get_name()}: {title}", hardware_id=hardware_id, now_ns=self.graph_time_ns
        )

    def declared_specs(self) -> tuple[ParamSpec, ...]:
        """The parameter table the node declares: :attr:`SPECS`."""
        return tuple(self.SPECS)

    def graph_time_ns(self) -> int:
        """Time of the node's diagnostics stamps [ns]: its ROS clock (the wall clock, or
        /clock when use_sim_time is true); emulators use their sensor time."""
        return self.get_clock().now().nanoseconds

    def values_of(self, specs) -> dict:
        """The node's parameter values of one of its tables (e.g. the device's), by name."""
        return {spec.name: self.p[spec.name] for spec in specs}

    def parameter_changed(self, name: str, value) -> None:
        """Called after a change of one of :attr:`RUNTIME_PARAMETERS` was accepted
        (``self.p`` already holds the new value)."""


#: Message type of a frame topic by its last name component (others: SignalFrame).
FRAME_TYPES = {"adc": AdcFrame, "estimate": StateEstimate, "loop_estimate": StateEstimate}


class EmulatorNode(PacedEmulator, MemsNode):
    """Base of the emulator nodes: parameters, device, frame publishers, diagnostics, pacing.

    The constructor does :class:`MemsNode`'s (:attr:`SPECS`: the device table(s) and the
    :data:`EMULATOR_SPECS`; ``realtime_factor`` can be changed while the node runs, every
    other parameter is set at start), then calls :meth:`make_device` (the subclass builds
    its device and publishers from ``self.p`` and returns the sample rate), sets up the
    pacing (:meth:`schedule_samples` bounds it) and starts the pacing timer unless
    ``drive_externally`` or not ``autostart``. :meth:`step` publishes one frame through
    the subclass's :meth:`publish_frame`. Every data publisher the subclass made is
    counted (``streams``) and, once the duration is published, an end-of-stream record
    with those counts goes out on ``end_of_stream`` (:mod:`~mems_sim.ros.end_of_stream`),
    so that a recorder sees a missing tail. Sensor time, pacing and /clock:
    :class:`PacedEmulator`; a node that paces itself from start (``stamp_origin`` 'auto')
    stamps from the graph's time at start, one its owner drives or starts from 0.

    One device of a batch at a temperature: :attr:`DEVICE_SPECS` is the device's table;
    :meth:`device_values` gives its values for the node's ``device_seed`` (every parameter
    with a :class:`~mems_sim.params.Spread` drawn, -1: the nominal device) at its
    ``temperature_c`` (every parameter with a :class:`~mems_sim.params.TempCo` moved from
    the reference temperature, the default of ``temperature_c``), a parameter set
    explicitly (``fixed_parameters``) left as given; the subclass builds its device from
    them. ``temperature_c`` can be changed while the node runs and follows the
    sensor_msgs/Temperature messages on :attr:`TEMPERATURE_INPUT` (relative to the
    namespace): the next frame generated after the change is at the new temperature
    (:meth:`retune_device`; frames already published are not touched). A temperature
    outside the parameter's range is ignored with a warning on /diagnostics.

    In a graph of processes (the node paces itself): with ``start_when_matched`` the
    pacing starts once the subscribers are matched (:meth:`missing_subscribers`), so that
    no frame is lost to discovery; with ``exit_when_acknowledged`` the process exits once
    the duration is published and acknowledged (:meth:`run_ended`).

    Args:
        drive_externally: if True no timer is created; the owner calls :meth:`step`
            (the scenario runner does this to run faster than real time without loss).
        autostart: start the pacing timer at once; if False the owner calls
            :meth:`start` once its subscribers are matched (no frame is lost to discovery).
        fixed_parameters: names of the device parameters the user set explicitly (never
            drawn nor moved by the temperature); None: every parameter given at
            construction (``parameter_overrides``, ``--ros-args -p``, ``--params-file``).
            The scenario runner passes the ones of ``--set`` / ``--params-file`` only.
        **node_kwargs: passed to rclpy's Node (context, namespace, parameter_overrides).
    """

    RUNTIME_PARAMETERS = ("realtime_factor", "temperature_c")
    DIAGNOSTICS_HARDWARE_ID = True
    #: The device's parameter table (drawn by ``device_seed``, moved by ``temperature_c``).
    DEVICE_SPECS: tuple[ParamSpec, ...] = ()
    #: Topic (relative) of the sensor_msgs/Temperature input.
    TEMPERATURE_INPUT = "temperature"

    def __init__(
        self,
        *,
        drive_externally: bool = False,
        autostart: bool = True,
        fixed_parameters: Iterable[str] | None = None,
        **node_kwargs,
    ) -> None:
        #: The device's values as last drawn (:meth:`device_values`); None until then.
        self.drawn: dict | None = None
        self._fixed_given = None if fixed_parameters is None else frozenset(fixed_parameters)
        super().__init__(**node_kwargs)
        given = self._fixed_given
        if given is None:
            given = frozenset(self._parameter_overrides)
        #: Device parameters set explicitly: never drawn nor moved by the temperature.
        self.fixed_parameters = given & {s.name for s in self.DEVICE_SPECS}
        self.reference_temperature_c = float(spec_table(self.SPECS)["temperature_c"].default)
        fs = self.make_device()
        self.sub_temperature = self.create_subscription(
            Temperature, self.TEMPERATURE_INPUT, self._on_temperature, 10
        )
        self.init_emulator(
            fs, self.schedule_samples(), self_paced=not drive_externally and autostart
        )
        # loss accounting: every data topic counted, an end-of-stream record at the end
        self.streams = account_publishers(self)
        fault_topic = getattr(self, "fault_topic", None)
        if fault_topic is not None:  # dropped samples: the streams cut around them
            fault_topic.attach(self.streams)
        self.pub_end_of_stream = self.create_publisher(
            DiagnosticArray, END_OF_STREAM, END_OF_STREAM_QOS
        )
        self.end_of_stream_sent = False
        self.wait_for = self._subscriber_needs()
        self.consumer_progress = self._consumer_subscribers()
        explicit = "exit_when_acknowledged" in self._parameter_overrides
        if explicit and self.p["exit_when_acknowledged"] and self.total_samples is None:
            raise ParameterError(
                "parameter 'exit_when_acknowledged' = True needs an end: set duration_s > 0 "
                "(the node has no schedule of its own)"
            )
        self._match_timer = None
        if not drive_externally and autostart:
            self.warm_kernels()
            if self.p["start_when_matched"]:
                self.start_when_matched()
            else:
                self.start()

    # ------------------------------------------------------------------ lifecycle

    def _subscriber_needs(self) -> dict[str, int]:
        """Subscriptions per topic (absolute) that ``start_when_matched`` waits for: every
        data topic ``min_subscribers``, the topics of ``wait_for_subscribers`` their count."""
        need = {t: self.p["min_subscribers"] for t in self.streams}
        text = self.p["wait_for_subscribers"]
        for item in filter(None, (x.strip() for x in text.split(","))):
            topic, _, count = item.rpartition(":")
            if not topic or not count.isdigit():
                raise ParameterError(
                    f"parameter 'wait_for_subscribers' = {text!r} is invalid: expected "
                    "'TOPIC:N,TOPIC:N' (N an integer >= 0)"
                )
            need[self.resolve_topic_name(topic)] = int(count)
        return {t: n for t, n in need.items() if n > 0}

    def _consumer_subscribers(self) -> list:
        """One :class:`~mems_sim.ros.flow.ProgressSubscriber` per node of ``consumers``."""
        from mems_sim.ros.flow import ProgressSubscriber

        names = [x.strip() for x in self.p["consumers"].split(",") if x.strip()]
        return [ProgressSubscriber(self, self.resolve_topic_name(n)) for n in names]

    def flow_allows(self, first: int, n: int) -> bool:
        """True if the frame ``[first, first + n)`` is within the credit of every consumer
        of ``consumers`` (:func:`~mems_sim.ros.flow.may_send`; before a consumer's first
        report the credit counts from sample 0)."""
        from mems_sim.ros.flow import may_send

        credit = CONSUMER_CREDIT_FRAMES * int(self.p["frame_size"])
        return all(may_send(first, n, c.value, credit, start=0) for c in self.consumer_progress)

    def missing_subscribers(self) -> dict[str, tuple[int, int]]:
        """Topics short of the subscriptions ``start_when_matched`` waits for: topic ->
        (have, need); the node's own topics count matched subscriptions, others the
        graph's."""
        own = {p.topic_name: p for p in self.publishers}
        missing = {}
        for topic, need in self.wait_for.items():
            pub = own.get(topic)
            have = (
                pub.get_subscription_count() if pub is not None else self.count_subscribers(topic)
            )
            if have < need:
                missing[topic] = (have, need)
        return missing

    def start_when_matched(self) -> None:
        """Start the pacing (:meth:`start`) once no subscriber is missing
        (:meth:`missing_subscribers`), polled on the steady clock."""
        self._match_started = time.monotonic()
        self._match_timer = self.create_timer(0.02, self._on_match_poll, clock=self._steady)
        wanted = ", ".join(f"{t} ({n})" for t, n in self.wait_for.items())
        self.get_logger().info(f"start_when_matched: waiting for the subscribers of {wanted}")

    def _on_match_poll(self) -> None:
        if self._match_timer is None or self.missing_subscribers():
            return
        self.destroy_timer(self._match_timer)
        self._match_timer = None
        self.get_logger().info(
            f"subscribers matched after {time.monotonic() - self._match_started:.2f} s; publishing"
        )
        self.start()

    def run_ended(self) -> bool:
        """True once the node's run is over and its process may exit
        (``exit_when_acknowledged`` and the duration published); the process's main
        (:func:`~mems_sim.ros.node_main.run_nodes`) then waits for the acknowledgements."""
        return bool(self.p["exit_when_acknowledged"]) and self.finished

    def warm_kernels(self) -> bool:
        """Load the device's compiled (numba) kernels before the first frame is due: one
        short frame of a copy of ``self.device`` (the node's own device, its state and
        noise streams, untouched). A node paced by its own timer calls it before it starts,
        so that its first frame is not published late by the loading (0.05-1 s). False
        when the node has no device with ``step(n)`` or the copy fails (a warm-up only)."""
        import copy

        device = getattr(self, "device", None)
        if device is None or not callable(getattr(device, "step", None)):
            return False
        try:
            copy.deepcopy(device).step(max(1, min(int(self.p["frame_size"]), 256)))
        except Exception:  # a failed warm-up leaves the loading to the first frame
            return False
        return True

    def declared_specs(self) -> tuple[ParamSpec, ...]:
        """:attr:`SPECS` with the defaults of the hardware profile the node is given
        (``hardware``, :func:`~mems_sim.params.profile_specs`; a parameter set explicitly
        wins over the profile's default). The names whose default the profile changed are
        kept in :attr:`profile_changed`."""
        given = self._parameter_overrides.get(HARDWARE_SPEC.name)
        profile = HARDWARE_SPEC.default if given is None else given.value
        try:
            specs = profile_specs(self.SPECS, profile)
        except ParameterError:  # declared as given, the value is refused in one line
            specs = tuple(self.SPECS)
        #: Parameters whose default the node's hardware profile changed.
        self.profile_changed = frozenset(
            new.name for old, new in zip(self.SPECS, specs, strict=True) if new is not old
        )
        return specs

    def make_device(self) -> float:
        """Build the device and the publishers from ``self.p``; return the sample rate [Hz]."""
        raise NotImplementedError

    def device_values(self) -> dict:
        """The values of :attr:`DEVICE_SPECS` of the device this node emulates: the node's
        parameters (the nominal device) drawn for ``device_seed`` and moved to
        ``temperature_c`` (:func:`~mems_sim.params.draw_device`); kept in :attr:`drawn`."""
        self.drawn = draw_device(
            self.DEVICE_SPECS,
            self.values_of(self.DEVICE_SPECS),
            self.p["device_seed"],
            self.p["temperature_c"] - self.reference_temperature_c,
            fixed=self.fixed_parameters,
        )
        return dict(self.drawn)

    def temperature_changed(self) -> None:
        """``temperature_c`` changed: the device's values at the new temperature go to
        :meth:`retune_device` (nothing to do when no parameter has a coefficient)."""
        before = self.drawn
        if before is None:
            return
        values = self.device_values()
        if values != before:
            self.retune_device(values)
        self.diag.counters["temperature_c"] = self.p["temperature_c"]

    def retune_device(self, values: dict) -> None:
        """Hand the device's values at a new temperature to the device (its ``retune``:
        derived quantities rebuilt, state and noise streams kept)."""
        self.device.retune(values)

    def _on_temperature(self, msg: Temperature) -> None:
        """sensor_msgs/Temperature input: ``temperature_c`` follows the message."""
        t = float(msg.temperature)
        spec = spec_table(self.SPECS)["temperature_c"]
        try:
            t = spec.validate(t)
        except ParameterError as exc:
            self.diag.count("temperature_ignored")
            self.diag.warn(f"temperature input ignored: {exc}")
            return
        if t != self.p["temperature_c"]:
            self.set_parameters([Parameter("temperature_c", value=t)])

    def schedule_samples(self) -> int | None:
        """Samples of the device's own schedule (the node stops after them); None: endless."""
        return None

    def publish_frame(self, first: int, n: int) -> None:
        """Run the device for the n samples from index ``first`` and publish them."""
        raise NotImplementedError

    def create_frame_publishers(self, *names: str) -> tuple[Publisher, ...]:
        """Publishers of frame topics (relative names, FRAME_QOS), typed by :data:`FRAME_TYPES`."""
        return tuple(
            self.create_publisher(
                FRAME_TYPES.get(name.rsplit("/", 1)[-1], SignalFrame), name, FRAME_QOS
            )
            for name in names
        )

    def publish_signals(self, pub: Publisher, first: int, data, names, units) -> None:
        """Publish ``data`` (n, channels) [SI units ``units``] as one SignalFrame whose first
        sample is ``first``, stamped in the node's sensor time."""
        pub.publish(
            make_signal_frame(
                data, first, self.fs, channel_names=names, channel_units=units, **self.frame_kwargs
            )
        )

    def step(self) -> int:
        """Generate and publish the next frame; return the number of samples (0 when done)."""
        n = self.next_frame_size()
        if n <= 0:
            return 0
        self.fix_epoch()
        self.publish_frame(self.next_index, n)
        self.diag.count("frames")
        self.frame_published(n)
        if self.finished:
            self.publish_end_of_stream()
        if self._timer is None:
            self.publish_clock_if_due()
        return n

    def publish_end_of_stream(self) -> None:
        """Publish the end-of-stream record (once): per data topic the messages and, for
        frames, the end sample index and samples published
        (:mod:`~mems_sim.ros.end_of_stream`). Sent when the duration is published, or at
        :meth:`close` for a node stopped before."""
        if self.end_of_stream_sent:
            return
        from mems_sim.ros.frames import index_to_ns, ns_to_time

        stamp = ns_to_time(index_to_ns(self.next_index, self.fs, self.t0_ns or 0))
        self.pub_end_of_stream.publish(
            end_of_stream_message(self.streams, stamp, self.get_fully_qualified_name())
        )
        self.end_of_stream_sent = True

    def cut_topic(self, topic: str, keep_messages: int) -> None:
        """Fault injection (tests of the loss reporting): hand only the first
        ``keep_messages`` messages of ``topic`` (absolute name) to the middleware; the
        end-of-stream record still counts every message the device produced."""
        if topic not in self.streams:
            raise KeyError(f"{self.get_fully_qualified_name()} does not publish {topic}")
        self.streams[topic].cut(keep_messages)

    def close(self) -> None:
        """End of the node's run: publish the end-of-stream record if not sent yet."""
        if self.frames_published:
            self.publish_end_of_stream()

    def parameter_changed(self, name: str, value) -> None:
        """``realtime_factor``: the pacing continues from the current index at the new rate;
        ``temperature_c``: the device moves (:meth:`temperature_changed`)."""
        if name == "realtime_factor":
            self.repace()
        elif name == "temperature_c":
            self.temperature_changed()

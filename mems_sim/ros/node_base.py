"""Bases of the nodes, parameters and the main() wrapper shared by the emulator and
estimator nodes.

* :class:`MemsNode`: every node (default namespace, ParamSpec parameters, diagnostics);
* :class:`PacedEmulator`: sensor time (epoch), pacing (wall clock or /clock), /clock and
  duration of an emulator;
* :class:`EmulatorNode`: every emulator node (device, frame publishers, ``step``; one device
  of a batch at a temperature: ``device_seed``, ``temperature_c``, :func:`variation_specs`);
* :func:`run_node`: the ``main()`` of every node executable (exit code 2 on a bad parameter);
  :func:`run_nodes`: several nodes in one process and one executor (``component_container``).

The estimator nodes' base, ``EstimatorNode``, is in ``mems_estimation.nodes.frame_input``.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Callable, Iterable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from sensor_msgs.msg import Temperature

from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.params import ParameterError, ParamSpec, draw_device, spec_table
from mems_sim.ros.diagnostics import DiagnosticsReporter
from mems_sim.ros.end_of_stream import (
    END_OF_STREAM,
    END_OF_STREAM_QOS,
    account_publishers,
    end_of_stream_message,
)
from mems_sim.ros.env import STOP_SIGNALS, apply_defaults, domain_id_problem
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.node_help import node_help, wants_help
from mems_sim.ros.param_overrides import check_parameter_overrides, command_line_parameters
from mems_sim.ros.params import declare_specs
from mems_sim.ros.qos import FRAME_QOS

#: Parameters every emulator node has, besides its device table.
EMULATOR_SPECS: tuple[ParamSpec, ...] = (
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
)


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


class PacedEmulator:
    """Mixin of emulator nodes: sensor time, pacing of ``step()``, /clock and the duration limit.

    The node sets ``self.p`` (with the :data:`EMULATOR_SPECS` values), calls
    :meth:`init_emulator` with its sample rate, and implements ``step()`` with
    :meth:`next_frame_size` and :meth:`frame_published`.

    Sensor time: sample k is stamped ``t0_ns + k / fs`` (:func:`~mems_sim.ros.frames.index_to_ns`,
    exact integer arithmetic), ``t0_ns`` being the run's epoch (``stamp_origin``): 0, or the
    graph's time when the node starts publishing (the wall clock; /clock's time when
    use_sim_time is true). The epoch is fixed once, before the first frame, and never moves.

    Pacing (a node that paces itself, :meth:`start`): a timer on the steady clock wakes the
    node every few milliseconds whatever the ROS time does, so the node never waits on a
    clock that does not move and still stops on SIGINT/SIGTERM. Each tick publishes the
    frames whose last sample is due:

    * by default on the wall clock, ``realtime_factor`` simulated seconds per wall-clock
      second, catching up on lag; ``realtime_factor`` may change while the node runs
      (:meth:`repace` continues from the current sample index at the new rate);
    * when use_sim_time is true (set at start or at runtime) and the node does not publish
      /clock itself: on the node's ROS clock, i.e. the /clock it receives, one simulated
      second per second of /clock (``realtime_factor`` does not apply; the clock's source
      sets the pace, e.g. ``mcap_play --clock --rate R``). The pacing is relative: from the
      sample index and /clock time at which it started, so the epochs of the node and of the
      clock source need not agree. Nothing is published before the first /clock message;
      a /clock that goes backwards (a replay that loops) restarts the pacing from there.

    Each tick does at most :data:`TICK_BUDGET_S` of work and continues at the next tick.

    /clock (``publish_clock`` > 0): the node is the graph's clock source and publishes its
    sensor time (:meth:`sensor_time_ns`) on /clock that many times per wall-clock second while
    it runs, then once more at the end of its data, and stops; it then paces on the wall clock
    even when use_sim_time is true (its own ROS clock follows the /clock it publishes).
    """

    #: Longest time [s] one pacing tick spends publishing frames (then the executor runs).
    TICK_BUDGET_S = 0.2

    def init_emulator(
        self, fs: float, schedule_samples: int | None = None, *, self_paced: bool = False
    ) -> None:
        """Sample rate fs [Hz], stamp origin, sample budget (``duration_s``; 0: unlimited;
        at most ``schedule_samples`` if given), counters and pacing state.

        ``self_paced``: the node paces itself from start (its executable); ``stamp_origin``
        'auto' is then 'wall', else 'zero'.
        """
        from rclpy.clock import Clock, ClockType

        self.fs = fs
        origin = self.p["stamp_origin"]
        if origin == "auto":
            origin = "wall" if self_paced else "zero"
        self.stamp_origin = origin
        #: Epoch [ns]: time of sample 0 (None until fixed, see :meth:`fix_epoch`).
        self.t0_ns: int | None = 0 if origin == "zero" else None
        total = int(round(self.p["duration_s"] * fs)) if self.p["duration_s"] > 0 else None
        if schedule_samples is not None:
            total = schedule_samples if total is None else min(total, schedule_samples)
        self.total_samples = total
        self.next_index = 0
        self.frames_published = 0
        self._timer = None
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._wall_start = None  # monotonic time [s] at which sample _index_start was due
        self._sim_start_ns = None  # /clock time [ns] at which sample _index_start was due
        self._sim_last_ns = 0  # /clock time [ns] at the last tick
        self._index_start = 0
        self._clock_pub = None
        self._next_clock = None  # monotonic time [s] of the next /clock message
        self._clock_done = False
        if self.p["publish_clock"] > 0:
            from rosgraph_msgs.msg import Clock as ClockMsg

            self._clock_pub = self.create_publisher(ClockMsg, "/clock", 10)

    # ------------------------------------------------------------------ sensor time

    def ros_time_active(self) -> bool:
        """True while use_sim_time is true (the node's ROS clock follows /clock)."""
        return bool(self.get_clock().ros_time_is_active)

    def follows_clock(self) -> bool:
        """True when the pacing follows /clock: use_sim_time is true and the node is not the
        clock source itself (``publish_clock`` = 0)."""
        return self.p["publish_clock"] <= 0 and self.ros_time_active()

    def fix_epoch(self, wait_for_clock: bool = False) -> bool:
        """Fix ``t0_ns`` if it is not fixed yet; True once it is.

        'zero': 0; 'wall': the node's ROS clock now (the wall clock, or /clock's time when
        use_sim_time is true). With ``wait_for_clock``, a node under use_sim_time that has not
        received /clock yet leaves the epoch open and returns False.
        """
        if self.t0_ns is not None:
            return True
        now = self.get_clock().now().nanoseconds
        if wait_for_clock and now == 0 and self.ros_time_active():
            return False
        self.t0_ns = int(now)
        return True

    def sensor_time_ns(self) -> int:
        """The node's current time on its sensor timeline [ns] (stamps and /clock).

        Following /clock: the node's ROS clock. Pacing itself on the wall clock: the epoch plus
        the simulated time reached by the pacing (at most the end of the data). Otherwise (its
        owner steps it): the time of the next sample to publish, epoch + next_index / fs.
        """
        from mems_sim.ros.frames import index_to_ns

        if self.follows_clock() and self._timer is not None:
            return self.get_clock().now().nanoseconds
        t0 = self.t0_ns if self.t0_ns is not None else self.get_clock().now().nanoseconds
        done = index_to_ns(self.next_index, self.fs, t0)
        if self._timer is None or self._wall_start is None or self._sim_start_ns is not None:
            return done
        import time

        elapsed = (time.monotonic() - self._wall_start) * self.p["realtime_factor"]
        now = index_to_ns(self._index_start, self.fs, t0) + int(elapsed * 1e9)
        if self.total_samples is not None:
            now = min(now, index_to_ns(self.total_samples, self.fs, t0))
        return max(now, done) if self.finished else now

    def graph_time_ns(self) -> int:
        """Time of the node's diagnostics stamps: its sensor time."""
        return self.sensor_time_ns()

    @property
    def frame_kwargs(self) -> dict:
        """``frame_id`` and ``t0_ns`` of every frame the node publishes."""
        self.fix_epoch()
        return dict(frame_id=self.p["frame_id"], t0_ns=self.t0_ns)

    # ------------------------------------------------------------------ frames

    def next_frame_size(self) -> int:
        """Samples of the next frame: ``frame_size``, fewer at the end, 0 when finished."""
        n = self.p["frame_size"]
        if self.total_samples is not None:
            n = min(n, self.total_samples - self.next_index)
        return max(n, 0)

    def frame_published(self, n: int) -> None:
        """Advance the sample index by the n samples just published."""
        self.next_index += n
        self.frames_published += 1

    @property
    def finished(self) -> bool:
        """True once ``duration_s`` worth of samples has been published."""
        return self.total_samples is not None and self.next_index >= self.total_samples

    # ------------------------------------------------------------------ pacing

    def _timer_period(self) -> float:
        period = self.p["frame_size"] / self.fs / self.p["realtime_factor"]
        return max(min(period, 0.05), 0.001)

    def start(self) -> None:
        """Start publishing, paced by a timer on the steady clock (class docstring)."""
        if self._timer is None:
            self._timer = self.create_timer(
                self._timer_period(), self._on_timer, clock=self._steady
            )

    def repace(self) -> None:
        """After a change of ``realtime_factor``: pace on from the current sample index at
        the new rate (a running timer gets the new period)."""
        import time

        if self._wall_start is not None:
            self._wall_start = time.monotonic()
            self._index_start = self.next_index
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(
                self._timer_period(), self._on_timer, clock=self._steady
            )

    def _due(self) -> float | None:
        """Samples due by now (None: nothing can be published yet); (re)starts the pacing
        reference when the pacing starts, changes between wall clock and /clock, or /clock
        went backwards."""
        import time

        if self.follows_clock():
            now_ns = self.get_clock().now().nanoseconds
            if now_ns == 0:
                return None  # no /clock received yet
            if self._sim_start_ns is None or now_ns < self._sim_last_ns:
                self._sim_start_ns, self._wall_start = now_ns, None
                self._index_start = self.next_index
            self._sim_last_ns = now_ns
            return self._index_start + (now_ns - self._sim_start_ns) * 1e-9 * self.fs
        now = time.monotonic()
        if self._wall_start is None:
            self._wall_start, self._sim_start_ns = now, None
            self._index_start = self.next_index
        return self._index_start + (now - self._wall_start) * self.p["realtime_factor"] * self.fs

    def _on_timer(self) -> None:
        """Publish every frame whose last sample is due (catches up on lag, within
        :data:`TICK_BUDGET_S` per tick); publish /clock when due."""
        import time

        if not self.finished and self.fix_epoch(wait_for_clock=True):
            due = self._due()
            if due is not None:
                budget = time.monotonic() + self.TICK_BUDGET_S
                while (
                    not self.finished
                    and self.next_index + self.p["frame_size"] <= due
                    and time.monotonic() < budget
                ):
                    self.step()
        self.publish_clock_if_due()

    def publish_clock_if_due(self) -> None:
        """Publish the sensor time on /clock when ``publish_clock`` says so (wall-clock
        period; once more at the end of the data, then no more)."""
        if self._clock_pub is None or self._clock_done or self.t0_ns is None:
            return
        import time

        now = time.monotonic()
        if self.finished:
            self._clock_done = True
        elif self._next_clock is not None and now < self._next_clock:
            return
        period = 1.0 / self.p["publish_clock"]
        nxt = now + period if self._next_clock is None else self._next_clock + period
        self._next_clock = max(nxt, now)
        from rosgraph_msgs.msg import Clock as ClockMsg

        msg = ClockMsg()
        msg.clock.sec, msg.clock.nanosec = divmod(int(self.sensor_time_ns()), 1_000_000_000)
        self._clock_pub.publish(msg)


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
            self, self.SPECS, runtime=self.RUNTIME_PARAMETERS, on_change=self.parameter_changed
        )
        title = self.DIAGNOSTICS_TITLE
        title = title if isinstance(title, str) else title(self.p)
        hardware_id = self.get_fully_qualified_name() if self.DIAGNOSTICS_HARDWARE_ID else ""
        self.diag = DiagnosticsReporter(
            self, f"{self.get_name()}: {title}", hardware_id=hardware_id, now_ns=self.graph_time_ns
        )

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
        self.pub_end_of_stream = self.create_publisher(
            DiagnosticArray, END_OF_STREAM, END_OF_STREAM_QOS
        )
        self.end_of_stream_sent = False
        if not drive_externally and autostart:
            self.warm_kernels()
            self.start()

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


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


#: Environment variable choosing the executor of :func:`run_node`: ``events`` (default:
#: rclpy's C++ ``rclpy.experimental.EventsExecutor``) or ``single``
#: (``rclpy.executors.SingleThreadedExecutor``).
EXECUTOR_ENV = "MEMS_EXECUTOR"


def _events_unsupported(node) -> bool:
    """True if ``node`` has what rclpy 9.1's events executor cannot run: a subscription
    whose callback takes the message info (``SystemError: null argument to internal
    routine`` at its first message) or a guard condition ("Guard conditions not
    supported")."""
    from rclpy.subscription import Subscription

    info = Subscription.CallbackType.WithMessageInfo
    return bool(list(node.guards)) or any(
        getattr(s, "_callback_type", None) == info for s in node.subscriptions
    )


def make_executor(nodes):
    """The executor :func:`run_node` spins ``nodes`` with (a node or several; :data:`EXECUTOR_ENV`).

    ``events`` (the default): rclpy's C++ ``rclpy.experimental.EventsExecutor``, which
    runs each ready subscription, timer or service from a C++ event queue. The Python
    ``SingleThreadedExecutor`` rebuilds its wait set (every entity of the nodes, through
    ``contextlib.ExitStack``) before every callback: CPU that a node taking ~100 frames a
    second pays (docs/profiles.md). ``single``: the ``SingleThreadedExecutor``.

    The single-threaded executor is used anyway when ``rclpy.experimental`` has no
    events executor or a node has what it cannot run (:func:`_events_unsupported`);
    entities created later are picked up by both. The events executor installs its own
    SIGINT/SIGTERM handlers when built; :func:`run_node` installs its handlers after.
    """
    from rclpy.executors import SingleThreadedExecutor

    nodes = [nodes] if isinstance(nodes, Node) else list(nodes)
    choice = os.environ.get(EXECUTOR_ENV, "events").strip().lower() or "events"
    if choice not in ("events", "single"):
        raise ParameterError(
            f"environment variable {EXECUTOR_ENV} = {choice!r} is invalid: allowed "
            "'events' or 'single'"
        )
    if choice == "events" and not any(_events_unsupported(n) for n in nodes):
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            pass
        else:
            return EventsExecutor()
    return SingleThreadedExecutor()


def run_node(factory: Callable[[], object], argv: list[str] | None = None) -> int:
    """Init rclpy, spin the node made by ``factory`` until shutdown; clean exit codes.

    An invalid parameter ends the process with exit code 2 and one line on
    stderr naming the parameter, the value and the allowed range. ``-h``/``--help``
    before any ``--ros-args`` prints the usage and the parameter table of the node class
    ``factory`` (:func:`~mems_sim.ros.node_help.node_help`) and returns 0 without
    starting ROS.
    """
    args = argv if argv is not None else sys.argv
    if isinstance(factory, type) and wants_help(args):
        sys.stdout.write(node_help(factory))
        return 0
    return run_nodes([("", factory)], args)


#: Longest wait at shutdown for the subscribers to acknowledge what was published [s].
DELIVERY_WAIT_S = 3.0


def wait_until_delivered(nodes: list, limit_s: float = DELIVERY_WAIT_S) -> None:
    """Before the nodes are destroyed: wait (at most ``limit_s`` in all) until every
    reliable publisher's samples are acknowledged by its subscribers. A process that exits
    at once takes the samples still in its writers with it: a recorder whose history was
    momentarily full recorded a stream without its last frames (a missing tail). Returns at
    once when everything was delivered."""
    from rclpy.duration import Duration

    deadline = time.monotonic() + limit_s
    for node in nodes:
        for pub in list(node.publishers):
            left = deadline - time.monotonic()
            if left <= 0:
                return
            try:
                pub.wait_for_all_acked(Duration(seconds=left))
            except Exception:  # a publisher already destroyed, or a best-effort one
                continue


def run_nodes(factories: list[tuple[str, Callable[[], object]]], args: list[str]) -> int:
    """Init rclpy with ``args``, build the nodes and spin them in one executor until a
    stop signal or shutdown; every node built is closed (its final results published) and
    destroyed, and 0 is returned.

    Args:
        factories: ``(label, factory)`` per node, built in this order; the label (empty
            for a process of one node) prefixes the error line of that node.
        args: the process's command line (rclpy's global arguments).

    An invalid parameter (:class:`ParameterError` while a node is built) returns 2 after
    one line on stderr. SIGINT and SIGTERM stop the spin between callbacks.
    """
    import signal

    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    apply_defaults()
    problem = domain_id_problem()
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        command_line_parameters(args)  # malformed rules, before rcl logs its own lines
    except ParameterError as exc:
        print(f"error: invalid ROS arguments: {exc}", file=sys.stderr)
        return 2
    # Our own stop-signal handling (SIGINT, SIGTERM, SIGHUP): the nodes publish their final results
    # before the context shuts down.
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rcl's RCLError: a malformed --ros-args rule (-p noequals)
        reason = str(exc).split(", at ")[0].removeprefix("failed to initialize rcl: ")
        print(f"error: invalid ROS arguments: {' '.join(reason.split())}", file=sys.stderr)
        return 2
    # SIGINT explicitly too: a process started in the background of a script inherits it
    # ignored, and would not stop on the SIGINT that launch tools send. While a node is
    # built a signal interrupts it (e.g. a wait for /clock); once they spin, see below.
    for sig in STOP_SIGNALS:
        signal.signal(sig, _raise_interrupt)
    nodes: list = []
    executor = None
    label = ""
    try:
        for label, factory in factories:
            nodes.append(factory())
        label = ""
        check_parameter_overrides(nodes, args)
        # one executor for the process's life: rclpy.spin_once(node) adds and removes the
        # node on every call, which wakes and rebuilds the wait set once per callback
        executor = make_executor(nodes)
        for node in nodes:
            executor.add_node(node)
        # while spinning, a stop signal only sets a flag that the loop reads between
        # callbacks: raised inside rclpy's C++ take of a message it surfaced as a RuntimeError
        # ("Unable to convert call argument") and the node died with a traceback; set after
        # the executor is built (they replace the events executor's own handlers)
        stop: list[int] = []
        for sig in STOP_SIGNALS:
            signal.signal(sig, lambda signum, frame: stop.append(signum))
        # short waits: SIGINT/SIGTERM are handled within 0.1 s even when no timer of a
        # node fires (e.g. under use_sim_time while nobody publishes /clock)
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.1)
    except ParameterError as exc:
        print(f"error: {label}: {exc}" if label else f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            close = getattr(node, "close", None)
            if close is not None:
                close()
        wait_until_delivered(nodes)
        for node in nodes:
            if executor is not None:
                executor.remove_node(node)
            node.destroy_node()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if rclpy.ok():
            rclpy.shutdown()
    return 0

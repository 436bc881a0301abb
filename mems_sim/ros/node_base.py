"""Bases of the nodes, parameters and the main() wrapper shared by the emulator and
estimator nodes.

* :class:`MemsNode`: every node (default namespace, ParamSpec parameters, diagnostics);
* :class:`PacedEmulator`: wall-clock pacing and duration of an emulator;
* :class:`EmulatorNode`: every emulator node (device, frame publishers, ``step``);
* :func:`run_node`: the ``main()`` of every node executable (exit code 2 on a bad parameter).

The estimator nodes' base, ``EstimatorNode``, is in ``mems_estimation.nodes.frame_input``.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable

from rclpy.node import Node
from rclpy.publisher import Publisher

from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros.diagnostics import DiagnosticsReporter
from mems_sim.ros.env import apply_defaults
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
        "pacing of the standalone node: simulated seconds per wall-clock second",
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
        "zero",
        "-",
        "time of sample 0: 'zero' (simulated time from 0, bit-identical runs) or "
        "'wall' (wall-clock time at start)",
        "sensor time: sample k is stamped epoch + k / fs",
        choices=("zero", "wall"),
    ),
    ParamSpec("frame_id", "imu_link", "-", "frame_id of published headers", "REP-103/105"),
)


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
    """Mixin of emulator nodes: wall-clock pacing of ``step()`` and the duration limit.

    The node sets ``self.p`` (with the :data:`EMULATOR_SPECS` values), calls
    :meth:`init_emulator` with its sample rate, and implements ``step()`` with
    :meth:`next_frame_size` and :meth:`frame_published`. ``realtime_factor`` may change
    while the node runs: :meth:`repace` continues the pacing from the current sample
    index at the new rate.
    """

    def init_emulator(self, fs: float, schedule_samples: int | None = None) -> None:
        """Sample rate fs [Hz], stamp origin, sample budget (``duration_s``; 0: unlimited;
        at most ``schedule_samples`` if given), counters and pacing state."""
        import time

        self.fs = fs
        self.t0_ns = 0 if self.p["stamp_origin"] == "zero" else time.time_ns()
        total = int(round(self.p["duration_s"] * fs)) if self.p["duration_s"] > 0 else None
        if schedule_samples is not None:
            total = schedule_samples if total is None else min(total, schedule_samples)
        self.total_samples = total
        self.next_index = 0
        self.frames_published = 0
        self._timer = None
        self._wall_start = None  # wall clock [s] at which sample _index_start was due
        self._index_start = 0

    @property
    def frame_kwargs(self) -> dict:
        """``frame_id`` and ``t0_ns`` of every frame the node publishes."""
        return dict(frame_id=self.p["frame_id"], t0_ns=self.t0_ns)

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

    def _timer_period(self) -> float:
        period = self.p["frame_size"] / self.fs / self.p["realtime_factor"]
        return max(min(period, 0.05), 0.001)

    def start(self) -> None:
        """Start publishing paced to the wall clock (``realtime_factor``)."""
        if self._timer is None:
            self._timer = self.create_timer(self._timer_period(), self._on_timer)

    def repace(self) -> None:
        """After a change of ``realtime_factor``: pace on from the current sample index at
        the new rate (a running timer gets the new period)."""
        import time

        if self._wall_start is not None:
            self._wall_start = time.monotonic()
            self._index_start = self.next_index
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(self._timer_period(), self._on_timer)

    def _on_timer(self) -> None:
        """Publish every frame whose last sample is due at the pacing (catches up on lag)."""
        import time

        now = time.monotonic()
        if self._wall_start is None:
            self._wall_start = now
        due = self._index_start + (now - self._wall_start) * self.p["realtime_factor"] * self.fs
        while not self.finished and self.next_index + self.p["frame_size"] <= due:
            self.step()


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
    #: The node's fully qualified name as hardware_id of its diagnostics status.
    DIAGNOSTICS_HARDWARE_ID = False

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
            self, f"{self.get_name()}: {title}", hardware_id=hardware_id
        )

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
    pacing (:meth:`schedule_samples` bounds it) and starts the wall-clock timer unless
    ``drive_externally`` or not ``autostart``. :meth:`step` publishes one frame through
    the subclass's :meth:`publish_frame`.

    Args:
        drive_externally: if True no timer is created; the owner calls :meth:`step`
            (the scenario runner does this to run faster than real time without loss).
        autostart: start the wall-clock timer at once; if False the owner calls
            :meth:`start` once its subscribers are matched (no frame is lost to discovery).
        **node_kwargs: passed to rclpy's Node (context, namespace, parameter_overrides).
    """

    RUNTIME_PARAMETERS = ("realtime_factor",)
    DIAGNOSTICS_HARDWARE_ID = True

    def __init__(
        self, *, drive_externally: bool = False, autostart: bool = True, **node_kwargs
    ) -> None:
        super().__init__(**node_kwargs)
        fs = self.make_device()
        self.init_emulator(fs, self.schedule_samples())
        if not drive_externally and autostart:
            self.start()

    def make_device(self) -> float:
        """Build the device and the publishers from ``self.p``; return the sample rate [Hz]."""
        raise NotImplementedError

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

    def step(self) -> int:
        """Generate and publish the next frame; return the number of samples (0 when done)."""
        n = self.next_frame_size()
        if n <= 0:
            return 0
        self.publish_frame(self.next_index, n)
        self.diag.count("frames")
        self.frame_published(n)
        return n

    def parameter_changed(self, name: str, value) -> None:
        """``realtime_factor``: the pacing continues from the current index at the new rate."""
        if name == "realtime_factor":
            self.repace()


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def run_node(factory: Callable[[], object], argv: list[str] | None = None) -> int:
    """Init rclpy, spin the node made by ``factory`` until shutdown; clean exit codes.

    An invalid parameter ends the process with exit code 2 and one line on
    stderr naming the parameter, the value and the allowed range.
    """
    import signal

    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    apply_defaults()
    # Our own SIGINT/SIGTERM handling: the node publishes its final results
    # before the context shuts down.
    rclpy.init(
        args=argv if argv is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO
    )
    # SIGINT explicitly too: a process started in the background of a script inherits it
    # ignored, and would not stop on the SIGINT that launch tools send
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _raise_interrupt)
    node = None
    try:
        node = factory()
        rclpy.spin(node)
    except ParameterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0

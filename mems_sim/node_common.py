"""Parameters and the main() wrapper shared by the emulator and estimator nodes."""
from __future__ import annotations

import dataclasses
import sys
from typing import Callable

from mems_sim.params import ParameterError, ParamSpec
from mems_sim.ros_env import apply_defaults

#: Parameters every emulator node has, besides its device table.
EMULATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("seed", 0, "-", "run seed of every random source of the device",
              "design.md principle 4 (deterministic)", min=0, max=2**62),
    ParamSpec("frame_size", 10, "samples", "samples per published frame", "design.md principle 2",
              min=1, max=1_000_000),
    ParamSpec("realtime_factor", 1.0, "-",
              "pacing of the standalone node: simulated seconds per wall-clock second",
              "", min=0.0, max=1.0e6, min_exclusive=True),
    ParamSpec("duration_s", 0.0, "s", "simulated duration after which the node stops "
              "publishing; 0 runs until shut down", "", min=0.0, max=1.0e9),
    ParamSpec("stamp_origin", "zero", "-",
              "time of sample 0: 'zero' (simulated time from 0, bit-identical runs) or "
              "'wall' (wall-clock time at start)", "design.md principle 5",
              choices=("zero", "wall")),
    ParamSpec("frame_id", "imu_link", "-", "frame_id of published headers", "REP-103/105"),
)


def emulator_specs(**defaults) -> tuple[ParamSpec, ...]:
    """:data:`EMULATOR_SPECS` with some defaults replaced (e.g. ``frame_size=10000``)."""
    unknown = set(defaults) - {s.name for s in EMULATOR_SPECS}
    if unknown:
        raise KeyError(f"not emulator parameters: {sorted(unknown)}")
    return tuple(dataclasses.replace(s, default=defaults[s.name]) if s.name in defaults else s
                 for s in EMULATOR_SPECS)


class PacedEmulator:
    """Mixin of emulator nodes: wall-clock pacing of ``step()`` and the duration limit.

    The node sets ``self.p`` (with the :data:`EMULATOR_SPECS` values), calls
    :meth:`init_emulator` with its sample rate, and implements ``step()`` with
    :meth:`next_frame_size` and :meth:`frame_published`.
    """

    def init_emulator(self, fs: float, total_samples: int | None = None) -> None:
        """Sample rate fs [Hz], stamp origin, sample budget (``duration_s``; 0: unlimited,
        or ``total_samples`` if given), counters and pacing state."""
        import time
        self.fs = fs
        self.t0_ns = 0 if self.p["stamp_origin"] == "zero" else time.time_ns()
        if total_samples is None and self.p["duration_s"] > 0:
            total_samples = int(round(self.p["duration_s"] * fs))
        self.total_samples = total_samples
        self.next_index = 0
        self.frames_published = 0
        self._timer = None
        self._wall_start = None

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

    def start(self) -> None:
        """Start publishing paced to the wall clock (``realtime_factor``)."""
        if self._timer is None:
            period = self.p["frame_size"] / self.fs / self.p["realtime_factor"]
            self._timer = self.create_timer(max(min(period, 0.05), 0.001), self._on_timer)

    def _on_timer(self) -> None:
        """Publish every frame whose last sample is due at the pacing (catches up on lag)."""
        import time
        now = time.monotonic()
        if self._wall_start is None:
            self._wall_start = now
        due = (now - self._wall_start) * self.p["realtime_factor"] * self.fs
        while not self.finished and self.next_index + self.p["frame_size"] <= due:
            self.step()


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
    rclpy.init(args=argv if argv is not None else sys.argv,
               signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGTERM, _raise_interrupt)
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

"""Stop signals of every executable: SIGINT (Ctrl-C), SIGTERM (``kill``) and SIGHUP (a
closed terminal or SSH session) ask a program to stop and finalise what it writes.

One handler for all three, :class:`StopRequest`: it records the request for a main loop to
poll, or raises :class:`StopSignal` where the program was (``raising``), as Python raises
KeyboardInterrupt for SIGINT. How each executable stops: docs/graphs.md.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable

#: The signals that ask a program to stop and finalise what it writes.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class StopSignal(KeyboardInterrupt):
    """A stop signal raised where the program was, as Python raises KeyboardInterrupt for
    SIGINT (so ``finally`` blocks close recordings for SIGTERM and SIGHUP too)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StopRequest:
    """The stop signals (:data:`STOP_SIGNALS`) as a request: the handler records the signal
    (``signals``, the time of the first one in ``first_at``, ``time.monotonic``), calls
    ``on_signal(signum)`` if given, and raises :class:`StopSignal` while ``raising`` is
    true; a main loop polls ``bool(stop)`` between its steps otherwise (a signal raised
    inside a C++ callback of rclpy would surface there as an unrelated error).

    :meth:`install` sets the handler (returns self), :meth:`restore` puts the previous ones
    back; as a context manager it does both.
    """

    def __init__(self, on_signal: Callable[[int], object] | None = None, raising: bool = False):
        self.on_signal = on_signal
        self.raising = raising
        self.signals: list[int] = []
        self.first_at: float | None = None
        self._previous: dict = {}

    @property
    def count(self) -> int:
        """Stop signals received (a second one cuts a finalisation short)."""
        return len(self.signals)

    @property
    def first_name(self) -> str:
        """Name of the first stop signal received (``SIGTERM``), "" before one."""
        return signal.Signals(self.signals[0]).name if self.signals else ""

    def __bool__(self) -> bool:
        return bool(self.signals)

    def _handle(self, signum: int, _frame) -> None:
        if self.first_at is None:
            self.first_at = time.monotonic()
        self.signals.append(signum)
        if self.on_signal is not None:
            self.on_signal(signum)
        if self.raising:
            raise StopSignal(signum)

    def install(self) -> StopRequest:
        """Handle the stop signals from now on (SIGINT explicitly too: a process started
        in the background of a script inherits it ignored)."""
        for sig in STOP_SIGNALS:
            previous = signal.signal(sig, self._handle)
            self._previous.setdefault(sig, previous)
        return self

    def restore(self) -> None:
        """The handlers from before :meth:`install`."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def __enter__(self) -> StopRequest:
        return self.install()

    def __exit__(self, *exc) -> None:
        self.restore()

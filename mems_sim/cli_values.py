"""Command-line values checked at parse time, for every executable: a one-line argparse
parser and argument types that refuse NaN, infinities and out-of-range numbers with the
option's allowed range (a bad value is one line and exit status 2, never a traceback, a hang
or a silent misreading)."""

from __future__ import annotations

import argparse
import math


class OneLineParser(argparse.ArgumentParser):
    """argparse with errors as one line (``PROG: error: ...``) and exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    integer: bool = False,
):
    """An argparse type: a finite number in the range [lo, hi] (``lo_open``/``hi_open``:
    that end excluded; None: unbounded), an integer if ``integer``."""

    def allowed() -> str:
        left = "-inf" if lo is None else f"{lo:g}"
        right = "inf" if hi is None else f"{hi:g}"
        return f"{'(' if lo_open or lo is None else '['}{left}, {right}{')' if hi_open or hi is None else ']'}"

    def parse(text: str):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} must be a finite number in {allowed()}")
        if integer and value != int(value):
            raise argparse.ArgumentTypeError(f"{text!r} must be a whole number in {allowed()}")
        below = lo is not None and (value < lo or (lo_open and value == lo))
        above = hi is not None and (value > hi or (hi_open and value == hi))
        if below or above:
            raise argparse.ArgumentTypeError(f"{text!r} is out of range: allowed {allowed()}")
        return int(value) if integer else value

    parse.__name__ = "number"  # argparse names the type in its messages
    return parse


#: Common ranges: a finite number > 0, and >= 0.
positive = number(0.0, lo_open=True)
non_negative = number(0.0)


def quiet_on_broken_pipe(main):
    """Wrap an entry point so that a reader that stops early (``run_scenario --list | head
    -1``) ends it quietly, as ``SIGPIPE`` ends a C program: exit status 128 + SIGPIPE, no
    traceback (Python's own recipe: stdout pointed at /dev/null so its flush at exit is
    silent too)."""
    import functools
    import os
    import signal
    import sys

    @functools.wraps(main)
    def wrapped(*args, **kwargs):
        try:
            status = main(*args, **kwargs)
            sys.stdout.flush()
            return status
        except BrokenPipeError:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return 128 + signal.SIGPIPE

    return wrapped

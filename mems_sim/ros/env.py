"""Process environment defaults for every executable of this package.

The graph stays on this machine unless the user
says otherwise. If ``ROS_AUTOMATIC_DISCOVERY_RANGE`` is not set, it is set to
``LOCALHOST`` before rclpy initialises; a user who wants a networked graph
sets it explicitly (e.g. ``SUBNET``). ``AMENT_PREFIX_PATH`` falls back to the
interpreter prefix, where the PyPI ROS 2 wheels install their ament index, so
that message definitions are found without sourcing a setup script.
"""

import os
import signal
import sys


def apply_defaults() -> None:
    """Set localhost-only discovery and an ament prefix if the user set neither."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not os.environ.get("AMENT_PREFIX_PATH"):
        os.environ["AMENT_PREFIX_PATH"] = sys.prefix


def install_stop_request() -> tuple[dict, dict]:
    """Turn SIGINT/SIGTERM into a flag (``stop["flag"]``) that a main loop polls.

    Returns:
        (stop, previous handlers); restore with ``signal.signal(sig, h)`` for each item.
    """
    stop = {"flag": False}

    def request_stop(signum, _frame):
        stop["flag"] = True

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    return stop, previous

"""The live view of a scenario run (``run_scenario --live-view [PORT]``).

The ``live_view`` executable (:mod:`mems_sim.nodes.live_view`) runs as a process of its own
on the graph's ROS domain, so that forwarding to Foxglove takes nothing from the graph's
executor: it only subscribes (best effort) to the topics a Foxglove client looks at, and
publishes nothing the graph's isolation checks would see. It is started before the graph's
nodes, and the run waits until its server listens (its URL is printed on standard error,
standard output being the run's table or JSON); it is stopped with SIGINT when the graph
closes.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

#: The line the live view prints once its server listens.
LISTENING = re.compile(r"live_view: Foxglove WebSocket server on (ws://\S+:(\d+))")

#: Longest wait for the live view's server to listen [s] (process start, rclpy import).
START_TIMEOUT_S = 60.0

#: Longest wait for the live view to exit after SIGINT before it is killed [s].
STOP_TIMEOUT_S = 5.0


class LiveViewError(RuntimeError):
    """The live view could not start."""


def live_view_command() -> list[str]:
    """The ``live_view`` executable beside this interpreter, else on PATH, else the module."""
    exe = Path(sys.executable).with_name("live_view")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("live_view")
    return [found] if found else [sys.executable, "-m", "mems_sim.nodes.live_view"]


class LiveView:
    """A running ``live_view`` process on a ROS domain.

    Args:
        domain_id: the graph's ROS domain.
        port: TCP port of the server (0: any free port).
        max_rate_hz: the live view's ``max_rate_hz`` (None: its default).
    """

    def __init__(self, domain_id: int, port: int, max_rate_hz: float | None = None) -> None:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
        args = ["--ros-args", "-p", f"port:={int(port)}", "--log-level", "warn"]
        if max_rate_hz is not None:
            args[3:3] = ["-p", f"max_rate_hz:={float(max_rate_hz)}"]
        self.proc = subprocess.Popen(
            live_view_command() + args,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.url: str | None = None
        self.port: int | None = None
        listening = threading.Event()

        def relay() -> None:  # its output goes to stderr: stdout is the run's report
            for line in self.proc.stdout:
                m = LISTENING.search(line)
                if m and self.url is None:
                    self.url, self.port = m.group(1), int(m.group(2))
                    listening.set()
                    continue
                sys.stderr.write(line)

        self._relay = threading.Thread(target=relay, name="live_view output", daemon=True)
        self._relay.start()
        deadline = time.monotonic() + START_TIMEOUT_S
        while not listening.wait(0.05):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise LiveViewError(
                    f"the live view did not start (port {port}; exit status "
                    f"{self.proc.returncode}): see its messages above"
                )
        print(
            f"live view: {self.url} (Foxglove: Open connection, Foxglove WebSocket)",
            file=sys.stderr,
            flush=True,
        )

    def stop(self) -> int | None:
        """Stop the process (SIGINT, then SIGKILL after :data:`STOP_TIMEOUT_S`); its exit
        status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._relay.join(timeout=1.0)
        return self.proc.returncode

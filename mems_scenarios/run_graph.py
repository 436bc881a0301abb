"""``run_graph``: run a node graph written in ROS 2 launch YAML, one process per node.

Usage::

    run_graph FILE.launch.yaml [name:=value ...] [--duration S] [--record FILE.mcap]
              [--record-regex RE] [--overwrite] [--allow-loss] [--stall-timeout S]
              [--log-dir DIR] [--kill-timeout S] [--show-args] [--dry-run]

Supported subset of the ROS 2 launch YAML format (what graph files need; anything else is
refused with one line naming the file, the entry and what is not supported)::

    launch:                    the root: a list of the entries below, run in order
    - arg:                     declares a launch argument
        name: NAME             (required)
        default: VALUE         (optional; without it the argument must be given)
        description: TEXT      (optional)
    - let:                     sets a launch variable
        name: NAME
        value: VALUE
    - node:                    starts one executable as a process of its own
        pkg: PACKAGE           (required)
        exec: EXECUTABLE       (required)
        name: NODE_NAME        (optional: ``-r __node:=NODE_NAME``)
        namespace: NS          (optional: ``-r __ns:=/NS``; made absolute)
        output: screen | log   (optional, default log as ros2 launch)
        param:                 (optional list)
        - name: P              ``-p P:=VALUE``
          value: VALUE
        - from: FILE.yaml      ``--params-file FILE.yaml``
        remap:                 (optional list)
        - from: A              ``-r A:=B``
          to: B
    - node_container:          several nodes in one process (ROS 2 composition)
        pkg: PACKAGE           (required; this package's ``component_container``)
        exec: EXECUTABLE       (required)
        name: NAME             (required: names the process in messages and logs)
        namespace: NS          (optional, as for ``node``: in messages and logs only)
        output: screen | log   (optional)
        composable_node:       (required list: the nodes of the process)
        - pkg: PACKAGE         (required)
          plugin: PLUGIN       (required: a node executable of PACKAGE, or MODULE:CLASS)
          name, namespace, param, remap   (optional, as for ``node``)
    - include:                 runs another launch YAML file's entries
        file: PATH
        arg:                   (optional list)
        - name: NAME
          value: VALUE

Substitutions, in any value: ``$(var NAME)`` (a launch argument or variable) and
``$(find-pkg-share PACKAGE)`` (the package's share directory in the ament index).

Semantics, as ros2 launch has them: a command-line ``name:=value`` sets the launch
configuration ``name`` before the file runs; an ``arg`` keeps a value already set (command
line, including file) and otherwise takes its default; ``let`` always sets; every value is
text after substitution, and a parameter value is typed by the node as YAML (``3`` an
integer, ``0.5`` a float, ``true`` a boolean). Each ``node`` is resolved through the ament
index as ``ros2 run`` does (``<prefix of PKG>/lib/PKG/EXECUTABLE``) and started as
``EXECUTABLE --ros-args -r __node:=NAME -r __ns:=/NS -p P:=VALUE ... --params-file F ...
-r A:=B ...`` in a process group of its own. A ``node_container`` is one such process,
``component_container --node PLUGIN --ros-args ... --node PLUGIN --ros-args ...``: each
composable node's name, namespace, parameters and remappings are its own (a composable node
without ``namespace`` keeps its node's default one, not the container's). Includes are not scoped: the include's ``arg``
values, and what the included file declares or sets, stay set for the entries after the
include (so an include that does not pass ``namespace`` inherits the one an earlier include
set). A relative path (``include`` file, ``param`` from) is relative to
the working directory, as for ros2 launch.

Where run_graph is stricter than ros2 launch: everything is checked before any process
starts -- YAML syntax, tags and attributes, substitutions, required arguments, command-line
arguments that no file declares, packages, executables, parameter files -- and a problem
gives one line on stderr and exit status 2.

Output: ``screen`` writes the node's stdout and stderr lines to the terminal prefixed with
``[label]``; ``log`` writes both to ``LOG_DIR/<label>.log`` and its stderr lines to the
terminal too. The log directory is ``--log-dir`` or a new directory
``run_graph_<time>_<pid>`` under ``$ROS_LOG_DIR`` (default ``~/.ros/log``).

Recording: ``--record FILE.mcap`` adds this package's recorder, ``mcap_record -o FILE.mcap
-a`` (or ``--regex RE`` with ``--record-regex``), resolved through the ament index like the
nodes; the nodes start once its node is visible in the ROS graph (at most 15 s). It
discovers topics periodically, so a topic is recorded from its subscription on (the first
messages of a node that publishes at once can be missed), as with a recorder started next
to a launch. It is stopped after the nodes, so their last messages are still recorded.
Loss fails the run: the recorder runs with ``--fail-on-loss``, so a recorded topic that
lost data or stalled (a publisher that sent steadily, then nothing for longer than
``--stall-timeout``) makes the exit status 1 (``--allow-loss``: reported only).

Stopping, SIGHUP, the parent-death signal and the exit status: docs/graphs.md ("Output,
stopping, exit status").
"""

from __future__ import annotations

import argparse
import ctypes
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

from mems_scenarios.launch_file import (
    Graph,
    GraphError,
    NodeAction,
    load_graph,
    parse_cli_args,
    resolve_executable,
)
from mems_sim.cli_values import quiet_on_broken_pipe
from mems_sim.ros.stop import StopRequest

PROG = "run_graph"

#: Exit statuses.
OK, FAILED, BAD_INPUT = 0, 1, 2
#: Package and executable of the recorder that ``--record`` adds.
RECORDER = ("mems_emulator", "mcap_record")
#: Exit status of ``mcap_record --fail-on-loss`` when a recorded topic lost data or stalled.
RECORDER_LOSS_STATUS = 3


# --------------------------------------------------------------------------- model


# --------------------------------------------------------------------------- loading


def recorder_action(
    output: str,
    regex: str | None,
    overwrite: bool,
    fail_on_loss: bool = True,
    stall_timeout: float | None = None,
) -> NodeAction:
    """The recorder process that ``--record`` adds (``stall_timeout`` [s]: its
    ``--stall-timeout``, None: the recorder's default)."""
    out = Path(output)
    if out.exists() and not overwrite:
        raise GraphError(f"--record {output}: the file exists (add --overwrite to replace it)")
    if not out.parent.is_dir():
        raise GraphError(f"--record {output}: directory {out.parent} does not exist")
    pkg, exe = RECORDER
    args = ["-o", str(out)] + (["--fail-on-loss"] if fail_on_loss else [])
    if stall_timeout is not None:
        args += ["--stall-timeout", repr(stall_timeout)]
    args += ["--regex", regex] if regex else ["-a"]
    if overwrite:
        args.append("--overwrite")
    return NodeAction(
        pkg=pkg,
        exe=exe,
        executable=resolve_executable(pkg, exe),
        output="screen",
        arguments=args,
        # its summary (stdout) on the terminal, not a line per topic it subscribes
        ros_arguments=["--log-level", "warn"],
        name=f"mcap_record_{os.getpid()}",
        label="mcap_record",
        title="recorder mcap_record",
    )


# --------------------------------------------------------------------------- running


#: Linux's prctl(2), bound once at import (the child after fork calls only this).
_PRCTL = None
if sys.platform.startswith("linux"):
    try:
        _PRCTL = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        _PRCTL = None
#: prctl option: the signal a process gets when the thread that started it ends.
PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int) -> None:
    """In the child, before exec: SIGTERM when run_graph ends in any way, even SIGKILL
    (Linux's parent-death signal; the nodes and the recorder finalise on SIGTERM); if
    run_graph is already gone, terminate at once."""
    if _PRCTL is not None:
        _PRCTL(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    if os.getppid() != parent:
        os._exit(143)


class _Process:
    """One started node: its Popen, output pumps and how it ended."""

    def __init__(self, action: NodeAction, log_dir: Path | None, env: dict, lock) -> None:
        self.action = action
        self.log_path = log_dir / f"{action.label}.log" if action.output == "log" else None
        self.signalled: int | None = None  # the last signal sent by us
        self.killed = False
        self._log = open(self.log_path, "ab") if self.log_path else None
        try:
            self.popen = subprocess.Popen(
                action.command(),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                env=env,
                start_new_session=True,  # a process group of its own: signals come from us only
                preexec_fn=partial(_die_with_parent, os.getpid()),  # reaped with run_graph
            )
        except OSError:
            if self._log is not None:
                self._log.close()
            raise
        prefix = f"[{action.label}] ".encode()
        screen_out = action.output == "screen"
        self._pumps = [
            threading.Thread(
                target=_pump,
                args=(
                    self.popen.stdout,
                    prefix,
                    sys.stdout if screen_out else None,
                    self._log,
                    lock,
                ),
                daemon=True,
            ),
            threading.Thread(
                target=_pump,
                args=(self.popen.stderr, prefix, sys.stderr, self._log, lock),
                daemon=True,
            ),
        ]
        for t in self._pumps:
            t.start()

    @property
    def returncode(self) -> int | None:
        return self.popen.poll()

    def send(self, sig: int) -> None:
        """Send ``sig`` to the process group (nothing if it has exited)."""
        if self.popen.poll() is None:
            self.signalled = sig
            try:
                os.killpg(self.popen.pid, sig)
            except ProcessLookupError:
                pass

    def kill(self) -> None:
        if self.popen.poll() is None:
            self.killed = True
            try:
                os.killpg(self.popen.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def join(self) -> None:
        """Wait for the output pumps (bounded) and close the log file."""
        for t in self._pumps:
            t.join(timeout=2.0)
        if self._log is not None:
            self._log.close()

    def clean(self) -> bool:
        """Exited with status 0, or from the signal it was sent."""
        rc = self.popen.poll()
        return rc == 0 or (self.signalled is not None and rc == -self.signalled and not self.killed)

    def problem(self) -> str:
        """One line on how the process failed."""
        a = self.action
        what = a.title or f"{a.fqn()} ({a.exe})"
        rc = self.popen.poll()
        if self.killed:
            text = f"{what} did not stop after {signal.Signals(self.signalled or 2).name}; killed"
        elif rc is not None and rc < 0:
            text = f"{what} died from {signal.Signals(-rc).name}"
        elif rc == RECORDER_LOSS_STATUS and self.action.label == "mcap_record":
            text = f"{what}: the recording lost data or stalled (the topics are named above)"
        else:
            text = f"{what} exited with status {rc}"
        return text + (f" (log: {self.log_path})" if self.log_path else "")


def _pump(stream, prefix: bytes, screen, log, lock) -> None:
    """Copy lines of ``stream`` to the screen (prefixed) and to the log file."""
    for line in iter(stream.readline, b""):
        with lock:
            if log is not None:
                log.write(line)
                log.flush()
            if screen is not None:
                raw = getattr(screen, "buffer", None)
                if raw is not None:
                    raw.write(prefix + line)
                else:  # a text stream without bytes underneath (e.g. a captured one)
                    screen.write((prefix + line).decode(errors="replace"))
                screen.flush()
    stream.close()


def default_log_dir() -> Path:
    """``$ROS_LOG_DIR`` (or ``$ROS_HOME/log``, ``~/.ros/log``) / ``run_graph_<time>_<pid>``."""
    base = os.environ.get("ROS_LOG_DIR") or str(
        Path(os.environ.get("ROS_HOME") or Path.home() / ".ros") / "log"
    )
    stamp = time.strftime("%Y-%m-%d-%H-%M-%S")
    return Path(base) / f"{PROG}_{stamp}_{os.getpid()}"


class Runner:
    """Starts the processes, forwards signals, stops the graph in order, reports."""

    POLL_S = 0.05
    #: Longest wait for the recorder to appear in the graph before the nodes start [s].
    READY_TIMEOUT_S = 15.0

    def __init__(
        self,
        graph: Graph,
        recorder: NodeAction | None = None,
        duration: float | None = None,
        kill_timeout: float = 5.0,
        log_dir: Path | None = None,
    ) -> None:
        self.graph = graph
        self.recorder_action = recorder
        self.duration = duration
        self.kill_timeout = kill_timeout
        self.log_dir = log_dir
        self._signals: list[int] = []
        self._lock = threading.Lock()
        self.failures: list[str] = []

    def run(self) -> int:
        """Run the graph until it stops; the exit status (module doc)."""
        with StopRequest(on_signal=self._signals.append):
            return self._run()

    def _start(self, action: NodeAction, env: dict) -> _Process | None:
        try:
            return _Process(action, self.log_dir, env, self._lock)
        except (OSError, ValueError) as exc:  # ValueError: a NUL in an argument
            self._fail(f"{action.title or f'{action.fqn()} ({action.exe})'} failed to start: {exc}")
            return None

    def _run(self) -> int:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        actions = self.graph.nodes + ([self.recorder_action] if self.recorder_action else [])
        if any(a.output == "log" for a in actions):
            if self.log_dir is None:
                self.log_dir = default_log_dir()
            self.log_dir.mkdir(parents=True, exist_ok=True)
            print(f"{PROG}: logs in {self.log_dir}", file=sys.stderr, flush=True)
        recorder = None
        if self.recorder_action is not None:
            recorder = self._start(self.recorder_action, env)
            if recorder is not None and not self._wait_visible(recorder):
                if recorder.returncode is None and not self._signals:
                    print(
                        f"{PROG}: warning: the recorder is not in the ROS graph after "
                        f"{self.READY_TIMEOUT_S:g} s; starting the nodes anyway",
                        file=sys.stderr,
                        flush=True,
                    )
        nodes: list[_Process] = []
        for action in self.graph.nodes:
            if self.failures or self._signals or (recorder and recorder.returncode is not None):
                break
            proc = self._start(action, env)
            if proc is not None:
                nodes.append(proc)
        started = time.monotonic()
        # phase: nodes run -> nodes stopping -> recorder stopping -> done
        stopping_nodes = bool(self.failures)
        node_deadline = recorder_deadline = None
        reported: set[int] = set()
        if stopping_nodes:
            node_deadline = time.monotonic() + self.kill_timeout
            for p in nodes:
                p.send(signal.SIGINT)
        while True:
            while self._signals:
                sig = self._signals.pop(0)
                if not stopping_nodes:
                    stopping_nodes, node_deadline = True, time.monotonic() + self.kill_timeout
                # the nodes and the recorder finalise on SIGINT and SIGTERM; a closed
                # terminal's SIGHUP reaches them as SIGTERM
                sig = signal.SIGTERM if sig == signal.SIGHUP else sig
                for p in nodes:
                    p.send(sig)
                if recorder_deadline is not None and recorder is not None:
                    recorder.send(sig)
            if (
                not stopping_nodes
                and self.duration is not None
                and time.monotonic() - started >= self.duration
            ):
                stopping_nodes, node_deadline = True, time.monotonic() + self.kill_timeout
                for p in nodes:
                    p.send(signal.SIGINT)
            for p in nodes + ([recorder] if recorder else []):
                if id(p) not in reported and p.returncode is not None and not p.clean():
                    reported.add(id(p))
                    if not p.killed:
                        self._fail(p.problem())
                    if not stopping_nodes:
                        stopping_nodes, node_deadline = True, time.monotonic() + self.kill_timeout
                        for q in nodes:
                            q.send(signal.SIGINT)
            running = [p for p in nodes if p.returncode is None]
            if running and node_deadline is not None and time.monotonic() >= node_deadline:
                for p in running:
                    p.kill()
                    self._fail(p.problem())
                    reported.add(id(p))
            if not running and recorder is not None and recorder_deadline is None:
                recorder_deadline = time.monotonic() + self.kill_timeout
                recorder.send(signal.SIGINT)
            if recorder is not None and recorder.returncode is None:
                if recorder_deadline is not None and time.monotonic() >= recorder_deadline:
                    recorder.kill()
                    self._fail(recorder.problem())
                    reported.add(id(recorder))
            if not running and (recorder is None or recorder.returncode is not None):
                break
            time.sleep(self.POLL_S)
        for p in nodes + ([recorder] if recorder else []):
            p.popen.wait()
            p.join()
            if id(p) not in reported and not p.clean():
                self._fail(p.problem())
        return FAILED if self.failures else OK

    def _wait_visible(self, proc: _Process) -> bool:
        """Wait until ``proc``'s node is in the ROS graph (at most :attr:`READY_TIMEOUT_S`),
        unless it exits or a stop signal arrives first; True if it is."""
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        name = proc.action.name
        ctx = Context()
        # no signal handlers of rclpy's: SIGINT/SIGTERM stay run_graph's
        rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
        try:
            node = rclpy.create_node(
                f"run_graph_{os.getpid()}",
                context=ctx,
                enable_rosout=False,
                start_parameter_services=False,
            )
            deadline = time.monotonic() + self.READY_TIMEOUT_S
            while time.monotonic() < deadline and proc.returncode is None and not self._signals:
                if any(n == name for n, _ns in node.get_node_names_and_namespaces()):
                    return True
                time.sleep(self.POLL_S)
            return False
        finally:
            rclpy.try_shutdown(context=ctx)

    def _fail(self, text: str) -> None:
        self.failures.append(text)
        with self._lock:
            print(f"{PROG}: error: {text}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- command line


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description=__doc__.splitlines()[0],
        epilog="Supported launch YAML: tags launch, arg, let, node (pkg, exec, name, "
        "namespace, param, remap, output), include; substitutions $(var NAME), "
        "$(find-pkg-share PACKAGE).",
    )
    p.add_argument("file", help="launch YAML file (e.g. FILE.launch.yaml)")
    p.add_argument("launch_args", nargs="*", metavar="name:=value", help="launch arguments")
    p.add_argument(
        "--duration", type=float, default=None, metavar="S", help="stop after S seconds (SIGINT)"
    )
    p.add_argument(
        "--record",
        default=None,
        metavar="FILE.mcap",
        help="record every topic with mcap_record (started first, stopped last)",
    )
    p.add_argument(
        "--record-regex", default=None, metavar="RE", help="record only topics matching RE"
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing --record file")
    p.add_argument(
        "--allow-loss",
        action="store_true",
        help="exit 0 when the recording lost data or a topic stalled (reported only); "
        "by default that is exit status 1",
    )
    p.add_argument(
        "--fail-on-loss",
        action="store_true",
        help="exit 1 when the recording lost data or a topic stalled: the default "
        "(kept for the command lines that give it)",
    )
    p.add_argument(
        "--stall-timeout",
        type=float,
        default=None,
        metavar="S",
        help="the recorder's --stall-timeout: a topic that had been sending steadily and "
        "then sends nothing for longer than S seconds stalled (default 5; 0: not timed)",
    )
    p.add_argument(
        "--log-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="directory of the output: log files (default: a new one under ~/.ros/log)",
    )
    p.add_argument(
        "--kill-timeout",
        type=float,
        default=5.0,
        metavar="S",
        help="seconds between the stop signal and SIGKILL (default 5)",
    )
    p.add_argument(
        "--show-args", action="store_true", help="list the file's launch arguments and exit"
    )
    p.add_argument(
        "--dry-run", action="store_true", help="print each process's command line and exit"
    )
    return p


def _error(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return BAD_INPUT


@quiet_on_broken_pipe
def main(argv: list[str] | None = None) -> int:
    """Entry point ``run_graph``; returns the exit status (module doc)."""
    from mems_sim.ros.env import apply_defaults, domain_id_problem

    args = _parser().parse_intermixed_args(argv)
    if args.duration is not None and not 0 < args.duration < 1e9:
        return _error(f"--duration = {args.duration!r} is invalid: allowed (0, 1e9) s")
    if not 0 <= args.kill_timeout < 1e6:
        return _error(f"--kill-timeout = {args.kill_timeout!r} is invalid: allowed [0, 1e6) s")
    if args.stall_timeout is not None and not 0 <= args.stall_timeout < 1e6:
        return _error(f"--stall-timeout = {args.stall_timeout!r} is invalid: allowed [0, 1e6) s")
    if args.allow_loss and args.fail_on_loss:
        return _error("--allow-loss and --fail-on-loss contradict each other")
    if args.record is None and (args.allow_loss or args.stall_timeout is not None):
        return _error("--allow-loss and --stall-timeout need --record FILE.mcap")
    if args.record_regex is not None:
        if args.record is None:
            return _error("--record-regex needs --record FILE.mcap")
        try:
            re.compile(args.record_regex)
        except re.error as exc:
            return _error(f"--record-regex {args.record_regex!r}: {exc}")
    apply_defaults()  # localhost discovery and an ament prefix, inherited by every process
    problem = domain_id_problem()
    if problem is not None:
        return _error(problem)
    try:
        graph = load_graph(args.file, parse_cli_args(args.launch_args), not args.show_args)
        if args.show_args:
            for name, (default, description) in graph.arguments.items():
                value = "(required)" if default is None else f"(default: {default!r})"
                print(f"{name} {value}" + (f": {description}" if description else ""))
            return OK
        recorder = None
        if args.record is not None:
            recorder = recorder_action(
                args.record,
                args.record_regex,
                args.overwrite,
                not args.allow_loss,
                args.stall_timeout,
            )
    except GraphError as exc:
        return _error(str(exc))
    if args.dry_run:
        for action in ([recorder] if recorder else []) + graph.nodes:
            print(shlex.join(action.command()))
        return OK
    if not graph.nodes:
        return _error(f"{args.file}: no node to run")
    return Runner(graph, recorder, args.duration, args.kill_timeout, args.log_dir).run()


if __name__ == "__main__":
    raise SystemExit(main())

"""The ``main()`` of every node executable: :func:`run_node` (one node) and :func:`run_nodes`
(several nodes in one process and one executor, ``component_container``), with clean exit
codes (2 for a bad parameter), stop signals (:mod:`~mems_sim.ros.stop`), the executor
(:func:`make_executor`) and the delivery of the last samples before exit
(:func:`wait_until_delivered`). How the nodes stop: docs/graphs.md.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable

from rclpy.node import Node

from mems_sim.params import ParameterError
from mems_sim.ros.env import apply_defaults, domain_id_problem
from mems_sim.ros.node_help import node_help, wants_help
from mems_sim.ros.param_overrides import check_parameter_overrides, command_line_parameters
from mems_sim.ros.stop import StopRequest

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
#: Longest wait of a node that ends its process (``exit_when_acknowledged``) for the
#: acknowledgements of its samples [s]; then the process exits with status 1.
ACKNOWLEDGE_WAIT_S = 30.0


def wait_until_delivered(nodes: list, limit_s: float = DELIVERY_WAIT_S) -> bool:
    """Before the nodes are destroyed: wait (at most ``limit_s`` in all) until every
    reliable publisher's samples are acknowledged by its subscribers. A process that exits
    at once takes the samples still in its writers with it: a recorder whose history was
    momentarily full recorded a stream without its last frames (a missing tail). Returns at
    once when everything was delivered; False if the time ran out first."""
    from rclpy.duration import Duration

    deadline = time.monotonic() + limit_s
    for node in nodes:
        for pub in list(node.publishers):
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            try:
                if not pub.wait_for_all_acked(Duration(seconds=left)):
                    return False
            except Exception:  # a publisher already destroyed, or a best-effort one
                continue
    return True


def nodes_ended(nodes: list) -> bool:
    """True when every node of the process has ended its run (a node's ``run_ended()``:
    an emulator with ``exit_when_acknowledged`` whose duration is published); the process
    then exits once the samples are acknowledged."""
    return bool(nodes) and all(getattr(n, "run_ended", lambda: False)() for n in nodes)


def run_nodes(factories: list[tuple[str, Callable[[], object]]], args: list[str]) -> int:
    """Init rclpy with ``args``, build the nodes and spin them in one executor until a
    stop signal, shutdown or the end of every node's run (:func:`nodes_ended`); every node
    built is closed (its final results published) and destroyed, and 0 is returned.

    Args:
        factories: ``(label, factory)`` per node, built in this order; the label (empty
            for a process of one node) prefixes the error line of that node.
        args: the process's command line (rclpy's global arguments).

    An invalid parameter (:class:`ParameterError` while a node is built) returns 2 after
    one line on stderr. SIGINT, SIGTERM and SIGHUP stop the spin between callbacks. After
    the end of every node's run, 1 is returned (after one line) if the subscribers did
    not acknowledge the samples within :data:`ACKNOWLEDGE_WAIT_S`.
    """
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
    # Our own stop-signal handling (SIGINT, SIGTERM, SIGHUP): the nodes publish their final
    # results before the context shuts down.
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rcl's RCLError: a malformed --ros-args rule (-p noequals)
        reason = str(exc).split(", at ")[0].removeprefix("failed to initialize rcl: ")
        print(f"error: invalid ROS arguments: {' '.join(reason.split())}", file=sys.stderr)
        return 2
    # SIGINT explicitly too (StopRequest.install). While a node is built a signal
    # interrupts it (e.g. a wait for /clock); once they spin, see below.
    stop = StopRequest(raising=True).install()
    nodes: list = []
    executor = None
    label = ""
    ended = False
    code = 0
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
        stop.raising = False
        stop.install()
        # short waits: SIGINT/SIGTERM are handled within 0.1 s even when no timer of a
        # node fires (e.g. under use_sim_time while nobody publishes /clock)
        while rclpy.ok() and not stop and not ended:
            executor.spin_once(timeout_sec=0.1)
            ended = nodes_ended(nodes)
    except ParameterError as exc:
        print(f"error: {label}: {exc}" if label else f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stop.raising = False
        for node in nodes:
            close = getattr(node, "close", None)
            if close is not None:
                close()
        limit = ACKNOWLEDGE_WAIT_S if ended else DELIVERY_WAIT_S
        if not wait_until_delivered(nodes, limit) and ended:
            print(
                f"error: the subscribers did not acknowledge every sample within {limit:g} s",
                file=sys.stderr,
            )
            code = 1
        for node in nodes:
            if executor is not None:
                executor.remove_node(node)
            node.destroy_node()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if rclpy.ok():
            rclpy.shutdown()
        stop.restore()
    return code

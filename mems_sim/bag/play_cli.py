"""MCAP player: ``mcap_play BAG [--rate R | --as-fast-as-possible] [--loop] [--clock [HZ]] ...``.

``BAG`` is an MCAP file or a rosbag2 bag directory (a split recording), played as one
timeline (:func:`~mems_sim.bag.reading.iter_raw`) by :class:`~mems_sim.bag.player.Player`.
Topics are remapped with ``--remap FROM:=TO`` or ROS's ``--ros-args -r FROM:=TO``;
``--start-paused`` and the services of
:class:`~mems_sim.bag.playback_control.PlaybackControl` (rosbag2's ``~/pause``,
``~/resume``, ``~/toggle_paused``, ``~/is_paused``, ``~/play_next``, as
std_srvs/srv/Trigger) pause and step the replay.

Publishes the serialised bytes stored in the file (no deserialisation) with
publishers created from the file's schemas (``pkg/msg/Type``, imported only
when it is an interface of the ament index: other types are reported and their
topics skipped) and the recorded ``offered_qos_profiles`` (fallback FRAME_QOS),
paced by ``log_time`` scaled by ``--rate``; optionally publishes ``/clock``.
The recorder's log times are sensor time, so ``--rate 1`` replays a 600 s
recording in 600 s and ``--clock`` publishes the time the stamps belong to.

Lossless replay into other processes (``--wait-for-consumer NODE_FQN``, repeatable,
with or without ``--as-fast-as-possible``): flow control at the application level
(:class:`~mems_sim.bag.flow_control.FlowControl`). The consumer reports its progress on
``NODE_FQN/progress`` (std_msgs/UInt64, one past the last sample index it processed, after
every frame); the player keeps at most ``--credit`` samples (``N``) or frames (``Nf``,
default 50f) published ahead of it on each played frame topic it subscribes to, waits at
the end until it has caught up, and reports per topic what was published and acknowledged
and the loss (frames its progress skipped, gaps it reports on /diagnostics, frames never
acknowledged); exit status 3 when anything was lost or a consumer was not ready, stalled
(``--consumer-timeout``) or left.

Files are read through :mod:`mems_sim.bag.reader` (bounded chunk
decompression, CRC, topic-name and QoS checks): a corrupt or hostile file gives
one line on stderr and exit status 2; a truncated one is played up to its last
complete chunk after a warning line.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from mems_sim.bag.flow_control import DEFAULT_CREDIT, FlowControl, parse_consumer, parse_credit
from mems_sim.bag.playback_control import PlaybackControl, control_available
from mems_sim.bag.player import Player, parse_remaps
from mems_sim.bag.reader import BagReadError, closed_pipe_exit, one_line, shown
from mems_sim.bag.reading import playable_topics
from mems_sim.cli_values import OneLineParser, non_negative, number, positive
from mems_sim.ros.env import apply_defaults, domain_id_problem
from mems_sim.ros.stop import StopRequest


def _parse_args(argv: list[str]) -> argparse.Namespace:
    parser = OneLineParser(prog="mcap_play", description=__doc__.splitlines()[0])
    parser.add_argument(
        "file", nargs="?", metavar="BAG", help="MCAP file or rosbag2 bag directory to play"
    )
    parser.add_argument(
        "--rate",
        "-r",
        type=number(0.0, 1e6, lo_open=True),
        default=1.0,
        help="playback rate factor (> 0)",
    )
    parser.add_argument(
        "--as-fast-as-possible",
        action="store_true",
        help="ignore timing, publish as fast as possible",
    )
    parser.add_argument("--loop", "-l", action="store_true", help="play in a loop")
    parser.add_argument(
        "--clock",
        nargs="?",
        type=number(0.0, 1e4, lo_open=True),
        const=40.0,
        default=None,
        metavar="HZ",
        help="publish /clock at HZ (default 40 Hz)",
    )
    parser.add_argument(
        "--start-offset", type=non_negative, default=0.0, help="skip this much of the bag [s]"
    )
    parser.add_argument(
        "--duration", type=positive, default=None, help="play this much bag time [s]"
    )
    parser.add_argument("--topics", nargs="+", default=None, help="play only these topics")
    parser.add_argument(
        "--remap",
        "-m",
        nargs="+",
        action="extend",
        default=[],
        metavar="FROM:=TO",
        help="topic remaps (also: --ros-args -r FROM:=TO, ROS's remapping rules)",
    )
    parser.add_argument(
        "--start-paused",
        action="store_true",
        help="start paused: ~/resume, ~/toggle_paused and ~/play_next (std_srvs/srv/Trigger "
        "services, rosbag2's names) go on",
    )
    parser.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        metavar="N",
        help="wait until each topic has N subscribers before playing",
    )
    parser.add_argument(
        "--wait-timeout",
        type=number(0.0, 1e6, lo_open=True),
        default=10.0,
        help="give up waiting for subscribers after this long [s]",
    )
    parser.add_argument(
        "--delay", type=number(0.0, 86400.0), default=0.0, help="sleep before playing [s]"
    )
    parser.add_argument(
        "--wait-for-consumer",
        action="append",
        default=[],
        metavar="NODE_FQN[:TOPIC]",
        help="lossless replay into this node (repeatable): wait for it, keep at most --credit "
        "published ahead of the progress it reports on NODE_FQN/progress on each played frame "
        "topic it subscribes to (or TOPIC only), wait for it at the end, report loss",
    )
    parser.add_argument(
        "--credit",
        default=DEFAULT_CREDIT,
        metavar="N|Nf",
        help="samples (N) or frames (Nf) a consumer may be behind (default %(default)s)",
    )
    parser.add_argument(
        "--consumer-timeout",
        type=number(0.0, 1e6, lo_open=True),
        default=30.0,
        metavar="S",
        help="stop waiting for a consumer whose progress has not moved for S seconds [s]",
    )
    args = parser.parse_args(argv)
    if args.file is None:
        # "--remap A:=B BAG" or "--topics T BAG": the bag was taken as one more list item
        if args.remap and ":=" not in args.remap[-1]:
            args.file = args.remap.pop()
        elif args.topics and len(args.topics) > 1 and os.path.exists(args.topics[-1]):
            args.file = args.topics.pop()
        else:
            parser.error("the following arguments are required: BAG")
    if not args.rate > 0 or args.rate == float("inf"):
        parser.error("--rate must be a finite number > 0 (use --as-fast-as-possible)")
    try:
        args.credit = parse_credit(args.credit)
        args.consumers = [parse_consumer(c) for c in args.wait_for_consumer]
    except ValueError as exc:
        parser.error(str(exc))
    if args.consumers and args.loop:
        parser.error("--wait-for-consumer and --loop cannot be combined")
    if not args.consumer_timeout > 0:
        parser.error("--consumer-timeout must be > 0")
    return args


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(own arguments, ROS arguments)``: by rcl's rule, the arguments from each
    ``--ros-args`` up to the next ``--`` (or the end) are ROS's (kept with their
    ``--ros-args``); everything else is the program's, including ``FROM:=TO`` after
    ``--remap``, which rcl alone would also take as a (deprecated) global remapping rule."""
    own: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in argv:
        if inside:
            if arg == "--":
                inside = False
            else:
                ros.append(arg)
        elif arg == "--ros-args":
            inside = True
            ros.append(arg)
        else:
            own.append(arg)
    return own, ros


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_play``; returns the process exit code (2 for a bad file,
    3 for loss in a lossless replay, 141 when stdout's reader went away)."""
    try:
        return _main(argv)
    except BrokenPipeError:
        return closed_pipe_exit()


def _main(argv: list[str] | None) -> int:
    apply_defaults()
    problem = domain_id_problem()
    if problem is not None:
        print(f"mcap_play: error: {problem}", file=sys.stderr)
        return 2
    argv = sys.argv[1:] if argv is None else list(argv)
    own, ros_args = split_ros_args(argv)
    args = _parse_args(own)
    try:
        remap = parse_remaps(args.remap)
        resolved = playable_topics(args.file, args.topics)
    except (BagReadError, ValueError) as exc:
        print(f"mcap_play: error: {one_line(exc)}", file=sys.stderr)
        return 2
    if args.start_paused and control_available() is not None:
        print(f"mcap_play: error: --start-paused: {control_available()}", file=sys.stderr)
        return 2
    playable, skipped = resolved
    if not playable:
        why = "; ".join(f"{shown(t)}: {r}" for t, r in skipped.items())
        print(
            one_line(
                f"mcap_play: error: {args.file}: no playable topics" + (f" ({why})" if why else ""),
                1000,
            ),
            file=sys.stderr,
        )
        return 2
    for topic, reason in skipped.items():
        print(
            one_line(f"mcap_play: warning: {args.file}: {shown(topic)}: {reason}; not played"),
            file=sys.stderr,
        )

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock

    rclpy.init(args=["mcap_play"] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopRequest().install()
    node = None
    code = 0
    try:
        node = Node("mcap_player")
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        control = PlaybackControl(paused=args.start_paused)
        if control_available() is None:
            control.create_services(node)
        player = Player(
            node,
            args.file,
            args.topics,
            remap,
            resolved=resolved,
            control=control,
            executor=executor,
        )
        clock_pub = node.create_publisher(Clock, "/clock", 10) if args.clock else None
        flow = None
        if args.consumers:
            flow = FlowControl(
                node, executor, args.consumers, args.credit, stall_s=args.consumer_timeout
            )
            why = flow.wait_ready(player, args.wait_timeout, lambda: bool(stop))
            if why is not None:
                print(one_line(f"mcap_play: error: consumer not ready: {why}"), file=sys.stderr)
                return 3
        if args.wait_for_subscribers > 0 and not player.wait_for_subscribers(
            args.wait_for_subscribers, args.wait_timeout, lambda: bool(stop)
        ):
            node.get_logger().warning("not every topic has its subscribers; playing anyway")
        delay_end = time.monotonic() + args.delay
        while not stop and time.monotonic() < delay_end:
            player._wait(min(0.05, delay_end - time.monotonic()))
        while not stop:
            player.play(
                rate=args.rate,
                fast=args.as_fast_as_possible,
                start_offset_s=args.start_offset,
                duration_s=args.duration,
                clock_publisher=clock_pub,
                clock_hz=args.clock or 0.0,
                stop=lambda: bool(stop),
                flow=flow,
            )
            if not args.loop:
                break
        lines = [f"mcap_play: published {player.published} messages"]
        if player.played_log_s > 0:
            lines[0] += f", {player.played_log_s:.3f} s of log time in {player.played_wall_s:.3f} s"
        if flow is not None:
            flow.finish(lambda: bool(stop))
            lines += flow.report(player)
            if flow.lost() or any(c.diag_gaps for c in flow.consumers):
                code = 3
        else:
            # deliver the tail before exit (the middleware's acknowledgement: no loss count)
            player.wait_acked(timeout_s=max(1.0, args.wait_timeout))
        print("\n".join(lines), flush=True)
    except BagReadError as exc:
        print(f"mcap_play: error: {one_line(exc)}", file=sys.stderr)
        return 2
    finally:
        stop.restore()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())

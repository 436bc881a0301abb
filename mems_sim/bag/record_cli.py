"""``mcap_record``, the command line of the MCAP recorder
(:class:`~mems_sim.bag.recorder.RecorderNode`):
``mcap_record -o FILE.mcap [-a | TOPIC ...] [-e RE] [-x RE] [-b BYTES] [-d S]``.

The command line follows ``ros2 bag record`` (rosbag2, Jazzy/Rolling) where an option
exists there: ``-s/--storage`` (``mcap`` only), ``--topics``, ``-a/--all``, ``-e/--regex``,
``-x/--exclude-regex``, ``--include-hidden-topics``, ``-b/--max-bag-size``,
``-d/--max-bag-duration``, ``--qos-profile-overrides-path``, ``--compression-format``,
``--storage-preset-profile`` (``none``, ``fastwrite``, ``zstd_fast``, ``zstd_small``:
:data:`~mems_sim.bag.compression.STORAGE_PRESETS`).
``--duration`` (rosbag2 has no such option) ends recording after that much wall-clock
time. With ``-b`` or ``-d`` the output is a rosbag2 bag directory of split MCAP files and a
``metadata.yaml`` (:class:`~mems_sim.bag.writer.McapBagWriter`); without them ``-o`` names
one ``.mcap`` file.

Stopping: a stop request (SIGINT; SIGTERM, as ``ros2 launch`` and ``docker stop`` send
before a SIGKILL; SIGHUP; :mod:`mems_sim.ros.stop`) ends recording in bounded time, live
publishers or not. Messages that arrive within :data:`STOP_GRACE_S` of the
request are still taken and written; then the subscriptions are destroyed, the
writer thread drains its queue until :data:`STOP_FINALISE_S` after the request
(what is still queued then is dropped and counted in the summary), and the
Summary, Statistics and footer are written; exit status 0. A second signal
skips the rest of the grace window and of the drain. Output problems (an
existing file without ``--overwrite``, a symbolic link, a directory, a missing
directory, a full disk) give one line on stderr naming the path and exit status
1 (2 for a path refused before recording).

Loss: the summary lists every recorded topic that lost data (``lost: ...``) and every
topic a publisher of which stalled (``stalled: TOPIC (N s without data)``: it had been
sending steadily, then sent nothing for longer than ``--stall-timeout``, default
:data:`STALL_TIMEOUT_S`; :class:`~mems_sim.bag.recorder.RecorderNode`); with
``--fail-on-loss`` either gives one line on stderr and exit status :data:`LOSS_STATUS`.
"""

from __future__ import annotations

import argparse
import re
import sys
import time

from mems_sim.bag.compression import STORAGE_PRESETS, storage_preset
from mems_sim.bag.recorder import RecorderNode
from mems_sim.bag.writer import (
    BagWriteError,
    bag_directory_path,
    bag_directory_problem,
    output_problem,
)
from mems_sim.cli_values import OneLineParser, non_negative, positive
from mems_sim.ros.env import apply_defaults, domain_id_problem
from mems_sim.ros.qos_yaml import load_overrides
from mems_sim.ros.stop import StopRequest

#: After a stop request, messages arriving within this time are still recorded [s].
STOP_GRACE_S = 0.4

#: After a stop request the file is finalised by this time at the latest [s]
#: (queued messages not written by then are dropped and counted).
STOP_FINALISE_S = 1.0

#: After ``--duration`` the writer queue is drained for at most this long before the
#: Summary is written [s] (what is still queued then is dropped and counted).
DURATION_FINALISE_S = 0.3


#: Exit status of ``mcap_record --fail-on-loss`` when a recorded topic lost data or stalled.
LOSS_STATUS = 3
#: Default ``--stall-timeout``: a steady publisher silent for longer than this is stalled [s].
STALL_TIMEOUT_S = 5.0
#: Smallest split size of ``-b`` [bytes]: below it every message would start a file.
MIN_SPLIT_BYTES = 16384


def _byte_count(text: str) -> int:
    """A number of bytes: an integer, or a number with a k/M/G suffix (powers of 1000)."""
    scale = {"k": 10**3, "K": 10**3, "M": 10**6, "G": 10**9}.get(text[-1:], 1)
    number = text[:-1] if scale != 1 else text
    try:
        value = float(number) * scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of bytes") from None
    if not (0 <= value < 2**63) or value != int(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be a whole number of bytes >= 0")
    return int(value)


def _storage(text: str) -> str:
    if text != "mcap":
        raise argparse.ArgumentTypeError(f"{text!r}: only 'mcap' is supported")
    return text


def _regex(text: str) -> str:
    try:
        re.compile(text)
    except re.error as exc:
        raise argparse.ArgumentTypeError(f"{text!r} is not a regular expression: {exc}") from None
    return text


def _parse_args(argv: list[str]) -> argparse.Namespace:
    parser = OneLineParser(
        prog="mcap_record",
        description=__doc__.splitlines()[0],
        epilog="Without -b/-d, -o names one MCAP file. With -b or -d, -o names a rosbag2 bag "
        "directory (a .mcap suffix is dropped) holding NAME_0.mcap, NAME_1.mcap, ... and "
        "metadata.yaml; an existing directory is refused unless --overwrite (which replaces "
        "only a bag directory).",
    )
    parser.add_argument("topics", nargs="*", help="topics to record")
    parser.add_argument(
        "--topics",
        dest="more_topics",
        nargs="+",
        default=[],
        metavar="TOPIC",
        help="topics to record (as rosbag2; the same as positional topics)",
    )
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        help="output: FILE.mcap, or the bag directory with -b/-d",
    )
    parser.add_argument(
        "-s", "--storage", type=_storage, default="mcap", help="storage identifier: mcap only"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the output file (bag directory) if it exists",
    )
    parser.add_argument("-a", "--all", action="store_true", help="record all topics")
    parser.add_argument(
        "-e", "--regex", type=_regex, default=None, help="record topics matching this regex"
    )
    parser.add_argument(
        "-x",
        "--exclude-regex",
        "--exclude",
        dest="exclude",
        metavar="REGEX",
        type=_regex,
        default=None,
        help="exclude topics matching this regex (--exclude: old name)",
    )
    parser.add_argument(
        "--include-hidden-topics",
        action="store_true",
        help="with -a/-e, record hidden topics (a name token starting with '_') too",
    )
    parser.add_argument(
        "--qos-profile-overrides-path",
        default=None,
        metavar="FILE.yaml",
        help="YAML file of topic -> QoS profile (history, depth, reliability, durability, "
        "deadline, lifespan, liveliness, liveliness_lease_duration, "
        "avoid_ros_namespace_conventions) used for those subscriptions",
    )
    parser.add_argument(
        "-b",
        "--max-bag-size",
        type=_byte_count,
        default=0,
        metavar="BYTES",
        help="split the bag into a new file at this size [bytes; k/M/G suffixes] (0: never)",
    )
    parser.add_argument(
        "-d",
        "--max-bag-duration",
        type=non_negative,
        default=0.0,
        metavar="SECONDS",
        help="split the bag into a new file at this much log (sensor) time [s] (0: never)",
    )
    parser.add_argument(
        "--duration",
        type=positive,
        default=None,
        metavar="SECONDS",
        help="stop after this much wall-clock time from the start of recording [s]",
    )
    parser.add_argument(
        "--compression-format",
        "--compression",
        dest="compression",
        choices=["zstd", "lz4", "none"],
        default=None,
        help="MCAP chunk compression (default zstd, or the preset's; --compression: old name)",
    )
    parser.add_argument(
        "--chunk-size",
        type=_byte_count,
        default=None,
        help="MCAP chunk size [bytes] (default 1 MiB, or the preset's)",
    )
    parser.add_argument(
        "--storage-preset-profile",
        choices=list(STORAGE_PRESETS),
        default="none",
        metavar="PROFILE",
        help="rosbag2's MCAP writer presets: none (default: zstd level 1, 1 MiB chunks, "
        "CRCs), fastwrite (no compression, no CRCs), zstd_fast (zstd level -5, no CRCs), "
        "zstd_small (zstd level 19, 4 MiB chunks); --compression-format and --chunk-size "
        "override the preset's",
    )
    parser.add_argument(
        "--fail-on-loss",
        action="store_true",
        help=f"exit with status {LOSS_STATUS} (after the summary, with one line naming the "
        "topics) when a recorded topic lost data or stalled (run_graph sets it)",
    )
    parser.add_argument(
        "--stall-timeout",
        type=non_negative,
        default=STALL_TIMEOUT_S,
        metavar="SECONDS",
        help="a publisher that sent steadily and then nothing for longer than this is "
        f"stalled [s] (default {STALL_TIMEOUT_S:g}; 0: stalls are not timed)",
    )
    parser.add_argument(
        "--report-progress",
        metavar="TOPIC",
        default=None,
        help="publish ~/progress (one past the last sample index written) after each frame "
        "of this recorded frame topic, so that mcap_play --wait-for-consumer NODE:TOPIC "
        "replays into the recorder without loss",
    )
    args = parser.parse_args(argv)
    args.writer_options = storage_preset(args.storage_preset_profile)
    if args.compression is not None:
        args.writer_options["compression"] = args.compression
        if args.compression != "zstd":
            args.writer_options.pop("compression_level", None)
    if args.chunk_size is not None:
        args.writer_options["chunk_size"] = args.chunk_size
    args.compression = args.writer_options.get("compression", "zstd")
    args.chunk_size = args.writer_options.get("chunk_size", 1 << 20)
    args.topics = list(args.topics) + list(args.more_topics)
    if not (args.topics or args.all or args.regex):
        parser.error("give topics, -a/--all or -e/--regex")
    if args.chunk_size < 1:
        parser.error("argument --chunk-size: must be at least 1 byte")
    if 0 < args.max_bag_size < MIN_SPLIT_BYTES:
        parser.error(f"argument -b/--max-bag-size: at least {MIN_SPLIT_BYTES} bytes (0: never)")
    args.split = bool(args.max_bag_size or args.max_bag_duration)
    if args.split:
        args.output = bag_directory_path(args.output)
    args.qos_overrides = {}
    if args.qos_profile_overrides_path:
        try:
            args.qos_overrides = load_overrides(args.qos_profile_overrides_path)
        except ValueError as exc:
            parser.error(f"argument --qos-profile-overrides-path: {exc}")
    return args


def drain(
    executor,
    recorder: RecorderNode,
    idle_s: float = 0.3,
    limit_s: float = 10.0,
    stop=lambda: False,
) -> None:
    """Write what the middleware already delivered before stopping.

    Messages acknowledged by the subscription but not yet taken by the
    executor would be lost on an immediate stop; spin until nothing has
    arrived for ``idle_s`` seconds, at most ``limit_s`` seconds, or until
    ``stop()`` (a second signal) or a write error.
    """
    deadline = time.monotonic() + limit_s
    last_total, last_change = -1, time.monotonic()
    while time.monotonic() < deadline and not stop() and recorder.write_error is None:
        executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))
        total = sum(recorder._rx_counts.values())
        if total != last_total:
            last_total, last_change = total, time.monotonic()
        elif time.monotonic() - last_change >= idle_s:
            return


def _loss_status(recorder: RecorderNode) -> int:
    """:data:`LOSS_STATUS` with one line naming the topics that lost data or stalled; 0 if
    none did."""
    lost, stalled = recorder.losses(), recorder.stalls()
    if not (lost or stalled):
        return 0
    return _error(
        "; ".join(([f"lost data: {'; '.join(lost)}"] if lost else []) + stalled), LOSS_STATUS
    )


def _error(text: str, code: int) -> int:
    print(f"mcap_record: error: {' '.join(str(text).split())}", file=sys.stderr, flush=True)
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mcap_record``; returns the process exit code.

    0 after a stop request or ``--duration``; 2 for an output path refused before
    recording; 1 when writing fails (disk full), with one line naming the path.
    """
    stop = StopRequest().install()  # before rclpy starts: a signal from now on finalises the file
    try:
        return _run(argv, stop)
    finally:
        stop.restore()


def _run(argv: list[str] | None, stop: StopRequest) -> int:
    apply_defaults()
    problem = domain_id_problem()
    if problem is not None:
        return _error(problem, 2)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    argv = sys.argv[1:] if argv is None else list(argv)
    args = _parse_args(remove_ros_args(["mcap_record"] + argv)[1:])
    check = bag_directory_problem if args.split else output_problem
    problem = check(args.output, overwrite=args.overwrite)
    if problem is not None:
        return _error(problem, 2)

    rclpy.init(args=["mcap_record"] + argv, signal_handler_options=SignalHandlerOptions.NO)
    recorder = None
    code = 0
    try:
        try:
            recorder = RecorderNode(
                args.output,
                topics=args.topics,
                all_topics=args.all,
                regex=args.regex,
                exclude=args.exclude,
                compression=args.compression,
                chunk_size=args.chunk_size,
                writer_options={
                    k: v
                    for k, v in args.writer_options.items()
                    if k in ("compression_level", "crcs")
                },
                overwrite=args.overwrite,
                max_bag_size=args.max_bag_size,
                max_bag_duration=args.max_bag_duration,
                qos_overrides=args.qos_overrides,
                include_hidden_topics=args.include_hidden_topics,
                progress_topic=args.report_progress,
                stall_timeout_s=args.stall_timeout or None,
            )
        except BagWriteError as exc:
            return _error(exc, 1)
        executor = SingleThreadedExecutor()
        executor.add_node(recorder)
        # --duration: wall-clock time from here (the file is open, discovery has run once)
        started = time.monotonic()
        deadline = None if args.duration is None else started + args.duration
        timed_out = False
        try:
            while not stop.count and recorder.write_error is None:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    timed_out = True
                    break
                wait = 0.1 if deadline is None else min(0.1, deadline - now)
                executor.spin_once(timeout_sec=wait)
            if recorder.write_error is None and not timed_out:
                if stop.count:  # bounded: grace window, then a drain deadline
                    t0 = stop.first_at
                    drain(
                        executor,
                        recorder,
                        idle_s=0.1,
                        limit_s=max(0.0, t0 + STOP_GRACE_S - time.monotonic()),
                        stop=lambda: stop.count > 1,
                    )
                else:
                    drain(executor, recorder, idle_s=0.3, limit_s=2.0)
        except BagWriteError:
            pass  # a write raised inside a callback: reported below
        recorder.stop_taking()
        timeout = None
        if stop.count:
            timeout = max(0.0, stop.first_at + STOP_FINALISE_S - time.monotonic())
        elif timed_out:  # end on time: what the writer has not taken by then is counted
            timeout = DURATION_FINALISE_S
        try:
            recorder.close(timeout_s=timeout, abort=lambda: stop.count > 1)
        except BagWriteError as exc:
            code = _error(
                f"{exc} (the file keeps the chunks completed before the error)",
                1,
            )
        if code == 0 and stop.first_at is not None:
            print(
                f"mcap_record: {stop.first_name}: file finalised "
                f"{time.monotonic() - stop.first_at:.3f} s after the stop request",
                flush=True,
            )
        elif code == 0 and timed_out:
            print(
                f"mcap_record: --duration {args.duration:g} s: file finalised "
                f"{time.monotonic() - deadline:.3f} s after it "
                f"({time.monotonic() - started:.3f} s of recording)",
                flush=True,
            )
        print(recorder.summary(), flush=True)
        if code == 0 and args.fail_on_loss:
            code = _loss_status(recorder)
    finally:
        if recorder is not None:
            try:
                recorder.destroy_node()
            except BagWriteError:
                pass  # already reported
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())

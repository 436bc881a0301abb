"""``run_scenario``: run a scenario's node graph in one process, record it, report.

Usage:
    run_scenario --list
    run_scenario NAME [--duration S] [--seed N] [--realtime] [--out FILE.mcap]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mems_scenarios import SCENARIOS, load
from mems_scenarios.base import ScenarioError, ScenarioOptions
from mems_sim.params import ParameterError
from mems_sim.ros.end_of_stream import is_end_of_stream_topic
from mems_sim.ros.env import apply_defaults


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="run_scenario", description=__doc__.splitlines()[0])
    p.add_argument("name", nargs="?", help="scenario name (see --list)")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="simulated duration in seconds (default: the scenario's)",
    )
    p.add_argument("--seed", type=int, default=0, metavar="N", help="run seed (default 0)")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="pace the graph to the wall clock (default: as fast as possible)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="FILE.mcap",
        help="MCAP output (default runs/<scenario>-<seed>.mcap)",
    )
    p.add_argument(
        "--domain-id",
        type=int,
        default=None,
        metavar="ID",
        help="ROS domain of the graph (default: $ROS_DOMAIN_ID, else a free one of 0..101 "
        "leased for the run); a domain another run holds, or where another graph publishes "
        "this scenario's topics, is refused",
    )
    # fault injection for the tests of the loss reporting: TOPIC:N hands only the first N
    # messages of TOPIC to the middleware (the run must then fail naming TOPIC)
    p.add_argument("--cut", action="append", default=[], help=argparse.SUPPRESS)
    p.add_argument("--no-plots", action="store_true", help="do not write PNG figures")
    p.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="force the progress bar (default: on a terminal)",
    )
    p.add_argument("--no-progress", dest="progress", action="store_false")
    return p


def _fail(message: str) -> int:
    print(f"run_scenario: error: {message}", file=sys.stderr)
    return 2


def validate(args) -> str | None:
    """Return an error message for invalid options, None if they are fine."""
    if args.name not in SCENARIOS:
        return (
            f"unknown scenario {args.name!r}: available are {', '.join(SCENARIOS)} "
            f"(run_scenario --list)"
        )
    if args.duration is not None and not (args.duration > 0 and args.duration < 1e9):
        return f"--duration = {args.duration!r} is invalid: allowed (0, 1e9) s"
    if args.seed < 0 or args.seed > 2**62:
        return f"--seed = {args.seed} is invalid: allowed [0, 2^62]"
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        return f"--domain-id = {args.domain_id} is invalid: allowed [0, 232]"
    for cut in args.cut:
        topic, _, n = cut.rpartition(":")
        if not topic.startswith("/") or not n.isdigit():
            return f"--cut = {cut!r} is invalid: TOPIC:MESSAGES"
    if args.out is not None and args.out.suffix != ".mcap":
        return f"--out = {str(args.out)!r} is invalid: the file name must end in .mcap"
    if args.out is not None and args.out.parent.is_dir():
        from mems_sim.bag.writer import output_problem

        problem = output_problem(str(args.out), overwrite=True)
        if problem is not None:
            return f"--out: {problem}"
    return None


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``run_scenario``."""
    args = _parser().parse_args(argv)
    if args.list:
        for name in SCENARIOS:
            module = load(name)
            print(
                f"{name:20s} {module.DESCRIPTION} (default duration "
                f"{module.DEFAULT_DURATION_S:g} s)"
            )
        return 0
    if args.name is None:
        return _fail("no scenario given (run_scenario --list shows them)")
    error = validate(args)
    if error:
        return _fail(error)
    apply_defaults()
    module = load(args.name)
    options = ScenarioOptions(
        duration_s=args.duration,
        seed=args.seed,
        realtime=args.realtime,
        out=args.out,
        domain_id=args.domain_id,
        progress=args.progress,
        plots=not args.no_plots,
    )
    if args.cut:
        options.extra["cut"] = {c.rpartition(":")[0]: int(c.rpartition(":")[2]) for c in args.cut}
    start = time.monotonic()
    try:
        result = module.run(options)
    except (ScenarioError, ParameterError) as exc:
        return _fail(str(exc))
    except OSError as exc:  # e.g. the output directory cannot be created, the disk is full
        return _fail(" ".join(str(exc).split()))
    except KeyboardInterrupt:
        return _fail("interrupted; the MCAP file was finalised")
    wall = time.monotonic() - start
    print(
        f"\nscenario {args.name}: seed {args.seed}, {result['duration_s']:g} s simulated in "
        f"{wall:.1f} s wall ({'real time' if args.realtime else 'as fast as possible'})\n"
    )
    print(result["table"])
    rec = result.get("recorder") or {}
    counts = {t: n for t, n in (rec.get("counts") or {}).items() if not is_end_of_stream_topic(t)}
    print(
        f"\nrecorded {result['mcap']}: " + ", ".join(f"{t} {n}" for t, n in sorted(counts.items()))
    )
    gaps = {t: g for t, g in (rec.get("gaps") or {}).items() if g}
    print(
        "frame-index gaps: " + (", ".join(f"{t} {g}" for t, g in gaps.items()) if gaps else "none")
    )
    if result.get("figure"):
        print(f"figure: {result['figure']}")
    if rec.get("losses"):  # a loss the run did not stop for (e.g. of an estimator's topic)
        print(
            "run_scenario: error: lost data, the recording is incomplete: "
            + "; ".join(rec["losses"]),
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

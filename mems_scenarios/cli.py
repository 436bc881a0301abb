"""``run_scenario``: run a scenario's node graph in one process, record it, report.

Usage:
    run_scenario --list
    run_scenario NAME --analyse FILE.mcap [--json]
    run_scenario NAME [--duration S] [--seed N] [--device-seed N] [--temperature C]
                 [--set NODE.PARAM=VALUE ...] [--params-file FILE.yaml] [--realtime]
                 [--out FILE.mcap [--overwrite]] [--json]

Outputs: ``--out FILE.mcap`` and the files a run writes beside it (figures and results
named ``<stem>-seed<N>...``, :func:`mems_scenarios.base.output_path`) are checked before
the run: a symbolic link is refused (never followed), an existing file unless
``--overwrite``. Without ``--out`` the outputs go to ``runs/`` and replace the previous
run's only when this run succeeded (:mod:`mems_scenarios.staged_outputs`).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

from mems_scenarios import SCENARIOS, load
from mems_scenarios.base import ScenarioError, ScenarioOptions, graphs_closed
from mems_scenarios.contract import RUN_INFO_TOPIC, AnalysisError
from mems_scenarios.delivery import THROUGHPUT
from mems_sim.cli_values import quiet_on_broken_pipe
from mems_sim.params import HARDWARE_PROFILES, ParameterError
from mems_sim.ros.end_of_stream import is_end_of_stream_topic
from mems_sim.ros.env import MAX_DOMAIN_ID, apply_defaults, domain_id_problem
from mems_sim.ros.params_file import Override, ParamsFileError, load_params_file, parse_set
from mems_sim.ros.stop import StopRequest, StopSignal
from mems_sim.table import fit_lines


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
        "--device-seed",
        type=int,
        default=None,
        metavar="N",
        help="device seed of every emulator node: one device of the batch, each parameter "
        "with a manufacturing spread drawn from N (default: the nominal devices); separate "
        "from the run seed (the noise); a --set of device_seed wins",
    )
    p.add_argument(
        "--hardware",
        choices=HARDWARE_PROFILES,
        default=None,
        help="hardware profile of every emulator node: 'ideal' (the idealised devices of "
        "the references) or 'realistic' (the real-part terms at their datasheet or paper "
        "level; docs/hardware.md); default: the nodes' own ('ideal'); a --set of hardware wins",
    )
    p.add_argument(
        "--temperature",
        type=float,
        default=None,
        metavar="C",
        help="temperature of every emulator node [degC]: each parameter with a temperature "
        "coefficient moves from the device's reference temperature (default: the reference, "
        "e.g. 25 C); a --set of temperature_c wins",
    )
    p.add_argument(
        "--set",
        dest="set_params",
        action="append",
        default=[],
        metavar="NODE.PARAM=VALUE",
        help="set a parameter of one of the scenario's nodes (NODE: its name, e.g. imu, in any "
        "namespace, or its fully qualified name, e.g. /imu/imu; VALUE: a YAML scalar or list); "
        "repeatable, applied after --params-file; overrides the scenario's own value",
    )
    p.add_argument(
        "--faults",
        action="append",
        default=[],
        metavar="[NODE=]FILE",
        help="a fault schedule (YAML, docs/faults.md) for the scenario's emulators that take "
        "one (with NODE=: those whose name matches NODE); repeatable; the recording holds "
        "each emulator's 'faults' topic",
    )
    p.add_argument(
        "--params-file",
        action="append",
        default=[],
        metavar="FILE.yaml",
        help="ROS 2 parameter file (node names, /** and namespaced names with "
        "ros__parameters, as --ros-args --params-file reads it) applied to the scenario's nodes",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="pace the graph to the wall clock (default: as fast as possible)",
    )
    p.add_argument(
        "--live-view",
        type=int,
        nargs="?",
        const=8765,
        default=None,
        metavar="PORT",
        help="show the run live in Foxglove: a WebSocket server on ws://127.0.0.1:PORT "
        "(default 8765; 0: a free port, printed); at most 30 messages/s per topic",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="FILE.mcap",
        help="MCAP output (default runs/<scenario>-<seed>.mcap, replaced only by a run that "
        "succeeded; a failed run's outputs go to runs/incomplete/)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing --out file and the files beside it that the run writes "
        "(a symbolic link is refused either way)",
    )
    p.add_argument(
        "--domain-id",
        type=int,
        default=None,
        metavar="ID",
        help="ROS domain of the graph (default: $ROS_DOMAIN_ID, else a free one of 0..101, "
        "or of $MEMS_FREE_DOMAINS, leased for the run); a domain another run holds, or where another graph publishes "
        "this scenario's topics, is refused",
    )
    # fault injection for the tests of the loss reporting: TOPIC:N hands only the first N
    # messages of TOPIC to the middleware (the run must then fail naming TOPIC)
    p.add_argument("--cut", action="append", default=[], help=argparse.SUPPRESS)
    p.add_argument(
        "--analyse",
        type=Path,
        default=None,
        metavar="FILE.mcap",
        help="run nothing: compute the scenario's figures from an existing recording (a run, "
        "a replay, a process graph's or your own recording with the scenario's topics); "
        "figures it cannot compute are listed, one line each, and the exit status is then 2",
    )
    p.add_argument(
        "--write-launch",
        type=Path,
        default=None,
        metavar="FILE.launch.yaml",
        help="run nothing: write the scenario's graph, with these options, as a launch file "
        "for run_graph (emulators paced at --realtime-factor that start when their consumers "
        "and the recorder are matched and exit when acknowledged; the run record for "
        "--analyse included)",
    )
    p.add_argument(
        "--realtime-factor",
        type=float,
        default=1.0,
        metavar="F",
        help="with --write-launch: simulated seconds per wall-clock second (default 1)",
    )
    p.add_argument("--no-plots", action="store_true", help="do not write PNG figures")
    p.add_argument(
        "--json",
        action="store_true",
        help="print the scenario's figures as one JSON object on stdout: {schema_version, "
        "scenario, figures: [{name, value, unit, target, pass, source, role}], unavailable, "
        "oracle_only} "
        "(the table and the other lines go to stderr); a missed target does not change the "
        "exit status",
    )
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
    if args.device_seed is not None and not 0 <= args.device_seed <= 2**62:
        return (
            f"--device-seed = {args.device_seed} is invalid: allowed [0, 2^62] "
            "(leave it out for the nominal devices)"
        )
    if args.temperature is not None and not -60.0 <= args.temperature <= 150.0:
        return f"--temperature = {args.temperature!r} is invalid: allowed [-60, 150] C"
    if args.domain_id is not None and not 0 <= args.domain_id <= MAX_DOMAIN_ID:
        return f"--domain-id = {args.domain_id} is invalid: allowed [0, {MAX_DOMAIN_ID}]"
    if args.live_view is not None and not 0 <= args.live_view <= 65535:
        return f"--live-view = {args.live_view} is invalid: allowed [0, 65535] (a TCP port)"
    for cut in args.cut:
        topic, _, n = cut.rpartition(":")
        if not topic.startswith("/") or not n.isdigit():
            return f"--cut = {cut!r} is invalid: TOPIC:MESSAGES"
    try:
        args.overrides = overrides(args)
        if args.faults:
            args.overrides += faults_of(args)
    except ParamsFileError as exc:
        return str(exc)
    if args.out is not None and args.out.suffix != ".mcap":
        return f"--out = {str(args.out)!r} is invalid: the file name must end in .mcap"
    if args.out is not None and args.out.parent.is_dir():
        problem = out_problem(args.out, args.seed, args.overwrite)
        if problem is not None:
            return f"--out: {problem}"
    return None


def out_problem(out: Path, seed: int, overwrite: bool) -> str | None:
    """Why ``out`` or a file the run writes beside it cannot be written (one line), or None:
    :func:`~mems_sim.bag.output_paths.output_problem` of each."""
    from mems_scenarios.base import outputs_beside
    from mems_sim.bag.output_paths import output_problem

    problem = output_problem(str(out), overwrite=overwrite)
    for path in outputs_beside(out, seed):
        problem = problem or output_problem(str(path), overwrite=overwrite, probe=False)
    return problem


def overrides(args) -> list[Override]:
    """The node parameters of ``--params-file`` (in file order), then of ``--set``."""
    out = []
    for path in args.params_file:
        out += load_params_file(path)
    return out + [parse_set(text) for text in args.set_params]


def faults_of(args) -> list[Override]:
    """The ``fault_schedule`` overrides of ``--faults`` on the scenario's graph
    (:func:`~mems_scenarios.faults_option.fault_overrides`)."""
    from mems_scenarios.faults_option import fault_overrides

    module = load(args.name)
    if not hasattr(module, "graph"):
        raise ParamsFileError(
            f"--faults: scenario {args.name} has no graph as data yet: use --set "
            "NODE.fault_schedule=FILE"
        )
    return fault_overrides(graph_of(module, args)[0], args.faults)


def graph_of(module, args, out: Path | None = None):
    """``(GraphSpec, ScenarioOptions, duration [s])`` of the run ``args`` ask for, without
    running it (the scenario's ``graph``); ``out``: the MCAP file the files a graph names
    are placed beside (None: the scenario's default)."""
    duration = module.DEFAULT_DURATION_S if args.duration is None else args.duration
    options = ScenarioOptions(
        out=out,
        duration_s=duration,
        seed=args.seed,
        overrides=args.overrides,
        device_seed=args.device_seed,
        temperature_c=args.temperature,
        hardware=args.hardware,
    )
    return module.graph(options, duration), options, duration


def device_text(args) -> str:
    """The devices of the run, e.g. ``device seed 3 at 40 C, realistic hardware`` or
    ``nominal devices at their reference temperatures`` (the profile when given)."""
    who = "nominal devices" if args.device_seed is None else f"device seed {args.device_seed}"
    at = (
        "at their reference temperatures"
        if args.temperature is None
        else f"at {args.temperature:g} C"
    )
    profile = "" if args.hardware is None else f", {args.hardware} hardware"
    return f"{who} {at}{profile}"


def applied_text(applied: dict) -> str:
    """One line per node: the overrides the run applied, e.g.
    ``/imu/imu: seed=3 (--set)``."""
    by_node: dict[str, list[str]] = {}
    for (node, name), (value, origin) in applied.items():
        by_node.setdefault(node, []).append(f"{name}={value!r} ({origin})")
    return "\n".join(f"  {node}: {', '.join(items)}" for node, items in sorted(by_node.items()))


@quiet_on_broken_pipe
def main(argv: list[str] | None = None) -> int:
    """Entry point of ``run_scenario``. Exit status: 0 ran, 1 lost data, 2 bad input,
    128 + N stopped by signal N (SIGINT, SIGTERM, SIGHUP; the recording is finalised); a
    missed target is reported in the table (and ``--json``), it does not change the status."""
    args = _parser().parse_args(argv)
    args.result = None
    if not args.json or args.list:
        return _main(args)
    import contextlib

    from mems_scenarios.figures import result_json

    with contextlib.redirect_stdout(sys.stderr):  # stdout carries the JSON only
        status = _main(args)
    if args.result is not None:
        r = args.result.get("result")
        print(
            result_json(
                args.name,
                args.result["figures"],
                r.unavailable if r is not None else (),
                r.oracle_only if r is not None else (),
            )
        )
    return status


def _main(args) -> int:
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
    if args.analyse is not None:
        return analyse_main(args)
    error = validate(args)
    if error:
        return _fail(error)
    if args.write_launch is not None:
        return write_launch_main(args)
    apply_defaults()
    problem = None if args.domain_id is not None else domain_id_problem()
    if problem is not None:
        return _fail(problem)
    module = load(args.name)
    options = ScenarioOptions(
        duration_s=args.duration,
        seed=args.seed,
        realtime=args.realtime,
        out=args.out,
        domain_id=args.domain_id,
        progress=args.progress,
        plots=not args.no_plots,
        overrides=args.overrides,
        device_seed=args.device_seed,
        temperature_c=args.temperature,
        hardware=args.hardware,
    )
    if args.cut:
        options.cut = {c.rpartition(":")[0]: int(c.rpartition(":")[2]) for c in args.cut}
    if args.live_view is not None:
        options.live_view = args.live_view
    staged = None
    if args.out is None:  # runs/: replaced only when the run succeeded (module doc)
        from mems_scenarios.staged_outputs import StagedOutputs

        try:
            staged = StagedOutputs(Path("runs"))
        except OSError as exc:
            return _fail(f"runs: {exc.strerror or exc}")
        options.out = staged.path(f"{args.name}-{args.seed}.mcap")
    try:
        return _run(args, module, options, staged)
    finally:
        if staged is not None:
            staged.discard()


def _run(args, module, options: ScenarioOptions, staged) -> int:
    """Run the scenario, publish its staged outputs (if any) and report."""
    THROUGHPUT.reset()
    start = time.monotonic()
    try:
        # SIGTERM and SIGHUP (a closed terminal) stop the run as SIGINT does: the graph
        # unwinds and the recording is finalised
        with StopRequest(raising=True) as stop, graphs_closed():
            try:
                result = args.result = module.run(options)
            except RuntimeError:
                # a stop signal raised while rclpy's C++ code called back into Python (a
                # take converting its message) surfaces as pybind's "Unable to convert call
                # argument"; the graph unwound all the same: it is the stop request
                if not stop:
                    raise
                raise StopSignal(stop.signals[0]) from None
    except (ScenarioError, ParameterError) as exc:
        return _failed_run(staged, _fail(str(exc)))
    except OSError as exc:  # e.g. the output directory cannot be created, the disk is full
        return _failed_run(staged, _fail(" ".join(str(exc).split())))
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        print(
            f"run_scenario: error: interrupted by {signal.Signals(signum).name}; the MCAP file "
            "was finalised",
            file=sys.stderr,
        )
        return _failed_run(staged, 128 + signum)
    rec = result.get("recorder") or {}
    try:
        _publish(staged, result, succeeded=not rec.get("losses"))
    except OSError as exc:
        return _fail(f"cannot move the outputs into runs/: {' '.join(str(exc).split())}")
    wall = time.monotonic() - start
    result["device_seed"], result["temperature_c"] = args.device_seed, args.temperature
    result["hardware"] = args.hardware
    # two lines: the run's settings, and its wall time (host-dependent, one "wall" line)
    print("\n" + fit_lines(f"scenario {args.name}: seed {args.seed}, {device_text(args)},"))
    print(
        f"  {result['duration_s']:g} s simulated in {wall:.1f} s wall "
        f"({'real time' if args.realtime else 'as fast as possible'})"
    )
    throughput = THROUGHPUT.summary()  # first frame to last: start-up excluded
    if throughput:
        print(throughput)
    print()
    if options.applied:
        print("parameters set (they override the scenario's values):")
        print(applied_text(options.applied) + "\n")  # the user's own values, as given
    print(fit_lines(result["table"]))
    counts = {
        t: n
        for t, n in (rec.get("counts") or {}).items()
        if not is_end_of_stream_topic(t) and t != RUN_INFO_TOPIC
    }
    print(
        "\n"
        + fit_lines(
            f"recorded {result['mcap']}: "
            + ", ".join(f"{t} {n}" for t, n in sorted(counts.items()))
        )
    )
    gaps = {t: g for t, g in (rec.get("gaps") or {}).items() if g}
    print(
        fit_lines(
            "frame-index gaps: "
            + (", ".join(f"{t} {g}" for t, g in gaps.items()) if gaps else "none")
        )
    )
    for text in rec.get("device_gaps") or ():  # scheduled dropped samples: not loss
        print(fit_lines(f"device gap: {text}"))
    if result.get("figure"):
        print(fit_lines(f"figure: {result['figure']}"))
    if rec.get("losses"):  # a loss the run did not stop for (e.g. of an estimator's topic)
        print(
            "run_scenario: error: lost data, the recording is incomplete: "
            + "; ".join(rec["losses"]),
            file=sys.stderr,
        )
        return 1
    return 0


def _relocated(value, staging: Path, dest: Path):
    """``value`` (a path, a text naming paths, or a tuple or list of them) with the staging
    directory ``staging`` replaced by ``dest``."""
    if isinstance(value, (tuple, list)):
        return type(value)(_relocated(v, staging, dest) for v in value)
    if isinstance(value, (str, Path)):
        text = str(value).replace(f"{staging}{os.sep}", f"{dest}{os.sep}")
        return Path(text) if isinstance(value, Path) else text
    return value


def _failed_run(staged, status: int) -> int:
    """``status`` of a run that failed; what it wrote of its default outputs (if anything)
    goes to runs/incomplete/, the previous outputs stay."""
    try:
        _publish(staged, None, succeeded=False)
    except OSError as exc:
        print(f"run_scenario: error: {exc}", file=sys.stderr)
    return status


def _publish(staged, result: dict | None, succeeded: bool) -> None:
    """Move the staged default outputs into runs/ (``succeeded``) or runs/incomplete/, and
    point ``result``'s paths at them (:mod:`mems_scenarios.staged_outputs`)."""
    if staged is None or not any(staged.staging.iterdir()):
        return
    staged.publish(succeeded)
    if result is not None:
        for key in ("mcap", "figure", "figure_paths"):
            result[key] = _relocated(result.get(key), staged.staging, staged.destination(succeeded))
    if not succeeded:
        print(
            f"run_scenario: this run's outputs are in {staged.destination(False)}/ "
            f"({staged.final_dir}/ keeps the previous run's)"
        )


def write_launch_main(args) -> int:
    """``run_scenario NAME --write-launch FILE``: the scenario's graph as a launch file for
    a runner of processes (:meth:`~mems_scenarios.contract.GraphSpec.as_processes`)."""
    import math
    from dataclasses import replace

    from mems_scenarios.base import options_record
    from mems_scenarios.contract import full_parameters, given_parameters, run_info
    from mems_scenarios.faults_option import fault_topics

    module = load(args.name)
    if not hasattr(module, "graph"):
        return _fail(f"scenario {args.name} has no graph as data yet")
    if not (math.isfinite(args.realtime_factor) and 0 < args.realtime_factor <= 1000):
        return _fail(f"--realtime-factor = {args.realtime_factor!r} is invalid: allowed (0, 1000]")
    if not args.write_launch.name.endswith(".yaml"):
        return _fail(f"--write-launch = {str(args.write_launch)!r}: the name must end in .yaml")
    from mems_sim.bag.output_paths import BagWriteError, output_problem, write_output

    record_file = args.write_launch.with_name(
        args.write_launch.name.removesuffix(".yaml").removesuffix(".launch") + ".run_record.json"
    )
    for path in (args.write_launch, record_file):  # a link, an existing file: refused
        problem = output_problem(str(path), overwrite=args.overwrite)
        if problem is not None:
            return _fail(f"--write-launch: {problem}")
    # the files the graph names (an identified model) go beside the launch file
    beside = args.write_launch.with_name(
        args.write_launch.name.removesuffix(".yaml").removesuffix(".launch") + ".mcap"
    )
    spec, options, duration = graph_of(module, args, beside)
    extra = {}
    if hasattr(module, "prepare"):  # made before the graph runs; their record kept
        try:
            extra = module.prepare(options) or {}
        except ScenarioError as exc:
            return _fail(str(exc))
    variation = dict(
        device_seed=args.device_seed, temperature_c=args.temperature, hardware=args.hardware
    )
    try:
        nodes = {
            e.fqn: dict(
                executable=e.executable,
                parameters=full_parameters(e, args.overrides, variation),
            )
            for e in spec.nodes
        }
    except ParameterError as exc:
        return _fail(str(exc))
    record = run_info(spec.scenario, options_record(options), nodes, duration_s=duration, **extra)
    given = tuple(
        replace(e, parameters=given_parameters(e, args.overrides, variation)) for e in spec.nodes
    )
    spec = replace(spec, nodes=given, recorded=spec.recorded + fault_topics(given))
    text = spec.as_processes(args.realtime_factor, str(record_file.resolve())).to_launch_yaml()
    try:
        for path, content in ((args.write_launch, text), (record_file, record + "\n")):
            write_output(path, lambda tmp, c=content: Path(tmp).write_text(c), args.overwrite)
    except BagWriteError as exc:
        return _fail(f"--write-launch: {exc}")
    print(f"wrote {args.write_launch} ({len(spec.nodes)} nodes) and its run record {record_file}")
    return 0


def analyse_main(args) -> int:
    """``run_scenario NAME --analyse BAG``: the scenario's figures from the recording alone
    (its ``analyse``); exit 2 with one line per figure it could not compute."""
    if args.name not in SCENARIOS:
        return _fail(
            f"unknown scenario {args.name!r}: available are {', '.join(SCENARIOS)} "
            f"(run_scenario --list)"
        )
    module = load(args.name)
    if not hasattr(module, "analyse"):
        return _fail(f"scenario {args.name} has no analysis of a recording yet")
    from mems_sim.bag.reader import BagReadError

    if not args.analyse.exists():
        return _fail(f"--analyse: {args.analyse}: no such file or bag directory")
    png = None
    if not args.no_plots:
        from mems_scenarios.base import output_path

        png = output_path(args.analyse.with_name(args.analyse.stem + "-analysis.mcap"), 0, ".png")
    try:
        result = module.analyse(args.analyse, png)
    except (AnalysisError, BagReadError, ScenarioError) as exc:
        return _fail(" ".join(str(exc).split()))
    args.result = {"figures": result.figures, "result": result}
    print(f"scenario {args.name}: analysis of {args.analyse}\n")
    if result.table:
        print(fit_lines(result.table))
    for path in result.plots:
        print(fit_lines(f"figure: {path}"))
    for what in result.oracle_only:
        print(f"oracle only (needs the simulation): {what}")
    for what, why in result.unavailable:
        print(f"run_scenario: not computed: {what}: {why}", file=sys.stderr)
    return 2 if result.unavailable else 0


if __name__ == "__main__":
    raise SystemExit(main())

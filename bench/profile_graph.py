"""Where a graph's wall time goes (docs/profiles.md): kernels, serialisation, executor,
recorder, per-frame Python.

Run:  .venv/bin/python bench/profile_graph.py scenario NAME [--duration S] [--perf]
      .venv/bin/python bench/profile_graph.py stage-processes [--compression C|PRESET] [--perf]

``scenario NAME``: the scenario in fast mode (``run_scenario NAME --no-plots``) three
times in one process: twice without a profiler for the wall time per phase (first to
last frame, drain, figures from the MCAP), cold (numba kernels loaded from their cache
at the first frame, as ``run_scenario`` runs) and warm, then with cProfile on the
first-to-last-frame phase only (``drive_fast``), its time split into categories
(below). ``--perf`` adds a ``perf record`` of the warm un-profiled first-to-last-frame
phase, split by shared object (libpython, Fast DDS, numba's JIT code, zstd, libc,
kernel); ``--save FILE`` keeps the cProfile statistics.

``stage-processes``: the stage calibration graph as four processes
(``bench_stage_ekf.py --graph-processes``, 6.6 s sweep) with every process under cProfile
through the ``sitecustomize`` hook in bench/profile_hook/, its time split the same way per process;
``--perf`` records the whole machine meanwhile and splits each process by shared object.

Categories of the profiled time (by the function that spent it; a built-in is charged to
its caller's category unless named below): ``kernels`` (numba-compiled functions of the
project), ``middleware`` (rclpy's publish, take, (de)serialise: Fast DDS and the C type
support), ``messages`` (rosidl message classes and their field setters, the frame
conversions of mems_sim/ros/frames.py), ``executor`` (rclpy's Python executor, tasks,
callback groups, wait-set bookkeeping), ``idle`` (waiting in the wait set or for
acknowledgements),
``recorder`` (mems_sim/bag, mcap, compression, CRC), ``numpy`` (numpy outside the
kernels), ``project Python`` (the nodes' and the runner's own Python per frame),
``other``. cProfile adds overhead per Python call, so the Python categories read high
(about 1.5-2x); the un-profiled phase times and perf's split are the calibration.
"""

from __future__ import annotations

import argparse
import glob
import importlib
import os
import pkgutil
import pstats
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

CATEGORIES = (
    "kernels",
    "middleware",
    "messages",
    "executor",
    "idle",
    "recorder",
    "numpy",
    "project Python",
    "other",
)


def numba_kernels() -> set[tuple[str, int, str]]:
    """(file, first line, name) of every numba dispatcher of the project's packages."""
    from numba.core.dispatcher import Dispatcher

    keys = set()
    for pkg in ("mems_sim", "mems_estimation"):
        root = importlib.import_module(pkg)
        for info in pkgutil.walk_packages(root.__path__, pkg + "."):
            if ".nodes" in info.name or ".tools" in info.name or ".bag" in info.name:
                continue
            try:
                mod = importlib.import_module(info.name)
            except Exception:  # a module that needs ROS or an extra
                continue
            for obj in vars(mod).values():
                if isinstance(obj, Dispatcher):
                    code = obj.py_func.__code__
                    keys.add((code.co_filename, code.co_firstlineno, code.co_name))
    return keys


def _by_file(key, kernels) -> str | None:
    path, _, name = key
    if key in kernels:
        return "kernels"
    if path == "~":
        return None
    if "/mems_msgs/msg/" in path or "/msg/_" in path or path.endswith("ros/frames.py"):
        return "messages"
    if "/rclpy/" in path:
        return "executor"
    if "/mems_sim/bag/" in path or "/mcap/" in path or "/zstandard/" in path:
        return "recorder"
    if "/numpy/" in path:
        return "numpy"
    if str(ROOT) in path:
        return "project Python"
    return "other"


def _builtin(name: str) -> str | None:
    if ("WaitSet" in name and "wait" in name) or name.endswith(
        ("_rclpy_pybind11.wait>", "wait_for_all_acked>")
    ):
        return "idle"
    if "rclpy_pybind11" in name and any(
        w in name for w in ("publish", "take", "serialize", "deserialize")
    ):
        return "middleware"
    if "zstd" in name.lower() or "crc32" in name or "lz4" in name:
        return "recorder"
    return None


def categorise(stats: pstats.Stats, kernels) -> dict[str, float]:
    """Seconds of tottime per category (module doc)."""
    raw = stats.stats
    memo: dict = {}

    def cat(key, depth=0) -> str:
        if key in memo:
            return memo[key]
        c = _by_file(key, kernels)
        if c is None:
            c = _builtin(key[2])
        if c is None:
            callers = raw.get(key, (0, 0, 0, 0, {}))[4]
            if callers and depth < 8:
                top = max(callers, key=lambda k: callers[k][3])
                c = cat(top, depth + 1)
            else:
                c = "other"
        memo[key] = c
        return c

    out = defaultdict(float)
    for key, (_, _, tt, _, _) in raw.items():
        out[cat(key)] += tt
    return dict(out)


def print_split(title: str, split: dict[str, float], wall: float | None = None) -> None:
    total = sum(split.values())
    busy = total - split.get("idle", 0.0)
    print(
        f"{title}: {total:.2f} s profiled ({busy:.2f} s busy)"
        + (f", {wall:.2f} s wall un-profiled" if wall else "")
    )
    for c in CATEGORIES:
        if split.get(c):
            print(f"  {c:15s} {split[c]:7.2f} s  {100 * split[c] / total:5.1f} %")


def top_functions(stats: pstats.Stats, n: int = 12) -> None:
    rows = sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:n]
    for (path, line, name), (_, nc, tt, ct, _) in rows:
        where = name if path == "~" else f"{Path(path).name}:{line}({name})"
        print(f"    {tt:7.2f} s tottime {ct:7.2f} s cum {nc:8d} calls  {where}")


# ---------------------------------------------------------------- perf by shared object


def perf_record(out: str, pid: int | None = None) -> subprocess.Popen | None:
    """``perf record`` of the whole machine (or ``pid``) until stopped; None without perf."""
    if not any(Path(d, "perf").exists() for d in os.environ.get("PATH", "").split(":")):
        return None
    target = ["-p", str(pid)] if pid else ["-a"]
    return subprocess.Popen(
        ["perf", "record", "-q", "-F", "499", "-o", out, *target],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def perf_split(data: str, pids: dict[int, str] | None = None) -> None:
    """Samples per shared object (per process of ``pids``), grouped."""
    res = subprocess.run(
        ["perf", "report", "-i", data, "--stdio", "-q", "--sort", "pid,dso", "-g", "none"],
        capture_output=True,
        text=True,
    )
    groups: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    for line in res.stdout.splitlines():
        parts = line.split()
        if len(parts) < 3 or not parts[0].endswith("%"):
            continue
        pct = float(parts[0].rstrip("%"))
        pid_s = parts[1].split(":")[0]
        dso = parts[-1]
        who = (pids or {}).get(int(pid_s)) if pid_s.isdigit() else None
        if pids is not None and who is None:
            who = "others"
        who = who or "process"
        groups[who][_dso_group(dso)] += pct
    for who, g in sorted(groups.items()):
        tot = sum(g.values())
        text = ", ".join(f"{k} {v:.1f}" for k, v in sorted(g.items(), key=lambda kv: -kv[1]))
        print(f"  perf {who:12s} {tot:5.1f} % of samples: {text}")


def _dso_group(dso: str) -> str:
    d = dso.lower()
    if "python" in d:
        return "libpython"
    if "fastdds" in d or "fastrtps" in d or "fastcdr" in d:
        return "fastdds"
    if "rcl" in d or "rmw" in d or "rosidl" in d or "rcutils" in d or "_msgs" in d:
        return "rcl/rmw/typesupport"
    if "zstd" in d or "zstandard" in d or "lz4" in d:
        return "compression"
    if "numpy" in d or "openblas" in d or "_multiarray" in d:
        return "numpy"
    if "libc" in d or "libstdc" in d or "libm" in d or "ld-linux" in d:
        return "libc/libstdc++"
    if "kernel" in d or "vmlinux" in d:
        return "kernel"
    if "unknown" in d or "perf-" in d or "jitted" in d or d.strip("[]").isdigit():
        return "JIT (numba)"
    return "other:" + Path(dso.strip("[]")).name


# ---------------------------------------------------------------- scenario in one process


def run_scenario_phases(
    name: str, duration: float | None, profile: bool, out: str, perf_data: str | None = None
) -> dict:
    """Run ``name`` in fast mode (no plots); wall time per phase, and with ``profile`` a
    cProfile of the first-to-last-frame phase (``perf_data``: a perf record of it)."""
    import cProfile

    from mems_scenarios import (  # the skeleton, profiled by wrapping its phases
        bag_frames,
        base,
        delivery,
        load,
    )
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    module = load(name)
    phases = defaultdict(float)
    prof = cProfile.Profile() if profile else None
    orig_drive, orig_finish, orig_frames = (
        delivery.drive_fast,
        delivery.finish_delivery,
        bag_frames.topic_frames,
    )

    def drive_fast(*a, **kw):
        perf = perf_record(perf_data, os.getpid()) if perf_data else None
        t0 = time.perf_counter()
        if prof:
            prof.enable()
        try:
            return orig_drive(*a, **kw)
        finally:
            if prof:
                prof.disable()
            if perf is not None:
                perf.send_signal(2)
                perf.wait()
            phases["first to last frame (drive_fast)"] += time.perf_counter() - t0

    def finish_delivery(*a, **kw):
        t0 = time.perf_counter()
        try:
            return orig_finish(*a, **kw)
        finally:
            phases["drain after the last frame"] += time.perf_counter() - t0

    def topic_frames(*a, **kw):
        t0 = time.perf_counter()
        try:
            return orig_frames(*a, **kw)
        finally:
            phases["figures: reading the MCAP (topic_frames)"] += time.perf_counter() - t0

    delivery.drive_fast, delivery.finish_delivery = drive_fast, finish_delivery
    if hasattr(module, "topic_frames"):
        module.topic_frames = topic_frames
    opts = base.ScenarioOptions(duration_s=duration, seed=1, out=out, progress=False, plots=False)
    t0 = time.perf_counter()
    try:
        result = module.run(opts)
    finally:
        delivery.drive_fast, delivery.finish_delivery = orig_drive, orig_finish
        if hasattr(module, "topic_frames"):
            module.topic_frames = orig_frames
    phases["total"] = time.perf_counter() - t0
    return dict(phases=dict(phases), prof=prof, duration=result["duration_s"], result=result)


def scenario_main(args) -> None:
    os.environ.setdefault("ROS_DOMAIN_ID", "160")
    with tempfile.TemporaryDirectory() as tmp:
        perf = f"{tmp}/perf.data" if args.perf else None
        cold = run_scenario_phases(args.name, args.duration, False, f"{tmp}/a.mcap")
        warm = run_scenario_phases(args.name, args.duration, False, f"{tmp}/b.mcap", perf)
        prof = run_scenario_phases(args.name, args.duration, True, f"{tmp}/c.mcap")
        print(f"scenario {args.name}, {cold['duration']:g} s simulated, fast mode, no plots")
        drive = "first to last frame (drive_fast)"
        for k in cold["phases"]:
            print(f"  {k:45s} {cold['phases'][k]:7.2f} s cold, {warm['phases'][k]:7.2f} s warm")
        print(
            "  first-to-last-frame real-time factor (whole graph, not per device): "
            f"{cold['duration'] / cold['phases'][drive]:.3f} cold (first run in the process: "
            f"numba kernels loaded from the cache at their first call), "
            f"{warm['duration'] / warm['phases'][drive]:.3f} warm"
        )
        if args.save:
            prof["prof"].dump_stats(args.save)
        stats = pstats.Stats(prof["prof"])
        print_split(
            "first to last frame under cProfile (warm)",
            categorise(stats, numba_kernels()),
            warm["phases"][drive],
        )
        top_functions(stats)
        if perf is not None:
            print("perf of the warm un-profiled run, first to last frame:")
            perf_split(f"{tmp}/perf.data")


# ---------------------------------------------------------------- stage graph, processes


def stage_main(args) -> None:
    sys.argv = [sys.argv[0]]
    sys.path.insert(0, str(HERE))
    import bench_stage_ekf as bse

    from mems_estimation.identification.stage_gyro_calibration import Plan, identify_stage

    model, _ = identify_stage(seed=5, plan=Plan.short())
    domain = int(os.environ.get("ROS_DOMAIN_ID") or 160)
    with tempfile.TemporaryDirectory() as tmp:
        pdir = f"{tmp}/prof"
        env = dict(
            MEMS_PROFILE_DIR=pdir,
            PYTHONPATH=os.pathsep.join([str(HERE / "profile_hook"), str(ROOT)]),
        )
        perf = perf_record(f"{tmp}/perf.data") if args.perf else None
        r = bse.graph_processes(
            model, args.compression, domain_id=domain, extra_env=env, frame_size=args.frame_size
        )
        if perf is not None:
            perf.send_signal(2)
            perf.wait()
        bse.print_graph_processes(r)
        kernels = numba_kernels()
        pids = {}
        for path in sorted(glob.glob(f"{pdir}/*.prof")):
            role, pid = Path(path).stem.rsplit("-", 1)
            pids[int(pid)] = role
            stats = pstats.Stats(path)
            print_split(f"process {role}", categorise(stats, kernels))
            top_functions(stats, 8)
        if perf is not None:
            print("perf, whole machine while the graph ran (profiled run: Python reads high):")
            perf_split(f"{tmp}/perf.data", pids)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    s = sub.add_parser("scenario")
    s.add_argument("name")
    s.add_argument("--duration", type=float)
    s.add_argument("--perf", action="store_true")
    s.add_argument("--save", help="write the cProfile statistics to this file")
    g = sub.add_parser("stage-processes")
    g.add_argument("--compression", default="zstd")
    g.add_argument("--frame-size", type=int)
    g.add_argument("--perf", action="store_true")
    args = ap.parse_args()
    (scenario_main if args.what == "scenario" else stage_main)(args)


if __name__ == "__main__":
    main()

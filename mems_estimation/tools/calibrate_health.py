"""``calibrate_health``: an estimator node's consistency monitor calibrated on the bench,
from a fault-free recording of its ``health`` topic.

Each ``health`` message (diagnostic_msgs/DiagnosticStatus) carries one window's NIS sum
(``statistic``) over ``samples`` samples of ``dof`` measurements (1 when the message does
not say); the fault-free window sums give the moments (per degree of freedom) of
the scaled chi-square the node's thresholds use (``health_nis_mean``,
``health_nis_dispersion``; Satterthwaite 1946), measured on the device itself rather than
taken from the filter's table, which was measured on the nominal device
(:mod:`mems_estimation.identification.health_calibration`).

Usage:
    calibrate_health BAG [--topic T] [--false-alarm A] [--out PARAMS.yaml] [--overwrite]
                     [--json]

Reads every topic of type DiagnosticStatus whose name ends in ``/health`` (``--topic``:
one of them); prints per topic the node, the window, the windows measured, the mean NIS
per sample and the dispersion with 95 % intervals, and the alarms these moments give on
the same windows at ``--false-alarm`` (default 1e-2; in sample, a check);
``--out`` writes a ROS 2 parameter file (per node, by its fully qualified name:
``health_window``, ``health_nis_mean``, ``health_nis_dispersion``) for
``--ros-args --params-file``; ``--json`` prints the results as JSON on stdout (the table
then goes to stderr). A recording with scheduled faults (any ``mems_msgs/FaultEvent``),
windows of different lengths, a non-finite statistic or fewer than 30 windows is refused:
exit status 2 with one line; 0 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from mems_sim.ros.env import apply_defaults

HEALTH_TYPE = "diagnostic_msgs/msg/DiagnosticStatus"
FAULT_TYPE = "mems_msgs/msg/FaultEvent"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="calibrate_health", description=__doc__.splitlines()[0])
    p.add_argument("bag", type=Path, help="bag: .mcap or a rosbag2 directory")
    p.add_argument("--topic", default=None, help="one health topic (default: every one)")
    p.add_argument("--false-alarm", type=float, default=1e-2, help="alpha of the in-sample check")
    p.add_argument("--out", type=Path, default=None, help="write a ROS 2 parameter file")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    return p


def _value(msg, key: str) -> str:
    for kv in msg.values:
        if kv.key == key:
            return kv.value
    raise ValueError(f"a health message of {msg.hardware_id or msg.name} has no {key!r}")


def read_health(path: Path, topics: list[str]) -> dict[str, dict]:
    """Per topic: the node (fully qualified name), the window length [samples] and the
    window sums, in the recording's order; ValueError for windows of different lengths."""
    from mems_sim.bag.player import read_messages

    out: dict[str, dict] = {}
    for topic, _, _, msg in read_messages(str(path), topics):
        n = int(_value(msg, "samples"))
        s = float(_value(msg, "statistic"))
        dof = int(dict((kv.key, kv.value) for kv in msg.values).get("dof", 1))
        rec = out.setdefault(
            topic, dict(node=msg.hardware_id or msg.name, window=n, dof=dof, sums=[])
        )
        if n != rec["window"]:
            raise ValueError(
                f"{topic}: windows of {rec['window']} and {n} samples: calibrate one "
                "health_window at a time"
            )
        if dof != rec["dof"]:
            raise ValueError(f"{topic}: windows of {rec['dof']} and {dof} degrees of freedom")
        rec["sums"].append(s)
    return out


def _count_faults(path: Path, topics: list[str]) -> int:
    from mems_sim.bag.player import read_messages

    return sum(1 for _ in read_messages(str(path), topics))


def _table(results: dict) -> str:
    from mems_sim.table import format_table

    rows = []
    for topic, r in results.items():
        c = r["calibration"]
        lo, hi = c["nis_mean_interval"]
        dlo, dhi = c["dispersion_interval"]
        rows.append(
            [
                topic,
                r["node"],
                str(c["window"]),
                str(c["windows"]),
                f"{c['nis_mean']:.5g} [{lo:.5g}, {hi:.5g}]",
                f"{c['dispersion']:.4g} [{dlo:.4g}, {dhi:.4g}]",
                f"{c['alarm_windows']} / {c['false_alarm'] * c['windows']:.1f}",
            ]
        )
    header = ["topic", "node", "window", "windows", "nis_mean [95 %]", "dispersion [95 %]"]
    return format_table(header + ["alarms / designed"], rows)


def _params(results: dict) -> dict:
    return {
        r["node"]: {
            "ros__parameters": {
                "health_window": r["calibration"]["window"],
                "health_nis_mean": r["calibration"]["nis_mean"],
                "health_nis_dispersion": r["calibration"]["dispersion"],
            }
        }
        for r in results.values()
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``calibrate_health``."""
    args = _parser().parse_args(argv)
    apply_defaults()
    import yaml

    from mems_estimation.identification.health_calibration import calibrate
    from mems_sim.bag.output_paths import BagWriteError, output_problem, write_output
    from mems_sim.bag.player import BagReadError, recorded_topics

    out = sys.stderr if args.json else sys.stdout
    problem = None if args.out is None else output_problem(str(args.out), args.overwrite)
    if problem is not None:
        print(f"calibrate_health: error: --out {problem}", file=sys.stderr)
        return 2
    try:
        if not (math.isfinite(args.false_alarm) and 0.0 < args.false_alarm < 0.5):
            raise ValueError(f"--false-alarm {args.false_alarm!r}: allowed (0, 0.5)")
        if not args.bag.exists():
            raise ValueError(f"{args.bag}: no such file or directory")
        types = {t: v[0] for t, v in recorded_topics(str(args.bag)).items()}
        health = [t for t, ty in types.items() if ty == HEALTH_TYPE and t.endswith("/health")]
        if args.topic is not None:
            if args.topic not in health:
                raise ValueError(f"{args.bag}: no health topic {args.topic!r}")
            health = [args.topic]
        if not health:
            raise ValueError(f"{args.bag}: no health topic (DiagnosticStatus on */health)")
        fault_topics = [t for t, ty in types.items() if ty == FAULT_TYPE]
        faults = _count_faults(args.bag, fault_topics) if fault_topics else 0
        if faults:
            raise ValueError(
                f"{args.bag}: the recording holds {faults} scheduled fault(s) on "
                f"{', '.join(fault_topics)}: calibrate on fault-free data"
            )
        results = read_health(args.bag, health)
        for topic in health:
            if topic not in results:
                raise ValueError(f"{topic}: no health message in the recording")
            r = results[topic]
            try:
                r["calibration"] = calibrate(
                    r.pop("sums"), r["window"], args.false_alarm, r["dof"]
                ).as_dict()
            except ValueError as exc:
                raise ValueError(f"{topic}: {exc}") from None
    except (BagReadError, ValueError) as exc:
        print(f"calibrate_health: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(_table(results), file=out)
    if args.out:
        text = yaml.safe_dump(_params(results), sort_keys=False)
        try:
            write_output(
                str(args.out), lambda tmp: Path(tmp).write_text(text), overwrite=args.overwrite
            )
        except BagWriteError as exc:
            print(f"calibrate_health: error: {exc}", file=sys.stderr)
            return 2
        print(f"parameters: {args.out}", file=out)
    if args.json:
        print(json.dumps(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

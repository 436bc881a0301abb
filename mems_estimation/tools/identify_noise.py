"""``identify_noise``: Allan-variance noise identification of AdcFrames stored in an MCAP file.

Runs exactly the code of the noise_identifier node (same accumulation, same
fit) on the frames of one topic, so its result equals the node's final
result for the same data.

Usage:
    identify_noise FILE.mcap [--topic /imu/adc] [--grid octave|decade|all]
                   [--plot FILE.png] [--json FILE.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mems_sim.ros.env import apply_defaults


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="identify_noise", description=__doc__.splitlines()[0])
    p.add_argument("bag", type=Path, help="MCAP file")
    p.add_argument("--topic", default="/imu/adc", help="AdcFrame topic (default /imu/adc)")
    p.add_argument(
        "--grid",
        default="octave",
        choices=("octave", "decade", "all"),
        help="Allan tau grid (default octave)",
    )
    p.add_argument("--plot", type=Path, default=None, help="write the Allan deviation figure")
    p.add_argument("--json", type=Path, default=None, help="write the model as JSON")
    return p


def identify_bag(path: Path, topic: str, grid: str):
    """NoiseModel identified from the AdcFrames of ``topic`` in ``path``.

    Returns:
        (NoiseModel message, frames used, frames rejected, accumulator).
    Raises:
        BagReadError: missing, unreadable, non-MCAP, corrupt or hostile file (one line).
        ValueError: the topic is absent, not of AdcFrame type, or has no usable frames.

    The topic's type is checked against the file's channels before anything is
    deserialised, so a type the file names is never imported unless it is AdcFrame.
    A truncated file is read up to its last complete chunk (a warning line).
    """
    from mems_sim.bag.player import read_messages, recorded_topics

    topics = recorded_topics(str(path))
    if topic not in topics:
        raise ValueError(f"{path}: no topic {topic!r} in the file")
    stored_type = topics[topic][0]
    if stored_type not in ("mems_msgs/msg/AdcFrame", "mems_msgs/AdcFrame"):
        from mems_sim.bag.schema import interface_problem

        problem = interface_problem(stored_type)
        raise ValueError(
            f"{path}: topic {topic} carries {stored_type[:80]!r}, not mems_msgs/msg/AdcFrame"
            + (f" ({problem}; not imported)" if problem else "")
        )
    # the identification stack (scipy) is imported only for a file that passed the checks
    from mems_estimation.nodes.imu_noise_identifier_node import NoiseAccumulator, identify_message
    from mems_sim.ros.frames import FrameError

    acc, rejected, frames = NoiseAccumulator(), 0, 0
    for _, type_name, _, msg in read_messages(str(path), [topic]):
        if type_name != stored_type:
            raise ValueError(
                f"{path}: topic {topic} carries {type_name[:80]!r}, not mems_msgs/msg/AdcFrame"
            )
        try:
            acc.add(msg)
            frames += 1
        except FrameError:
            rejected += 1
    if frames == 0:
        raise ValueError(f"{path}: no AdcFrame messages on topic {topic}")
    return identify_message(acc, grid, final=True), frames, rejected, acc


def model_to_dict(model) -> dict:
    """Plain dict of a NoiseModel (SI), for JSON."""
    axes = []
    for a in model.axes:
        entry = {"axis": a.axis, "unit": a.unit, "mean": a.mean}
        for field in (
            "white_noise_density",
            "bias_instability",
            "correlation_time",
            "random_walk",
            "quantization",
        ):
            t = getattr(a, field)
            entry[field] = {
                "value": t.value,
                "standard_error": t.standard_error,
                "ci95": [t.ci_low, t.ci_high],
            }
        entry["discrete_model"] = {
            "a_d": a.a_d,
            "b_d": a.b_d,
            "sigma_eta": a.sigma_eta,
            "white_std_per_sample": a.white_std_per_sample,
            "random_walk_increment_std": a.random_walk_increment_std,
        }
        axes.append(entry)
    return {
        "sample_rate_hz": model.sample_rate_hz,
        "num_samples": model.num_samples,
        "first_sample_index": model.first_sample_index,
        "tau_grid": model.tau_grid,
        "axes": axes,
    }


def format_model(model) -> str:
    """Table of N, B, K, T per axis with 95 % intervals."""
    from mems_sim.table import format_table

    rows = []
    for a in model.axes:
        for sym, field, unit in (
            ("N", "white_noise_density", f"{a.unit}/sqrt(Hz)"),
            ("B", "bias_instability", a.unit),
            ("K", "random_walk", f"{a.unit}/sqrt(s)"),
            ("T", "correlation_time", "s"),
        ):
            t = getattr(a, field)
            rows.append([a.axis, sym, unit, f"{t.value:.4g}", f"[{t.ci_low:.3g}, {t.ci_high:.3g}]"])
    return format_table(["axis", "param", "unit", "identified", "95 % CI"], rows)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``identify_noise``."""
    args = _parser().parse_args(argv)
    apply_defaults()
    from mems_sim.bag.player import BagReadError

    try:
        model, frames, rejected, acc = identify_bag(args.bag, args.topic, args.grid)
    except (BagReadError, ValueError) as exc:
        print(f"identify_noise: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(
        f"{args.bag}: {args.topic}, {frames} frames, {model.num_samples} samples at "
        f"{model.sample_rate_hz:g} Hz, {rejected} rejected, {acc.tracker.gaps} gaps\n"
    )
    print(format_model(model))
    if args.json:
        args.json.write_text(json.dumps(model_to_dict(model), indent=2))
    if args.plot:
        from mems_estimation.identification.imu_noise_plots import plot_allan

        plot_allan(model, args.plot)
        print(f"figure: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""``identify_noise``: Allan-variance noise identification from a bag.

Reads either the project's ``mems_msgs/AdcFrame`` frames (running exactly the code of the
identifier node: same accumulation, same fit, so the result equals the node's final
result for the same data) or ``sensor_msgs/Imu`` messages of any IMU, from rosbag2 bags
(MCAP or sqlite3, a bag directory with ``metadata.yaml``, or a bare ``.mcap`` file) and ROS 1
bags (``rosbags`` reads all three; type definitions come from the bag itself or from
rosbags' typestore, nothing the file names is imported).

For ``sensor_msgs/Imu`` the sample rate comes from the stamps (samples - 1 over the span of
``header.stamp``; the bag's log times if every stamp is zero) and irregular sampling is
reported (intervals more than 10 % off the median, the longest interval, samples
presumably missing); the six channels are ``gyro_x..z`` [rad/s] (``angular_velocity``)
and ``accel_x..z`` [m/s^2] (``linear_acceleration``), REP-145's raw IMU data.

Usage:
    identify_noise BAG [--topic T] [--grid octave|decade|all] [--plot FILE.png]
                   [--json] [--kalibr FILE.yaml] [--model gm|auto|flicker]
                   [--twin TWIN.yaml]

``--json`` prints the model as JSON on stdout (the table then goes to stderr); ``--kalibr``
writes a Kalibr IMU file (``imu.yaml``: ``accelerometer_noise_density`` [m/s^2/sqrt(Hz)],
``accelerometer_random_walk`` [m/s^3/sqrt(Hz)], ``gyroscope_noise_density``
[rad/s/sqrt(Hz)], ``gyroscope_random_walk`` [rad/s^2/sqrt(Hz)], ``rostopic``,
``update_rate`` [Hz]; Kalibr's continuous-time densities are the Allan fit's N and K, and
Kalibr takes one value per sensor: the largest of the three axes, the conservative choice).
``--model auto`` (or ``flicker``) adds a second table (and a ``model_choice`` JSON list):
per axis the flicker-floor model and the Gauss-Markov model fitted to the same Allan points,
the BIC and AIC of both, and the model BIC chooses (or the flicker model) with its
parameters and 95 % intervals; the first table, ``--kalibr`` and ``--plot`` stay those of the
Gauss-Markov model (``--model gm``, the default, reports only that).
``--twin`` writes a ROS 2 parameter file for ``imu_node`` (``--ros-args --params-file``)
that emulates the recorded IMU: rate, resolution, per-axis mean and the stochastic terms,
each sensor with the bias-instability model its Allan variance prefers
(:mod:`mems_estimation.identification.imu_twin`).
Exit status: 0, or 2 with one line for a file or topic it cannot use (too little data
included).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from mems_sim.ros.env import apply_defaults
from mems_sim.stream_index import DuplicateFilter

ADC_TYPES = ("mems_msgs/msg/AdcFrame", "mems_msgs/AdcFrame")
IMU_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")
IMU_CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
IMU_UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3
#: An interval this far from the median counts as irregular.
IRREGULAR = 0.10
#: Largest magnitude of an Imu value accepted [rad/s, m/s^2]: its square summed over any
#: record stays finite in float64 (1e100**2 = 1e200, the limit is 1.8e308).
MAX_VALUE = 1e100


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="identify_noise", description=__doc__.splitlines()[0])
    p.add_argument("bag", type=Path, help="bag: .mcap, .db3, .bag, or a rosbag2 directory")
    p.add_argument(
        "--topic",
        default=None,
        help="AdcFrame or sensor_msgs/Imu topic (default: /imu/adc, else the only Imu topic)",
    )
    p.add_argument(
        "--grid",
        default="octave",
        choices=("octave", "decade", "all"),
        help="Allan tau grid (default octave)",
    )
    p.add_argument("--plot", type=Path, default=None, help="write the Allan deviation figure")
    p.add_argument("--json", action="store_true", help="print the model as JSON on stdout")
    p.add_argument("--kalibr", type=Path, default=None, help="write a Kalibr imu.yaml")
    p.add_argument(
        "--twin",
        type=Path,
        default=None,
        help="write the imu_node parameter file of a digital twin of the recorded IMU",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace existing --kalibr/--plot/--twin files"
    )
    p.add_argument(
        "--model",
        default="gm",
        choices=("gm", "auto", "flicker"),
        help="gm (default): Gauss-Markov fit only; auto/flicker: also the model-choice table",
    )
    return p


def _is_mcap(path: Path) -> bool:
    """An MCAP bag (a ``.mcap`` file, or a bag directory of MCAP files), read by the
    project's reader; else a ROS 1 or sqlite3 bag (:mod:`mems_sim.bag.foreign`)."""
    from mems_sim.bag.foreign import bag_format

    return (path.suffix == ".mcap" and not path.is_dir()) or bag_format(path) == "mcap"


def bag_topics(path: Path) -> dict[str, str]:
    """Topic -> type name of a bag (any format ``identify_noise`` reads)."""
    if _is_mcap(path):
        from mems_sim.bag.player import recorded_topics

        return {t: v[0] for t, v in recorded_topics(str(path)).items()}
    from mems_sim.bag.foreign import open_foreign

    with open_foreign(path) as bag:
        return dict(bag.topics)


def choose_topic(topics: dict[str, str], topic: str | None, path: Path) -> str:
    """The topic to identify: the given one, else /imu/adc, else the only Imu topic."""
    if topic is not None:
        if topic not in topics:
            raise ValueError(f"{path}: no topic {topic!r} in the bag")
        return topic
    if "/imu/adc" in topics:  # the project's topic (its type is checked when read)
        return "/imu/adc"
    imu = [t for t, ty in topics.items() if ty in IMU_TYPES]
    if len(imu) == 1:
        return imu[0]
    raise ValueError(
        f"{path}: give --topic: "
        + (f"Imu topics {', '.join(sorted(imu))}" if imu else "no /imu/adc and no Imu topic")
    )


def read_imu(
    path: Path, topic: str, duplicates: DuplicateFilter | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Stamps [ns] (n,) and values (n, 6) of the sensor_msgs/Imu messages of ``topic``,
    each duplicated message once (counted in ``duplicates``)."""
    stamps: list[int] = []
    logs: list[int] = []
    rows: list[tuple[float, ...]] = []

    def take(msg, log_ns: int) -> None:
        st = msg.header.stamp
        w, a = msg.angular_velocity, msg.linear_acceleration
        stamps.append(int(st.sec) * 10**9 + int(st.nanosec))
        logs.append(int(log_ns))
        rows.append((w.x, w.y, w.z, a.x, a.y, a.z))

    if _is_mcap(path):
        from mems_sim.bag.player import read_messages

        for _, _, log_ns, msg in read_messages(str(path), [topic], duplicates=duplicates):
            take(msg, log_ns)
    else:
        from mems_sim.bag.foreign import open_foreign

        with open_foreign(path) as bag:
            for log_ns, msg in bag.messages(topic, duplicates):
                take(msg, log_ns)
    t = np.asarray(stamps if any(stamps) else logs, dtype=np.int64)  # unstamped: log times
    return t, np.asarray(rows, dtype=float).reshape(-1, 6)


def sampling(stamps_ns: np.ndarray) -> dict:
    """Sample rate from the stamps and how regular they are (module doc)."""
    n = stamps_ns.size
    order = np.argsort(stamps_ns, kind="stable")
    t = stamps_ns[order]
    dt = np.diff(t).astype(float)
    span = float(t[-1] - t[0]) if n > 1 else 0.0
    if n < 3 or span <= 0.0:
        raise ValueError(f"{n} messages with distinct stamps: too few to identify noise")
    med = float(np.median(dt))
    fs = (n - 1) * 1e9 / span
    irregular = int(np.count_nonzero(np.abs(dt - med) > IRREGULAR * med))
    missing = int(np.round(np.sum(np.maximum(dt / med - 1.0, 0.0)))) if med > 0 else 0
    return dict(
        sample_rate_hz=fs,
        median_interval_s=med * 1e-9,
        irregular_intervals=irregular,
        longest_interval_s=float(dt.max()) * 1e-9,
        missing_samples_estimate=missing,
        unordered=bool(np.any(np.diff(stamps_ns) < 0)),
        order=order,
    )


def identify_imu(path: Path, topic: str, grid: str, duplicates: DuplicateFilter | None = None):
    """NoiseModel identified from the sensor_msgs/Imu messages of ``topic`` (each duplicated
    message once, counted in ``duplicates``); also returns the sampling report and the
    accumulator. The bag is read before the identification stack (scipy) is imported, so a
    hostile bag meets only the reader's memory."""
    stamps, values = read_imu(path, topic, duplicates)
    if stamps.size == 0:
        raise ValueError(f"{path}: no sensor_msgs/Imu messages on topic {topic}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: topic {topic} holds non-finite values")
    if values.size and np.abs(values).max() > MAX_VALUE:
        raise ValueError(
            f"{path}: topic {topic} holds values beyond {MAX_VALUE:g} (the analysis' sums "
            "of squares would overflow)"
        )
    report = sampling(stamps)
    from mems_estimation.identification.imu_twin import value_resolution
    from mems_estimation.nodes.imu_noise_identifier_node import NoiseAccumulator, identify_message

    acc = NoiseAccumulator(grid)
    acc.start(report["sample_rate_hz"], 0, IMU_CHANNELS, IMU_UNITS)
    acc.extend(values[report.pop("order")])
    acc.steps = tuple(value_resolution(values[:, j]) for j in range(values.shape[1]))
    return identify_message(acc, grid, final=True), report, acc


def identify_bag(path: Path, topic: str, grid: str, duplicates: DuplicateFilter | None = None):
    """NoiseModel identified from the AdcFrames of ``topic`` in ``path``, each duplicated
    message (identical topic, log time and bytes) once, counted in ``duplicates``.

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
    if stored_type not in ADC_TYPES:
        from mems_sim.bag.schema import interface_problem

        problem = interface_problem(stored_type)
        raise ValueError(
            f"{path}: topic {topic} carries {stored_type[:80]!r}, not mems_msgs/msg/AdcFrame"
            + (f" ({problem}; not imported)" if problem else "")
        )
    # the identification stack (scipy) is imported only for a file that passed the checks
    from mems_estimation.nodes.imu_noise_identifier_node import NoiseAccumulator, identify_message
    from mems_sim.ros.frames import FrameError

    acc, rejected, frames = NoiseAccumulator(grid), 0, 0
    for _, type_name, _, msg in read_messages(str(path), [topic], duplicates=duplicates):
        if type_name != stored_type:
            raise ValueError(
                f"{path}: topic {topic} carries {type_name[:80]!r}, not mems_msgs/msg/AdcFrame"
            )
        try:
            acc.add(msg)
            frames += 1
        except FrameError:
            rejected += 1
            continue
        if frames == 1:
            acc.steps = tuple(float(q) for q in msg.lsb)  # the converter's own step
    if frames == 0:
        raise ValueError(f"{path}: no AdcFrame messages on topic {topic}")
    return identify_message(acc, grid, final=True), frames, rejected, acc


def kalibr_dict(model, topic: str, notes: list[str] | None = None) -> dict:
    """Kalibr's IMU parameters (module doc) from a model with gyro_* and accel_* axes.

    Kalibr rejects a noise value <= 0: where every axis fitted a term as 0 (a random walk
    too small for the record to see), the largest upper 95 % bound stands in, and a line
    saying so is appended to ``notes``; with no positive bound either, ValueError.
    ``topic``: the ``sensor_msgs/Imu`` topic Kalibr reads.
    """
    out = {}
    for prefix, sensor in (("accel", "accelerometer"), ("gyro", "gyroscope")):
        axes = [a for a in model.axes if a.axis.startswith(prefix)]
        if not axes:
            raise ValueError(f"no {prefix}_* axes for Kalibr's {sensor} entries")
        for key, field in (
            ("noise_density", "white_noise_density"),
            ("random_walk", "random_walk"),
        ):
            terms = [getattr(a, field) for a in axes]
            value = max(t.value for t in terms)
            name = f"{sensor}_{key}"
            if not value > 0:
                bounds = [t.ci_high for t in terms if math.isfinite(t.ci_high) and t.ci_high > 0]
                if not bounds:
                    raise ValueError(
                        f"--kalibr: {name} fitted 0 on every axis and has no finite upper "
                        "bound; Kalibr takes only positive values (a longer record is needed)"
                    )
                value = max(bounds)
                if notes is not None:
                    notes.append(
                        f"{name}: fitted 0 on every axis; the upper 95 % bound {value:.4g} is "
                        "written (Kalibr takes only positive values)"
                    )
            out[name] = float(value)
    out["rostopic"] = topic
    out["update_rate"] = float(model.sample_rate_hz)
    return out


def kalibr_topic(topics: dict[str, str], identified: str) -> str:
    """The ``sensor_msgs/Imu`` topic for Kalibr's ``rostopic``: the identified topic if it
    is one, else the Imu topic of the same namespace (or the bag's only one); ValueError if
    the bag has none (Kalibr cannot read the project's AdcFrame)."""
    if topics.get(identified) in IMU_TYPES:
        return identified
    imu = sorted(t for t, ty in topics.items() if ty in IMU_TYPES)
    namespace = identified.rsplit("/", 1)[0] + "/"
    near = [t for t in imu if t.startswith(namespace)]
    if len(near) == 1 or len(imu) == 1:
        return (near or imu)[0]
    if not imu:
        raise ValueError(
            f"--kalibr: the bag has no sensor_msgs/Imu topic for Kalibr to read "
            f"({identified} is {topics.get(identified)})"
        )
    raise ValueError(f"--kalibr: several Imu topics ({', '.join(imu)}); give --topic one of them")


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
    """Table of N, B, K, T per axis with 95 % intervals and the Cramer-Rao standard error
    for a record of this length (mems_estimation.identification.imu_noise_fit.crb_relative_se)."""
    from mems_estimation.identification.imu_noise_fit import crb_relative_se
    from mems_sim.table import format_table

    rows = []
    for a in model.axes:
        vals = {
            "N": a.white_noise_density.value,
            "B": a.bias_instability.value,
            "K": a.random_walk.value,
            "T": a.correlation_time.value,
        }
        crb = crb_relative_se(*vals.values(), model.sample_rate_hz, model.num_samples)
        for sym, field, unit in (
            ("N", "white_noise_density", f"{a.unit}/sqrt(Hz)"),
            ("B", "bias_instability", a.unit),
            ("K", "random_walk", f"{a.unit}/sqrt(s)"),
            ("T", "correlation_time", "s"),
        ):
            t = getattr(a, field)
            rows.append(
                [
                    a.axis,
                    sym,
                    unit,
                    f"{t.value:.4g}",
                    f"[{t.ci_low:.3g}, {t.ci_high:.3g}]",
                    f"{crb[sym] * t.value:.3g}",
                ]
            )
    return format_table(["axis", "param", "unit", "identified", "95 % CI", "CRB s.e."], rows)


def twin_text(acc, choices, source: str) -> tuple[str, dict]:
    """The ``--twin`` parameter file of the accumulator's record and its parameters;
    ``choices``: the model choice per channel (computed here when None)."""
    from mems_estimation.identification.imu_twin import twin_parameters, twin_yaml

    if choices is None:
        from mems_estimation.tools.noise_choice_report import axis_choices

        choices = axis_choices(acc)
    _, means = acc.results()
    params = twin_parameters(
        choices, acc.channels, acc.fs, acc.duration_s(), [float(m) for m in means], acc.steps
    )
    return twin_yaml(params, source), params


def _write_outputs(args, model, kalibr: dict | None, notes: list[str], out, twin=None) -> None:
    """Write ``--kalibr``, ``--plot`` and ``--twin`` (each whole or not at all, never through
    a symbolic link: :func:`~mems_sim.bag.output_paths.write_output`); BagWriteError."""
    from mems_sim.bag.output_paths import write_output

    if args.twin:
        text, params = twin
        write_output(args.twin, lambda tmp: Path(tmp).write_text(text), args.overwrite)
        models = ", ".join(f"{s} {m}" for s, m in params["_models"].items())
        print(f"twin: {args.twin} (imu_node --params-file; {models})", file=out)

    if args.kalibr:
        import yaml

        text = yaml.safe_dump(kalibr, sort_keys=False)
        write_output(args.kalibr, lambda tmp: Path(tmp).write_text(text), args.overwrite)
        print(f"kalibr: {args.kalibr} (rostopic {kalibr['rostopic']})", file=out)
        for note in notes:
            print(f"kalibr: {note}", file=out)
    if args.plot:
        from mems_estimation.identification.imu_noise_plots import plot_allan

        plot_allan(model, args.plot, overwrite=args.overwrite)
        print(f"figure: {args.plot}", file=out)


def _model_choices(option: str, acc, out) -> list | None:
    """``--model auto|flicker``: the model choice of every channel, its table printed; None
    for ``gm``."""
    if option == "gm":
        return None
    from mems_estimation.tools.noise_choice_report import axis_choices, format_choices

    choices = axis_choices(acc)
    print("\n" + format_choices(choices, acc.channels, acc.units, option), file=out)
    return choices


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``identify_noise``."""
    args = _parser().parse_args(argv)
    apply_defaults()
    from mems_sim.bag.player import BagReadError

    out = sys.stderr if args.json else sys.stdout
    from mems_sim.bag.output_paths import BagWriteError, output_problem

    for option, path in (("--kalibr", args.kalibr), ("--plot", args.plot), ("--twin", args.twin)):
        # before the analysis: a symbolic link, a directory or an existing file (without
        # --overwrite) is refused, an unwritable directory too
        problem = None if path is None else output_problem(str(path), args.overwrite)
        if problem is not None:
            print(f"identify_noise: error: {option} {problem}", file=sys.stderr)
            return 2
    duplicates = DuplicateFilter()
    try:
        topics = bag_topics(args.bag)
        topic = choose_topic(topics, args.topic, args.bag)
        if topics[topic] in IMU_TYPES:
            model, rep, acc = identify_imu(args.bag, topic, args.grid, duplicates)
            head = (
                f"{args.bag}: {topic} (sensor_msgs/Imu), {model.num_samples} samples at "
                f"{model.sample_rate_hz:.6g} Hz from the stamps; {rep['irregular_intervals']} "
                f"irregular intervals (> {IRREGULAR:.0%} off the median "
                f"{rep['median_interval_s']:.6g} s), longest {rep['longest_interval_s']:.6g} s, "
                f"~{rep['missing_samples_estimate']} samples missing"
                + (", stamps out of order (sorted)" if rep["unordered"] else "")
            )
        else:
            model, frames, rejected, acc = identify_bag(args.bag, topic, args.grid, duplicates)
            rep = None
            head = (
                f"{args.bag}: {topic}, {frames} frames, {model.num_samples} samples at "
                f"{model.sample_rate_hz:g} Hz, {rejected} rejected, {acc.tracker.gaps} gaps"
            )
        head += f", {duplicates.total} duplicate messages (used once)" if duplicates.total else ""
        notes: list[str] = []
        kalibr = kalibr_dict(model, kalibr_topic(topics, topic), notes) if args.kalibr else None
    except (BagReadError, ValueError) as exc:
        print(f"identify_noise: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(head + "\n", file=out)
    print(format_model(model), file=out)
    choices = _model_choices(args.model, acc, out)
    try:
        twin = None
        if args.twin:
            try:
                twin = twin_text(acc, choices, f"{args.bag} {topic}")
            except ValueError as exc:
                print(f"identify_noise: error: --twin: {exc}", file=sys.stderr)
                return 2
        _write_outputs(args, model, kalibr, notes, out, twin)
    except BagWriteError as exc:  # e.g. the disk filled up, or a link appeared meanwhile
        print(f"identify_noise: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        d = model_to_dict(model)
        d["topic"] = topic
        d["duplicates"] = duplicates.total
        if rep is not None:
            d["sampling"] = rep
        if choices is not None:
            from mems_estimation.tools.noise_choice_report import choices_to_dicts

            d["model_choice"] = choices_to_dicts(choices, acc.channels, args.model)
        print(json.dumps(d))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""``calibrate_imu``: IMU multi-position / rate-table / thermal calibration from a bag.

Reads the IMU's frames -- the project's ``mems_msgs/AdcFrame`` (channels gyro_x..z [rad/s],
accel_x..z [m/s^2]; default topic ``/imu/adc``) or ``sensor_msgs/Imu`` (via the reader of
``identify_noise``; sample indices from the stamps) -- from an MCAP file or any bag
``identify_noise`` reads, aligns the profile's start with the stream's first sample and
calibrates (:mod:`mems_estimation.identification.imu_calibration`: segment means, GLS with
the segment-mean covariance of a noise model, 95 % intervals).

Usage:
    calibrate_imu BAG --profile NAME|FILE.yaml [--thermal] [--base CAL.yaml]
                  [--noise PRESET|data|NOISE.json] [--temperature C] [--out CAL.yaml]
                  [--overwrite] [--json] [--topic T]

``--profile`` a built-in profile (six_position, multi_position, thermal_ramp,
thermal_multi_position) or a profile YAML (mems_sim.devices.imu_profiles); ``--thermal``
fits the temperature terms (default: when the profile's temperature spans more than 1 K);
``--base`` a calibration YAML whose values stand for the parameters this profile cannot
observe (e.g. the matrices from a multi-position run under a thermal ramp); ``--noise``
the noise model of the segment-mean covariance: an emulator preset (``petkov``,
``adis16350``, ``icm42688p``), an ``identify_noise --json`` file of the same IMU at rest,
or ``data`` (estimated inside the segments: the bias intervals are then too narrow, about
70 % coverage of the nominal 95 % measured; default ``data``, with a note);
``--temperature`` the device temperature of segments without their own [degC, default
25]. Prints a table (parameter, value, unit, +-95 %), writes the YAML (``--out``, format in
:func:`mems_estimation.identification.imu_calibration_io.calibration_to_dict`), ``--json``
prints the result as JSON on stdout (the table then goes to stderr). ``--out`` is checked
before the calibration: a symbolic link (never followed), a directory, a missing directory
or an existing file without ``--overwrite`` is refused; the file is written whole or not at
all. Exit status 0, or 2 with one line for input it cannot use (e.g. a recording whose
segment means do not follow the profile: a static bag given a multi-position profile) or an
output it cannot write.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from mems_sim.ros.env import apply_defaults


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="calibrate_imu", description=__doc__.splitlines()[0])
    p.add_argument("bag", type=Path, help="bag: .mcap, .db3, .bag, or a rosbag2 directory")
    p.add_argument("--profile", required=True, help="built-in profile name or profile YAML")
    p.add_argument("--thermal", action="store_true", help="fit the temperature terms")
    p.add_argument("--base", type=Path, default=None, help="calibration YAML for unobservables")
    p.add_argument("--noise", default="data", help="preset name, 'data' or identify_noise JSON")
    p.add_argument("--temperature", type=float, default=25.0, help="device temperature [degC]")
    p.add_argument("--out", type=Path, default=None, help="write the calibration YAML")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.add_argument("--topic", default=None, help="AdcFrame or Imu topic (default /imu/adc)")
    return p


def read_adc(path: Path, topic: str) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Sample indices (n,), values (n, 6), sample rate [Hz] and rejected frames of the
    AdcFrames of ``topic`` (channels gyro_x..z, accel_x..z); repeated frames dropped."""
    from mems_estimation.tools.identify_noise import ADC_TYPES
    from mems_sim.bag.player import read_messages, recorded_topics
    from mems_sim.ros.frames import FrameError, adc_physical

    topics = recorded_topics(str(path))
    if topic not in topics:
        raise ValueError(f"{path}: no topic {topic!r} in the file")
    if topics[topic][0] not in ADC_TYPES:
        raise ValueError(f"{path}: topic {topic} carries {topics[topic][0][:80]!r}, not AdcFrame")
    want = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
    frames: dict[int, np.ndarray] = {}
    fs, rejected = None, 0
    for _, _, _, msg in read_messages(str(path), [topic]):
        try:
            v = adc_physical(msg)
        except FrameError:
            rejected += 1
            continue
        names = list(msg.channel_names)
        if not all(c in names for c in want):
            raise ValueError(f"{path}: {topic} has channels {names}, not gyro_x..accel_z")
        if fs is None:
            fs = float(msg.sample_rate_hz)
        elif msg.sample_rate_hz != fs:
            rejected += 1
            continue
        frames.setdefault(int(msg.first_sample_index), v[:, [names.index(c) for c in want]])
    if not frames:
        raise ValueError(f"{path}: no usable AdcFrame on topic {topic}")
    firsts = sorted(frames)
    idx = np.concatenate([f + np.arange(frames[f].shape[0]) for f in firsts])
    vals = np.concatenate([frames[f] for f in firsts])
    keep = np.concatenate([[True], np.diff(idx) > 0])  # overlapping frames: first one wins
    return idx[keep], vals[keep], fs, rejected


def read_imu_topic(path: Path, topic: str) -> tuple[np.ndarray, np.ndarray, float, int]:
    """As :func:`read_adc` for sensor_msgs/Imu: indices from the stamps at the rate of
    ``identify_noise``'s sampling report (rounded to the nearest sample)."""
    from mems_estimation.tools.identify_noise import read_imu, sampling

    stamps, values = read_imu(path, topic)
    if stamps.size == 0:
        raise ValueError(f"{path}: no sensor_msgs/Imu messages on topic {topic}")
    rep = sampling(stamps)
    order = rep["order"]
    fs = rep["sample_rate_hz"]
    t = (stamps[order] - stamps[order][0]) * 1e-9
    idx = np.rint(t * fs).astype(np.int64)
    keep = np.concatenate([[True], np.diff(idx) > 0])
    return idx[keep], values[order][keep], fs, int(np.count_nonzero(~keep))


def format_result(cal) -> str:
    """The table: parameter, value, unit, +-95 %."""
    from mems_sim.table import format_table

    rows = []
    for name, value, unit, half in cal.table():
        note = " (aliased)" if name in cal.aliases else ""
        rows.append(
            [name + note, f"{value:.6g}", unit, f"{half:.3g}" if math.isfinite(half) else "-"]
        )
    return format_table(["parameter", "value", "unit", "+-95 %"], rows)


def result_dict(cal) -> dict:
    """JSON form: the YAML mapping plus the estimated parameters with units and intervals."""
    from mems_estimation.identification.imu_calibration_io import calibration_to_dict

    d = calibration_to_dict(cal)
    d["parameters"] = [
        {
            "name": n,
            "value": v,
            "unit": u,
            "standard_error": cal.standard_errors[n],
            "ci95": list(cal.ci95(n)),
        }
        for n, v, u, _ in cal.table()
    ]
    d["info"] = cal.info
    return d


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``calibrate_imu``."""
    args = _parser().parse_args(argv)
    apply_defaults()
    from mems_estimation.identification import imu_calibration as ic
    from mems_estimation.identification import imu_calibration_io as icio
    from mems_estimation.tools.identify_noise import IMU_TYPES, bag_topics
    from mems_sim.bag.output_paths import BagWriteError, output_problem
    from mems_sim.bag.player import BagReadError
    from mems_sim.devices.imu_profiles import ProfileError, load_profile

    out = sys.stderr if args.json else sys.stdout
    problem = None if args.out is None else output_problem(str(args.out), args.overwrite)
    if problem is not None:
        print(f"calibrate_imu: error: --out {problem}", file=sys.stderr)
        return 2
    try:
        if not math.isfinite(args.temperature):
            raise ValueError(f"--temperature {args.temperature!r} is not finite")
        profile = load_profile(args.profile)
        noise = icio.noise_option(args.noise)
        base = icio.load_yaml(args.base) if args.base else None
        if not args.bag.exists():
            raise ValueError(f"{args.bag}: no such file or directory")
        topics = bag_topics(args.bag)
        topic = args.topic or "/imu/adc"
        if topic not in topics:
            imu = [t for t, ty in topics.items() if ty in IMU_TYPES]
            if args.topic is None and len(imu) == 1:
                topic = imu[0]
            else:
                raise ValueError(f"{args.bag}: no topic {topic!r} (give --topic)")
        if topics[topic] in IMU_TYPES:
            idx, vals, fs, rejected = read_imu_topic(args.bag, topic)
        else:
            idx, vals, fs, rejected = read_adc(args.bag, topic)
        cal = ic.calibrate_profile(
            vals[:, :3],
            vals[:, 3:],
            profile,
            fs,
            index=idx,
            device_temperature_c=args.temperature,
            noise=noise,
            thermal=True if args.thermal else None,
            base=base,
        )
    except (BagReadError, ProfileError, ValueError, np.linalg.LinAlgError) as exc:
        print(f"calibrate_imu: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    missing = int(idx[-1] - idx[0] + 1 - idx.size)
    print(
        f"{args.bag}: {topic}, {idx.size} samples at {fs:g} Hz ({missing} missing, "
        f"{rejected} frames rejected); profile {profile.name}: {cal.info['segments']} of "
        f"{len(profile.segments)} segments used; noise model: {args.noise}"
        + (
            " (bias intervals too narrow: give the IMU's identify_noise --json)"
            if noise is None
            else ""
        )
        + "\n",
        file=out,
    )
    print(format_result(cal), file=out)
    for name, text in cal.aliases.items():
        print(f"note: {name} {text} (not separable in this profile)", file=out)
    if args.out:
        try:
            icio.save_yaml(cal, args.out, overwrite=args.overwrite)
        except BagWriteError as exc:  # e.g. the disk filled up meanwhile
            print(f"calibrate_imu: error: {exc}", file=sys.stderr)
            return 2
        print(f"calibration: {args.out}", file=out)
    if args.json:
        print(json.dumps(result_dict(cal)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

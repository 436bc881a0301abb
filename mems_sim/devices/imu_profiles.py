"""Motion and temperature profiles of an IMU calibration: positions on a rate table and
temperature ramps, and the ground truth they give per sample.

A profile is a sequence of segments. In each segment the IMU rests on a single-axis rate
table with the body vector ``up_body`` pointing up (along the table's vertical axis) and the
table turning at ``rate_rad_s`` about that vertical axis, while its temperature ramps
linearly from ``temperature_start_c`` to ``temperature_end_c``. The truth in segment i is
(body frame, SI)::

    specific force  f = +g * up_body                 (m/s^2, g = 9.80665; at rest the
                                                      specific force points up: z up gives
                                                      [0, 0, +g], the convention of
                                                      mems_sim.devices.imu.truth_motion)
    angular rate    w = rate * up_body               (rad/s)
    temperature     T(t) = T_start + (T_end - T_start) (t - t_i) / duration_i    (degC)

with t = k / fs the time of sample k and t_i the segment's start. Turning about the
vertical leaves the specific force constant because the IMU is assumed at the table's
centre (no centripetal acceleration) and the earth's rate (7.29e-5 rad/s, well below the
gyro noise of a consumer MEMS part over a 60 s segment) is ignored: the truth is exactly
the table's rate. These are the multi-position and rate-table schemes of the classical
IMU calibration (Titterton & Weston, "Strapdown Inertial Navigation Technology", 2nd ed.,
Sec. 8.3 and 8.4; Tedaldi, Pretto & Menegatti, "A robust and easy to implement method for
IMU calibration without external equipments", ICRA 2014, for the static positions).

Segment i covers the samples ``round(t_i fs) .. round(t_(i+1) fs) - 1``; past the end of the
profile (sample ``round(duration fs)`` on) the truth holds the last segment's state and the
segment number is -1. A calibration should skip the first ``settle_s`` seconds of each
segment (the table's move and the sensor's settling).

Built-in profiles (:data:`BUILTIN_PROFILES`, all at the device temperature unless stated):

* ``six_position``: gravity along +x, -x, +y, -y, +z, -z (the two positions of an axis next
  to each other), 60 s each, 360 s; makes every accelerometer bias and scale factor
  observable and, with the misalignment, the whole accelerometer matrix (each column from
  the difference of a +/- pair); the gyro sees no rate (biases only).
* ``multi_position``: the six positions, then for each axis x, y, z that axis up on the rate
  table at +100 deg/s and then -100 deg/s, 60 s each: 12 segments, 720 s. The rate pairs
  give each column of the gyro matrix (difference) and the gyro bias (sum); the g-sensitivity
  is seen in the static positions (bias differences between opposite positions).
* ``thermal_ramp``: z up, 20 -> 60 degC at 1 K/min (2400 s) while the table turns about z,
  alternately +100 and -100 deg/s in 60 s segments. Observable during the ramp: the
  temperature slope of every gyro bias, of the gyro z scale factor (the rate is only about
  z), of the accelerometer x and y biases; the accelerometer z sees only +g, so its bias and
  scale-factor slopes add up (b_T,z + g s_T,z). The x/y scale-factor slopes of both sensors
  are NOT observable in this profile: use ``thermal_multi_position``.
* ``thermal_multi_position``: the 12 segments of ``multi_position`` four times over (48
  segments, 2880 s) while the temperature ramps 20 -> 60 degC (0.83 K/min): every bias and
  scale-factor slope of both sensors is observable.

YAML format of :func:`load_profile` (SI, angles in degrees only where the key says so)::

    name: my_profile            # optional; default: the file's stem
    settle_s: 1.0               # optional; default 1.0 s
    segments:                   # one or more
      - duration_s: 60.0        # required, s, > 0
        up_body: [0, 0, 1]      # required, body vector pointing up (normalised to unit length)
        rate_deg_s: 100.0       # optional, deg/s (or rate_rad_s in rad/s, not both); default 0
        temperature_start_c: 20 # optional, degC; default: the device temperature
        temperature_end_c: 21   # optional, degC; default: temperature_start_c
        label: z_up_ccw         # optional
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from mems_sim import bounded_yaml

__all__ = [
    "G0",
    "Segment",
    "ImuProfile",
    "ProfileTruth",
    "ProfileError",
    "profile_truth",
    "builtin_profile",
    "load_profile",
    "profile_to_dict",
    "dump_profile",
    "BUILTIN_PROFILES",
]

G0 = 9.80665  # standard gravity, m/s^2
_DEG = math.pi / 180.0


class ProfileError(ValueError):
    """An invalid profile or profile file; the message names the field."""


@dataclass(frozen=True)
class Segment:
    """One segment of a profile: a position on the rate table and a temperature ramp.

    Attributes:
        duration_s: length, s (> 0).
        up_body: body-frame vector pointing up, normalised to unit length on construction
            (specific force at rest = +g * up_body).
        rate_rad_s: rate-table rotation about ``up_body`` (the table's vertical axis),
            rad/s; truth angular rate = rate * up_body.
        temperature_start_c: temperature at the segment's start, degC; None: the device
            temperature (``temperature_c`` of :func:`profile_truth`).
        temperature_end_c: temperature at the segment's end (linear ramp), degC; None: the
            start temperature.
        label: free text, e.g. ``"x_up"``.
    """

    duration_s: float
    up_body: tuple[float, float, float]
    rate_rad_s: float = 0.0
    temperature_start_c: float | None = None
    temperature_end_c: float | None = None
    label: str = ""

    def __post_init__(self) -> None:
        d = float(self.duration_s)
        if not (math.isfinite(d) and d > 0.0):
            raise ProfileError(f"duration_s = {self.duration_s!r} is invalid: must be > 0 s")
        try:
            up = np.asarray(self.up_body, dtype=float)
        except (TypeError, ValueError):
            raise ProfileError(
                f"up_body = {self.up_body!r} is invalid: must be 3 numbers"
            ) from None
        if up.shape != (3,) or not np.all(np.isfinite(up)):
            raise ProfileError(f"up_body = {self.up_body!r} is invalid: must be 3 finite numbers")
        norm = float(np.linalg.norm(up))
        if norm == 0.0:
            raise ProfileError(f"up_body = {self.up_body!r} is invalid: must not be zero")
        up = up / norm
        rate = float(self.rate_rad_s)
        if not math.isfinite(rate):
            raise ProfileError(f"rate_rad_s = {self.rate_rad_s!r} is invalid: must be finite")
        object.__setattr__(self, "duration_s", d)
        object.__setattr__(self, "up_body", (float(up[0]), float(up[1]), float(up[2])))
        object.__setattr__(self, "rate_rad_s", rate)
        for name in ("temperature_start_c", "temperature_end_c"):
            v = getattr(self, name)
            if v is not None:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ProfileError(f"{name} = {v!r} is invalid: must be a finite number (degC)")
                object.__setattr__(self, name, float(v))
        object.__setattr__(self, "label", str(self.label))


@dataclass(frozen=True)
class ImuProfile:
    """A named sequence of :class:`Segment` (module docstring).

    Attributes:
        name: profile name.
        segments: the segments, in order (at least one).
        settle_s: leading seconds of each segment a calibration should ignore, s (>= 0).
    """

    name: str
    segments: tuple[Segment, ...]
    settle_s: float = 1.0

    def __post_init__(self) -> None:
        segs = tuple(self.segments)
        if not segs or not all(isinstance(s, Segment) for s in segs):
            raise ProfileError(f"profile {self.name!r}: segments must be one or more Segment")
        settle = float(self.settle_s)
        if not (math.isfinite(settle) and settle >= 0.0):
            raise ProfileError(
                f"profile {self.name!r}: settle_s = {self.settle_s!r} is invalid: must be >= 0 s"
            )
        object.__setattr__(self, "segments", segs)
        object.__setattr__(self, "settle_s", settle)

    def duration_s(self) -> float:
        """Total duration, s (sum of the segments' durations)."""
        return float(math.fsum(s.duration_s for s in self.segments))

    def start_times_s(self) -> np.ndarray:
        """Start time of each segment, s, (n_segments,) float64."""
        return np.array(
            [math.fsum(s.duration_s for s in self.segments[:i]) for i in range(len(self.segments))]
        )

    def segment_starts(self, fs: float) -> np.ndarray:
        """First sample index of each segment at sample rate ``fs`` (Hz): round(t_i fs),
        int64 (n_segments,); segment i covers that index up to the next start - 1."""
        return np.rint(self.start_times_s() * float(fs)).astype(np.int64)

    def n_samples(self, fs: float) -> int:
        """Samples of the whole profile at ``fs`` (Hz): round(duration fs)."""
        return int(round(self.duration_s() * float(fs)))


class ProfileTruth(NamedTuple):
    """Ground truth of n consecutive samples of a profile (body frame, SI).

    gyro: (n,3) angular rate, rad/s. accel: (n,3) specific force, m/s^2.
    temperature_c: (n,) degC. segment: (n,) int32 segment number, -1 after the profile's end
    (where the truth holds the last segment's final state).
    """

    gyro: np.ndarray
    accel: np.ndarray
    temperature_c: np.ndarray
    segment: np.ndarray


def profile_truth(
    profile: ImuProfile,
    first_index: int,
    n: int,
    fs: float,
    temperature_c: float = 25.0,
    g: float = G0,
    delay_s: float = 0.0,
) -> ProfileTruth:
    """Truth of samples ``first_index .. first_index + n - 1`` of ``profile`` (module
    docstring: f = g up_body, w = rate up_body, linear temperature ramp per segment).

    Args:
        profile: the profile.
        first_index: index of the first sample (t = index / fs), >= 0.
        n: number of samples, >= 0.
        fs: sample rate, Hz (> 0).
        temperature_c: device temperature, degC, for segments without their own.
        g: magnitude of gravity, m/s^2 (default standard gravity).
        delay_s: the truth of time t - delay_s for the sample of time t, s (a sensor's
            latency; before the profile's start the first segment's state).
    Returns:
        :class:`ProfileTruth`.
    """
    fs = float(fs)
    if not fs > 0.0:
        raise ValueError(f"fs = {fs!r} Hz must be > 0")
    if int(first_index) < 0 or int(n) < 0:
        raise ValueError(f"first_index = {first_index!r} and n = {n!r} must be >= 0")
    segs = profile.segments
    starts = profile.segment_starts(fs)
    t_start = profile.start_times_s()
    end = profile.n_samples(fs)
    idx = int(first_index) + np.arange(int(n), dtype=np.int64)
    if delay_s != 0.0:
        idx = idx - float(delay_s) * fs  # fractional sample positions of t - delay
    seg = np.searchsorted(starts, idx, side="right") - 1
    after = idx >= end
    seg = np.where(after, len(segs) - 1, np.maximum(seg, 0))
    up = np.array([s.up_body for s in segs])
    rate = np.array([s.rate_rad_s for s in segs])
    t0 = np.array(
        [temperature_c if s.temperature_start_c is None else s.temperature_start_c for s in segs]
    )
    t1 = np.array(
        [t0[i] if s.temperature_end_c is None else s.temperature_end_c for i, s in enumerate(segs)]
    )
    dur = np.array([s.duration_s for s in segs])
    t = idx / fs
    frac = np.clip((t - t_start[seg]) / dur[seg], 0.0, 1.0)
    frac = np.where(after, 1.0, frac)
    temperature = t0[seg] + (t1[seg] - t0[seg]) * frac
    accel = g * up[seg]
    gyro = rate[seg, None] * up[seg]
    seg_out = np.where(after, -1, seg).astype(np.int32)
    return ProfileTruth(gyro, accel, temperature, seg_out)


# ------------------------------------------------------------------------------ built-ins
_SIX = (
    ((1.0, 0.0, 0.0), "x_up"),
    ((-1.0, 0.0, 0.0), "x_down"),
    ((0.0, 1.0, 0.0), "y_up"),
    ((0.0, -1.0, 0.0), "y_down"),
    ((0.0, 0.0, 1.0), "z_up"),
    ((0.0, 0.0, -1.0), "z_down"),
)
_TABLE_RATE = 100.0 * _DEG  # rad/s
_SEGMENT_S = 60.0


def _six_position() -> tuple[Segment, ...]:
    return tuple(Segment(_SEGMENT_S, up, label=label) for up, label in _SIX)


def _rate_runs() -> tuple[Segment, ...]:
    out = []
    for up, axis in (((1.0, 0.0, 0.0), "x"), ((0.0, 1.0, 0.0), "y"), ((0.0, 0.0, 1.0), "z")):
        out.append(Segment(_SEGMENT_S, up, _TABLE_RATE, label=f"{axis}_up_+100dps"))
        out.append(Segment(_SEGMENT_S, up, -_TABLE_RATE, label=f"{axis}_up_-100dps"))
    return tuple(out)


def _ramped(segments: tuple[Segment, ...], t_from: float, t_to: float) -> tuple[Segment, ...]:
    """The segments with one linear temperature ramp t_from -> t_to (degC) over all of them."""
    total = math.fsum(s.duration_s for s in segments)
    out, t = [], 0.0
    for s in segments:
        a = t_from + (t_to - t_from) * t / total
        t += s.duration_s
        b = t_from + (t_to - t_from) * t / total
        out.append(Segment(s.duration_s, s.up_body, s.rate_rad_s, a, b, s.label))
    return tuple(out)


def _thermal_ramp() -> tuple[Segment, ...]:
    n = 40  # 20 -> 60 degC at 1 K/min: 2400 s in 60 s segments
    segs = tuple(
        Segment(
            _SEGMENT_S,
            (0.0, 0.0, 1.0),
            _TABLE_RATE if i % 2 == 0 else -_TABLE_RATE,
            label=f"z_up_{'+' if i % 2 == 0 else '-'}100dps",
        )
        for i in range(n)
    )
    return _ramped(segs, 20.0, 60.0)


_BUILDERS = {
    "six_position": _six_position,
    "multi_position": lambda: _six_position() + _rate_runs(),
    "thermal_ramp": _thermal_ramp,
    "thermal_multi_position": lambda: _ramped((_six_position() + _rate_runs()) * 4, 20.0, 60.0),
}

#: Names of the built-in profiles (module docstring).
BUILTIN_PROFILES: tuple[str, ...] = tuple(_BUILDERS)


def builtin_profile(name: str) -> ImuProfile:
    """The built-in profile ``name`` (one of :data:`BUILTIN_PROFILES`, module docstring)."""
    if name not in _BUILDERS:
        raise ProfileError(
            f"unknown IMU profile {name!r}: built-in are {', '.join(BUILTIN_PROFILES)}"
        )
    return ImuProfile(name, _BUILDERS[name](), settle_s=1.0)


# ------------------------------------------------------------------------------ YAML
_SEGMENT_KEYS = (
    "duration_s",
    "up_body",
    "rate_deg_s",
    "rate_rad_s",
    "temperature_start_c",
    "temperature_end_c",
    "label",
)


def _number(where: str, value: Any, *, optional: bool = False) -> float | None:
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProfileError(f"{where} = {value!r} is invalid: must be a number")
    return float(value)


def profile_from_dict(data: Any, default_name: str = "profile") -> ImuProfile:
    """A profile from the mapping of the YAML format (module docstring); every error is a
    :class:`ProfileError` naming the field (e.g. ``segments[2].duration_s``)."""
    if not isinstance(data, dict):
        raise ProfileError(f"profile must be a mapping with 'segments', got {type(data).__name__}")
    unknown = set(data) - {"name", "settle_s", "segments"}
    if unknown:
        raise ProfileError(
            f"unknown profile field(s) {sorted(map(str, unknown))}: allowed name, settle_s, "
            "segments"
        )
    name = str(data.get("name", default_name))
    settle = _number("settle_s", data.get("settle_s", 1.0))
    raw = data.get("segments")
    if not isinstance(raw, list) or not raw:
        raise ProfileError(f"segments = {raw!r} is invalid: must be a non-empty list")
    segs = []
    for i, item in enumerate(raw):
        where = f"segments[{i}]"
        if not isinstance(item, dict):
            raise ProfileError(f"{where} = {item!r} is invalid: must be a mapping")
        unknown = set(item) - set(_SEGMENT_KEYS)
        if unknown:
            raise ProfileError(
                f"{where}: unknown field(s) {sorted(map(str, unknown))}: allowed "
                + ", ".join(_SEGMENT_KEYS)
            )
        for key in ("duration_s", "up_body"):
            if key not in item:
                raise ProfileError(f"{where}.{key} is missing")
        if "rate_deg_s" in item and "rate_rad_s" in item:
            raise ProfileError(f"{where}: give rate_deg_s or rate_rad_s, not both")
        rate = 0.0
        if "rate_deg_s" in item:
            rate = _number(f"{where}.rate_deg_s", item["rate_deg_s"]) * _DEG
        elif "rate_rad_s" in item:
            rate = _number(f"{where}.rate_rad_s", item["rate_rad_s"])
        up = item["up_body"]
        if not isinstance(up, list) or len(up) != 3:
            raise ProfileError(f"{where}.up_body = {up!r} is invalid: must be a list of 3 numbers")
        up = tuple(_number(f"{where}.up_body[{j}]", v) for j, v in enumerate(up))
        try:
            segs.append(
                Segment(
                    _number(f"{where}.duration_s", item["duration_s"]),
                    up,
                    rate,
                    _number(
                        f"{where}.temperature_start_c",
                        item.get("temperature_start_c"),
                        optional=True,
                    ),
                    _number(
                        f"{where}.temperature_end_c", item.get("temperature_end_c"), optional=True
                    ),
                    str(item.get("label", "")),
                )
            )
        except ProfileError as exc:
            raise ProfileError(f"{where}.{exc}") from None
    return ImuProfile(name, tuple(segs), settle)


def profile_to_dict(profile: ImuProfile) -> dict:
    """The YAML mapping of ``profile`` (rates in rad/s, exact round trip)."""
    segs = []
    for s in profile.segments:
        d: dict[str, Any] = {
            "duration_s": s.duration_s,
            "up_body": list(s.up_body),
            "rate_rad_s": s.rate_rad_s,
        }
        if s.temperature_start_c is not None:
            d["temperature_start_c"] = s.temperature_start_c
        if s.temperature_end_c is not None:
            d["temperature_end_c"] = s.temperature_end_c
        if s.label:
            d["label"] = s.label
        segs.append(d)
    return {"name": profile.name, "settle_s": profile.settle_s, "segments": segs}


def dump_profile(profile: ImuProfile, path: str | Path | None = None) -> str:
    """YAML text of ``profile`` (written to ``path`` if given); :func:`load_profile` reads
    it back to an equal profile."""
    import yaml

    text = yaml.safe_dump(profile_to_dict(profile), sort_keys=False)
    if path is not None:
        Path(path).write_text(text)
    return text


def load_profile(path_or_name: str | Path) -> ImuProfile:
    """A built-in profile by name (:data:`BUILTIN_PROFILES`) or a profile YAML file
    (format in the module docstring).

    Raises:
        ProfileError: unknown name / missing file, unreadable YAML, or an invalid field
            (the message names the file and the field).
    """
    key = str(path_or_name)
    if key in _BUILDERS:
        return builtin_profile(key)
    path = Path(key)
    if not path.is_file():
        raise ProfileError(
            f"IMU profile {key!r} is neither a built-in ({', '.join(BUILTIN_PROFILES)}) "
            "nor a readable YAML file"
        )
    import yaml

    try:
        data = bounded_yaml.load_file(path)
    except (OSError, yaml.YAMLError) as exc:
        reason = bounded_yaml.problem(exc) if isinstance(exc, yaml.YAMLError) else exc
        raise ProfileError(f"IMU profile file {key!r}: cannot read YAML: {reason}") from None
    try:
        return profile_from_dict(data, default_name=path.stem)
    except ProfileError as exc:
        raise ProfileError(f"IMU profile file {key!r}: {exc}") from None

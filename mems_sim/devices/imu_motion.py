"""Motion and environment inputs of the IMU emulator: a 6-DoF trajectory (attitude and,
optionally, position) from a CSV file, the Earth's rate, a gravity model, vibration of the
specific force, and the truth of every motion kind at the sample times (with a sensor
latency). ROS-free; docs/imu.md, "Motion and vibration inputs".

Frames (REP-103, REP-145, as docs/imu.md): the navigation frame n is a local-level ENU
frame fixed to the Earth at the IMU's site (x east, y north, z up), the body frame b is FLU
(x forward, y left, z up). The attitude is the rotation of b into n: a quaternion
``q = (qw, qx, qy, qz)`` (Hamilton, scalar first; v_n = q v_b q*, what
``geometry_msgs/Quaternion`` of a body in an ENU frame holds, there in x, y, z, w order) or
Euler angles roll, pitch, yaw (intrinsic z-y'-x'': C_b^n = Rz(yaw) Ry(pitch) Rx(roll), yaw
counter-clockwise from east about up, REP-103).

Truth (body frame, SI), with C_n^b = (C_b^n)^T::

    omega_ib^b = omega_nb^b + C_n^b omega_ie^n                      (rad/s)
    f^b        = C_n^b (a^n + 2 omega_ie^n x v^n + [0, 0, g])        (m/s^2)
    omega_ie^n = Omega_e [0, cos(lat), sin(lat)]      (only with ``earth_rate``)

omega_nb^b from the attitude (q* dq/dt = omega_nb^b / 2), v^n and a^n the first and
second derivatives of the position; the transport rate and the centripetal term of the
Earth's rate on the offset from the site (Omega_e^2 r = 5.3e-9 m/s^2 per m) are neglected
(a local tangent plane); g is the magnitude of gravity of ``gravity_model``, which already
contains the centripetal acceleration of the site. At rest and level: f^b = [0, 0, +g], the
convention of :func:`mems_sim.devices.imu.truth_motion`.

**Trajectory CSV** (:func:`load_trajectory`): a header line naming the columns, then one
row per time, comma-separated; lines starting with ``#`` and blank lines are skipped.
Columns: ``time_s``, then either ``qw, qx, qy, qz`` or ``roll_deg, pitch_deg, yaw_deg`` (or
``roll_rad, pitch_rad, yaw_rad``), then optionally ``x_m, y_m, z_m`` (position in n). Times
strictly increasing; sample k of the stream is CSV time ``t_0 + k / fs``, and the stream
ends at ``t_end`` (``round((t_end - t_0) fs)`` samples) unless ``duration_s`` is given; past
the end (and before the start, with a latency) the IMU holds the end (start) attitude and
position at rest. The quaternion's sign may flip between rows (q and -q are one attitude):
the reader makes it continuous; its norm is not required to be 1.

**Derivatives.** The four quaternion components and the three position coordinates are
each interpolated by a spline of degree :data:`SPLINE_DEGREE` = 7 through the rows
(``scipy.interpolate.make_interp_spline``, not-a-knot ends); omega_nb^b = 2 vec(q* dq/dt) /
|q|^2 (exact for a spline q of any norm: a scalar factor cancels) and a^n the spline's
second derivative. The interpolation error of the k-th derivative of a degree-7 spline
with row spacing h is O(h^(8-k)) times the 8th derivative of the motion (de Boor, A Practical
Guide to Splines, 2001, Ch. XII): for a motion of frequency f_m, relative errors of the
order (2 pi f_m h)^7 for the rates and (2 pi f_m h)^6 for the specific force. Measured
(tests, 1 kHz rows): a 2 Hz coning motion of 10 deg reproduces its rates and specific force
to < 1e-9 of their amplitudes; write the rows at least 50 times faster than the fastest
motion for that. The rows need not be at the IMU's rate.

**Earth rate and gravity.** Omega_e = 7.292115e-5 rad/s and the WGS-84 normal gravity of
Somigliana's formula with the second-order height series (NIMA TR8350.2, 3rd ed., 2000,
Table 3.1 and eqs. (4-1), (4-3)); at 45 deg latitude the Earth's rate is 15.041 deg/h,
10.636 deg/h north and up. For the simple motions (static, constant rate and sinusoid
about z) the attitude is level with yaw psi(t) the integral of the rate from psi(0) = 0;
a calibration profile fixes only the up vector, so the Earth's rate is refused with it.

**Vibration** (:class:`Vibration`) is added to the true specific force in the body frame:
a sinusoid of peak amplitude A_a per axis, or band-limited random vibration of one-sided
PSD S_a over [f_lo, f_hi], realised as a sum of sinusoids of equal spacing df at the
line centres f_lo + (j + 1/2) df, amplitude sqrt(2 S_a df) and independent uniform phases
(the spectral representation of Shinozuka & Deodatis, Appl. Mech. Rev. 44(4), 1991):
variance S_a (f_hi - f_lo), Gaussian as the number of lines grows, periodic after 2/df.
The phases come from stream 10 of the run seed (``SeedSequence(seed).spawn(11)[10]``; the
IMU model's streams are 0-9). Both are functions of time, so any frame split and any
latency give the same values. Frequencies must stay below fs/2 (the truth is sampled).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numba
import numpy as np

from mems_sim import bounded_yaml
from mems_sim.devices.imu_motion_specs import AXES, ENVIRONMENT_SPECS, VIBRATION_SPECS
from mems_sim.devices.imu_profiles import ImuProfile, profile_truth
from mems_sim.devices.imu_specs import G0, LATENCY_SPEC

__all__ = [
    "EARTH_RATE",
    "SPLINE_DEGREE",
    "MAX_CSV_BYTES",
    "TrajectoryError",
    "Trajectory",
    "TrajectoryState",
    "Vibration",
    "MotionTruth",
    "ImuMotion",
    "normal_gravity",
    "earth_rate_nav",
    "quat_multiply",
    "quat_conjugate",
    "quat_to_dcm",
    "euler_to_quat",
    "load_trajectory",
    "parse_trajectory",
]

#: Earth's rotation rate, rad/s (WGS-84, NIMA TR8350.2 Table 3.1).
EARTH_RATE = 7.292115e-5
#: Degree of the interpolating splines of the trajectory (module docstring).
SPLINE_DEGREE = 7
#: Largest trajectory CSV read, bytes.
MAX_CSV_BYTES = 64 * 1024 * 1024

# WGS-84 (NIMA TR8350.2, 3rd ed., Table 3.1 and Sec. 4)
_A = 6378137.0  # semi-major axis, m
_F = 1.0 / 298.257223563  # flattening
_GAMMA_E = 9.7803253359  # normal gravity at the equator, m/s^2
_K_SOMIGLIANA = 0.00193185265241  # Somigliana's constant
_E2 = 6.69437999014e-3  # first eccentricity squared
_M = 0.00344978650684  # omega^2 a^2 b / GM


class TrajectoryError(ValueError):
    """An invalid trajectory file (one line naming the file, the line and the field)."""


def normal_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS-84 normal gravity, m/s^2: Somigliana's closed formula on the ellipsoid (NIMA
    TR8350.2 eq. (4-1)) times the second-order height series of eq. (4-3)::

        gamma(lat)    = gamma_e (1 + k sin^2 lat) / sqrt(1 - e^2 sin^2 lat)
        gamma(lat, h) = gamma(lat) [1 - 2/a (1 + f + m - 2 f sin^2 lat) h + 3 h^2 / a^2]

    Args:
        latitude_deg: geodetic latitude, deg, [-90, 90].
        height_m: ellipsoidal height, m.
    """
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    gamma = _GAMMA_E * (1.0 + _K_SOMIGLIANA * s2) / math.sqrt(1.0 - _E2 * s2)
    h = float(height_m)
    return gamma * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 * h * h / _A**2)


def earth_rate_nav(latitude_deg: float) -> np.ndarray:
    """The Earth's rate in the local ENU frame, rad/s: Omega_e [0, cos lat, sin lat]."""
    lat = math.radians(latitude_deg)
    return np.array([0.0, EARTH_RATE * math.cos(lat), EARTH_RATE * math.sin(lat)])


# ---------------------------------------------------------------------------- quaternions
def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p q of (..., 4) scalar-first quaternions."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """q* of (..., 4) scalar-first quaternions."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """C_b^n (..., 3, 3) of (..., 4) quaternions q (normalised here): v_n = C v_b."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def euler_to_quat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions of C_b^n = Rz(yaw) Ry(pitch) Rx(roll), angles in rad."""
    half = [np.asarray(a, dtype=float) / 2.0 for a in (roll, pitch, yaw)]
    (cr, sr), (cp, sp), (cy, sy) = ((np.cos(a), np.sin(a)) for a in half)
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=-1,
    )


def _rotate_to_body(dcm: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C_n^b v for (n, 3, 3) C_b^n and (n, 3) or (3,) v, written out (no BLAS reduction)."""
    v = np.broadcast_to(v, (dcm.shape[0], 3))
    return np.stack(
        [
            dcm[:, 0, j] * v[:, 0] + dcm[:, 1, j] * v[:, 1] + dcm[:, 2, j] * v[:, 2]
            for j in range(3)
        ],
        axis=-1,
    )


# ----------------------------------------------------------------------------- trajectory
_ATTITUDE_COLUMNS = {
    "quaternion": ("qw", "qx", "qy", "qz"),
    "euler_deg": ("roll_deg", "pitch_deg", "yaw_deg"),
    "euler_rad": ("roll_rad", "pitch_rad", "yaw_rad"),
}
_POSITION_COLUMNS = ("x_m", "y_m", "z_m")


class TrajectoryState(NamedTuple):
    """A trajectory at n times (navigation frame ENU, body FLU, SI).

    dcm: (n, 3, 3) C_b^n. omega_nb: (n, 3) body rate relative to n, rad/s, body frame.
    velocity, acceleration: (n, 3) in n, m/s and m/s^2 (zeros without a position).
    """

    dcm: np.ndarray
    omega_nb: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@dataclass(frozen=True)
class Trajectory:
    """Attitude (and position) rows of a 6-DoF motion, interpolated by splines (module
    docstring).

    Attributes:
        name: for messages (the file name).
        time_s: (m,) strictly increasing times, s.
        quaternion: (m, 4) attitude quaternions, sign made continuous.
        position: (m, 3) positions in n, m, or None (at the site).
    """

    name: str
    time_s: np.ndarray
    quaternion: np.ndarray
    position: np.ndarray | None = None
    _splines: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        from scipy.interpolate import make_interp_spline

        t = np.asarray(self.time_s, dtype=float)
        if t.ndim != 1 or t.size < SPLINE_DEGREE + 1:
            raise TrajectoryError(
                f"trajectory {self.name!r}: {t.size} rows, need at least {SPLINE_DEGREE + 1}"
            )
        q = np.array(self.quaternion, dtype=float)
        # q and -q are one attitude: keep each row in the hemisphere of the previous one
        flips = np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0.0) % 2
        q[1:][flips == 1] *= -1.0
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "quaternion", q)
        splines = [make_interp_spline(t, q, k=SPLINE_DEGREE)]
        if self.position is not None:
            p = np.asarray(self.position, dtype=float)
            object.__setattr__(self, "position", p)
            splines.append(make_interp_spline(t, p, k=SPLINE_DEGREE))
        object.__setattr__(self, "_splines", tuple(splines))

    def duration_s(self) -> float:
        """t_end - t_0, s."""
        return float(self.time_s[-1] - self.time_s[0])

    def n_samples(self, fs: float) -> int:
        """Samples of the trajectory at ``fs`` (Hz): round(duration fs)."""
        return int(round(self.duration_s() * float(fs)))

    def state(self, t: np.ndarray) -> TrajectoryState:
        """The motion at times ``t`` (s from the first row, (n,)); outside the rows the
        end (start) attitude and position at rest."""
        t0, t1 = self.time_s[0], self.time_s[-1]
        tau = np.asarray(t, dtype=float) + t0
        inside = ((tau >= t0) & (tau <= t1))[:, None]
        tau = np.clip(tau, t0, t1)
        qs = self._splines[0]
        q, dq = qs(tau), qs(tau, 1)
        rel = quat_multiply(quat_conjugate(q), dq)
        omega = np.where(inside, 2.0 * rel[:, 1:] / np.sum(q * q, axis=1)[:, None], 0.0)
        vel = acc = np.zeros((tau.size, 3))
        if len(self._splines) > 1:
            ps = self._splines[1]
            vel = np.where(inside, ps(tau, 1), 0.0)
            acc = np.where(inside, ps(tau, 2), 0.0)
        return TrajectoryState(quat_to_dcm(q), omega, vel, acc)


def _fail(name: str, where: str, what: str) -> TrajectoryError:
    return TrajectoryError(f"trajectory file {name!r}{where}: {what}")


def parse_trajectory(text: str, name: str = "trajectory") -> Trajectory:
    """A :class:`Trajectory` from the CSV text of the module docstring's format; every error
    is one line naming the file (``name``), the line and the column."""
    lines = [
        (i + 1, line.strip())
        for i, line in enumerate(text.splitlines())
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise _fail(name, "", "no header line (time_s, qw, qx, qy, qz, ...)")
    head_no, head = lines[0]
    columns = [c.strip() for c in head.split(",")]
    kind = next(
        (k for k, cols in _ATTITUDE_COLUMNS.items() if columns[1 : 1 + len(cols)] == list(cols)),
        None,
    )
    if columns[:1] != ["time_s"] or kind is None:
        allowed = " | ".join(", ".join(c) for c in _ATTITUDE_COLUMNS.values())
        raise _fail(
            name,
            f" line {head_no}",
            f"header {head!r} is invalid: must be time_s, then {allowed}, then optionally "
            + ", ".join(_POSITION_COLUMNS),
        )
    n_att = len(_ATTITUDE_COLUMNS[kind])
    rest = columns[1 + n_att :]
    if rest not in ([], list(_POSITION_COLUMNS)):
        raise _fail(
            name,
            f" line {head_no}",
            f"columns {rest} after the attitude are invalid: none or "
            + ", ".join(_POSITION_COLUMNS),
        )
    width = len(columns)
    rows = np.empty((len(lines) - 1, width))
    for r, (no, line) in enumerate(lines[1:]):
        cells = line.split(",")
        if len(cells) != width:
            raise _fail(name, f" line {no}", f"{len(cells)} values, the header has {width}")
        for c, cell in enumerate(cells):
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise _fail(
                    name, f" line {no}", f"{columns[c]} = {cell.strip()!r} is not a finite number"
                )
            rows[r, c] = v
    if rows.shape[0] < SPLINE_DEGREE + 1:
        raise _fail(name, "", f"{rows.shape[0]} rows, need at least {SPLINE_DEGREE + 1}")
    t = rows[:, 0]
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        no = lines[1 + bad[0] + 1][0]
        raise _fail(
            name, f" line {no}", f"time_s = {float(t[bad[0] + 1])!r} is not after the row before"
        )
    att = rows[:, 1 : 1 + n_att]
    if kind == "quaternion":
        q = att
        zero = np.flatnonzero(np.linalg.norm(q, axis=1) < 1e-6)
        if zero.size:
            raise _fail(name, f" line {lines[1 + zero[0]][0]}", "quaternion of (near) zero norm")
    else:
        scale = math.pi / 180.0 if kind == "euler_deg" else 1.0
        q = euler_to_quat(*(att[:, j] * scale for j in range(3)))
    pos = rows[:, 1 + n_att :] if rest else None
    return Trajectory(name, t, q, pos)


def load_trajectory(path: str | os.PathLike) -> Trajectory:
    """A trajectory CSV file (module docstring), read through the project's bounded reader
    (a regular file of at most :data:`MAX_CSV_BYTES`, UTF-8).

    Raises:
        TrajectoryError: one line naming the file and the problem.
    """
    key = str(path)
    try:
        text = bounded_yaml.read_text(Path(key), MAX_CSV_BYTES)
    except (OSError, bounded_yaml.YamlLimitError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise TrajectoryError(f"trajectory file {key!r}: cannot read: {reason}") from None
    return parse_trajectory(text, key)


# ------------------------------------------------------------------------------ vibration
@numba.njit(cache=True)
def _multisine(t, freq, amp, phase, out):
    """out[k, a] += sum_j amp[a, j] sin(2 pi freq[j] t[k] + phase[a, j]), summed in j order."""
    two_pi = 2.0 * math.pi
    for k in range(t.shape[0]):
        for a in range(amp.shape[0]):
            s = 0.0
            for j in range(freq.shape[0]):
                s += amp[a, j] * math.sin(two_pi * freq[j] * t[k] + phase[a, j])
            out[k, a] += s


@dataclass(frozen=True)
class Vibration:
    """Vibration of the specific force, body frame (module docstring).

    Attributes:
        kind: "none", "sinusoid" or "random".
        amplitude: (3,) peak amplitudes of "sinusoid", m/s^2.
        frequency_hz, phase_rad: of "sinusoid".
        psd: (3,) one-sided PSD levels of "random", (m/s^2)^2/Hz.
        band_hz: (f_lo, f_hi) of "random", Hz.
        resolution_hz: line spacing df of "random", Hz.
        seed: run seed (phases from its stream 10).
    """

    kind: str = "none"
    amplitude: tuple = (0.0, 0.0, 0.0)
    frequency_hz: float = 10.0
    phase_rad: float = 0.0
    psd: tuple = (0.0, 0.0, 0.0)
    band_hz: tuple = (1.0, 40.0)
    resolution_hz: float = 0.1
    seed: int = 0
    _lines: tuple = field(init=False, repr=False, compare=False)

    @classmethod
    def from_values(cls, values: Mapping[str, Any], seed: int = 0) -> Vibration:
        """From the parameters of :data:`~mems_sim.devices.imu_motion_specs.VIBRATION_SPECS`."""
        v = values
        return cls(
            kind=v["vibration"],
            amplitude=tuple(float(v[f"vibration_amplitude_{a}"]) for a in AXES),
            frequency_hz=float(v["vibration_frequency_hz"]),
            phase_rad=float(v["vibration_phase_rad"]),
            psd=tuple(float(v[f"vibration_psd_{a}"]) for a in AXES),
            band_hz=(float(v["vibration_band_low_hz"]), float(v["vibration_band_high_hz"])),
            resolution_hz=float(v["vibration_resolution_hz"]),
            seed=int(seed),
        )

    def __post_init__(self) -> None:
        lines = ()
        if self.kind == "random":
            lo, hi = self.band_hz
            if not hi > lo:
                raise ValueError(
                    f"parameter 'vibration_band_high_hz' = {hi!r} is invalid: must be above "
                    f"vibration_band_low_hz = {lo!r} Hz"
                )
            m = max(1, int(round((hi - lo) / self.resolution_hz)))
            df = (hi - lo) / m
            freq = lo + (np.arange(m) + 0.5) * df
            child = np.random.SeedSequence(int(self.seed)).spawn(11)[10]
            phase = np.random.Generator(np.random.PCG64(child)).uniform(0.0, 2 * math.pi, (3, m))
            amp = np.sqrt(2.0 * np.asarray(self.psd, dtype=float)[:, None] * df) * np.ones((1, m))
            axes = np.flatnonzero(np.asarray(self.psd) > 0.0)  # only the vibrating axes
            lines = (freq, amp, phase, axes)
        elif self.kind not in ("none", "sinusoid"):
            raise ValueError(f"vibration kind {self.kind!r} is invalid: none, sinusoid, random")
        object.__setattr__(self, "_lines", lines)

    def max_frequency_hz(self) -> float:
        """Highest frequency present, Hz (0 for none)."""
        if self.kind == "sinusoid":
            return self.frequency_hz
        return self.band_hz[1] if self.kind == "random" else 0.0

    def variance(self) -> np.ndarray:
        """(3,) variance of the vibration per axis, (m/s^2)^2 (A^2/2, or the lines' sum
        of amp^2/2 = S (f_hi - f_lo))."""
        if self.kind == "sinusoid":
            return np.asarray(self.amplitude, dtype=float) ** 2 / 2.0
        if self.kind == "random":
            return np.sum(self._lines[1] ** 2, axis=1) / 2.0
        return np.zeros(3)

    def at(self, t: np.ndarray) -> np.ndarray:
        """(n, 3) vibration at times ``t`` (s), m/s^2."""
        t = np.ascontiguousarray(t, dtype=float)
        out = np.zeros((t.size, 3))
        if self.kind == "sinusoid":
            s = np.sin(2.0 * math.pi * self.frequency_hz * t + self.phase_rad)
            out += s[:, None] * np.asarray(self.amplitude, dtype=float)
        elif self.kind == "random":
            freq, amp, phase, axes = self._lines
            if axes.size:
                part = np.zeros((t.size, axes.size))
                _multisine(t, freq, amp[axes], phase[axes], part)
                out[:, axes] += part
        return out


# ---------------------------------------------------------------------------------- truth
class MotionTruth(NamedTuple):
    """Truth of n samples (body frame, SI): gyro (n,3) rad/s, accel (n,3) m/s^2,
    temperature_c (n,) degC."""

    gyro: np.ndarray
    accel: np.ndarray
    temperature_c: np.ndarray


class ImuMotion:
    """The true motion of every kind at the sample times, with the Earth's rate, gravity,
    vibration and a latency (module docstring).

    Args:
        kind: "static", "constant_rate", "sinusoid", "profile" or "trajectory".
        values: the parameters of ENVIRONMENT_SPECS and VIBRATION_SPECS (and
            ``latency_s``); missing ones take their defaults.
        seed: run seed (vibration phases).
        rate, amplitude, frequency: of "constant_rate" (rad/s) and "sinusoid" (rad/s, Hz).
        profile: the :class:`~mems_sim.devices.imu_profiles.ImuProfile` of "profile".
        trajectory: the :class:`Trajectory` of "trajectory".
        temperature_c: device temperature, degC (profiles: of segments without their own).
    Raises:
        ValueError: the Earth's rate with a profile (no heading).
    """

    def __init__(
        self,
        kind: str,
        values: Mapping[str, Any] | None = None,
        seed: int = 0,
        *,
        rate: float = 0.1,
        amplitude: float = 0.5,
        frequency: float = 1.0,
        profile: ImuProfile | None = None,
        trajectory: Trajectory | None = None,
        temperature_c: float = 25.0,
    ) -> None:
        from mems_sim.params import resolve

        specs = ENVIRONMENT_SPECS + VIBRATION_SPECS + (LATENCY_SPEC,)
        names = {s.name for s in specs}
        v = resolve(specs, {k: x for k, x in (values or {}).items() if k in names})
        if kind == "profile" and profile is None or kind == "trajectory" and trajectory is None:
            raise ValueError(f"motion {kind!r} needs its {kind}")
        if kind == "profile" and v["earth_rate"]:
            raise ValueError(
                "parameter 'earth_rate' = True is invalid with motion 'profile': a profile "
                "segment gives the up vector only, not the heading the Earth's rate needs (use "
                "a trajectory)"
            )
        self.kind = kind
        self.rate, self.amplitude, self.frequency = float(rate), float(amplitude), float(frequency)
        self.profile, self.trajectory = profile, trajectory
        self.temperature_c = float(temperature_c)
        self.latency_s = float(v["latency_s"])
        self.g = (
            G0
            if v["gravity_model"] == "standard"
            else normal_gravity(v["latitude_deg"], v["height_m"])
        )
        self.earth = earth_rate_nav(v["latitude_deg"]) if v["earth_rate"] else None
        self.vibration = Vibration.from_values(v, seed)
        #: whether anything beyond the motion kinds of truth_motion / profile_truth is on
        self._plain = self.earth is None and self.vibration.kind == "none" and self.g == G0

    def n_samples(self, fs: float) -> int | None:
        """Samples of a profile or trajectory at ``fs`` (Hz); None for the endless kinds."""
        if self.profile is not None:
            return self.profile.n_samples(fs)
        if self.trajectory is not None:
            return self.trajectory.n_samples(fs)
        return None

    def truth(
        self, first: int, n: int, fs: float, temperature_c: float | None = None
    ) -> MotionTruth:
        """The true motion of samples ``first .. first + n - 1`` (what the truth topic
        publishes: the motion at the sample's own time t = index / fs); ``temperature_c``
        (degC) replaces the device temperature from these samples on."""
        if temperature_c is not None:
            self.temperature_c = float(temperature_c)
        return self._at(first, n, fs, 0.0)

    def measured(self, first: int, n: int, fs: float, truth: MotionTruth) -> MotionTruth:
        """The motion the sensor measures in those samples: that of t - latency_s (the
        temperature of t); ``truth`` itself without a latency."""
        if self.latency_s == 0.0:
            return truth
        late = self._at(first, n, fs, self.latency_s)
        return MotionTruth(late.gyro, late.accel, truth.temperature_c)

    def _at(self, first: int, n: int, fs: float, delay: float) -> MotionTruth:
        from mems_sim.devices.imu import truth_motion

        temperature = np.full(n, self.temperature_c)
        yaw = None
        if self.kind == "profile":
            p = profile_truth(self.profile, first, n, fs, self.temperature_c, self.g, delay)
            gyro, accel, temperature = p.gyro, p.accel, p.temperature_c
        elif self.kind == "trajectory":
            gyro, accel = self._trajectory(first, n, fs, delay)
        else:
            gyro, accel = truth_motion(
                self.kind,
                first,
                n,
                fs,
                rate=self.rate,
                amplitude=self.amplitude,
                frequency=self.frequency,
                delay_s=delay,
            )
            if self.g != G0:
                accel[:, 2] = self.g
            if self.earth is not None:
                yaw = self._yaw((first + np.arange(n)) / fs - delay)
        if self._plain:
            return MotionTruth(gyro, accel, temperature)
        if yaw is not None:  # level, yaw about up: C_n^b = Rz(yaw)^T
            e = self.earth
            gyro = gyro + np.stack(
                [e[1] * np.sin(yaw), e[1] * np.cos(yaw), np.full(n, e[2])], axis=-1
            )
        if self.vibration.kind != "none":
            accel = accel + self.vibration.at((first + np.arange(n)) / fs - delay)
        return MotionTruth(gyro, accel, temperature)

    def _yaw(self, t: np.ndarray) -> np.ndarray:
        """Heading of the simple motions about z from psi(0) = 0, rad."""
        if self.kind == "constant_rate":
            return self.rate * t
        if self.kind == "sinusoid":
            w = 2.0 * math.pi * self.frequency
            if w == 0.0:
                return np.zeros_like(t)  # sin(0) = 0: no rate
            return self.amplitude / w * (1.0 - np.cos(w * t))
        return np.zeros_like(t)

    def _trajectory(
        self, first: int, n: int, fs: float, delay: float
    ) -> tuple[np.ndarray, np.ndarray]:
        s = self.trajectory.state((first + np.arange(n)) / fs - delay)
        omega = s.omega_nb
        force = s.acceleration.copy()
        force[:, 2] += self.g
        if self.earth is not None:
            omega = omega + _rotate_to_body(s.dcm, self.earth)
            force = force + 2.0 * np.cross(self.earth, s.velocity)
        return omega, _rotate_to_body(s.dcm, force)

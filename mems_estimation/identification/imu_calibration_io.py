"""Files and lists in and out of :mod:`~mems_estimation.identification.imu_calibration`.

Calibration YAML (format in :func:`calibration_to_dict`, :func:`save_yaml` /
:func:`load_yaml`), calibrations from name/value lists (CalibrationResult,
``truth_calibration``) and noise models named on a command line (:func:`noise_option`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mems_estimation.identification.imu_calibration import (
    AXES,
    SENSORS,
    T_REF_C,
    CalibrationError,
    ImuCalibration,
    NoiseSpec,
    neutral_calibration,
    nominal_noise,
)
from mems_sim import bounded_yaml

__all__ = [
    "noise_option",
    "noise_from_identify_json",
    "calibration_to_dict",
    "calibration_from_dict",
    "calibration_from_values",
    "save_yaml",
    "load_yaml",
]


# ------------------------------------------------------------------------------ noise files


def noise_option(text: str) -> dict[str, NoiseSpec] | None:
    """Noise model named on a command line or parameter: an emulator preset name, ``data``
    (None: :func:`estimate_noise`), or an ``identify_noise --json`` file.
    :class:`CalibrationError` with one line otherwise."""
    import json

    from mems_sim.devices.imu import PRESETS

    if text == "data":
        return None
    if text in PRESETS:
        return nominal_noise(text)
    try:
        return noise_from_identify_json(json.loads(Path(text).read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CalibrationError(
            f"noise model {text!r}: not a preset ({', '.join(PRESETS)}), 'data', or a "
            f"readable identify_noise --json file ({' '.join(str(exc).split())[:120]})"
        ) from None


def noise_from_identify_json(data: Mapping) -> dict[str, NoiseSpec]:
    """Noise from ``identify_noise --json`` output (axes gyro_x..z, accel_x..z; values of
    white_noise_density, bias_instability, correlation_time, random_walk)."""
    axes = {a["axis"]: a for a in data["axes"]}
    out = {}
    for s in SENSORS:
        vals = {
            k: [float(axes[f"{s}_{a}"][f]["value"]) for a in AXES]
            for k, f in (
                ("N", "white_noise_density"),
                ("B", "bias_instability"),
                ("T", "correlation_time"),
                ("K", "random_walk"),
            )
        }
        T = [t if math.isfinite(t) and t > 0 else 100.0 for t in vals["T"]]
        out[s] = NoiseSpec.of(vals["N"], vals["B"], T, vals["K"])
    return out


# ------------------------------------------------------------------------------ YAML

FORMAT = "mems_emulator/imu_calibration"
_BLOCKS = {
    "gyroscope": ("gyro", "rad/s"),
    "accelerometer": ("accel", "m/s^2"),
}


def calibration_to_dict(cal: ImuCalibration) -> dict:
    """The YAML mapping of a calibration (format ``mems_emulator/imu_calibration`` v1).

    ::

        format: mems_emulator/imu_calibration
        version: 1
        model: <the measurement model, text>
        t_ref_c: 25.0                  # degC
        method: multi_position_gls
        gyroscope:                     # rad/s
          unit: rad/s
          matrix: [[Cxx, Cxy, Cxz], [Cyx, ...], [...]]   # C, row = output axis, 1
          bias: [bx, by, bz]                              # at t_ref_c, rad/s
          bias_tempco: [...]                              # rad/s/K
          sf_tempco: [...]                                # 1/K
          g_sensitivity: [[...], [...], [...]]            # (rad/s)/(m/s^2)
          correction_matrix: [[...]]   # C^-1, informative: corrected = C^-1 (raw - bias)
        accelerometer:                 # m/s^2, same keys without g_sensitivity
          ...
        standard_errors: {gyro_bias_x: ..., ...}          # SI, estimated parameters only
        estimated: [names]
        aliases: {name: text}

    ``correction_matrix`` with ``bias`` is the compensation form of imu_tk (Tedaldi, Pretto
    & Menegatti, ICRA 2014: corrected = T K (raw - b), T K = C^-1) and of most IMU drivers;
    it is ignored when loading (``matrix`` is authoritative). Noise densities for Kalibr's
    imu.yaml come from ``identify_noise --kalibr``, not from this file.
    """

    def lst(x):
        return np.asarray(x, float).tolist()

    d: dict[str, Any] = {
        "format": FORMAT,
        "version": 1,
        "model": (
            "y = diag(1 + sf_tempco (T - t_ref_c)) C truth + bias + bias_tempco (T - t_ref_c)"
            " (+ g_sensitivity f for the gyroscope); T in degC, SI units"
        ),
        "t_ref_c": float(cal.t_ref_c),
        "method": cal.method,
    }
    for block, (s, unit) in _BLOCKS.items():
        b = {
            "unit": unit,
            "matrix": lst(cal.matrix(s)),
            "bias": lst(cal.vector(s, "bias")),
            "bias_tempco": lst(cal.vector(s, "bias_tempco")),
            "sf_tempco": lst(cal.vector(s, "sf_tempco")),
        }
        if s == "gyro":
            b["g_sensitivity"] = lst(cal.g_sensitivity())
        b["correction_matrix"] = lst(np.linalg.inv(cal.matrix(s)))
        d[block] = b
    d["standard_errors"] = {n: float(cal.standard_errors[n]) for n in cal.estimated}
    d["estimated"] = list(cal.estimated)
    d["aliases"] = dict(cal.aliases)
    return d


def _mat(where, v, shape):
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where} must be numbers of shape {shape}") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise CalibrationError(f"{where} must be finite numbers of shape {shape}, got {v!r}")
    return a


def calibration_from_dict(d: Any) -> ImuCalibration:
    """A calibration from the mapping of :func:`calibration_to_dict` (missing blocks or keys:
    neutral values); :class:`CalibrationError` naming the field otherwise."""
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise CalibrationError(f"not an IMU calibration: 'format' must be {FORMAT!r}")
    cal = neutral_calibration()
    cal.method = str(d.get("method", "loaded"))
    cal.t_ref_c = float(_mat("t_ref_c", d.get("t_ref_c", T_REF_C), ()))
    for block, (s, _) in _BLOCKS.items():
        b = d.get(block) or {}
        if not isinstance(b, dict):
            raise CalibrationError(f"{block} must be a mapping")
        if "matrix" in b:
            m = _mat(f"{block}.matrix", b["matrix"], (3, 3))
            if abs(np.linalg.det(m)) < 1e-6:
                raise CalibrationError(f"{block}.matrix is singular")
            for i, ai in enumerate(AXES):
                for j, bj in enumerate(AXES):
                    cal.values[f"{s}_matrix_{ai}{bj}"] = float(m[i, j])
        for key in ("bias", "bias_tempco", "sf_tempco"):
            if key in b:
                v = _mat(f"{block}.{key}", b[key], (3,))
                for i, ai in enumerate(AXES):
                    cal.values[f"{s}_{key}_{ai}"] = float(v[i])
        if s == "gyro" and "g_sensitivity" in b:
            m = _mat(f"{block}.g_sensitivity", b["g_sensitivity"], (3, 3))
            for i, ai in enumerate(AXES):
                for j, bj in enumerate(AXES):
                    cal.values[f"gyro_g_sensitivity_{ai}{bj}"] = float(m[i, j])
    for n, v in (d.get("standard_errors") or {}).items():
        if n in cal.values:
            cal.standard_errors[n] = float(v)
    cal.estimated = [n for n in d.get("estimated") or [] if n in cal.values]
    cal.aliases = {str(k): str(v) for k, v in (d.get("aliases") or {}).items()}
    return cal


def save_yaml(cal: ImuCalibration, path: str | Path, overwrite: bool = True) -> None:
    """Write ``cal`` as YAML (:func:`calibration_to_dict`), whole or not at all and never
    through a symbolic link (:func:`mems_sim.bag.output_paths.write_output`: an existing
    file only with ``overwrite``); BagWriteError (an OSError, one line) when it cannot."""
    import yaml

    from mems_sim.bag.output_paths import write_output

    text = yaml.safe_dump(calibration_to_dict(cal), sort_keys=False)
    write_output(path, lambda tmp: Path(tmp).write_text(text), overwrite)


def load_yaml(path: str | Path) -> ImuCalibration:
    """Read a calibration YAML; :class:`CalibrationError` with one line on a bad file."""
    import yaml

    try:
        d = bounded_yaml.load_file(path)
    except (OSError, yaml.YAMLError) as exc:
        raise CalibrationError(f"{path}: cannot read YAML: {' '.join(str(exc).split())}") from None
    try:
        return calibration_from_dict(d)
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None


def calibration_from_values(
    names: Sequence[str],
    values: Sequence[float],
    ses: Sequence[float] | None = None,
    method: str = "",
) -> ImuCalibration:
    """A calibration from parallel name/value lists (e.g. a CalibrationResult message; the
    emulator's ``truth_calibration``); names not given keep neutral values."""
    cal = neutral_calibration()
    cal.method = method
    ses = [math.nan] * len(names) if ses is None else ses
    for n, v, e in zip(names, values, ses):
        if n in cal.values:
            cal.values[n] = float(v)
            cal.standard_errors[n] = float(e)
            cal.estimated.append(n)
    return cal

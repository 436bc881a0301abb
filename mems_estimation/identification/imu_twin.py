"""A digital twin of a recorded IMU: the emulator's parameters (``imu_node``) from the noise
identified on the record, its rate, its resolution and its mean.

Per sensor (gyro, accelerometer) the emulator has one value of each stochastic term for its
three axes, so the twin takes the root mean square over the axes of N, B and K (the
geometric mean of T), and the noise model the record's Allan variance prefers over the
three axes together: the sum of their BIC for the Gauss-Markov bump against the flicker
floor (Schwarz, "Estimating the dimension of a model", Ann. Statist. 6(2), 1978). A flicker
floor becomes the emulator's flicker bias (``{s}_flicker_coefficient``, band from a tenth
of 1/(2 pi duration) to fs/2) with the Gauss-Markov term off; a bump becomes the
Gauss-Markov term (``{s}_bias_instability``, ``{s}_correlation_time``). The deterministic
terms the record shows without a calibration: each axis' mean as a constant bias (the
accelerometer's against the emulator's static specific force [0, 0, g]: a record at rest
with z up). The resolution is the record's value step (the LSB) where its values lie on a
grid, else a step far below the white noise. Not seen, so not in the twin: scale factors,
misalignment, temperature terms, the sensor's low-pass (a record's Allan deviation does
not show it), per-axis differences of the stochastic terms.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: Standard gravity [m/s^2] (the emulator's static specific force on z).
G0 = 9.80665
#: Largest relative misfit of a value to the grid of a candidate LSB, -.
GRID_TOLERANCE = 1e-6
#: Step of an off-grid record's twin below its white noise per sample, -.
FINE_STEP = 1e-4
SENSORS = ("gyro", "accel")
AXES = ("x", "y", "z")


def value_resolution(column: np.ndarray) -> float | None:
    """The step of a record's values [their unit]: the smallest difference of distinct
    values when every value is a whole multiple of it (within :data:`GRID_TOLERANCE` of a
    step), else None (values not on a grid, or fewer than two distinct values)."""
    u = np.unique(np.asarray(column, dtype=float))
    if u.size < 2:
        return None
    q = float(np.min(np.diff(u)))
    if not q > 0:
        return None
    k = u / q
    if np.max(np.abs(k - np.rint(k))) > GRID_TOLERANCE * max(1.0, float(np.max(np.abs(k)))):
        return None
    return q


def _rms(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def sensor_model(choices: Sequence) -> str:
    """ "gm" or "flicker": the model with the smaller BIC summed over the axes
    (``NoiseModelChoice`` of each axis); a tie goes to flicker, as per axis."""
    total = {m: sum(c.bic[m] for c in choices) for m in ("gm", "flicker")}
    return "gm" if total["gm"] < total["flicker"] else "flicker"


def _stochastic(s: str, choices: Sequence, fs: float, duration_s: float) -> dict:
    """The stochastic terms of sensor ``s`` from its axes' fits (module doc)."""
    name = sensor_model(choices)
    fits = [c.fits[name] for c in choices]
    out = {
        f"{s}_noise_density": _rms([f.N for f in fits]),
        f"{s}_random_walk": _rms([f.K for f in fits]),
    }
    if name == "gm":
        out[f"{s}_bias_instability"] = _rms([f.B for f in fits])
        ts = [f.T for f in fits if f.T > 0 and math.isfinite(f.T)]
        if ts:
            out[f"{s}_correlation_time"] = math.exp(sum(math.log(t) for t in ts) / len(ts))
        out[f"{s}_flicker_coefficient"] = 0.0
    else:
        out[f"{s}_bias_instability"] = 0.0
        out[f"{s}_flicker_coefficient"] = _rms([f.B for f in fits])
        out[f"{s}_flicker_f_low_hz"] = max(1e-7, 0.1 / (2 * math.pi * duration_s))
        out[f"{s}_flicker_f_high_hz"] = fs / 2
    return out


def twin_parameters(
    choices: Sequence,
    channels: Sequence[str],
    fs: float,
    duration_s: float,
    means: Sequence[float],
    steps: Sequence[float | None],
) -> dict:
    """The ``imu_node`` parameters of the twin (module doc).

    Args:
        choices: per channel, the model choice of its Allan variance (``NoiseModelChoice``).
        channels: the channels, ``gyro_x .. gyro_z, accel_x .. accel_z`` in that order.
        fs: the record's sample rate [Hz]; duration_s: its length [s].
        means: per channel, the record's mean [rad/s or m/s^2].
        steps: per channel, the record's value step (:func:`value_resolution`) or None.
    Returns:
        parameter name -> value (SI), with the model chosen per sensor under
        ``"_models"`` (not a parameter: the file writer leaves it out).
    """
    want = tuple(f"{s}_{a}" for s in SENSORS for a in AXES)
    if tuple(channels) != want:
        raise ValueError(f"a twin needs the channels {', '.join(want)}; got {list(channels)}")
    p: dict = {"preset": "petkov", "sample_rate_hz": float(fs), "latency_s": 0.0}
    models, lsbs, peaks = {}, {}, []
    for i, s in enumerate(SENSORS):
        axes = slice(3 * i, 3 * i + 3)
        p.update(_stochastic(s, choices[axes], fs, duration_s))
        models[s] = sensor_model(choices[axes])
        p[f"{s}_bias"] = 0.0
        static = (0.0, 0.0, G0) if s == "accel" else (0.0, 0.0, 0.0)
        for a, m, g in zip(AXES, means[axes], static, strict=True):
            p[f"{s}_axis_bias_{a}"] = float(m - g)
        grid = [q for q in steps[axes] if q is not None]
        fine = FINE_STEP * p[f"{s}_noise_density"] * math.sqrt(fs)
        lsbs[s] = max(grid) if len(grid) == 3 else (fine if fine > 0 else 1e-9)
        p[f"{s}_lsb"] = lsbs[s]
        peaks.append(max(abs(float(m)) for m in means[axes]) / lsbs[s])
    # both sensors share the converter width: enough codes for the larger mean, with room
    # for the signal (x 8), at most 32 bits
    p["bits"] = int(min(32, max(16, math.ceil(math.log2(max(peaks) * 8 + 1)) + 1)))
    p["_models"] = models
    return p


def twin_yaml(params: dict, source: str) -> str:
    """A ROS 2 parameter file (``--params-file``) of ``params`` for every node
    (``/**``), with a comment naming ``source`` and the models chosen."""
    import yaml

    values = {k: v for k, v in params.items() if not k.startswith("_")}
    models = params.get("_models", {})
    head = (
        f"# Digital twin of {source} (identify_noise --twin): imu_node --ros-args "
        "--params-file THIS\n"
        + "".join(f"# {s}: {m} bias-instability model\n" for s, m in models.items())
    )
    return head + yaml.safe_dump({"/**": {"ros__parameters": values}}, sort_keys=False)

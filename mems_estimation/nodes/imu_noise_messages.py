"""Conversion of identified noise models (mems_estimation.identification.imu_noise_fit) to mems_msgs/NoiseModel."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from mems_estimation.identification.imu_noise_fit import NoiseModelFit, discrete_model
from mems_msgs.msg import AxisNoiseModel, NoiseModel, NoiseTerm

#: NoiseModelFit attribute -> AxisNoiseModel field.
TERM_FIELDS = {
    "N": "white_noise_density",
    "B": "bias_instability",
    "T": "correlation_time",
    "K": "random_walk",
    "Q": "quantization",
}


def noise_term(fit: NoiseModelFit, name: str) -> NoiseTerm:
    """NoiseTerm (value, standard error, 95 % interval) of parameter ``name`` of ``fit``."""
    low, high = fit.ci95.get(name, (math.nan, math.nan))
    return NoiseTerm(
        value=float(getattr(fit, name)),
        standard_error=float(fit.se.get(name, math.nan)),
        ci_low=float(low),
        ci_high=float(high),
    )


def axis_model(
    axis: str, unit: str, fit: NoiseModelFit, allan, fs: float, mean: float
) -> AxisNoiseModel:
    """AxisNoiseModel from one axis' fit and Allan result (SI units)."""
    msg = AxisNoiseModel(axis=axis, unit=unit, mean=float(mean))
    for attr, field in TERM_FIELDS.items():
        setattr(msg, field, noise_term(fit, attr))
    d = discrete_model(fit, fs)
    msg.a_d, msg.b_d, msg.sigma_eta = float(d.a_d), float(d.b_d), float(d.sigma_eta)
    msg.white_std_per_sample = float(d.sigma_white)
    msg.random_walk_increment_std = float(d.sigma_rw_increment)
    msg.tau = [float(v) for v in allan.taus]
    msg.adev = [float(v) for v in allan.adev]
    msg.adev_ci_low = [float(v) for v in allan.ci_low]
    msg.adev_ci_high = [float(v) for v in allan.ci_high]
    return msg


def noise_model_msg(
    results: Sequence,
    axes: Sequence[str],
    units: Sequence[str],
    means: np.ndarray,
    *,
    fs: float,
    first_index: int,
    num_samples: int,
    grid: str,
    final: bool,
    stamp,
    frame_id: str = "",
) -> NoiseModel:
    """NoiseModel message from ``identify_axes`` results, one per axis."""
    msg = NoiseModel(
        first_sample_index=int(first_index),
        num_samples=int(num_samples),
        sample_rate_hz=float(fs),
        tau_grid=grid,
        final=bool(final),
    )
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.axes = [
        axis_model(a, u, fit, allan, fs, m)
        for a, u, (fit, allan), m in zip(axes, units, results, means)
    ]
    return msg

"""MPU-6500-like MEMS gyroscope riding on the micro-stage (Chen 2018 sec. 3.3.1, Table 3.1).

One axis (the stage's main tilt axis) of eq. (20) with temperature-dependent scale
factor and bias::

    omega_I(t_j) = k_I(T) omega(t_j) + omega_I0(T) + n_j,    n_j ~ N(0, (0.1 dps)^2)
    k_I(T)       = k_I,ref (1 + c_k (T - T_ref)),  c_k = -5.43 % / 12.8 K (sec. 3.6.3)
    omega_I0(T)  = b_ref + c_b (T - T_ref)
    code_j       = round(omega_I / lsb), 16 bit, +-2000 dps full scale (Table 3.1)

Own clock: t_j = t_start + j / f_g, f_g = f_nominal (1 + clock_error), asynchronous to the
stage's 625 kHz. Mapping to the graph's time: t_j is on the stage's time base (t = 0 at
stage sample 0, t_start = ``gyro_start_offset_s``), so the node stamps gyro sample j at
``epoch + t_start + j / f_g`` with the stage's epoch, and its frames carry f_g as their
``sample_rate_hz`` and j as the sample index: the gyro's own sample clock, seen through a
perfectly synchronised time base. The rate at t_j is exact: the stage state at the preceding stage sample k
is propagated over t_j - t_k with its held drive (ZOH, eq. 34) using the emulator's true
dynamics (this is the physical input of the gyro, not an estimate).

No digital low-pass is modelled (the MPU-6500 at 8 kHz with the DLPF bypassed has a
wide band; a filter would make the effective scale factor at 1.7 kHz differ from k_I).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from mems_sim.params import ParamSpec, resolve

__all__ = ["GYRO_SPECS", "GyroFrame", "MemsGyro", "DPS"]

DPS = math.pi / 180.0

GYRO_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "gyro_nominal_rate_hz",
        8000.0,
        "Hz",
        "nominal output data rate",
        "sec. 3.6.3: sampled at about 8 kHz",
        min=1.0,
        max=1.0e5,
    ),
    ParamSpec(
        "gyro_clock_error_ppm",
        150.0,
        "ppm",
        "error of the gyro's own clock",
        "assumption (MPU-6500 internal oscillator, +-1 % class)",
        min=-5e4,
        max=5e4,
    ),
    ParamSpec(
        "gyro_start_offset_s",
        3.7e-5,
        "s",
        "time of the first gyro sample after stage sample 0",
        "assumption (asynchronous start)",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_scale_factor_ref",
        1.0,
        "-",
        "scale factor k_I at the reference temperature",
        "Table 3.6: 1.00000 at 22.9 C (after the initial calibration)",
        min=0.5,
        max=1.5,
    ),
    ParamSpec(
        "gyro_sf_tempco_per_k",
        -0.0543 / 12.8,
        "1/K",
        "relative scale-factor change per K",
        "sec. 3.6.3: -5.43 % for +12.8 C",
        min=-0.1,
        max=0.1,
    ),
    ParamSpec(
        "gyro_bias_ref",
        2.0 * DPS,
        "rad/s",
        "bias omega_I0 at the reference temperature",
        "Table 3.1: +-5 dps",
        min=-1.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_bias_tempco",
        0.02 * DPS,
        "rad/s/K",
        "bias change per K",
        "assumption",
        min=-0.1,
        max=0.1,
    ),
    ParamSpec(
        "gyro_ref_temperature_c",
        22.9,
        "degC",
        "reference temperature",
        "Table 3.6",
        min=-60.0,
        max=150.0,
    ),
    ParamSpec(
        "gyro_noise_rms",
        0.1 * DPS,
        "rad/s",
        "total RMS noise per sample",
        "Table 3.1: 0.1 dps-rms",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_full_scale",
        2000.0 * DPS,
        "rad/s",
        "full-scale range (+-)",
        "Table 3.1: +-2000 dps",
        min=0.01,
        max=100.0,
    ),
    ParamSpec("gyro_bits", 16, "bits", "output word length", "MPU-6500: 16-bit", min=8, max=32),
)


class GyroFrame(NamedTuple):
    """Gyro samples in one stage frame: index (m,) gyro sample numbers; t (m,) sample times
    [s, stage time base]; codes (m,) int32; omega_true (m,) rad/s input; value (m,) rad/s
    decoded output; saturated: clipped samples."""

    index: np.ndarray
    t: np.ndarray
    codes: np.ndarray
    omega_true: np.ndarray
    value: np.ndarray
    saturated: int


def _omega_after(theta, omega, u, wn, zeta, b_c, dt):
    """omega(t_k + dt) from (theta_k, omega_k) with u held (row 2 of the ZOH of eq. 34)."""
    wd = wn * np.sqrt(1.0 - zeta * zeta)
    e = np.exp(-zeta * wn * dt)
    c, s = np.cos(wd * dt), np.sin(wd * dt)
    a10 = -e * wn * wn / wd * s
    a11 = e * (c - zeta * wn / wd * s)
    b1 = -a10 / (wn * wn) * b_c
    return a10 * theta + a11 * omega + b1 * u


class MemsGyro:
    """Gyro with its own clock (module doc). ``seed``: run seed of the noise stream."""

    def __init__(
        self, params: Mapping[str, Any] | None = None, seed: int = 0, temperature_c: float = 22.9
    ) -> None:
        self.params = resolve(GYRO_SPECS, params)
        p = self.params
        self.rate = p["gyro_nominal_rate_hz"] * (1.0 + 1e-6 * p["gyro_clock_error_ppm"])
        self.lsb = p["gyro_full_scale"] / 2 ** (p["gyro_bits"] - 1)
        self.code_max = 2 ** (p["gyro_bits"] - 1) - 1
        self._gen = np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed) + 7919)))
        self.temperature_c = float(temperature_c)
        self._next = 0

    def scale_factor(self, temperature_c: float | None = None) -> float:
        """True k_I(T) [-]."""
        p = self.params
        t = self.temperature_c if temperature_c is None else temperature_c
        return p["gyro_scale_factor_ref"] * (
            1.0 + p["gyro_sf_tempco_per_k"] * (t - p["gyro_ref_temperature_c"])
        )

    def bias(self, temperature_c: float | None = None) -> float:
        """True omega_I0(T) [rad/s]."""
        p = self.params
        t = self.temperature_c if temperature_c is None else temperature_c
        return p["gyro_bias_ref"] + p["gyro_bias_tempco"] * (t - p["gyro_ref_temperature_c"])

    def step(
        self,
        k0: int,
        fs: float,
        theta: np.ndarray,
        omega: np.ndarray,
        u: np.ndarray,
        wn: float,
        zeta: float,
        b_c: float,
    ) -> GyroFrame:
        """Gyro samples with times in [k0/fs, (k0+n)/fs) given the stage's true main-axis
        theta, omega and held drive u (incl. its noise) of stage samples k0..k0+n-1."""
        n = omega.size
        p = self.params
        t_end = (k0 + n) / fs
        j0 = self._next
        j1 = max(j0, int(math.ceil((t_end - p["gyro_start_offset_s"]) * self.rate)))
        idx = np.arange(j0, j1)
        t = p["gyro_start_offset_s"] + idx / self.rate
        t = t[t < t_end]
        idx = idx[: t.size]
        k = np.floor(t * fs).astype(np.int64) - k0
        k = np.clip(k, 0, n - 1)
        dt = t - (k + k0) / fs
        w = _omega_after(theta[k], omega[k], u[k], wn, zeta, b_c, dt)
        val = self.scale_factor() * w + self.bias()
        if p["gyro_noise_rms"] > 0:
            val = val + self._gen.standard_normal(w.size) * p["gyro_noise_rms"]
        codes = np.rint(val / self.lsb)
        sat = int(np.count_nonzero(np.abs(codes) > self.code_max))
        codes = np.clip(codes, -self.code_max - 1, self.code_max).astype(np.int32)
        self._next = j0 + idx.size
        return GyroFrame(idx, t, codes, w, codes * self.lsb, sat)

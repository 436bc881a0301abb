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

Digital low-pass filter (off by default: ``gyro_dlpf_cfg = -1``, no filter, the
MPU-6500 at 8 kHz with its DLPF bypassed read as wide band). ``gyro_dlpf_cfg`` = 0..7 is
DLPF_CFG of the MPU-6500's CONFIG register (InvenSense MPU-6500 Register Map and
Descriptions, rev. 2.1, register 26 CONFIG, with FCHOICE_B = 00), whose table gives the
gyro's -3 dB bandwidth f_c, its delay tau and the internal rate (:data:`DLPF_TABLE`; the
revision and the numbers from memory, unchecked against the document). The register map
does not give the filter itself; the model is a stated stand-in with the table's bandwidth
and delay::

    H(z) = z^-d H_1(z),  H_1: first-order Butterworth low-pass at f_c, bilinear transform
                         (prewarped, scipy.signal.butter(1, f_c, fs=f_g)) at the gyro's rate
    |H(e^jw)|^2 = 1 / (1 + Omega^2),  Omega = tan(pi f / f_g) / tan(pi f_c / f_g)
    tau_1(0) = 1/2 - a_1 / (1 + a_1) samples (DC group delay of H_1, a_1 its pole term)
    d = max(0, round(tau f_g - tau_1(0)))   whole samples, so the DC group delay
                                            tau_1(0) + d is the table's tau within 1/2 sample

It acts on the rate signal k_I omega + omega_I0 before the noise (``gyro_noise_rms`` stays
the output's RMS noise) and the output quantiser; its state is carried across frames
(``scipy.signal.sosfilt`` with ``zi``, a sequential recurrence: the samples are the same at
any frame size and on any CPU) and starts in steady state at the first sample. The filter
runs at the gyro's output rate (SMPLRT_DIV = 0), so ``gyro_nominal_rate_hz`` must be the
table's internal rate of that row (8 kHz for DLPF_CFG 0 and 7, 1 kHz for 1-6). The
apparent scale factor at a drive frequency f is then k_I |H(e^{j 2 pi f / f_g})|
(:meth:`MemsGyro.dlpf_response`), no longer k_I.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import scipy.signal

from mems_sim.params import ParameterError, ParamSpec, resolve

__all__ = ["GYRO_SPECS", "GyroFrame", "MemsGyro", "DPS", "DLPF_TABLE", "Dlpf"]

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
    ParamSpec(
        "gyro_dlpf_cfg",
        -1,
        "-",
        "DLPF_CFG of the gyro's digital low-pass (0..7: the register map's row, with "
        "FCHOICE_B = 00; gyro_nominal_rate_hz must be that row's internal rate); -1: no "
        "filter (the DLPF bypassed, a wide-band gyro)",
        "InvenSense MPU-6500 Register Map and Descriptions rev. 2.1, register 26 CONFIG "
        "(revision, bandwidth, delay and rate of each row from memory, unchecked); -1 the "
        "default: the thesis' 8 kHz gyro with no filter modelled",
        min=-1,
        max=7,
    ),
)

#: MPU-6500 gyro DLPF, DLPF_CFG -> (-3 dB bandwidth [Hz], delay [s], internal rate [Hz])
#: with FCHOICE_B = 00 (Register Map rev. 2.1, register 26 CONFIG; from memory, unchecked).
DLPF_TABLE: dict[int, tuple[float, float, float]] = {
    0: (250.0, 0.97e-3, 8000.0),
    1: (184.0, 2.9e-3, 1000.0),
    2: (92.0, 3.9e-3, 1000.0),
    3: (41.0, 5.9e-3, 1000.0),
    4: (20.0, 9.9e-3, 1000.0),
    5: (10.0, 17.85e-3, 1000.0),
    6: (5.0, 33.48e-3, 1000.0),
    7: (3600.0, 0.17e-3, 8000.0),
}


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


class Dlpf:
    """The gyro's DLPF stand-in H(z) = z^-d H_1(z) of the module doc, with its state.

    Args:
        bandwidth_hz: -3 dB bandwidth f_c [Hz] (< rate_hz / 2).
        delay_s: the delay tau the DC group delay is matched to [s].
        rate_hz: the filter's sample rate f_g [Hz].
    """

    def __init__(self, bandwidth_hz: float, delay_s: float, rate_hz: float) -> None:
        self.bandwidth_hz = float(bandwidth_hz)
        self.rate_hz = float(rate_hz)
        lowpass = scipy.signal.butter(1, self.bandwidth_hz, fs=self.rate_hz, output="sos")
        a1 = float(lowpass[0, 4])
        #: DC group delay of H_1 [samples]: 1/2 - a_1/(1 + a_1) (b_0 = b_1, module doc)
        self.lowpass_delay = 0.5 - a1 / (1.0 + a1)
        #: whole samples of pure delay d [-]
        self.delay_samples = max(0, int(round(delay_s * self.rate_hz - self.lowpass_delay)))
        unit_delay = np.array([[0.0, 1.0, 0.0, 1.0, 0.0, 0.0]])  # z^-1 as a section, exact
        self.sos = np.vstack([lowpass] + [unit_delay] * self.delay_samples)
        self._zi: np.ndarray | None = None

    @property
    def group_delay_s(self) -> float:
        """DC group delay of H [s]: (tau_1(0) + d) / f_g."""
        return (self.lowpass_delay + self.delay_samples) / self.rate_hz

    def response(self, freq_hz: np.ndarray | float) -> np.ndarray:
        """H(e^{j 2 pi f / f_g}) [-] at ``freq_hz`` [Hz] (``scipy.signal.sosfreqz``)."""
        f = np.atleast_1d(np.asarray(freq_hz, float))
        return scipy.signal.sosfreqz(self.sos, worN=f, fs=self.rate_hz)[1]

    def steady_state(self, x0: float) -> np.ndarray:
        """Section states (n_sections, 2) of the transposed direct form II at rest under
        the constant input ``x0``: per section with DC gain g = sum(b)/sum(a) and output
        y = g x, z_1 = b_2 x - a_2 y and z_0 = b_1 x - a_1 y + z_1 (closed form, no solver)."""
        zi = np.empty((self.sos.shape[0], 2))
        x = float(x0)
        for i, (b0, b1, b2, _, a1, a2) in enumerate(self.sos):
            y = (b0 + b1 + b2) / (1.0 + a1 + a2) * x
            zi[i, 1] = b2 * x - a2 * y
            zi[i, 0] = b1 * x - a1 * y + zi[i, 1]
            x = y
        return zi

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Filter the next samples ``x`` [input unit] (state carried; the first sample ever
        starts the state at rest, :meth:`steady_state`)."""
        x = np.asarray(x, float)
        if x.size == 0:
            return x.copy()
        if self._zi is None:
            self._zi = self.steady_state(x[0])
        y, self._zi = scipy.signal.sosfilt(self.sos, x, zi=self._zi)
        return y


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
        #: the digital low-pass (module doc), None when ``gyro_dlpf_cfg`` is -1
        self.dlpf = None
        cfg = int(p["gyro_dlpf_cfg"])
        if cfg >= 0:
            bandwidth, delay, internal = DLPF_TABLE[cfg]
            if p["gyro_nominal_rate_hz"] != internal:
                raise ParameterError(
                    f"parameter 'gyro_nominal_rate_hz' = {p['gyro_nominal_rate_hz']!r} is out "
                    f"of range: gyro_dlpf_cfg = {cfg} runs at {internal!r} Hz (the output rate "
                    "is the filter's internal rate)"
                )
            self.dlpf = Dlpf(bandwidth, delay, self.rate)

    def scale_factor(self, temperature_c: float | None = None) -> float:
        """True k_I(T) [-]."""
        p = self.params
        t = self.temperature_c if temperature_c is None else temperature_c
        return p["gyro_scale_factor_ref"] * (
            1.0 + p["gyro_sf_tempco_per_k"] * (t - p["gyro_ref_temperature_c"])
        )

    def dlpf_response(self, freq_hz: np.ndarray | float) -> np.ndarray:
        """H at ``freq_hz`` [Hz] of the digital low-pass (:meth:`Dlpf.response`), 1 without
        it: the apparent scale factor at f is k_I |H| (module doc)."""
        if self.dlpf is None:
            return np.ones(np.atleast_1d(freq_hz).shape, complex)
        return self.dlpf.response(freq_hz)

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
        if self.dlpf is not None:
            val = self.dlpf(val)
        if p["gyro_noise_rms"] > 0:
            val = val + self._gen.standard_normal(w.size) * p["gyro_noise_rms"]
        codes = np.rint(val / self.lsb)
        sat = int(np.count_nonzero(np.abs(codes) > self.code_max))
        codes = np.clip(codes, -self.code_max - 1, self.code_max).astype(np.int32)
        self._next = j0 + idx.size
        return GyroFrame(idx, t, codes, w, codes * self.lsb, sat)

"""IMU error model (3-axis gyro + 3-axis accelerometer): deterministic errors, temperature
dependence and the stochastic terms of Petkov & Slavov.

Measurement model, per sensor s (gyro, accel) and sample k, every vector over the axes
x, y, z, SI units (rad/s for the gyro, m/s^2 for the accelerometer)::

    y_k = D(T_k) C u_k  +  b_T (T_k - T_ref)  +  G f_k + G2 f_k^2 (gyro only)
          + K2 u_k^2 (accelerometer only)
          + b  +  x_k  +  white_k  +  rw_k                                    (1)
    then an optional first-order output low-pass, then ADC quantisation

* u_k: the truth (angular rate, or specific force f_k), T_k the device temperature (degC,
  per sample), T_ref = 25 degC (:data:`T_REF_C`).
* C = I + diag(sf) + M: sf the scale-factor errors per axis as fractions (0.01 = +1 % =
  10,000 ppm), M the axis misalignment / cross-axis sensitivity with zero diagonal, M[a, b]
  the output on axis a per unit input on axis b (for small angles the misalignment angle in
  rad). MATLAB's gyroparams/accelparams ``AxesMisalignment`` is the same matrix in percent
  (its diagonal ignored): M = AxesMisalignment / 100 off the diagonal; its
  ``ConstantBias`` is b, its ``AccelerationBias`` the diagonal of G (MATLAB Sensor Fusion
  and Tracking Toolbox documentation, "gyroparams" and "accelparams").
* D(T) = diag(1 + s_T (T - T_ref)): the gain of output axis a drifts by s_T,a per kelvin
  (1/K); MATLAB's ``TemperatureScaleFactor`` is s_T in %/degC: s_T = TemperatureScaleFactor
  / 100. To first order the diagonal of the matrix moves by s_T per kelvin.
* b_T: bias temperature coefficient per axis (unit/K), MATLAB's ``TemperatureBias``.
* G: gyro g-sensitivity (linear-acceleration effect), 3x3, rad/s per m/s^2, G[a, b] the
  rate error on gyro axis a per unit specific force along b.
* G2: gyro g^2 sensitivity, 3x3, rad/s per (m/s^2)^2, G2[a, b] the rate error on gyro axis a
  per unit of f_b^2 (f^2 element-wise); K2: the accelerometer's second-order coefficient per
  axis, 1/(m/s^2), output a += K2_a f_a^2 (IEEE Std 1293 model). A vibration of variance
  sigma_b^2 along b rectifies through them to the means G2[a, b] sigma_b^2 and K2_a sigma_a^2
  (a sinusoid of peak A: sigma^2 = A^2 / 2). Both 0 by default.
* b = b_const + b_turnon: the constant bias (``{s}_bias``, every axis, plus
  ``{s}_axis_bias_{a}`` per axis) and a turn-on (run-to-run) bias drawn once per power-up,
  i.e. per model construction, N(0, sigma_on,a^2) per axis from its own random stream, as
  the Gazebo IMU sensor plugin draws its turn-on bias at start.
* x: first-order Gauss-Markov bias instability, Petkov Sec. 3-4, eqs. (3)-(6) with the
  misprints corrected (see :func:`discrete_gm_coefficients`); x(0) is drawn from the
  stationary distribution N(0, B^2).
* white: ARW / VRW, per-sample std N*sqrt(fs) for a density N (Petkov eq. (9) gives this
  per-sample std directly).
* rw: rate / acceleration random walk, Petkov eqs. (7)-(8): rw(k+1) = rw(k) + dT*K*w(k)
  with std(w) = 1/sqrt(dT), i.e. increments of std K*sqrt(dT), rw(0) = 0.
* Output low-pass (``{s}_bandwidth`` > 0): first-order IIR with 3 dB bandwidth f_c,
  z_k = z_(k-1) + alpha (y_k - z_(k-1)), alpha = 1 - exp(-2 pi f_c / fs) (the impulse-
  invariant discretisation of 1/(1 + s/(2 pi f_c))), started at the first sample (no
  start transient); 0 (default): off.
* ADC: integer codes round(value/LSB) (half to even), clipped to the signed
  two's-complement range [-2^(bits-1), 2^(bits-1)-1]; clipped samples are counted as
  saturated.

Bias instability conventions. Petkov's B is the Gauss-Markov stationary std. MATLAB's
``BiasInstability`` is instead the amplitude b of a flicker (1/f) bias whose Allan deviation
floor is sqrt(2 ln 2 / pi) b = 0.6643 b (IEEE Std 952-1997, Annex C). The Allan deviation
of a Gauss-Markov process of std B and correlation time T peaks at 0.6174 B at tau = 1.893 T
(:func:`gm_allan_peak`, from the closed form of El-Sheimy, Hou & Niu, "Analysis and Modeling
of Inertial Sensors Using Allan Variance", IEEE Trans. Instrum. Meas. 57(1), 2008), so a
Gauss-Markov term with the same Allan peak as MATLAB's b has B = 1.0760 b
(:func:`gm_std_for_bias_instability`). A flicker (1/f) bias is not implemented.

Presets (``preset``): "petkov" (default: Petkov's stochastic terms and constant gyro bias,
every new deterministic term 0, so outputs are those of the stochastic model alone),
"adis16350" (Petkov's stochastic terms with the deterministic terms of the Analog Devices
ADIS16350 datasheet) and "icm42688p" (TDK InvenSense ICM-42688-P datasheet DS-000347, a
current consumer 6-axis IMU). Values given explicitly override the preset's. A device of the
batch (``device_seed`` >= 0, :func:`draw_imu_device`) draws each per-axis bias, scale
factor, misalignment element, temperature coefficient and g-sensitivity element within the
preset's datasheet tolerance, independently per element: uniform within +-limit for a
min/max or typical tolerance, normal with that std for a 1-sigma specification (a
datasheet gives the tolerance, not the distribution: this is the stated assumption).

Determinism: ``np.random.SeedSequence(seed)`` spawns one child PCG64 stream per random
source and sensor: children 0-3 the gyro's white, GM initial state, GM drive and random
walk, 4-7 the accelerometer's, 8 and 9 the gyro's and accelerometer's turn-on bias
(``spawn(n)`` gives the same first children for any n, so the first eight streams, and the
outputs with every deterministic term 0, are those of the stochastic-only model). Every
stream is consumed sample-row by sample-row, so n1 then n2 samples are bit-identical to
n1+n2 at once. The per-sample recursions (GM, random walk, low-pass) run in numba
``@njit(cache=True)`` loops carrying their state between frames.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numba
import numpy as np

from mems_sim.devices.imu_adc import axis_converters
from mems_sim.devices.imu_specs import (
    ACCEL_SPECS,
    AXES,
    COMMON_SPECS,
    DEG,
    ERROR_SPECS,
    FLICKER_SPECS,
    G0,
    GYRO_SPECS,
    IMU_SPECS,
    PRESET_SPEC,
    PRESETS,
    PRESETS_NAMES,
    SENSOR_UNITS,
    SENSORS,
    T_REF_C,
    draw_imu_device,
    imu_specs,
    imu_values,
)
from mems_sim.hardware.flicker import flicker_config
from mems_sim.hardware.flicker_stream import FlickerChannels
from mems_sim.params import ParameterError

#: Each sensor's flicker table (the four FLICKER_SPECS named ``<sensor>_flicker_*``).
FLICKER_SPEC_TABLES = {
    s: tuple(spec for spec in FLICKER_SPECS if spec.name.startswith(f"{s}_flicker_"))
    for s in ("gyro", "accel")
}

__all__ = [
    "G0",
    "DEG",
    "COMMON_SPECS",
    "GYRO_SPECS",
    "ACCEL_SPECS",
    "IMU_SPECS",
    "ERROR_SPECS",
    "PRESET_SPEC",
    "PRESETS",
    "PRESETS_NAMES",
    "T_REF_C",
    "AXES",
    "SENSORS",
    "SENSOR_UNITS",
    "TRUTH_UNITS",
    "FLICKER_ALLAN_FLOOR",
    "imu_specs",
    "imu_values",
    "draw_imu_device",
    "gm_allan_peak",
    "gm_std_for_bias_instability",
    "lowpass_alpha",
    "discrete_gm_coefficients",
    "white_sample_std",
    "random_walk_increment_std",
    "imu_covariances",
    "covariance9",
    "quantize",
    "truth_motion",
    "SensorNoise",
    "SensorErrors",
    "ImuFrame",
    "ImuNoiseModel",
]

#: Random streams of a model: white, GM initial state, GM drive, random walk per sensor,
#: then the turn-on biases (module doc, Determinism).
_N_STREAMS = 10


def gm_allan_peak() -> tuple[float, float]:
    """Peak of the Allan deviation of a first-order Gauss-Markov process of std B and
    correlation time T: (tau_peak / T, sigma_A,peak / B) = (1.8926, 0.61736).

    Closed form (El-Sheimy, Hou & Niu, IEEE Trans. Instrum. Meas. 57(1), 2008; IEEE Std
    952-1997 Annex C) with x = tau/T: sigma_A^2 / B^2 = (2/x) [1 - (3 - 4 e^-x + e^-2x)/(2x)],
    maximised by golden-section search.
    """

    def f(x: float) -> float:
        return (2.0 / x) * (1.0 - (3.0 - 4.0 * math.exp(-x) + math.exp(-2.0 * x)) / (2.0 * x))

    lo, hi = 0.5, 5.0
    r = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - r * (hi - lo), lo + r * (hi - lo)
    for _ in range(100):
        if f(a) > f(b):
            hi, b = b, a
            a = hi - r * (hi - lo)
        else:
            lo, a = a, b
            b = lo + r * (hi - lo)
    x = 0.5 * (lo + hi)
    return x, math.sqrt(f(x))


#: Allan deviation floor of a flicker (1/f) bias of amplitude b, per unit b: sqrt(2 ln 2 / pi)
#: (IEEE Std 952-1997 Annex C; MATLAB's BiasInstability is b).
FLICKER_ALLAN_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)


def gm_std_for_bias_instability(b: float) -> float:
    """Gauss-Markov std B whose Allan peak equals the Allan floor of a flicker bias of
    amplitude ``b`` (MATLAB BiasInstability, rad/s or m/s^2): B = 0.6643 b / 0.6174 =
    1.0760 b (module docstring)."""
    return b * FLICKER_ALLAN_FLOOR / gm_allan_peak()[1]


def discrete_gm_coefficients(T: float, dt: float) -> tuple[float, float, float]:
    """Exact ZOH discretisation of the Gauss-Markov lag, Petkov eqs. (3)-(6), corrected.

    Eq. (3) T dx/dt + x = v discretises (zero-order hold) to eq. (4)
    x(k+1) = a_d x(k) + b_d eta(k) with
      a_d = exp(-dT/T)            (the paper prints exp(+dT/T): a misprint, its
                                   number 0.999917 is exp(-dT/T));
      b_d = (1/T) int_0^dT exp(-s/T) ds = 1 - a_d
                                  (the paper's printed integral lacks the 1/T and
                                   the minus sign; its number 8.33299e-5 is 1 - a_d);
    and from eq. (5), (1 - a_d^2) sigma_x^2 = b_d^2 sigma_eta^2 with sigma_x = B:
      sigma_eta = sqrt(1 - a_d^2) / b_d   [per unit B]
    (the paper's eq. (6) sqrt(1 - a_d^2 B / b_d) is misprinted; its number
    2.40125 is sqrt(1 - a_d^2) * B / b_d with B = 1.55e-2 deg/s).

    Args:
        T: correlation time, s (> 0).
        dt: sample interval dT, s (> 0).
    Returns:
        (a_d -, b_d -, sigma_eta per unit of B, -): multiply sigma_eta by B
        (rad/s or m/s^2) to get the driving-noise std in those units.
    """
    if not (T > 0.0 and dt > 0.0):
        raise ValueError(f"T = {T!r} s and dt = {dt!r} s must both be > 0")
    x = dt / T
    a_d = math.exp(-x)
    b_d = -math.expm1(-x)
    sigma_eta = math.sqrt(-math.expm1(-2.0 * x)) / b_d
    return a_d, b_d, sigma_eta


def white_sample_std(density: float, fs: float) -> float:
    """Per-sample std of white noise of density N (Petkov eq. (9) sigma_arw = N*sqrt(fs)).

    Args:
        density: N, rad/s/sqrt(Hz) or m/s^2/sqrt(Hz).
        fs: sample rate, Hz.
    Returns:
        std per sample, rad/s or m/s^2.
    """
    return density * math.sqrt(fs)


def random_walk_increment_std(K: float, fs: float) -> float:
    """Std of one random-walk increment, K*sqrt(dT) (Petkov eqs. (7)-(8), sigma_w = 1/sqrt(dT)).

    Args:
        K: random-walk coefficient, rad/s/sqrt(s) or m/s^2/sqrt(s).
        fs: sample rate, Hz.
    Returns:
        increment std, rad/s or m/s^2.
    """
    return K / math.sqrt(fs)


def lowpass_alpha(bandwidth_hz: float, fs: float) -> float:
    """Gain alpha = 1 - exp(-2 pi f_c / fs) of the first-order output low-pass (module
    docstring); 1.0 (no filtering) for f_c = 0 (off).

    Args:
        bandwidth_hz: 3 dB bandwidth f_c, Hz (0: off).
        fs: sample rate, Hz.
    """
    if bandwidth_hz <= 0.0:
        return 1.0
    return -math.expm1(-2.0 * math.pi * bandwidth_hz / fs)


def imu_covariances(params: Mapping[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis model variances for sensor_msgs/Imu covariance diagonals.

    variance = (N*sqrt(fs))^2 * alpha/(2 - alpha) + B^2: the white per-sample variance
    (Petkov eq. (9)) through the output low-pass (a first-order IIR of gain alpha passes
    alpha/(2 - alpha) of a white variance; 1 when the filter is off), plus the Gauss-Markov
    stationary variance (eq. (6), slow enough to pass the filter). The random walk is
    non-stationary and the biases, scale factors, misalignments and temperature terms are
    deterministic (calibration), so none of them is included.

    Args:
        params: overrides of :data:`IMU_SPECS` (SI units, ``preset`` included); None for
            the defaults.
    Returns:
        (gyro variances (3,) (rad/s)^2, accel variances (3,) (m/s^2)^2).
    """
    p = imu_values(params)
    fs = p["sample_rate_hz"]
    out = []
    for s in SENSORS:
        alpha = lowpass_alpha(p[f"{s}_bandwidth"], fs)
        white = white_sample_std(p[f"{s}_noise_density"], fs) ** 2
        if alpha < 1.0:
            white *= alpha / (2.0 - alpha)
        var = white + p[f"{s}_bias_instability"] ** 2
        out.append(np.full(3, var))
    return out[0], out[1]


def covariance9(variances: np.ndarray) -> list[float]:
    """Row-major 3x3 diagonal covariance (sensor_msgs/Imu layout) from (3,) variances."""
    return [float(v) for v in np.diag(np.asarray(variances, dtype=float)).ravel()]


def quantize(values: np.ndarray, lsb: float, bits: int) -> tuple[np.ndarray, np.ndarray]:
    """ADC conversion: codes = round(value/LSB), clipped to two's-complement range.

    Args:
        values: analog values, SI (rad/s or m/s^2).
        lsb: one code, same unit.
        bits: ADC resolution, codes in [-2^(bits-1), 2^(bits-1)-1].
    Returns:
        (codes int32 like ``values``, saturated bool like ``values``).
    """
    lo, hi = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
    raw = np.rint(np.asarray(values, dtype=float) / lsb)
    saturated = (raw < lo) | (raw > hi)
    return np.clip(raw, lo, hi).astype(np.int32), saturated


def truth_motion(
    kind: str, first_index: int, n: int, fs: float, delay_s: float = 0.0, **params
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth angular rate and specific force of simple motions, body frame.

    kind "static": gyro 0, accel [0, 0, +9.80665] m/s^2 (specific force at rest, z up).
    kind "constant_rate": rotation about z at ``rate`` rad/s (default 0.1).
    kind "sinusoid": rotation about z, rate = ``amplitude`` (rad/s, default 0.5) *
    sin(2 pi ``frequency`` (Hz, default 1) t + ``phase`` (rad, default 0)).
    Rotation about the vertical z keeps the specific force [0, 0, g]. ``delay_s``: the motion
    of t - delay_s (a sensor latency, s). The Earth's rate, other gravity models, vibration
    and 6-DoF trajectories: :mod:`mems_sim.devices.imu_motion`.

    Args:
        kind: "static", "constant_rate" or "sinusoid".
        first_index: index of the first sample (t = index/fs), -.
        n: number of samples, -.
        fs: sample rate, Hz.
    Returns:
        (gyro (n,3) rad/s, accel (n,3) m/s^2).
    """
    gyro = np.zeros((n, 3))
    accel = np.zeros((n, 3))
    accel[:, 2] = G0
    if kind == "static":
        pass
    elif kind == "constant_rate":
        gyro[:, 2] = float(params.get("rate", 0.1))
    elif kind == "sinusoid":
        t = (first_index + np.arange(n)) / float(fs)
        if delay_s != 0.0:
            t = t - float(delay_s)
        amp, f = float(params.get("amplitude", 0.5)), float(params.get("frequency", 1.0))
        gyro[:, 2] = amp * np.sin(2.0 * math.pi * f * t + float(params.get("phase", 0.0)))
    else:
        raise ValueError(
            f"motion kind {kind!r} is invalid: allowed one of 'static', 'constant_rate', 'sinusoid'"
        )
    return gyro, accel


@numba.njit(cache=True)
def _noise_recursion(bias, a_d, eta_gain, x_state, eta, white, rw_state, rw_inc, out):
    """Per-sample eq. (1) stochastic part: out[k] += b + x(k) + white(k) + rw(k); advance x, rw.

    x(k+1) = a_d x(k) + eta_gain*eta(k)   (Petkov eq. (4), eta_gain = b_d*sigma_eta*B)
    rw(k+1) = rw(k) + rw_inc(k)           (Petkov eqs. (7)-(8))
    ``bias`` (3,) is b per axis; ``x_state`` and ``rw_state`` (3,) are updated in place
    (carried to the next frame).
    """
    n, k_axes = out.shape
    for k in range(n):
        for j in range(k_axes):
            out[k, j] += bias[j] + x_state[j] + white[k, j] + rw_state[j]
            x_state[j] = a_d * x_state[j] + eta_gain * eta[k, j]
            rw_state[j] = rw_state[j] + rw_inc[k, j]


@numba.njit(cache=True)
def _lowpass(alpha, state, out):
    """First-order output low-pass in place: z(k) = z(k-1) + alpha (y(k) - z(k-1)); a NaN
    ``state`` (3,) starts at the first sample. ``state`` is carried to the next frame."""
    n, k_axes = out.shape
    for j in range(k_axes):
        z = state[j]
        if math.isnan(z):
            z = out[0, j] if n > 0 else z
        for k in range(n):
            z = z + alpha * (out[k, j] - z)
            out[k, j] = z
        state[j] = z


@dataclass
class SensorNoise:
    """Noise state of one 3-axis sensor (gyro or accelerometer), SI units.

    Attributes:
        bias: (3,) b = constant + turn-on bias per axis (rad/s or m/s^2; a float: every axis).
        B, T, N, K, lsb: parameters (see GYRO_SPECS/ACCEL_SPECS).
        fs: sample rate, Hz. bits: ADC resolution.
        streams: PCG64 generators: white, GM initial state, GM drive, random walk.
    """

    bias: Any
    B: float
    T: float
    N: float
    K: float
    lsb: float
    fs: float
    bits: int
    streams: tuple
    #: Flicker bias instability on top of x (None: off), :class:`FlickerChannels` of 3 axes.
    flicker: FlickerChannels | None = None
    #: One converter per axis with the ADC's static errors (None: the ideal quantiser).
    converters: tuple | None = None
    x_state: np.ndarray = field(init=False)
    rw_state: np.ndarray = field(init=False)
    saturated_total: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.bias = np.broadcast_to(np.asarray(self.bias, dtype=float), (3,)).copy()
        self.a_d, b_d, sigma_eta = discrete_gm_coefficients(self.T, 1.0 / self.fs)
        self.eta_gain = b_d * sigma_eta * self.B
        self.x_state = self.B * self.streams[1].standard_normal(3)
        self.rw_state = np.zeros(3)
        self.saturated_total = np.zeros(3, dtype=np.int64)

    def analog(self, truth: np.ndarray) -> np.ndarray:
        """truth + b + x + white + rw for the next n samples, (n,3) SI."""
        n = truth.shape[0]
        white = self.streams[0].standard_normal((n, 3)) * white_sample_std(self.N, self.fs)
        eta = self.streams[2].standard_normal((n, 3))
        rw_inc = self.streams[3].standard_normal((n, 3)) * random_walk_increment_std(
            self.K, self.fs
        )
        out = np.array(truth, dtype=float, order="C", copy=True)
        _noise_recursion(
            self.bias, self.a_d, self.eta_gain, self.x_state, eta, white, self.rw_state, rw_inc, out
        )
        if self.flicker is not None:
            out += self.flicker.next(n)
        return out

    def quantize(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(codes int32 (n,3), value of the codes (n,3) SI, saturated count per axis (3,)):
        :func:`quantize`, or each axis' converter when the ADC has static errors."""
        if self.converters is None:
            codes, sat = quantize(values, self.lsb, self.bits)
        else:
            values = np.asarray(values, dtype=float)
            codes = np.empty(values.shape, np.int32)
            sat = np.empty(values.shape, bool)
            for j, conv in enumerate(self.converters):
                codes[:, j], sat[:, j] = conv.quantize(values[:, j])
        counts = sat.sum(axis=0).astype(np.int64)
        self.saturated_total += counts
        return codes, codes * self.lsb, counts

    def convert(self, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ADC conversion of :meth:`analog` (no deterministic errors, no low-pass)."""
        return self.quantize(self.analog(truth))


@dataclass
class SensorErrors:
    """Deterministic errors of one 3-axis sensor, eq. (1), SI units.

    Attributes:
        matrix: (3,3) C = I + diag(sf) + M (-), row = output axis, column = input axis.
        bias_tempco: (3,) b_T, unit/K.
        sf_tempco: (3,) s_T, 1/K.
        g_sensitivity: (3,3) G, rad/s per m/s^2 (zeros for the accelerometer).
        alpha: output low-pass gain (1.0: off).
        g2_sensitivity: (3,3) G2, rad/s per (m/s^2)^2 (zeros for the accelerometer).
        k2: (3,) K2, 1/(m/s^2) (zeros for the gyro).
    """

    matrix: np.ndarray
    bias_tempco: np.ndarray
    sf_tempco: np.ndarray
    g_sensitivity: np.ndarray
    alpha: float
    g2_sensitivity: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    k2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    lp_state: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.lp_state = np.full(3, np.nan)
        self._unit_matrix = bool(np.array_equal(self.matrix, np.eye(3)))
        self._temperature = bool(np.any(self.bias_tempco) or np.any(self.sf_tempco))
        self._g = bool(np.any(self.g_sensitivity))
        self._g2 = bool(np.any(self.g2_sensitivity))
        self._k2 = bool(np.any(self.k2))

    def apply(self, truth: np.ndarray, delta_k: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """D(T) C u + b_T dT + G f + G2 f^2 + K2 u^2 (eq. (1) before the bias and noise);
        ``truth`` itself when every term is zero (bit-identical to the stochastic-only model).

        Args:
            truth: (n,3) u, rad/s or m/s^2.
            delta_k: (n,) T - T_ref, K.
            accel: (n,3) true specific force f, m/s^2 (used by G).
        """
        out = truth
        if not self._unit_matrix:
            out = truth @ self.matrix.T
        if self._temperature:
            dk = delta_k[:, None]
            out = out * (1.0 + self.sf_tempco * dk) + self.bias_tempco * dk
        if self._g:
            out = out + accel @ self.g_sensitivity.T
        if self._g2:
            out = out + (accel * accel) @ self.g2_sensitivity.T
        if self._k2:
            out = out + self.k2 * (truth * truth)
        return out

    def lowpass(self, values: np.ndarray) -> np.ndarray:
        """The output low-pass (in place on a copy) when on, else ``values``."""
        if self.alpha >= 1.0:
            return values
        out = np.array(values, dtype=float, order="C", copy=True)
        _lowpass(self.alpha, self.lp_state, out)
        return out


class ImuFrame(NamedTuple):
    """One frame of IMU output.

    gyro_codes, accel_codes: (n,3) int32 ADC codes.
    gyro_si: (n,3) rad/s and accel_si: (n,3) m/s^2, the values the codes
    represent (codes*LSB).
    saturated: (6,) int64 saturated samples in this frame per channel
    [gx, gy, gz, ax, ay, az].
    """

    gyro_codes: np.ndarray
    accel_codes: np.ndarray
    gyro_si: np.ndarray
    accel_si: np.ndarray
    saturated: np.ndarray


#: Units of the error terms published as truth (:meth:`ImuNoiseModel.calibration_truth`).
TRUTH_UNITS = {
    "bias": SENSOR_UNITS,
    "matrix": {"gyro": "-", "accel": "-"},
    "bias_tempco": {"gyro": "rad/s/K", "accel": "m/s^2/K"},
    "sf_tempco": {"gyro": "1/K", "accel": "1/K"},
    "g_sensitivity": {"gyro": "rad/s/(m/s^2)"},
}


class ImuNoiseModel:
    """IMU error model with carried state: eq. (1) of the module docstring (deterministic
    errors, temperature terms, turn-on bias, Petkov's stochastic terms, low-pass, ADC).

    Args:
        params: overrides of :data:`IMU_SPECS` (SI units; ``preset`` selects the defaults,
            :func:`imu_values`); validated, an invalid value raises ``ParameterError``
            naming it and its range.
        seed: run seed (int >= 0) for ``np.random.SeedSequence``.
        temperature_c: device temperature, degC, of :meth:`generate` calls without one
            (default the reference 25 C; changed by :meth:`set_temperature`).
    """

    def __init__(
        self, params: Mapping[str, Any] | None = None, seed: int = 0, temperature_c: float = T_REF_C
    ) -> None:
        self.params = imu_values(params)
        self.seed = int(seed)
        # children 0.._N_STREAMS-1 as ever; one more per sensor for its flicker term (spawn
        # keys are the children's indices, so the first ones do not change)
        children = np.random.SeedSequence(self.seed).spawn(_N_STREAMS + len(SENSORS))
        self._flicker_seeds = dict(zip(SENSORS, children[_N_STREAMS:], strict=True))
        gens = [np.random.Generator(np.random.PCG64(c)) for c in children[:_N_STREAMS]]
        fs, bits = self.params["sample_rate_hz"], self.params["bits"]
        p = self.params
        #: Turn-on bias of this power-up per sensor, (3,) rad/s or m/s^2.
        self.turn_on_bias = {
            s: np.array([p[f"{s}_turnon_bias_std_{a}"] for a in AXES])
            * gens[8 + i].standard_normal(3)
            for i, s in enumerate(SENSORS)
        }
        self.sensors = {
            s: self._make_sensor(s, fs, bits, tuple(gens[4 * i : 4 * i + 4]))
            for i, s in enumerate(SENSORS)
        }
        self.errors = {s: self._make_errors(s, fs) for s in SENSORS}
        self.temperature_c = float(temperature_c)
        self.next_index = 0
        #: Scheduled sensor faults (mems_sim.hardware.sensor_faults), acting on the low-passed
        #: analog values before the ADC, channels gyro_x..z, accel_x..z; None: no faults.
        self.faults = None

    def white_sample_stds(self) -> tuple[float, ...]:
        """Standard deviation per sample of the white noise of each channel (gyro_x..z
        [rad/s], accel_x..z [m/s^2]): N sqrt(fs), the level a ``noise_burst`` multiplies."""
        return tuple(
            white_sample_std(self.params[f"{s}_noise_density"], self.fs)
            for s in SENSORS
            for _ in AXES
        )

    def _bias(self, s: str) -> np.ndarray:
        p = self.params
        axis = np.array([p[f"{s}_axis_bias_{a}"] for a in AXES])
        return p[f"{s}_bias"] + axis + self.turn_on_bias[s]

    def _make_sensor(self, s: str, fs: float, bits: int, streams: tuple) -> SensorNoise:
        p = self.params
        return SensorNoise(
            bias=self._bias(s),
            B=p[f"{s}_bias_instability"],
            T=p[f"{s}_correlation_time"],
            N=p[f"{s}_noise_density"],
            K=p[f"{s}_random_walk"],
            lsb=p[f"{s}_lsb"],
            fs=fs,
            bits=bits,
            streams=streams,
            flicker=self._make_flicker(s, fs),
            converters=axis_converters(p, s, bits, 3 * SENSORS.index(s)),
        )

    def _make_flicker(self, s: str, fs: float) -> FlickerChannels | None:
        """The flicker term of sensor ``s`` (None when its coefficient is 0); its band's
        upper corner must lie below the Nyquist frequency (a ParameterError otherwise)."""
        table = FLICKER_SPEC_TABLES[s]
        values = {spec.name: self.params[spec.name] for spec in table}
        config = flicker_config(values, f"{s}_flicker", table)
        if config.coefficient == 0.0:
            return None
        if config.f_high_hz > fs / 2:
            raise ParameterError(
                f"parameter '{s}_flicker_f_high_hz' = {config.f_high_hz!r} is out of range: "
                f"allowed up to the Nyquist frequency {fs / 2!r} Hz of sample_rate_hz"
            )
        return FlickerChannels(config, fs, 3, self._flicker_seeds[s])

    def _make_errors(self, s: str, fs: float) -> SensorErrors:
        p = self.params
        c = np.eye(3)
        for i, a in enumerate(AXES):
            c[i, i] += p[f"{s}_scale_factor_{a}"]
            for j, b in enumerate(AXES):
                if a != b:
                    c[i, j] = p[f"{s}_misalignment_{a}{b}"]
        g, g2, k2 = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3)
        if s == "gyro":
            g = np.array([[p[f"gyro_g_sensitivity_{a}{b}"] for b in AXES] for a in AXES])
            g2 = np.array([[p[f"gyro_g2_sensitivity_{a}{b}"] for b in AXES] for a in AXES])
        else:
            k2 = np.array([p[f"accel_k2_{a}"] for a in AXES])
        return SensorErrors(
            matrix=c,
            bias_tempco=np.array([p[f"{s}_bias_tempco_{a}"] for a in AXES]),
            sf_tempco=np.array([p[f"{s}_sf_tempco_{a}"] for a in AXES]),
            g_sensitivity=g,
            alpha=lowpass_alpha(p[f"{s}_bandwidth"], fs),
            g2_sensitivity=g2,
            k2=k2,
        )

    @property
    def fs(self) -> float:
        """Sample rate, Hz."""
        return self.params["sample_rate_hz"]

    @property
    def saturated_total(self) -> np.ndarray:
        """(6,) saturated samples since construction, [gx, gy, gz, ax, ay, az]."""
        return np.concatenate(
            [self.sensors["gyro"].saturated_total, self.sensors["accel"].saturated_total]
        )

    def set_temperature(self, temperature_c: float) -> None:
        """Device temperature, degC, of the next :meth:`generate` calls without their own."""
        self.temperature_c = float(temperature_c)

    def error_terms(self) -> dict[str, dict[str, np.ndarray]]:
        """The realised deterministic error terms of this device and power-up (the truth a
        calibration is judged against), per sensor 'gyro' / 'accel':

        * ``bias`` (3,): b = constant + per-axis + turn-on bias at T_ref, rad/s or m/s^2;
        * ``matrix`` (3,3): C = I + diag(sf) + M, - (row output axis, column input axis);
        * ``bias_tempco`` (3,): b_T, unit/K; ``sf_tempco`` (3,): s_T, 1/K;
        * ``g_sensitivity`` (3,3), gyro only: G, rad/s per m/s^2.
        """
        out = {}
        for s in SENSORS:
            e = self.errors[s]
            d = {
                "bias": self.sensors[s].bias.copy(),
                "matrix": e.matrix.copy(),
                "bias_tempco": e.bias_tempco.copy(),
                "sf_tempco": e.sf_tempco.copy(),
            }
            if s == "gyro":
                d["g_sensitivity"] = e.g_sensitivity.copy()
            out[s] = d
        return out

    def calibration_truth(self) -> list[tuple[str, float, str]]:
        """:meth:`error_terms` as (name, value, SI unit) with the names of a calibration
        result: ``{s}_bias_{a}``, ``{s}_matrix_{a}{b}`` (element (a, b) of C),
        ``{s}_bias_tempco_{a}``, ``{s}_sf_tempco_{a}`` for s in gyro, accel and
        ``gyro_g_sensitivity_{a}{b}``; a, b in x, y, z; then, only when set (so the rows
        of the references are unchanged), ``gyro_g2_sensitivity_{a}{b}``, ``accel_k2_{a}``
        and ``latency_s`` [s]."""
        rows: list[tuple[str, float, str]] = []
        terms = self.error_terms()
        for s in SENSORS:
            t = terms[s]
            rows += [
                (f"{s}_bias_{a}", float(t["bias"][i]), SENSOR_UNITS[s]) for i, a in enumerate(AXES)
            ]
            rows += [
                (f"{s}_matrix_{a}{b}", float(t["matrix"][i, j]), "-")
                for i, a in enumerate(AXES)
                for j, b in enumerate(AXES)
            ]
            rows += [
                (f"{s}_bias_tempco_{a}", float(t["bias_tempco"][i]), TRUTH_UNITS["bias_tempco"][s])
                for i, a in enumerate(AXES)
            ]
            rows += [
                (f"{s}_sf_tempco_{a}", float(t["sf_tempco"][i]), "1/K") for i, a in enumerate(AXES)
            ]
        g = terms["gyro"]["g_sensitivity"]
        rows += [
            (f"gyro_g_sensitivity_{a}{b}", float(g[i, j]), TRUTH_UNITS["g_sensitivity"]["gyro"])
            for i, a in enumerate(AXES)
            for j, b in enumerate(AXES)
        ]
        # the second-order terms and the latency only when set (the references have none)
        g2, k2 = self.errors["gyro"].g2_sensitivity, self.errors["accel"].k2
        if np.any(g2):
            rows += [
                (f"gyro_g2_sensitivity_{a}{b}", float(g2[i, j]), "rad/s/(m/s^2)^2")
                for i, a in enumerate(AXES)
                for j, b in enumerate(AXES)
            ]
        if np.any(k2):
            rows += [(f"accel_k2_{a}", float(k2[i]), "1/(m/s^2)") for i, a in enumerate(AXES)]
        if self.params["latency_s"] != 0.0:
            rows.append(("latency_s", float(self.params["latency_s"]), "s"))
        return rows

    def generate(
        self,
        n: int,
        truth_gyro: np.ndarray | None = None,
        truth_accel: np.ndarray | None = None,
        temperature_c: float | np.ndarray | None = None,
    ) -> ImuFrame:
        """Next n samples of both sensors (eq. (1): deterministic and temperature terms,
        bias, stochastic terms, low-pass, ADC).

        Args:
            n: number of samples, -.
            truth_gyro: (n,3) true angular rate, rad/s (None: zeros).
            truth_accel: (n,3) true specific force, m/s^2 (None: [0, 0, g]).
            temperature_c: device temperature, degC: a number or (n,) per sample (None:
                :attr:`temperature_c`).
        Returns:
            :class:`ImuFrame` (gyro_codes, accel_codes, gyro_si, accel_si, saturated).
        """
        n = int(n)
        static_g, static_a = truth_motion("static", self.next_index, n, self.fs)
        tg = static_g if truth_gyro is None else self._check(truth_gyro, n, "truth_gyro")
        ta = static_a if truth_accel is None else self._check(truth_accel, n, "truth_accel")
        temp = self.temperature_c if temperature_c is None else temperature_c
        temp = np.asarray(temp, dtype=float)
        if temp.ndim == 0:
            temp = np.full(n, float(temp))
        elif temp.shape != (n,):
            raise ValueError(f"temperature_c must be a number or shape ({n},), got {temp.shape}")
        delta_k = temp - T_REF_C
        out = []
        for j, (s, truth) in enumerate((("gyro", tg), ("accel", ta))):
            e, sensor = self.errors[s], self.sensors[s]
            analog = e.lowpass(sensor.analog(e.apply(truth, delta_k, ta)))
            if self.faults:
                analog = self.faults.apply(analog, self.next_index, slice(3 * j, 3 * j + 3))
            out.append(sensor.quantize(analog))
        (gc, gsi, gsat), (ac, asi, asat) = out
        self.next_index += n
        return ImuFrame(gc, ac, gsi, asi, np.concatenate([gsat, asat]))

    @staticmethod
    def _check(a: np.ndarray, n: int, name: str) -> np.ndarray:
        a = np.asarray(a, dtype=float)
        if a.shape != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3), got {a.shape}")
        return a

"""Electrostatic comb-drive micro-scanner: mechanics, comb capacitance, DC transimpedance readout.

Source: Y. Chen, "High-accuracy Motion Estimation for MEMS Devices with Capacitive Sensors",
PhD thesis, U. Michigan 2018, chapter 4: dynamics eqs. (66)-(68), sensing eq. (64)/(71),
experiment Sec. 4.4.1 (0-60 V unipolar drive swept 1600 -> ~1250 Hz into parametric
resonance, drive cut off, free ring-down recorded at 500 kHz, PSD delay 0.114 ms), Table 4.2
(fs, amplitude 0.15 rad, sigma_n = 0.0435 V, R_s = 10 MOhm, V_bias = 10 V), identified wn =
2 pi 624.6 Hz, zeta = 0.0066, theta_th = 0.0037 rad; capacitance profile: the Gaussian model
of chapter 5, eq. (105), C(theta) = C0 exp(-((theta - theta_th)/theta0)^2) + C_b, with the
maximum moved to the threshold angle theta_th (chapter 4: the maximum overlap is at
theta_th, not at 0).

Public API shared with the chapter-5 front end (``mems_sim.devices.scanner_amdm``) -- keep stable:

* :data:`SCANNER_SPECS` -- ParamSpec table of the chapter-4 device + drive programme + readout.
* :class:`ScannerParams` -- numeric mechanics/capacitance parameters (SI), built by
  :func:`scanner_params` (from the spec table) or :meth:`ScannerParams.from_physical`
  (J, k, b given directly, e.g. chapter 5, Table 5.2).
* :func:`capacitance` / :func:`dcap_dtheta` / :func:`d2cap_dtheta2` -- C(theta) [F],
  dC/dtheta [F/rad], d2C/dtheta2 [F/rad^2] of the ``"sense"`` or ``"drive"`` comb.
* :func:`drive_waveform` -- unipolar 0..V_max drive: sweep, hold, cut-off.
* :func:`simulate_mechanics` -- theta [rad], omega [rad/s] per sample for a drive record.
* :func:`dc_transimpedance_output` -- y = -R_s V_bias dC_s/dtheta omega (+ noise), eq. (64).
* :func:`psd_reference` -- delayed "PSD" angle reference (Sec. 4.4.1, 0.114 ms).
* :class:`MicroScannerDevice` -- frame-by-frame streaming emulator (used by the node).

Conventions: theta[k], omega[k] are the state at t_k = k / fs; the drive sample v[k] is held
(zero-order hold, like the 500 kHz DAQ of Sec. 4.4.1) over [t_k, t_k+1). The ODE is
integrated with classical RK4 over each sample interval (``substeps`` per sample).
Process noise: a white torque w[k] ~ N(0, torque_noise_std^2) [N m] held over the sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numba
import numpy as np

from mems_sim.devices.scanner_specs import SCANNER_SPECS
from mems_sim.params import (
    ParameterError,
    resolve,
)

__all__ = [
    "SCANNER_SPECS",
    "ScannerParams",
    "scanner_params",
    "resolve_scanner",
    "capacitance",
    "dcap_dtheta",
    "d2cap_dtheta2",
    "drive_torque",
    "drive_waveform",
    "drive_plan_from",
    "DrivePlan",
    "simulate_mechanics",
    "dc_transimpedance_output",
    "sensor_gain",
    "psd_reference",
    "MicroScannerDevice",
    "ScannerFrame",
    "FRONT_ENDS",
]

#: Sensing front ends of the emulator node. ``shared_amdm`` is implemented in
#: ``mems_sim.devices.scanner_amdm`` (chapter 5).
FRONT_ENDS = ("dc_transimpedance", "shared_amdm")


class ScannerParams(NamedTuple):
    """Numeric scanner parameters (SI).

    J [kg m^2], k [N m/rad], b [N m s/rad]: eq. (66). theta_th [rad]: capacitance maximum.
    sense_c0, sense_cb [F], sense_theta0 [rad]: sensing comb, eq. (105) with offset.
    drive_c0, drive_cb [F], drive_theta0 [rad]: driving comb (torque eq. (67)).
    """

    J: float
    k: float
    b: float
    theta_th: float
    sense_c0: float
    sense_theta0: float
    sense_cb: float
    drive_c0: float
    drive_theta0: float
    drive_cb: float

    @property
    def wn(self) -> float:
        """Natural angular frequency sqrt(k/J) [rad/s]."""
        return math.sqrt(self.k / self.J)

    @property
    def zeta(self) -> float:
        """Damping ratio b / (2 sqrt(J k))."""
        return self.b / (2.0 * math.sqrt(self.J * self.k))

    @classmethod
    def from_physical(
        cls,
        J: float,
        k: float,
        b: float,
        theta_th: float,
        c0: float,
        theta0: float,
        cb: float,
        drive_c0: float | None = None,
        drive_theta0: float | None = None,
        drive_cb: float | None = None,
    ) -> ScannerParams:
        """From J, k, b directly (e.g. chapter 5, Table 5.2); the drive comb defaults to the
        sensing comb (shared electrodes)."""
        for name, val in (("J", J), ("k", k), ("theta0", theta0)):
            if not (math.isfinite(val) and val > 0):
                raise ParameterError(
                    f"parameter '{name}' = {val!r} is out of range: allowed (0, inf)"
                )
        return cls(
            float(J),
            float(k),
            float(b),
            float(theta_th),
            float(c0),
            float(theta0),
            float(cb),
            float(c0 if drive_c0 is None else drive_c0),
            float(theta0 if drive_theta0 is None else drive_theta0),
            float(cb if drive_cb is None else drive_cb),
        )


def resolve_scanner(overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Validated parameter dict of :data:`SCANNER_SPECS` with cross checks.

    Raises:
        ParameterError: unknown name, value out of range, or motion above fs/2.
    """
    p = resolve(SCANNER_SPECS, overrides)
    fs = p["sample_rate_hz"]
    for name in ("natural_freq_hz", "sweep_start_hz", "sweep_end_hz"):
        if not p[name] < fs / 2:
            raise ParameterError(
                f"parameter '{name}' = {p[name]!r} is out of range: must be "
                f"below sample_rate_hz/2 = {fs / 2!r} Hz"
            )
    return p


def scanner_params(p: Mapping[str, Any] | None = None) -> ScannerParams:
    """:class:`ScannerParams` from a (partial) spec dict: k = J wn^2, b = 2 zeta sqrt(J k)."""
    if p is None or set(p) != {s.name for s in SCANNER_SPECS}:
        p = resolve_scanner(p)
    J = p["inertia"]
    wn = 2.0 * math.pi * p["natural_freq_hz"]
    k = J * wn * wn
    b = 2.0 * p["damping_ratio"] * math.sqrt(J * k)
    return ScannerParams(
        J,
        k,
        b,
        p["threshold_angle"],
        p["sense_c0"] * (1.0 + p["sense_gain_drift"]),
        p["sense_theta0"] * (1.0 + p["sense_width_drift"]),
        p["sense_cb"],
        p["drive_c0"],
        p["drive_theta0"],
        p["drive_cb"],
    )


# ----------------------------------------------------------------------------- capacitance
@numba.njit(cache=True, inline="always")
def _gauss_c(theta, c0, theta0, theta_th, cb):
    u = (theta - theta_th) / theta0
    return c0 * math.exp(-u * u) + cb


@numba.njit(cache=True, inline="always")
def _gauss_dc(theta, c0, theta0, theta_th):
    u = (theta - theta_th) / theta0
    return -2.0 * c0 * u / theta0 * math.exp(-u * u)


@numba.njit(cache=True, inline="always")
def _gauss_d2c(theta, c0, theta0, theta_th):
    u = (theta - theta_th) / theta0
    return 2.0 * c0 / (theta0 * theta0) * (2.0 * u * u - 1.0) * math.exp(-u * u)


def _comb(p: ScannerParams, which: str):
    if which == "sense":
        return p.sense_c0, p.sense_theta0, p.sense_cb
    if which == "drive":
        return p.drive_c0, p.drive_theta0, p.drive_cb
    raise ValueError(f"which = {which!r}: expected 'sense' or 'drive'")


def capacitance(theta, p: ScannerParams, which: str = "sense"):
    """C(theta) = C0 exp(-((theta - theta_th)/theta0)^2) + C_b [F] -- eq. (105) + offset.

    Args:
        theta: angle [rad] (scalar or array).
        p: scanner parameters.
        which: ``"sense"`` or ``"drive"`` comb.
    """
    c0, th0, cb = _comb(p, which)
    u = (np.asarray(theta, dtype=float) - p.theta_th) / th0
    return c0 * np.exp(-u * u) + cb


def dcap_dtheta(theta, p: ScannerParams, which: str = "sense"):
    """dC/dtheta = -2 C0 (theta - theta_th)/theta0^2 exp(-u^2) [F/rad] (derivative of (105))."""
    c0, th0, _ = _comb(p, which)
    u = (np.asarray(theta, dtype=float) - p.theta_th) / th0
    return -2.0 * c0 * u / th0 * np.exp(-u * u)


def d2cap_dtheta2(theta, p: ScannerParams, which: str = "sense"):
    """d2C/dtheta2 = 2 C0/theta0^2 (2u^2 - 1) exp(-u^2) [F/rad^2], u = (theta-theta_th)/theta0."""
    c0, th0, _ = _comb(p, which)
    u = (np.asarray(theta, dtype=float) - p.theta_th) / th0
    return 2.0 * c0 / th0**2 * (2.0 * u * u - 1.0) * np.exp(-u * u)


def drive_torque(theta, v, p: ScannerParams):
    """tau_L = 1/2 dC_dr/dtheta V^2 [N m] -- eq. (67). theta [rad], v [V]."""
    return 0.5 * dcap_dtheta(theta, p, "drive") * np.asarray(v, dtype=float) ** 2


def sensor_gain(theta, p: ScannerParams, sense_resistance: float, bias_voltage: float):
    """h_cap(theta) = -R_s V_bias dC_s/dtheta [V s/rad] -- eq. (71)."""
    return -sense_resistance * bias_voltage * dcap_dtheta(theta, p, "sense")


# ----------------------------------------------------------------------------- drive
class DrivePlan(NamedTuple):
    """Drive record and its phase boundaries (sample indices).

    voltage: (n,) V. frequency: (n,) instantaneous drive frequency [Hz] (0 after cut-off).
    sweep_end, cutoff: first sample of the hold and of the ring-down.
    """

    voltage: np.ndarray
    frequency: np.ndarray
    sweep_end: int
    cutoff: int


def drive_waveform(
    fs: float,
    v_max: float,
    f_start: float,
    f_end: float,
    t_sweep: float,
    t_hold: float,
    t_ringdown: float,
) -> DrivePlan:
    """Unipolar drive V(t) = V_max (1 - cos phi(t))/2, phi = 2 pi int f dt (Sec. 4.4.1).

    f(t) goes linearly from ``f_start`` to ``f_end`` [Hz] over ``t_sweep`` [s], stays at
    ``f_end`` for ``t_hold`` [s], then V = 0 (cut-off) for ``t_ringdown`` [s]. fs [Hz].
    """
    n_sw = int(round(t_sweep * fs))
    n_ho = int(round(t_hold * fs))
    n_rd = int(round(t_ringdown * fs))
    n = n_sw + n_ho + n_rd
    t = np.arange(n) / fs
    f = np.zeros(n)
    if n_sw:
        f[:n_sw] = f_start + (f_end - f_start) * t[:n_sw] / t_sweep
    f[n_sw : n_sw + n_ho] = f_end
    phase = 2.0 * math.pi * np.concatenate(([0.0], np.cumsum(f[:-1]) / fs)) if n else np.zeros(0)
    v = 0.5 * v_max * (1.0 - np.cos(phase))
    v[n_sw + n_ho :] = 0.0
    return DrivePlan(v, f, n_sw, n_sw + n_ho)


def drive_plan_from(p: Mapping[str, Any]) -> DrivePlan:
    """:func:`drive_waveform` from a resolved :data:`SCANNER_SPECS` dict."""
    return drive_waveform(
        p["sample_rate_hz"],
        p["drive_voltage_max"],
        p["sweep_start_hz"],
        p["sweep_end_hz"],
        p["sweep_time_s"],
        p["hold_time_s"],
        p["ringdown_time_s"],
    )


# ----------------------------------------------------------------------------- mechanics
#: Angle [rad] below which a mirror whose angular step per RK4 step is below it too is at
#: rest (:func:`rk4_step` sets both to exactly 0). A ring-down without drive or noise decays
#: through every power of ten: after ~700 time constants the state would reach the
#: subnormal floats (below 2.2e-308), where each operation costs 10-100x a normal one (the
#: AMDM device slowed from 2 to ~30 CPU s per simulated s 2.5 s into its default run).
#: 1e-290 rad keeps every intermediate of the step normal; no output moves (the combs'
#: capacitances and torques at 1e-290 rad round to their values at 0).
REST_ANGLE = 1e-290


@numba.njit(cache=True, inline="always")
def _accel(th, om, v2, tau_n, J, k, b, dc0, dth0, thth):
    """theta'' = (1/2 dC_dr/dtheta V^2 + tau_n - b omega - k theta)/J -- eq. (66)."""
    tq = 0.5 * _gauss_dc(th, dc0, dth0, thth) * v2 if v2 != 0.0 else 0.0
    return (tq + tau_n - b * om - k * th) / J


@numba.njit(cache=True, inline="always")
def rk4_step(th, om, v2, tn, hs, J, k, b, dc0, dth0, thth):
    """One classical RK4 step of eq. (66) over hs [s] with V^2 = v2 [V^2] and the noise
    torque tn [N m] held: (theta [rad], omega [rad/s]) after the step; exactly (0, 0) once
    |theta| and |omega| hs are below :data:`REST_ANGLE` (a mirror at rest)."""
    a1 = _accel(th, om, v2, tn, J, k, b, dc0, dth0, thth)
    t2 = th + 0.5 * hs * om
    o2 = om + 0.5 * hs * a1
    a2 = _accel(t2, o2, v2, tn, J, k, b, dc0, dth0, thth)
    t3 = th + 0.5 * hs * o2
    o3 = om + 0.5 * hs * a2
    a3 = _accel(t3, o3, v2, tn, J, k, b, dc0, dth0, thth)
    t4 = th + hs * o3
    o4 = om + hs * a3
    a4 = _accel(t4, o4, v2, tn, J, k, b, dc0, dth0, thth)
    th = th + hs / 6.0 * (om + 2.0 * o2 + 2.0 * o3 + o4)
    om = om + hs / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    if abs(th) < REST_ANGLE and abs(om) * hs < REST_ANGLE:
        return 0.0, 0.0
    return th, om


@numba.njit(cache=True)
def _mech_run(th, om, v, tau, h, m, J, k, b, dc0, dth0, thth, out_th, out_om):
    """RK4 over each sample interval with held v[i], tau[i]; out[i] = state at t_i."""
    hs = h / m
    for i in range(v.shape[0]):
        out_th[i] = th
        out_om[i] = om
        v2 = v[i] * v[i]
        tn = tau[i]
        for _ in range(m):
            th, om = rk4_step(th, om, v2, tn, hs, J, k, b, dc0, dth0, thth)
    return th, om


def simulate_mechanics(
    drive_voltage: np.ndarray,
    fs: float,
    p: ScannerParams,
    *,
    theta0: float = 0.0,
    omega0: float = 0.0,
    torque_noise: np.ndarray | None = None,
    substeps: int = 1,
    return_final: bool = False,
):
    """Integrate J theta'' + b theta' + k theta = 1/2 dC_dr/dtheta V^2 + w (eqs. (66)-(67)).

    Args:
        drive_voltage: (n,) drive V[k] [V], held over [t_k, t_k+1).
        fs: sample rate [Hz].
        p: scanner parameters.
        theta0, omega0: state at t_0 [rad], [rad/s].
        torque_noise: optional (n,) process torque w[k] [N m] held per sample.
        substeps: RK4 steps per sample.
        return_final: also return the state at t_n (for chaining records).

    Returns:
        (theta, omega): (n,) arrays [rad], [rad/s] at t_k = k/fs (theta[0] = theta0);
        plus ``(theta_n, omega_n)`` if ``return_final``.
    """
    v = np.ascontiguousarray(drive_voltage, dtype=np.float64)
    if v.ndim != 1 or not np.all(np.isfinite(v)):
        raise ValueError("drive_voltage must be a finite 1-D array")
    if not (fs > 0 and math.isfinite(fs)):
        raise ParameterError(f"parameter 'fs' = {fs!r} is out of range: allowed (0, inf) Hz")
    tau = (
        np.zeros_like(v)
        if torque_noise is None
        else np.ascontiguousarray(torque_noise, dtype=np.float64)
    )
    if tau.shape != v.shape:
        raise ValueError("torque_noise must have the shape of drive_voltage")
    th = np.empty_like(v)
    om = np.empty_like(v)
    fin = _mech_run(
        float(theta0),
        float(omega0),
        v,
        tau,
        1.0 / fs,
        int(substeps),
        p.J,
        p.k,
        p.b,
        p.drive_c0,
        p.drive_theta0,
        p.theta_th,
        th,
        om,
    )
    return (th, om, fin) if return_final else (th, om)


def dc_transimpedance_output(
    theta: np.ndarray,
    omega: np.ndarray,
    p: ScannerParams,
    sense_resistance: float = 10.0e6,
    bias_voltage: float = 10.0,
    noise: np.ndarray | None = None,
) -> np.ndarray:
    """y_cap = -R_s V_bias dC_s/dtheta omega (+ noise) [V] -- eqs. (64), (71).

    theta [rad], omega [rad/s], R_s [Ohm], V_bias [V], noise: optional (n,) [V].
    """
    y = sensor_gain(theta, p, sense_resistance, bias_voltage) * np.asarray(omega, dtype=float)
    return y if noise is None else y + noise


def psd_reference(
    theta: np.ndarray,
    fs: float,
    delay_s: float,
    history: np.ndarray | None = None,
    noise: np.ndarray | None = None,
) -> np.ndarray:
    """PSD-like angle reference theta_PSD[k] = theta[k - d] (+ noise), d = round(delay fs).

    Sec. 4.4.1: the PSD lags the capacitive readout by 0.114 ms. Samples before the start
    are taken from ``history`` (the previous d samples) or 0. Units rad.
    """
    d = int(round(delay_s * fs))
    theta = np.asarray(theta, dtype=float)
    if d == 0:
        out = theta.copy()
    else:
        prev = np.zeros(d) if history is None else np.asarray(history, dtype=float)[-d:]
        if prev.shape[0] < d:
            prev = np.concatenate((np.zeros(d - prev.shape[0]), prev))
        out = np.concatenate((prev, theta))[: theta.shape[0]]
    return out if noise is None else out + noise


# ----------------------------------------------------------------------------- streaming device
class ScannerFrame(NamedTuple):
    """One frame of the chapter-4 device (n samples starting at ``first_index``).

    drive [V], theta [rad], omega [rad/s], y_clean and y [V] (dc_transimpedance output
    without / with noise), psd [rad] (delayed reference; delay in ``MicroScannerDevice.psd_delay``).
    """

    first_index: int
    drive: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    y_clean: np.ndarray
    y: np.ndarray
    psd: np.ndarray


class MicroScannerDevice:
    """Streaming chapter-4 scanner with the ``dc_transimpedance`` front end.

    Deterministic: ``SeedSequence(seed).spawn(3)`` -> torque noise, readout noise, PSD noise,
    drawn frame by frame so that frames concatenate bit-identically to one long run.
    The drive follows the programme of the spec dict unless ``drive_frequency_hz`` is given
    (constant-frequency 0..V_max drive, used for the far-from-resonance check).
    """

    def __init__(
        self,
        overrides: Mapping[str, Any] | None = None,
        seed: int = 0,
        drive_frequency_hz: float | None = None,
    ):
        self.p = resolve_scanner(overrides)
        self.params = scanner_params(self.p)
        self.fs = self.p["sample_rate_hz"]
        self.const_freq = drive_frequency_hz
        if drive_frequency_hz is not None and not (0 < drive_frequency_hz < self.fs / 2):
            raise ParameterError(
                f"parameter 'drive_frequency_hz' = {drive_frequency_hz!r} is out "
                f"of range: allowed (0, {self.fs / 2!r}) Hz"
            )
        self.plan = drive_plan_from(self.p)
        self.total_samples = self.plan.voltage.shape[0]
        ss = np.random.SeedSequence(seed).spawn(3)
        self._rng_tau, self._rng_y, self._rng_psd = (
            np.random.Generator(np.random.PCG64(s)) for s in ss
        )
        self.psd_delay_samples = int(round(self.p["psd_delay_s"] * self.fs))
        self.psd_delay = self.psd_delay_samples / self.fs
        self._state = (self.p["initial_angle"], 0.0)
        self._hist = np.zeros(self.psd_delay_samples)
        self.next_index = 0

    def retune(self, overrides: Mapping[str, Any]) -> None:
        """The device's physical parameters moved (a temperature change): mechanics and
        combs follow ``overrides`` from the next sample on; the state, the drive programme
        and the noise streams are kept."""
        self.p = resolve_scanner(overrides)
        self.params = scanner_params(self.p)

    def drive(self, first: int, n: int) -> np.ndarray:
        """Drive samples first..first+n-1 [V] (0 after the programme ends)."""
        if self.const_freq is not None:
            t = (first + np.arange(n)) / self.fs
            return (
                0.5
                * self.p["drive_voltage_max"]
                * (1.0 - np.cos(2 * math.pi * self.const_freq * t))
            )
        v = np.zeros(n)
        lo, hi = first, min(first + n, self.total_samples)
        if hi > lo:
            v[: hi - lo] = self.plan.voltage[lo:hi]
        return v

    def step(self, n: int) -> ScannerFrame:
        """Simulate the next ``n`` samples."""
        k0 = self.next_index
        v = self.drive(k0, n)
        tau = self._rng_tau.standard_normal(n) * self.p["torque_noise_std"]
        th, om, fin = simulate_mechanics(
            v,
            self.fs,
            self.params,
            theta0=self._state[0],
            omega0=self._state[1],
            torque_noise=tau,
            substeps=self.p["substeps"],
            return_final=True,
        )
        self._state = fin
        yc = dc_transimpedance_output(
            th, om, self.params, self.p["sense_resistance"], self.p["bias_voltage"]
        )
        y = yc + self._rng_y.standard_normal(n) * self.p["noise_std"]
        psd_noise = self._rng_psd.standard_normal(n) * self.p["psd_noise_std"]
        psd = psd_reference(th, self.fs, self.p["psd_delay_s"], self._hist, psd_noise)
        d = self.psd_delay_samples
        if d:
            self._hist = np.concatenate((self._hist, th))[-d:]
        self.next_index += n
        return ScannerFrame(k0, v, th, om, yc, y, psd)

"""Force-to-rebalance capacitive MEMS accelerometer (Zhang 2010, chapters 2, 3 and 5).

A surface-micromachined proof mass between two fixed electrodes:

* plant (2-1): ``m x'' + b(x) x' + k x = m a + F_el + F_B``;
* readout (2-9): the synchronous-demodulated charge amplifier output
  ``v_o = -2 eps0 epsr A x V1 / (C4 (d0^2 - x^2))`` (exact parallel-plate form),
  plus electronic noise, sampled by an ADC once per sample period;
* electrostatic force of the carrier (2-12) and of the rebalance electrodes with
  bias ``V_B`` and feedback voltage ``v_F`` (2-15), in their nonlinear form
  averaged over the 1 MHz carrier (the mechanics, with poles below 2e5 rad/s,
  cannot follow the 2 MHz force ripple, so ``<sin^2> = 1/2`` is exact to
  the ripple's ~1e-4 relative displacement);
* squeeze-film damping ``b(x)`` (2-14, corrected: see :func:`damping`);
* a mechanical stop at the parallel-plate pull-in distance ``d0/3`` with contact
  reported (the saturation block of Fig. 7);
* Brownian force noise ``4 kB T b`` (3-1) or the thesis's chapter-5 level, and
  electronic readout noise (3-10) referred to acceleration as in section 3.1.2.

Controller modes: ``open_loop`` (Fig. 7/14: carrier only, no bias, ``v_F = 0``),
``pi_rebalance`` (Fig. 9/13: PI with Kp = 10, Ki = 1 on the readout voltage),
``ekf_rebalance`` (Fig. 17: the same PI acting on the hybrid EKF's estimate of the
readout voltage, :mod:`mems_sim.kernels.accelerometer_ekf`).

Sign convention: ``v_o`` is negative for positive ``x`` (2-9) and a positive
``v_F`` pushes the mass towards negative ``x`` (2-15), so negative feedback uses the
inverted readout as the controller's error, ``e = -v_o``, ``v_F = Kp e + Ki int e dt``.

Every parameter is in :data:`ACCEL_SPECS` with its unit, source and valid range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numba
import numpy as np

from mems_sim.devices.accelerometer_specs import ACCEL_SPECS, EPS0, G0, K_BOLTZMANN, MODES, PROFILES
from mems_sim.kernels.accelerometer_ekf import (
    N_STATES,
    HybridEkfConfig,
    ekf_init,
    ekf_predict,
    ekf_update,
    is_positive_definite,
    model_vector,
)
from mems_sim.params import ParameterError, resolve

__all__ = [
    "ACCEL_SPECS",
    "EPS0",
    "G0",
    "K_BOLTZMANN",
    "MODES",
    "PROFILES",
    "TABLE_III_VARIANT",
    "validate_params",
    "eps_area",
    "bias_voltage",
    "readout_gain",
    "readout_voltage",
    "electrostatic_force",
    "damping",
    "readout_noise_std",
    "brownian_force_std",
    "adc_lsb",
    "static_acceleration",
    "pull_in_acceleration",
    "input_acceleration",
    "load_profile_file",
    "plant_vector",
    "run_block",
    "AccelFrame",
    "ForceRebalanceAccelerometer",
    "ekf_config",
    "LOOP_MODEL_KEYS",
]

#: The Table III reading (Zhang 2010 Table III): a carrier amplitude of 0.675 V instead of
#: Table I's 0.6 V. The carrier's softening eps A V1^2 / d0^3 (eq. 2-12 linearised) then
#: leaves k_eff = 0.53 N/m of Table I's k = 3 N/m, which gives the thesis' open-loop 7e-8 m
#: at 1 g and a static pull-in at 4.06 g (Table III: the open loop fails at 5 g). With Table I
#: as printed (0.6 V) k_eff = 1.05 N/m, 1 g gives 3.5e-8 m and the pull-in is at 12.2 g.
TABLE_III_VARIANT = {"carrier_amplitude": 0.675}


def validate_params(values: Mapping[str, Any]) -> dict:
    """All parameters, defaults filled in; ParameterError names the bad one."""
    p = resolve(ACCEL_SPECS, values)
    if p["profile"] == "file" and not p["profile_file"]:
        raise ParameterError(
            "parameter 'profile_file' = '' invalid: profile 'file' needs a "
            "file of 'time_s accel_m_s2' rows"
        )
    if p["profile"] == "file" and not Path(p["profile_file"]).is_file():
        raise ParameterError(
            f"parameter 'profile_file' = {p['profile_file']!r} invalid: no such file"
        )
    if p["accel_frequency"] >= p["sample_rate_hz"] / 2:
        raise ParameterError(
            f"parameter 'accel_frequency' = {p['accel_frequency']!r} invalid: "
            f"must be below sample_rate_hz/2 = {p['sample_rate_hz'] / 2!r} Hz"
        )
    return p


# --------------------------------------------------------------------------- physics
def eps_area(p: Mapping[str, Any]) -> float:
    """eps0 * eps_r * A [F m] (Zhang 2010 eq. 2-8)."""
    return EPS0 * p["rel_permittivity"] * p["plate_area"]


def bias_voltage(p: Mapping[str, Any]) -> float:
    """Rebalance bias V_B = sqrt(m a_DR d0^2 / (eps0 eps_r A)) [V] (Zhang 2010 eq. 2-18)."""
    return math.sqrt(p["mass"] * p["dynamic_range"] * p["gap"] ** 2 / eps_area(p))


def readout_gain(p: Mapping[str, Any]) -> float:
    """Small-signal readout gain H = 2 eps0 eps_r A V1 / (C4 d0^2) [V/m] (eqs. 2-10, 5-3)."""
    return 2.0 * eps_area(p) * p["carrier_amplitude"] / (p["feedback_capacitor"] * p["gap"] ** 2)


def readout_voltage(x, p: Mapping[str, Any]):
    """Demodulated readout v_o(x) = -2 eps A x V1 / (C4 (d0^2 - x^2)) [V] (eq. 2-9); x in m."""
    d0 = p["gap"]
    return (
        -2.0
        * eps_area(p)
        * x
        * p["carrier_amplitude"]
        / (p["feedback_capacitor"] * (d0 * d0 - np.square(x)))
    )


def electrostatic_force(x, v_f, v_b, p: Mapping[str, Any]):
    """Carrier-averaged electrostatic force on the mass [N] (Zhang 2010 eq. 2-15).

    ``<(V1 sin wt + c)^2> = V1^2/2 + c^2``, so
    ``F = eps A / 2 [(V1^2/2 + (v_F - V_B)^2)/(d0 - x)^2 - (V1^2/2 + (v_F + V_B)^2)/(d0 + x)^2]``.
    With ``v_F = V_B = 0`` this is the carrier force (2-12). Its small-signal form is
    ``-2 eps A V_B v_F / d0^2 + eps A (V1^2 + 2 V_B^2 + 2 v_F^2) x / d0^3``; the
    thesis's (2-16) has ``(V1^2 + V_B^2 + v_F^2)`` there (a factor 2 on the bias
    terms is lost), and (2-17) keeps only the first term. x in m, voltages in V.
    """
    d0 = p["gap"]
    c2 = 0.5 * p["carrier_amplitude"] ** 2
    return (
        0.5
        * eps_area(p)
        * ((c2 + (v_f - v_b) ** 2) / (d0 - x) ** 2 - (c2 + (v_f + v_b) ** 2) / (d0 + x) ** 2)
    )


def damping(x, p: Mapping[str, Any]):
    """Squeeze-film damping b(x) [kg/s] (Zhang 2010 eq. 2-14, corrected).

    As printed, (2-14) ``b(x) = mu A^2 / 2 [1/(d0 - x)^3 - 1/(d0 + x)^3]`` is odd in x:
    zero at rest and negative for x < 0, which is not a damping. The two squeeze
    films (upper and lower gap) add, so the physical form is the sum
    ``[1/(d0 - x)^3 + 1/(d0 + x)^3]``. Its prefactor ``mu A^2/d0^3`` gives 5 kg/s at
    rest, 7000 times Table I's b; we keep the cubic gap law and scale it so that
    ``b(0)`` equals Table I's ``b = 7e-4 kg/s``:
    ``b(x) = b0 [(d0/(d0 - x))^3 + (d0/(d0 + x))^3] / 2``.
    """
    if p["damping_model"] == "constant":
        return p["damping"] + 0.0 * np.asarray(x)
    u = np.asarray(x) / p["gap"]
    return p["damping"] * 0.5 * (1.0 / (1.0 - u) ** 3 + 1.0 / (1.0 + u) ** 3)


def readout_noise_std(p: Mapping[str, Any]) -> float:
    """Electronic noise at the readout [V]: electronic_accel_std * H * m / k (eqs. 2-4, 2-10)."""
    return p["electronic_accel_std"] * readout_gain(p) * p["mass"] / p["stiffness"]


def brownian_force_std(p: Mapping[str, Any]) -> float:
    """Brownian force std per sample [N] held over one sample (ZOH).

    'thermal': one-sided PSD ``4 kB T b`` (eq. 3-1) over ``fs/2`` -> ``sqrt(2 kB T b fs)``;
    'specified': ``m * brownian_accel_std`` (the thesis's ch. 5 level).
    """
    if p["brownian_source"] == "thermal":
        return math.sqrt(2.0 * K_BOLTZMANN * p["temperature"] * p["damping"] * p["sample_rate_hz"])
    return p["mass"] * p["brownian_accel_std"]


def adc_lsb(p: Mapping[str, Any]) -> float:
    """Readout ADC step [V]: full scale / 2^(bits-1)."""
    return p["adc_full_scale"] / 2 ** (p["adc_bits"] - 1)


def static_acceleration(x, p: Mapping[str, Any], v_b: float = 0.0):
    """Acceleration that holds the mass at x with v_F = 0: (k x - F_el(x)) / m [m/s^2]."""
    return (p["stiffness"] * x - electrostatic_force(x, 0.0, v_b, p)) / p["mass"]


def pull_in_acceleration(p: Mapping[str, Any], v_b: float = 0.0) -> tuple[float, float]:
    """(a_pi, x_pi): the largest static acceleration the open loop can hold and where.

    Beyond ``a_pi`` there is no static equilibrium of (2-1) with the carrier force (2-12):
    the mass snaps to the stop (electrostatic pull-in).
    """
    x = np.linspace(0.0, p["stop_fraction"] * p["gap"], 200001)
    a = static_acceleration(x, p, v_b)
    i = int(np.argmax(a))
    return float(a[i]), float(x[i])


# --------------------------------------------------------------------------- inputs
def input_acceleration(
    t: np.ndarray, p: Mapping[str, Any], file_table: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """The input acceleration a(t) [m/s^2] of the configured profile at times t [s]."""
    amp = p["accel_amplitude"]
    prof = p["profile"]
    if prof == "sinusoid":
        return amp * np.sin(2.0 * np.pi * p["accel_frequency"] * t)
    if prof == "step":
        return np.where(t >= p["step_time"], amp, 0.0)
    if prof == "chirp":
        f0, f1, T = p["accel_frequency"], p["chirp_end_frequency"], p["chirp_duration"]
        tc = np.minimum(t, T)
        phase = 2.0 * np.pi * (f0 * tc + 0.5 * (f1 - f0) / T * tc * tc)
        phase = phase + 2.0 * np.pi * f1 * (t - tc)
        return amp * np.sin(phase)
    if file_table is None:
        file_table = load_profile_file(p["profile_file"])
    return np.interp(t, file_table[0], file_table[1])


def load_profile_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(time [s], accel [m/s^2]) from a two-column CSV or whitespace file; '#' comments."""
    text = Path(path).read_text()
    data = np.loadtxt(text.replace(",", " ").splitlines(), comments="#", ndmin=2)
    if data.shape[1] < 2 or data.shape[0] < 2 or not np.all(np.isfinite(data[:, :2])):
        raise ParameterError(
            f"parameter 'profile_file' = {path!r} invalid: need >= 2 finite "
            "rows of 'time_s accel_m_s2'"
        )
    t = data[:, 0]
    if np.any(np.diff(t) <= 0):
        raise ParameterError(f"parameter 'profile_file' = {path!r} invalid: times must increase")
    return t, data[:, 1]


# --------------------------------------------------------------------------- kernel
def plant_vector(p: Mapping[str, Any], v_b: float) -> np.ndarray:
    """Packed plant constants for the numba kernel (layout of :mod:`hybrid_ekf`'s model)."""
    return model_vector(
        mass=p["mass"],
        stiffness=p["stiffness"],
        damping=p["damping"],
        squeeze_film=p["damping_model"] == "squeeze_film",
        eps_area=eps_area(p),
        gap=p["gap"],
        carrier=p["carrier_amplitude"],
        c4=p["feedback_capacitor"],
        v_b=v_b,
    )


@numba.njit(cache=True)
def _plant_rhs(x, v, a, v_f, f_b, mv):
    """(x', v') of eq. (2-1) with (2-14) and (2-15); mv from :func:`plant_vector`."""
    k, b0, sq, ea, d0, v1, v_b = mv[1], mv[2], mv[3], mv[4], mv[5], mv[6], mv[8]
    ilo = 1.0 / (d0 - x)  # reciprocals once: divisions dominate the cost
    ihi = 1.0 / (d0 + x)
    ilo2, ihi2 = ilo * ilo, ihi * ihi
    b = b0
    if sq > 0.5:
        b = b0 * 0.5 * d0 * d0 * d0 * (ilo2 * ilo + ihi2 * ihi)
    c2 = 0.5 * v1 * v1
    f_el = 0.5 * ea * ((c2 + (v_f - v_b) ** 2) * ilo2 - (c2 + (v_f + v_b) ** 2) * ihi2)
    return v, a + (f_el + f_b - k * x - b * v) / mv[0]


@numba.njit(cache=True)
def run_block(
    acc,
    noise_f,
    noise_v,
    dt,
    substeps,
    mv,
    x_stop,
    mode,
    kp,
    ki,
    v_f_max,
    v_noise_std,
    lsb,
    code_max,
    state,
    faults_on,
    f_gain,
    f_offset,
    f_rail,
    f_hold,
    f_state,
    ekf_x,
    ekf_p,
    ekf_q,
    ekf_r,
    ekf_mv,
    out_x,
    out_v,
    out_code,
    out_vf,
    out_contact,
    out_sat,
    out_est,
    out_var,
    out_pd,
):
    """Advance the device by len(noise_v) samples (Zhang 2010 Figs. 14, 13, 17).

    Sample k: read the ADC (eq. 2-9 + noise, quantised), run the controller, hold
    v_F over [t_k, t_k+1) and integrate (2-1) with RK4 (``substeps`` per sample).

    Args:
        acc: input acceleration [m/s^2] on the grid t_k + j dt/(2 substeps),
            j = 0..2 substeps n (length 2 substeps n + 1).
        noise_f: Brownian force per sample [N]; noise_v: readout noise per sample [V].
        mode: 0 open loop, 1 PI on the readout, 2 PI on the hybrid EKF estimate.
        state: [x, v, integrator, contact] carried between blocks (updated in place).
        faults_on: whether the readout has scheduled faults this block; f_gain, f_offset
            [V], f_rail [V], f_hold per sample: the faulty readout
            hold(clip(gain y + offset, -rail, rail)) before the ADC
            (:meth:`~mems_sim.hardware.sensor_faults.SensorFaultInjector.loop_terms`);
            f_state: [held entry + 1, held value V] carried between blocks (in place).
        ekf_x, ekf_p: EKF state [x, v, a] and covariance (in place); ekf_q = (q_F, q_a)
            continuous PSDs; ekf_r the measurement variance [V^2]; ekf_mv its model.
    Outputs (per sample): true x [m], v [m/s] at the sample instant, ADC code, v_F [V],
    contact flag, feedback-saturated flag, EKF estimates [x, v, a] and variances, and
    whether the EKF covariance is positive definite (Sylvester's criterion).
    """
    n = noise_v.shape[0]
    x, v, integ = state[0], state[1], state[2]
    h = dt / substeps
    v1, c4, ea, d0 = mv[6], mv[7], mv[4], mv[5]
    for i in range(n):
        y = -2.0 * ea * x * v1 / (c4 * (d0 * d0 - x * x)) + noise_v[i]
        if faults_on:
            y = f_gain[i] * y + f_offset[i]
            if y > f_rail[i]:
                y = f_rail[i]
            elif y < -f_rail[i]:
                y = -f_rail[i]
            if f_hold[i] != f_state[0]:
                f_state[0] = f_hold[i]
                f_state[1] = y
            if f_hold[i] > 0:
                y = f_state[1]
        code = math.floor(y / lsb + 0.5)
        if code > code_max:
            code = code_max
        elif code < -code_max - 1:
            code = -code_max - 1
        y_adc = code * lsb
        v_f = 0.0
        if mode == 1:
            e = -y_adc
            integ += ki * e * dt
            v_f = kp * e + integ
        elif mode == 2:
            ekf_update(ekf_x, ekf_p, y_adc, ekf_r, ekf_mv)
            # the estimated readout -h(x_hat) (eq. 2-9) with the designer's constants
            xh, dm = ekf_x[0], ekf_mv[5]
            e = 2.0 * ekf_mv[4] * xh * ekf_mv[6] / (ekf_mv[7] * (dm * dm - xh * xh))
            integ += ki * e * dt
            v_f = kp * e + integ
        sat = False
        if v_f > v_f_max:
            v_f = v_f_max
            sat = True
        elif v_f < -v_f_max:
            v_f = -v_f_max
            sat = True
        out_x[i] = x
        out_v[i] = v
        out_code[i] = code
        out_vf[i] = v_f
        out_sat[i] = sat
        if mode == 2:
            for j in range(3):
                out_est[i, j] = ekf_x[j]
                out_var[i, j] = ekf_p[j, j]
            out_pd[i] = is_positive_definite(ekf_p)
            ekf_predict(ekf_x, ekf_p, v_f, dt, ekf_q, ekf_mv)
        contact = False
        fb = noise_f[i]
        base = 2 * substeps * i
        for s in range(substeps):
            a0 = acc[base + 2 * s]
            a1 = acc[base + 2 * s + 1]
            a2 = acc[base + 2 * s + 2]
            k1x, k1v = _plant_rhs(x, v, a0, v_f, fb, mv)
            k2x, k2v = _plant_rhs(x + 0.5 * h * k1x, v + 0.5 * h * k1v, a1, v_f, fb, mv)
            k3x, k3v = _plant_rhs(x + 0.5 * h * k2x, v + 0.5 * h * k2v, a1, v_f, fb, mv)
            k4x, k4v = _plant_rhs(x + h * k3x, v + h * k3v, a2, v_f, fb, mv)
            x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
            v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
            if x >= x_stop:
                x = x_stop
                if v > 0.0:
                    v = 0.0
                contact = True
            elif x <= -x_stop:
                x = -x_stop
                if v < 0.0:
                    v = 0.0
                contact = True
        out_contact[i] = contact
    state[0], state[1], state[2] = x, v, integ
    return n


#: The loop fault terms of a block without faults (not read by the kernel).
_NO_FAULTS = (np.ones(1), np.zeros(1), np.full(1, np.inf), np.zeros(1, np.int64))


@dataclass
class AccelFrame:
    """One block of samples of :class:`ForceRebalanceAccelerometer`."""

    first_index: int
    accel: np.ndarray  # input acceleration at the sample instants [m/s^2]
    x: np.ndarray  # true displacement [m]
    v: np.ndarray  # true velocity [m/s]
    code: np.ndarray  # readout ADC codes
    v_f: np.ndarray  # feedback voltage [V]
    contact: np.ndarray  # mass at the stop during the sample interval
    saturated: np.ndarray  # feedback voltage clipped at +-V_B
    estimate: np.ndarray  # (n, 3) in-loop EKF [x, v, a] (ekf_rebalance), else empty
    variance: np.ndarray  # (n, 3) its variances
    positive_definite: np.ndarray  # (n,) EKF covariance positive definite (ekf_rebalance)


class ForceRebalanceAccelerometer:
    """The emulated accelerometer with its controller; ``step(n)`` yields the next n samples.

    Args:
        params: values for :data:`ACCEL_SPECS` (validated; defaults filled in): the
            device as built (one draw of a batch, at its temperature).
        seed: seed of the Brownian and electronic noise.
        nominal: the designer's values (default: ``params``): the rebalance bias V_B
            (2-18) and the in-loop EKF's model and noise levels are designed from them,
            not from the device as built.
        loop_model: values replacing ``nominal``'s in the in-loop EKF's model and noise
            levels only (an identified model, such as ``mass``, ``stiffness``,
            ``damping``, ``gap``, ``electronic_accel_std``: the controller's firmware is
            given the bench's model); V_B stays the designer's. None: ``nominal``.
    """

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        seed: int = 0,
        nominal: Mapping[str, Any] | None = None,
        loop_model: Mapping[str, Any] | None = None,
    ) -> None:
        self.p = validate_params(params or {})
        p = self.p
        self.nominal = p if nominal is None else validate_params(nominal)
        self.fs = p["sample_rate_hz"]
        self.dt = 1.0 / self.fs
        self.mode = MODES.index(p["mode"])
        self.v_b = bias_voltage(self.nominal) if self.mode > 0 else 0.0
        self.mv = plant_vector(p, self.v_b)
        self.x_stop = p["stop_fraction"] * p["gap"]
        self.lsb = adc_lsb(p)
        self.code_max = 2 ** (p["adc_bits"] - 1) - 1
        self.v_noise_std = readout_noise_std(p)
        self.f_noise_std = brownian_force_std(p)
        self.file_table = load_profile_file(p["profile_file"]) if p["profile"] == "file" else None
        self.rng = np.random.default_rng(seed)
        self.state = np.zeros(3)
        self.next_index = 0
        loop = self.nominal if not loop_model else validate_params(dict(self.nominal, **loop_model))
        self.ekf_config = ekf_config(loop, self.v_b)
        self.ekf_x, self.ekf_p = ekf_init(self.ekf_config.p0_diag)
        #: Scheduled sensor faults on the readout voltage before the ADC, inside the loop
        #: (mems_sim.hardware.sensor_faults; channel ``readout``); None: no faults.
        self.faults = None
        self.fault_state = np.zeros(2)

    def retune(self, params: Mapping[str, Any]) -> None:
        """The device's physical parameters moved (a temperature change): the plant, the
        stop and the noise levels follow ``params`` from the next sample on; the state, the
        noise streams, the controller, V_B and the EKF (the designer's) are kept."""
        p = validate_params(params)
        self.p = p
        self.mv = plant_vector(p, self.v_b)
        self.x_stop = p["stop_fraction"] * p["gap"]
        self.v_noise_std = readout_noise_std(p)
        self.f_noise_std = brownian_force_std(p)

    def input_at(self, t: np.ndarray) -> np.ndarray:
        """Input acceleration [m/s^2] at times t [s]."""
        return input_acceleration(t, self.p, self.file_table)

    def step(self, n: int) -> AccelFrame:
        """Simulate the next ``n`` samples."""
        sub = self.p["substeps"]
        first = self.next_index
        t = (first + np.arange(2 * sub * n + 1) / (2 * sub)) * self.dt
        acc = self.input_at(t)
        noise = self.rng.standard_normal((n, 2))
        terms = self.faults.loop_terms(first, n) if self.faults else None
        out = AccelFrame(
            first,
            acc[: -1 : 2 * sub].copy(),
            np.empty(n),
            np.empty(n),
            np.empty(n, np.int64),
            np.empty(n),
            np.empty(n, np.bool_),
            np.empty(n, np.bool_),
            np.zeros((n, N_STATES)),
            np.zeros((n, N_STATES)),
            np.ones(n, np.bool_),
        )
        c = self.ekf_config
        run_block(
            acc,
            noise[:, 0] * self.f_noise_std,
            noise[:, 1] * self.v_noise_std,
            self.dt,
            sub,
            self.mv,
            self.x_stop,
            self.mode,
            self.p["kp"],
            self.p["ki"],
            self.v_b if self.mode > 0 else 0.0,
            self.v_noise_std,
            self.lsb,
            self.code_max,
            self.state,
            terms is not None,
            *(terms if terms is not None else _NO_FAULTS),
            self.fault_state,
            self.ekf_x,
            self.ekf_p,
            c.q,
            c.r,
            c.model,
            out.x,
            out.v,
            out.code,
            out.v_f,
            out.contact,
            out.saturated,
            out.estimate,
            out.variance,
            out.positive_definite,
        )
        if self.mode != 2:
            out.estimate = np.zeros((n, 0))
            out.variance = np.zeros((n, 0))
        self.next_index += n
        return out


#: The parameters a bench identification gives the hybrid EKF's model (ACCEL_SPECS names):
#: what an identified model YAML holds, for the in-loop and the downstream filter alike.
LOOP_MODEL_KEYS = ("mass", "stiffness", "damping", "gap", "electronic_accel_std")


def ekf_config(p: Mapping[str, Any], v_b: float) -> HybridEkfConfig:
    """The hybrid EKF configuration of the designer's model of parameter set ``p``.

    P0: the device starts at rest; Table II's P0 = 0 is replaced by the one-sample
    resolution of the readout so that P is positive definite from the start:
    ``sigma_x = sigma_v / H``, ``sigma_v' = omega_n sigma_x``, ``sigma_a = electronic_accel_std``.
    Q and R come from the device's documented noise levels (Table II's role):
    ``q_F = sigma_F^2 dt`` (the ZOH Brownian force as a continuous intensity),
    ``q_a = ekf_accel_rw^2``; ``R = sigma_v^2 + lsb^2/12``; both scaled by
    ``ekf_q_scale`` / ``ekf_r_scale`` (the thesis's Table IV sweep).
    """
    dt = 1.0 / p["sample_rate_hz"]
    q = np.array([brownian_force_std(p) ** 2 * dt, p["ekf_accel_rw"] ** 2])
    r = readout_noise_std(p) ** 2 + adc_lsb(p) ** 2 / 12.0
    sx = readout_noise_std(p) / readout_gain(p)
    wn = math.sqrt(p["stiffness"] / p["mass"])
    p0 = (sx**2, (wn * sx) ** 2, p["electronic_accel_std"] ** 2)
    return HybridEkfConfig(
        model=plant_vector(p, v_b),
        q=q * p["ekf_q_scale"],
        r=r * p["ekf_r_scale"],
        dt=dt,
        p0_diag=p0,
    )

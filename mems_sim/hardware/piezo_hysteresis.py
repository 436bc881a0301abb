"""Piezoelectric actuator: rate-independent Bouc-Wen hysteresis followed by creep.

A linear piezo gives ``x = d u`` (``u`` drive voltage [V], ``d`` the actuator's gain in the
caller's unit of displacement per volt: m/V for a stack, rad/V for a tilt stage whose
quasi-static tilt is ``b_c / wn^2`` per volt). Real PZT adds a hysteresis loop (open-loop
stacks: 10-15 % of the stroke) and a slow creep after every change of the drive (about
1-2 % of the step per decade of time). This module gives both, ROS-free, with a parameter
table (:data:`PIEZO_SPECS`) whose all-zero setting (:data:`IDEAL`) is the linear piezo bit
for bit.

Hysteresis: the Bouc-Wen model in the form used for piezo actuators by Low & Guo,
"Modeling of a three-layer piezoelectric bimorph beam with hysteresis", J. MEMS 4(4)
1995, and Rakotondrabe, "Bouc-Wen modeling and inverse multiplicative structure to
compensate hysteresis nonlinearity in piezoelectric actuators", IEEE T-ASE 8(2) 2011,
Sec. II (the equation numbers below are this module's)::

    (H1)  x = d u - h,      h = d z
    (H2)  dz/dt = alpha du/dt - beta |du/dt| |z|^(n-1) z - gamma du/dt |z|^n

``z`` [V] is the hysteresis expressed as a voltage: for n = 1, (H2) times d is the papers'
``dh/dt = alpha d du/dt - beta |du/dt| h - gamma du/dt |h|`` exactly; for n != 1 the
papers' beta and gamma (per unit of h^(n-1)) are this module's times d^(1-n), so the
table's values do not depend on the unit of d. alpha [-], beta and gamma [1/V^n], n [-].

(H2) is rate independent: dividing by du/dt, along a monotone piece of the input of
direction s = sign(du) and travel v = |u - u_start| [V], the hysteresis seen in the
direction of motion, w = s z, obeys::

    (H3)  dw/dv = alpha - (beta sign(w) + gamma) |w|^n

Only the path of u matters, never its speed. For alpha > 0, beta + gamma > 0 and
beta >= |gamma| (the bounded class of Ikhouane & Rodellar, "Systems with Hysteresis:
Analysis, Identification and Control using the Bouc-Wen Model", Wiley 2007) a state
that starts inside stays inside::

    (H4)  |z| <= z_s = (alpha / (beta + gamma))^(1/n),   |h| <= h_max = d z_s

and dw/dv <= 2 alpha beta / (beta + gamma); the table requires that bound <= 1, so x never
moves against the drive (monotone branches, the loop's extremes at its turning points).

For n = 1 (H3) is linear in w on either side of w = 0, and its solution after a travel
v from w0 is exact (b = beta - gamma while w < 0, b = beta + gamma once w >= 0; from
w0 < 0, w reaches 0 after v0 = ln(1 + b |w0| / alpha) / b, = |w0| / alpha for b = 0)::

    (H5)  w(v) = w0 exp(-b v) + alpha (1 - exp(-b v)) / b      (alpha v at b = 0)

A symmetric periodic drive of travel 2 U per half period (amplitude U) settles on a loop
with turning-point value Z, the root of (H5) from w0 = -Z over the travel 2 U ending at
+Z; for gamma = 0 it is Z = (alpha / beta) tanh(beta U). The loop is widest at the middle
of the drive (w is concave along a branch), where ascending and descending branches are
2 d w_mid apart (w_mid: (H5) from -Z over U), and the stroke is 2 d (U - Z)::

    (H6)  loop width = w_mid / (U - Z)     (fraction of the stroke; :func:`loop_width`)

Discretisation: u[k] is sampled at fs and the path between samples is taken as the
straight segment u[k-1] -> u[k] (a held, staircase drive has the same path: (H3) sees
no time). n = 1: (H5) per segment, exact. n != 1: classical RK4 on (H3) over the
segment's travel with ``bw_substeps`` fixed substeps. A turning point between two
samples is cut to the sample; the loop then misses a travel of up to U (pi f / fs)^2 / 2
per turn.

Creep: a bank of first-order creep elements (the spring-damper creep model of Croft, Shed
& Devasia, "Creep, hysteresis, and vibration compensation for piezoactuators: atomic
force microscopy application", J. Dyn. Sys. Meas. Control 123(1) 2001), one per decade of
time, acting on the hysteretic displacement x_h of (H1)::

    (C1)  y = x_h + sum_i c_i,   tau_i dc_i/dt = kappa x_h - c_i,
          tau_i = tau_1 10^(i-1), i = 1..N,   kappa = creep_per_decade

After a step of x_h from 0 to x0 at t = 0, closed form::

    (C2)  y(t) = x0 (1 + kappa sum_i (1 - exp(-t / tau_i)))

which for tau_1 <= t <= tau_N / 30 is the logarithmic creep law of Jung & Gweon, "Creep
characteristics of piezoelectric actuators", Rev. Sci. Instrum. 71(4) 2000 (and of
Physik Instrumente's piezo tutorial, x(t) = x(0.1 s) (1 + gamma lg(t / 0.1 s)))::

    (C3)  y(t) ~ x0 (1 + kappa log10(t / t_e)),   t_e = tau_1 exp(-euler_gamma) / sqrt(10)

within 0.02 kappa x0 (the decade-spaced exponentials ripple about the logarithm; their
mean offset is 1/2 + euler_gamma / ln 10 decades). Discretised exactly for x_h held over
each sample: c_i[k+1] = a_i c_i[k] + (1 - a_i) kappa x_h[k], a_i = exp(-1 / (fs tau_i)),
and y[k] = x_h[k] + sum_i c_i[k] (so a step at sample 0 gives (C2) at t = k / fs).

Every kernel is a plain sequential numba loop (no fastmath, no parallel reduction): the
same floats on every CPU. :class:`PiezoActuator` carries its state across calls, so a
stream cut into blocks gives the bits of one call.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numba
import numpy as np
from scipy.optimize import brentq

from mems_sim.params import ParameterError, ParamSpec, Spread, resolve

__all__ = [
    "PIEZO_SPECS",
    "IDEAL",
    "PiezoFrame",
    "PiezoActuator",
    "piezo_values",
    "validate_piezo",
    "saturation_z",
    "travel_n1",
    "loop_peak_z",
    "loop_width",
    "creep_taus",
    "creep_step_response",
    "creep_log_law",
    "creep_log_time",
]

_PI_TUTORIAL = "Physik Instrumente, Piezoelectrics in Positioning (piezo tutorial)"
_STAGE_DRIVE = "the stage's top calibration drive +-1.3 V (Chen 2018 Table 3.2)"

PIEZO_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "bw_alpha",
        0.3,
        "-",
        "Bouc-Wen alpha of (H2): the hysteresis' initial slope dz/du",
        "assumption: with beta, gamma a loop of 12.2 % of the stroke at "
        + _STAGE_DRIVE
        + ", inside the 10-15 % of open-loop piezo stacks ("
        + _PI_TUTORIAL
        + "); 0 switches the hysteresis off",
        min=0.0,
        max=1.0,
        spread=Spread(
            "uniform", 0.2, source="assumption: +-20 % loop size from part to part (PZT batch)"
        ),
    ),
    ParamSpec(
        "bw_beta",
        1.0,
        "1/V^n",
        "Bouc-Wen beta of (H2) (the |du/dt| term); beta >= |gamma|",
        "assumption: 1/V sets the loop's saturation to the stage's volt-level drive; "
        "bounded class beta + gamma > 0, beta - gamma >= 0 (Ikhouane & Rodellar 2007)",
        min=0.0,
        max=1.0e4,
    ),
    ParamSpec(
        "bw_gamma",
        0.5,
        "1/V^n",
        "Bouc-Wen gamma of (H2) (the du/dt |z|^n term); |gamma| <= beta",
        "assumption: loop shape between gamma = 0 (tanh loop) and gamma = beta; "
        "12.2 % of the stroke at " + _STAGE_DRIVE + " with alpha 0.3, beta 1/V",
        min=-1.0e4,
        max=1.0e4,
    ),
    ParamSpec(
        "bw_n",
        1.0,
        "-",
        "Bouc-Wen exponent n of (H2) (1: exact per-sample solution (H5))",
        "n = 1, the piezo form of Low & Guo 1995 and Rakotondrabe 2011",
        min=1.0,
        max=8.0,
    ),
    ParamSpec(
        "bw_substeps",
        8,
        "-",
        "RK4 substeps per sample along (H3) for n != 1 (unused for n = 1)",
        "numerical setting: the travel per sample is a small fraction of 1/(beta + gamma)",
        min=1,
        max=1024,
    ),
    ParamSpec(
        "creep_per_decade",
        0.015,
        "-",
        "creep kappa of (C1)-(C3): fractional creep of a step per decade of time",
        "creep factor 0.01-0.02 per time decade of the log law (" + _PI_TUTORIAL + "; "
        "Jung & Gweon, Rev. Sci. Instrum. 71(4) 2000); 0 switches creep off",
        min=0.0,
        max=0.2,
        spread=Spread("uniform", 0.3, source="assumption: +-30 % creep from part to part"),
    ),
    ParamSpec(
        "creep_tau_min_s",
        0.01,
        "s",
        "tau_1 of (C1): the fastest creep element (log law (C3) from t_e = 0.178 tau_1)",
        "assumption: creep visible from 10 ms after a step (the log law is fitted from "
        "0.1 s on, " + _PI_TUTORIAL + ")",
        min=1.0e-6,
        max=1.0e4,
    ),
    ParamSpec(
        "creep_decades",
        5,
        "-",
        "N of (C1): creep elements, one per decade from tau_1 (5: 10 ms to 100 s)",
        "assumption: creep measured over 1e-2..1e2 s (Jung & Gweon 2000 record minutes)",
        min=0,
        max=12,
    ),
)

#: Overrides that switch every term off: the linear piezo x = d u, bit for bit.
IDEAL: dict[str, Any] = {
    "bw_alpha": 0.0,
    "bw_beta": 0.0,
    "bw_gamma": 0.0,
    "creep_per_decade": 0.0,
}


def validate_piezo(p: Mapping[str, Any]) -> None:
    """Cross-parameter checks of (H2)-(H4) on resolved values ``p`` (each value already in
    its range). Raises :class:`ParameterError` naming the violated condition."""
    a, b, g = p["bw_alpha"], p["bw_beta"], p["bw_gamma"]
    if b < abs(g):
        raise ParameterError(
            f"bw_beta = {b!r} 1/V^n must be >= |bw_gamma| = {abs(g)!r}: Bouc-Wen with "
            "beta - gamma < 0 or beta + gamma < 0 has no bounded hysteresis (H4)"
        )
    if a > 0.0 and b + g <= 0.0:
        raise ParameterError(
            f"bw_alpha = {a!r} > 0 needs bw_beta + bw_gamma > 0 (got {b + g!r} 1/V^n): "
            "the hysteresis would grow without bound (H4)"
        )
    if a > 0.0 and 2.0 * a * b / (b + g) > 1.0:
        raise ParameterError(
            f"2 bw_alpha bw_beta / (bw_beta + bw_gamma) = {2.0 * a * b / (b + g)!r} must be "
            "<= 1: otherwise the displacement moves against the drive after a turn (H4)"
        )


def piezo_values(overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Defaults of :data:`PIEZO_SPECS` updated with validated ``overrides`` (ranges and the
    cross checks of :func:`validate_piezo`). Raises :class:`ParameterError`."""
    p = resolve(PIEZO_SPECS, overrides)
    validate_piezo(p)
    return p


def saturation_z(p: Mapping[str, Any]) -> float:
    """z_s of (H4) [V]: the bound of |z| (h_max = d z_s); 0 with the hysteresis off."""
    a, b, g = p["bw_alpha"], p["bw_beta"], p["bw_gamma"]
    if a == 0.0:
        return 0.0
    return (a / (b + g)) ** (1.0 / p["bw_n"])


# ----------------------------------------------------------------------------- kernels
@numba.njit(cache=True)
def _phi(b, v):
    """(1 - exp(-b v)) / b of (H5), = v at b = 0. b [1/V], v [V]; returns V."""
    if b == 0.0:
        return v
    return -math.expm1(-b * v) / b


@numba.njit(cache=True)
def travel_n1(w, v, alpha, b1, b2):
    """w after a travel v >= 0 [V] from w [V] for n = 1: (H5) with b1 = beta - gamma
    [1/V] while w < 0 and b2 = beta + gamma [1/V] once w >= 0; alpha [-]. Exact."""
    if w < 0.0:
        if alpha > 0.0:
            v0 = math.log1p(-b1 * w / alpha) / b1 if b1 > 0.0 else -w / alpha
        else:
            v0 = math.inf
        if v <= v0:
            return w * math.exp(-b1 * v) + alpha * _phi(b1, v)
        v -= v0
        w = 0.0
    return w * math.exp(-b2 * v) + alpha * _phi(b2, v)


@numba.njit(cache=True)
def _rate(w, alpha, beta, gamma, n):
    """dw/dv of (H3) [-]: alpha - (beta sign(w) + gamma) |w|^n; w [V]."""
    sb = beta if w >= 0.0 else -beta
    return alpha - (sb + gamma) * math.pow(abs(w), n)


@numba.njit(cache=True)
def _travel_rk4(w, v, alpha, beta, gamma, n, m):
    """w after a travel v >= 0 [V] along (H3): classical RK4 in v, m equal substeps."""
    dv = v / m
    for _ in range(m):
        k1 = _rate(w, alpha, beta, gamma, n)
        k2 = _rate(w + 0.5 * dv * k1, alpha, beta, gamma, n)
        k3 = _rate(w + 0.5 * dv * k2, alpha, beta, gamma, n)
        k4 = _rate(w + dv * k3, alpha, beta, gamma, n)
        w = w + dv / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return w


@numba.njit(cache=True)
def _piezo_run(u, st, d, alpha, beta, gamma, n, m, ca, cb, x, h):
    """(H1)-(H5) and (C1) over the samples u [V]: x [d's unit] and h = d z per sample.

    st = [u_prev, z, c_1..c_N] carried (V, V, d's unit); d the gain [unit/V]; ca[i] =
    a_i, cb[i] = (1 - a_i) kappa (creep elements, may be empty); m RK4 substeps for
    n != 1. With z = 0 and alpha = 0 every x[k] is d u[k] exactly.
    """
    up = st[0]
    z = st[1]
    nc = ca.shape[0]
    b1 = beta - gamma
    b2 = beta + gamma
    exact = n == 1.0
    for k in range(u.shape[0]):
        uk = u[k]
        du = uk - up
        if du != 0.0:
            s = 1.0 if du > 0.0 else -1.0
            if exact:
                w = travel_n1(s * z, abs(du), alpha, b1, b2)
            else:
                w = _travel_rk4(s * z, abs(du), alpha, beta, gamma, n, m)
            z = s * w
        up = uk
        hk = d * z
        xh = d * uk if hk == 0.0 else d * uk - hk
        y = xh
        for i in range(nc):
            c = st[2 + i]
            y += c
            st[2 + i] = ca[i] * c + cb[i] * xh
        x[k] = y
        h[k] = hk
    st[0] = up
    st[1] = z


# ----------------------------------------------------------------------------- actuator
class PiezoFrame(NamedTuple):
    """One block: x displacement (H1) + creep (C1) [unit of d]; h the hysteresis d z
    of (H1) after each sample [unit of d] (x = d u - h + creep)."""

    x: np.ndarray
    h: np.ndarray


def creep_taus(p: Mapping[str, Any]) -> np.ndarray:
    """tau_i of (C1) [s]: tau_1 10^(i-1), i = 1..N (empty with creep off)."""
    if p["creep_per_decade"] == 0.0:
        return np.empty(0)
    return p["creep_tau_min_s"] * 10.0 ** np.arange(p["creep_decades"], dtype=float)


def _positive(name: str, value: float, unit: str) -> float:
    """``value`` as a float if finite and > 0, else :class:`ParameterError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{name} = {value!r} is invalid: expected a number > 0 {unit}")
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ParameterError(f"{name} = {value!r} is out of range: allowed (0, inf) {unit}")
    return v


class PiezoActuator:
    """Piezo actuator with Bouc-Wen hysteresis and creep, streamed sample by sample.

    Args:
        params: overrides of :data:`PIEZO_SPECS` (:data:`IDEAL` for the linear piezo).
        gain: d of (H1), displacement per volt in the caller's unit (m/V, rad/V), > 0.
        sample_rate_hz: fs [Hz] of the drive samples, > 0 (sets the creep's a_i).
        u0: drive [V] the actuator rests at before the first sample (z = 0 there).

    Raises:
        ParameterError: an unknown or out-of-range parameter or argument.
    """

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        gain: float = 1.0,
        sample_rate_hz: float = 625_000.0,
        u0: float = 0.0,
    ) -> None:
        self.params = piezo_values(params)
        self.gain = _positive("gain", gain, "(unit of x)/V")
        self.fs = _positive("sample_rate_hz", sample_rate_hz, "Hz")
        if isinstance(u0, bool) or not isinstance(u0, (int, float)) or not math.isfinite(u0):
            raise ParameterError(f"u0 = {u0!r} is invalid: expected a finite voltage in V")
        taus = creep_taus(self.params)
        dt_tau = 1.0 / (self.fs * taus)
        self._ca = np.exp(-dt_tau)
        self._cb = -np.expm1(-dt_tau) * self.params["creep_per_decade"]
        self._st = np.zeros(2 + taus.size)
        self._st[0] = float(u0)

    @property
    def state(self) -> np.ndarray:
        """Copy of [u_prev V, z V, c_1..c_N (unit of d)]."""
        return self._st.copy()

    def step(self, u: np.ndarray) -> PiezoFrame:
        """The next samples of the drive u [V] (1-D, finite) -> :class:`PiezoFrame`."""
        u = np.ascontiguousarray(u, dtype=float)
        if u.ndim != 1:
            raise ValueError(f"u must be 1-D, got shape {u.shape}")
        if not np.all(np.isfinite(u)):
            raise ValueError("u must be finite (V)")
        p = self.params
        x = np.empty(u.size)
        h = np.empty(u.size)
        _piezo_run(
            u,
            self._st,
            self.gain,
            float(p["bw_alpha"]),
            float(p["bw_beta"]),
            float(p["bw_gamma"]),
            float(p["bw_n"]),
            int(p["bw_substeps"]),
            self._ca,
            self._cb,
            x,
            h,
        )
        return PiezoFrame(x, h)


# ----------------------------------------------------------------------------- closed forms
def _n1_parts(p: Mapping[str, Any]) -> tuple[float, float, float]:
    """(alpha, beta - gamma, beta + gamma) for the n = 1 closed forms; ParameterError if
    n != 1 or the hysteresis is off."""
    p = piezo_values(p)
    if p["bw_n"] != 1.0 or p["bw_alpha"] == 0.0:
        raise ParameterError("the loop's closed form (H5)-(H6) needs bw_n = 1 and bw_alpha > 0")
    b, g = p["bw_beta"], p["bw_gamma"]
    return p["bw_alpha"], b - g, b + g


def _zero_travel(alpha: float, b1: float, w0: float) -> float:
    """v0 [V]: the travel from w0 < 0 [V] to w = 0 under (H5) (n = 1)."""
    return math.log1p(-b1 * w0 / alpha) / b1 if b1 > 0.0 else -w0 / alpha


def loop_peak_z(p: Mapping[str, Any], amplitude_v: float) -> float:
    """Z [V]: turning-point hysteresis of the periodic loop of a drive of amplitude U [V]
    (n = 1): the root of Z = z_s (1 - exp(-b2 (2U - v0(-Z)))) from (H5), by Brent's
    method; Z = (alpha/beta) tanh(beta U) for gamma = 0."""
    alpha, b1, b2 = _n1_parts(p)
    u_amp = _positive("amplitude_v", amplitude_v, "V")
    zs = alpha / b2

    def residual(z: float) -> float:
        return zs * -math.expm1(-b2 * (2.0 * u_amp - _zero_travel(alpha, b1, -z))) - z

    return float(brentq(residual, 0.0, zs, xtol=1e-300, rtol=4.0 * np.finfo(float).eps))


def loop_width(p: Mapping[str, Any], amplitude_v: float) -> float:
    """Largest gap between the loop's branches over its stroke, (H6) [fraction]: w_mid /
    (U - Z) for a symmetric periodic drive of amplitude U [V] (n = 1)."""
    alpha, b1, b2 = _n1_parts(p)
    u_amp = float(amplitude_v)
    z = loop_peak_z(p, u_amp)
    v0 = _zero_travel(alpha, b1, -z)
    if u_amp <= v0:
        w_mid = -z * math.exp(-b1 * u_amp) + alpha * (
            -math.expm1(-b1 * u_amp) / b1 if b1 > 0.0 else u_amp
        )
    else:
        w_mid = alpha / b2 * -math.expm1(-b2 * (u_amp - v0))
    return w_mid / (u_amp - z)


def creep_step_response(p: Mapping[str, Any], t: np.ndarray) -> np.ndarray:
    """y(t) / x0 of (C2) after a step at t = 0; t [s] (>= 0)."""
    taus = creep_taus(p)
    t = np.asarray(t, dtype=float)
    s = np.zeros_like(t)
    for tau in taus:
        s = s - np.expm1(-t / tau)
    return 1.0 + p["creep_per_decade"] * s


def creep_log_time(p: Mapping[str, Any]) -> float:
    """t_e of (C3) [s]: tau_1 exp(-euler_gamma) / sqrt(10)."""
    return p["creep_tau_min_s"] * math.exp(-float(np.euler_gamma)) / math.sqrt(10.0)


def creep_log_law(p: Mapping[str, Any], t: np.ndarray) -> np.ndarray:
    """y(t) / x0 of the logarithmic law (C3), valid for tau_1 <= t <= tau_N / 30; t [s]."""
    return 1.0 + p["creep_per_decade"] * np.log10(np.asarray(t, dtype=float) / creep_log_time(p))

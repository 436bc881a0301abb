"""Shared linear models of the pulse-actuated resonator and its sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator
using digital Kalman observer", eqs. (7)-(13).
Used by the device (:mod:`mems_sim.devices.resonator`) and by the observers
(:mod:`mems_sim.kernels.resonator_observer_model`, :mod:`mems_sim.kernels.resonator_kf_steps`,
:mod:`mems_estimation.filters.resonator_adaptive_observer`) so that "exact model" means
bit-for-bit the same matrices.  No ROS here.

Resonator, eq. (7), with time normalised to the sample period as in the
paper's simulations (f0 given as 0.05 of fs)::

    H(s) = fs*w0 / (s^2 + s*w0/Q + w0^2)     [V/V]

i.e. y'' + (w0/Q) y' + w0^2 y = fs*w0*u with y the position expressed as the
sigma-delta input voltage [V] and u the pulse in the same normalised volts [V].
In normalised time t' = t*fs this is exactly the paper's
H(s') = w0'/(s'^2 + s' w0'/Q + w0'^2), w0' = w0/fs; its DC gain is
fs/w0 = 1/(2 pi f0/fs) (3.18 at f0 = 0.05 fs) and a one-sample pulse of height
U adds about U to the oscillation amplitude, whatever fs is.  (A literal
H(s) = w0/(...) in SI time would have a DC gain of 1/w0 [s] and need pulses of
~1e5 V at fs = 1 MHz.)

Discretisation, eqs. (8)-(9): zero-order hold, implemented in the physical
2-state form X = [y (V), dy/dt (V/s)], X(k+1) = Phi X(k) + Gam u(k), with the
closed-form matrix exponential of the underdamped oscillator
(:func:`resonator_zoh`).  It has the transfer function of eq. (8),
(b1 z^-1 + b2 z^-2)/(1 + a1 z^-1 + a2 z^-2).  The paper's eq. (9)
companion form A_res = [[1, 0], [a1, a2]], C_res = [b2, b1] is not a
realisation of eq. (8) (its first row makes z = 1 an eigenvalue), so it is not
used literally; C_res below is [1, 0] (position).

Sub-sample pulses (not in the paper, whose pulses are one-sample ZOH values of
eq. (8)): a pulse of height u fired at s*T after a sample instant, of width w*T
(0 <= s < 1, 0 < w <= 1), enters the sampled model exactly as
X(k+1) = Phi X(k) + u Phi((1 - b) T) Gam((b - s) T), b = min(s + w, 1), its tail
[0, s + w - 1) contributing u Phi((2 - s - w) T) Gam((s + w - 1) T) to the next
interval (:func:`interval_input`), i.e. the impulse response integrated over the
partial interval with the same closed-form matrix exponential at any duration
(:func:`resonator_zoh_dt`).  The device and the observers' known-input models
use the same function, so the observer stays exact.

Sigma-delta, eqs. (10)-(12): integrators H1 = 0.5 z^-1/(1 - z^-1) and
H2 = z^-1/(1 - z^-1), comparator to +-1 (q >= 0 -> +1), two DAC feedbacks and
an input feed-in of gain c into the second integrator (:func:`sd_step`)::

    s1(k+1) = s1(k) + 0.5*(x(k) - v(k))
    s2(k+1) = s2(k) + s1(k) + c*x(k) - v(k)
    q(k) = s2(k),  v(k) = sign(q(k)),  e(k) = v(k) - q(k)

so that v = STF x + NTF e exactly, with
NTF = (1 - z^-1)^2 / (1 - z^-1 + 0.5 z^-2)   (eq. (12), any c) and
STF = (c z^-1 + (0.5 - c) z^-2) / (1 - z^-1 + 0.5 z^-2).
c = 0.5 (default) gives the printed eq. (11), STF = 0.5 z^-1/(...);
c = 0 is the plain double-loop (Boser-Wooley-like) structure whose
STF = 0.5 z^-2/(...) matches the paper's text ("the signal is ... z^2
delayed", Fig. 4 caption) but not its eq. (11).  Eqs. (10) and (11) together
need the feed-in; the paper's Fig. 3a is not available to decide.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "SD_DEN",
    "NTF_NUM",
    "stf_num",
    "resonator_zoh",
    "resonator_zoh_dt",
    "resonator_zoh_t",
    "resonator_zoh_np",
    "segment_response",
    "interval_input",
    "next_spill",
    "next_crossing",
    "sd_step",
    "sd_step_standin",
    "modulate",
]

#: Common denominator 1 - z^-1 + 0.5 z^-2 of STF and NTF, eqs. (11)-(12).
SD_DEN = np.array([1.0, -1.0, 0.5])
#: NTF numerator (1 - z^-1)^2, eq. (12).
NTF_NUM = np.array([1.0, -2.0, 1.0])


def stf_num(c: float = 0.5) -> np.ndarray:
    """STF numerator [0, c, 0.5 - c] (c = 0.5: eq. (11) as printed)."""
    return np.array([0.0, c, 0.5 - c])


@numba.njit(cache=True, inline="always")
def resonator_zoh_parts(f0, Q, fs, dt):
    """The closed form of :func:`resonator_zoh_t` with its intermediates (Colinet, Galayko &
    Juillard, eqs. (7)-(9)): w0 = 2 pi f0 [rad/s], sigma = w0/(2Q) [1/s], wd (damped
    frequency) [rad/s], E = exp(-sigma dt), cos(wd dt), sin(wd dt), Phi11, Phi12 [s], Phi22
    and g = fs w0 [rad/s^2] (f0, fs in Hz, dt in s); for derivatives that reuse them."""
    w0 = 2.0 * math.pi * f0
    sig = w0 / (2.0 * Q)
    wd = w0 * math.sqrt(1.0 - 1.0 / (4.0 * Q * Q))
    E = math.exp(-sig * dt)
    c = math.cos(wd * dt)
    s = math.sin(wd * dt)
    p12 = E * s / wd
    p11 = E * (c + sig / wd * s)
    g = fs * w0
    return w0, sig, wd, E, c, s, p11, p12, E * (c - sig / wd * s), g


@numba.njit(cache=True, inline="always")
def resonator_zoh_t(f0, Q, fs, dt):
    """:func:`resonator_zoh_dt` as a tuple (Phi11, Phi12, Phi21, Phi22, Gam1, Gam2), the same
    operations (no array argument: inlined into the per-sample loops, where the call with
    an output array costs more than the closed form)."""
    w0, _, _, _, _, _, p11, p12, p22, g = resonator_zoh_parts(f0, Q, fs, dt)
    return p11, p12, -w0 * w0 * p12, p22, g * (1.0 - p11) / (w0 * w0), g * p12


@numba.njit(cache=True, inline="always")
def resonator_zoh_dt(f0, Q, fs, dt, out):
    """ZOH discretisation of eq. (7) over a duration dt (eqs. (8)-(9) for dt = 1/fs), closed form.

    State [y (V), dy/dt (V/s)], input u (V) held over dt (underdamped, Q > 0.5):
    sigma = w0/(2Q), wd = w0 sqrt(1 - 1/(4Q^2)), E = exp(-sigma dt),
      Phi11 = E (cos wd dt + sigma/wd sin wd dt),   Phi12 = E sin(wd dt)/wd,
      Phi21 = -w0^2 Phi12,                          Phi22 = E (cos wd dt - sigma/wd sin wd dt),
      Gam1 = g (1 - Phi11)/w0^2,  Gam2 = g Phi12,  g = fs*w0 (input gain, see module doc),
    i.e. Phi(dt) = exp(Ac dt) and Gam(dt) = int_0^dt exp(Ac r) Bc dr.  dt = 0 gives
    Phi = I, Gam = 0 exactly.

    Args:
        f0: natural frequency, Hz. Q: quality factor (> 0.5). fs: sample rate, Hz (sets g).
        dt: duration, s (>= 0).
        out: (6,) float64 filled with [Phi11, Phi12, Phi21, Phi22, Gam1, Gam2]
            (:func:`resonator_zoh_t`).
    """
    z = resonator_zoh_t(f0, Q, fs, dt)
    out[0] = z[0]
    out[1] = z[1]
    out[2] = z[2]
    out[3] = z[3]
    out[4] = z[4]
    out[5] = z[5]


@numba.njit(cache=True, inline="always")
def resonator_zoh(f0, Q, fs, out):
    """One-sample ZOH discretisation of eq. (7) (eqs. (8)-(9)): :func:`resonator_zoh_dt`
    with dt = T = 1/fs.  out: (6,) [Phi11, Phi12, Phi21, Phi22, Gam1, Gam2]."""
    resonator_zoh_dt(f0, Q, fs, 1.0 / fs, out)


@numba.njit(cache=True)
def segment_response(f0, Q, fs, a, b, t, out, z):
    """Response at time t*T of the resonator state to a unit force acting on [a T, b T).

    Exact (impulse response integrated over the segment, eq. (7)):
    0 for t <= a, else Phi((t - min(t, b)) T) Gam((min(t, b) - a) T).

    Args:
        f0 (Hz), Q, fs (Hz): resonator and sample rate.  a <= b, t: times in units of
        T = 1/fs from the sample instant.  out: (2,) filled with [dy (V), d(dy/dt) (V/s)]
        per V of force.  z: (6,) scratch.
    """
    if t <= a:
        out[0] = 0.0
        out[1] = 0.0
        return
    bb = b if b < t else t
    resonator_zoh_dt(f0, Q, fs, (bb - a) / fs, z)
    g1 = z[4]
    g2 = z[5]
    resonator_zoh_dt(f0, Q, fs, (t - bb) / fs, z)
    out[0] = z[0] * g1 + z[1] * g2
    out[1] = z[2] * g1 + z[3] * g2


@numba.njit(cache=True)
def interval_input(f0, Q, fs, gam, spill_u, spill_end, u, s, w, out, z, wc):
    """Exact input term of one sample interval [k T, (k+1) T) for sub-sample pulses.

    X(k+1) = Phi X(k) + out (+ Gam f(k) for the ZOH force noise), where out is the
    effect at (k+1) T of (i) the tail [0, spill_end) of a pulse of height spill_u
    started in the previous interval and (ii) a pulse of height u fired at s*T
    (0 <= s < 1) of width w*T (0 < w <= 1), its part inside this interval,
    [s, min(s + w, 1)) (:func:`segment_response` at t = 1).  A one-sample pulse
    (s = 0, w = 1) gives exactly Gam(T) u of eqs. (8)-(9) (``gam``, precomputed).

    Args:
        f0 (Hz), Q, fs (Hz): model. gam: (2,) one-sample Gam(T). spill_u (V), spill_end
        (fraction of T): previous pulse's tail. u (V), s, w (fractions of T): new pulse.
        out: (2,) [dy (V), d(dy/dt) (V/s)].  z: (6,) scratch.
        wc: (3,) cache [w, Gam1(w T), Gam2(w T)] of the last pulse width at this f0, Q
            (speed only; set wc[0] = -1 whenever f0 or Q change).
    """
    out[0] = 0.0
    out[1] = 0.0
    if u != 0.0:
        if s == 0.0 and w == 1.0:
            out[0] = gam[0] * u
            out[1] = gam[1] * u
        elif s + w <= 1.0:
            # whole pulse inside: Phi((1 - s - w) T) Gam(w T), Gam(w T) cached
            if wc[0] != w:
                resonator_zoh_dt(f0, Q, fs, w / fs, z)
                wc[0] = w
                wc[1] = z[4]
                wc[2] = z[5]
            resonator_zoh_dt(f0, Q, fs, (1.0 - s - w) / fs, z)
            out[0] = (z[0] * wc[1] + z[1] * wc[2]) * u
            out[1] = (z[2] * wc[1] + z[3] * wc[2]) * u
        else:
            segment_response(f0, Q, fs, s, 1.0, 1.0, out, z)
            out[0] *= u
            out[1] *= u
    if spill_u != 0.0:
        e0 = out[0]
        e1 = out[1]
        segment_response(f0, Q, fs, 0.0, spill_end, 1.0, out, z)
        out[0] = e0 + spill_u * out[0]
        out[1] = e1 + spill_u * out[1]


@numba.njit(cache=True)
def next_spill(u, s, w, spill):
    """Carry a pulse's tail into the next interval: spill = [height (V), end (fraction of T)]
    = [u, s + w - 1] if the pulse fired at s with width w outlasts the interval, else [0, 0]."""
    if u != 0.0 and s + w > 1.0:
        spill[0] = u
        spill[1] = s + w - 1.0
    else:
        spill[0] = 0.0
        spill[1] = 0.0


@numba.njit(cache=True)
def next_crossing(f0, Q, fs, y, yd, t_lo, t_hi):
    """First equilibrium crossing of the free resonator in (t_lo T, t_hi T] from [y, yd].

    Free response of eq. (7): y(t) = exp(-sigma t) (y cos wd t + c sin wd t),
    c = (yd + sigma y)/wd, = R exp(-sigma t) cos(wd t - phi), phi = atan2(c, y); its zeros
    are t_n = (phi + pi/2 + n pi)/wd.  Returns the smallest t_n in (t_lo, t_hi] in units of
    T = 1/fs, or -1.0 if there is none (or the state is 0).

    Args:
        f0 (Hz), Q, fs (Hz): model. y (V), yd (V/s): state at t = 0. t_lo, t_hi: window, T.
    """
    if y == 0.0 and yd == 0.0:
        return -1.0
    w0 = 2.0 * math.pi * f0
    sig = w0 / (2.0 * Q)
    wd = w0 * math.sqrt(1.0 - 1.0 / (4.0 * Q * Q))
    phi = math.atan2((yd + sig * y) / wd, y)
    half = math.pi / wd * fs  # half a damped period, T
    t1 = (phi + 0.5 * math.pi) / wd * fs
    n = math.ceil((t_lo - t1) / half)
    t = t1 + n * half
    if t <= t_lo:
        t += half
    if t > t_hi:
        return -1.0
    return t


def resonator_zoh_np(f0: float, Q: float, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi (2,2), Gam (2,)) of :func:`resonator_zoh` as arrays."""
    o = np.empty(6)
    resonator_zoh(float(f0), float(Q), float(fs), o)
    return o[:4].reshape(2, 2).copy(), o[4:].copy()


@numba.njit(cache=True)
def sd_step(x, s, c):
    """One sample of the nonlinear one-bit second-order modulator (eqs. (10)-(12)).

    Args:
        x: modulator input, V (reference +-1 V).
        s: (2,) integrator states [s1, s2] (V), updated in place.
        c: input feed-in gain of the second integrator (0.5: eq. (11)).
    Returns:
        (bit in {-1, +1}, comparator input q = s2 before the update, V).
    """
    q = s[1]
    v = 1.0 if q >= 0.0 else -1.0
    s1 = s[0]
    s[0] = s1 + 0.5 * (x - v)
    s[1] = q + s1 + c * x - v
    return v, q


@numba.njit(cache=True)
def sd_step_standin(x, s, c, w):
    """One sample of the modulator of eqs. (10)-(12) with the one-bit comparator replaced by
    its linear-Gaussian stand-in v = q + w (w: a draw of the additive quantisation noise of
    the observer's model, eq. (13)): then v = STF x + NTF w holds exactly with a white
    Gaussian w, the linear-Gaussian case in which Kalman theory applies as stated.

    Args:
        x: modulator input, V. s: (2,) integrator states, updated in place.
        c: STF feed-in gain. w: the stand-in's quantisation noise for this sample, V.
    Returns:
        (output v = q + w (real-valued), comparator input q), V.
    """
    q = s[1]
    v = q + w
    s1 = s[0]
    s[0] = s1 + 0.5 * (x - v)
    s[1] = q + s1 + c * x - v
    return v, q


@numba.njit(cache=True)
def _modulate(x, s, c, bits, q):
    for k in range(x.shape[0]):
        v, qq = sd_step(x[k], s, c)
        bits[k] = v
        q[k] = qq


def modulate(
    x: np.ndarray, c: float = 0.5, state: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Run the modulator on x (V) from ``state`` (zeros); returns (bits int8, q float64)."""
    x = np.ascontiguousarray(x, dtype=float)
    s = np.zeros(2) if state is None else state
    bits = np.empty(x.shape[0])
    q = np.empty(x.shape[0])
    _modulate(x, s, float(c), bits, q)
    return bits.astype(np.int8), q

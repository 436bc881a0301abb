"""Shared linear models of the pulse-actuated resonator and its sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator
using digital Kalman observer" (seed
``colinet_pulse_resonator_sigma_delta_kalman_observer.md``), eqs. (7)-(13).
Used by the device (:mod:`mems_sim.sd_resonator`) and by the observers
(:mod:`mems_estimation.kalman_observer`, :mod:`mems_estimation.adaptive_observer`)
so that "exact model" means bit-for-bit the same matrices.  No ROS here.

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

__all__ = ["SD_DEN", "NTF_NUM", "stf_num", "resonator_zoh", "resonator_zoh_np",
           "sd_step", "modulate"]

#: Common denominator 1 - z^-1 + 0.5 z^-2 of STF and NTF, eqs. (11)-(12).
SD_DEN = np.array([1.0, -1.0, 0.5])
#: NTF numerator (1 - z^-1)^2, eq. (12).
NTF_NUM = np.array([1.0, -2.0, 1.0])


def stf_num(c: float = 0.5) -> np.ndarray:
    """STF numerator [0, c, 0.5 - c] (c = 0.5: eq. (11) as printed)."""
    return np.array([0.0, c, 0.5 - c])


@numba.njit(cache=True)
def resonator_zoh(f0, Q, fs, out):
    """ZOH discretisation of eq. (7) (eqs. (8)-(9)), closed form, underdamped (Q > 0.5).

    State [y (V), dy/dt (V/s)], input u (V) held over one sample T = 1/fs:
    sigma = w0/(2Q), wd = w0 sqrt(1 - 1/(4Q^2)), E = exp(-sigma T),
      Phi11 = E (cos wd T + sigma/wd sin wd T),   Phi12 = E sin(wd T)/wd,
      Phi21 = -w0^2 Phi12,                        Phi22 = E (cos wd T - sigma/wd sin wd T),
      Gam1 = g (1 - Phi11)/w0^2,  Gam2 = g Phi12,  g = fs*w0 (input gain, see module doc).

    Args:
        f0: natural frequency, Hz. Q: quality factor (> 0.5). fs: sample rate, Hz.
        out: (6,) float64 filled with [Phi11, Phi12, Phi21, Phi22, Gam1, Gam2].
    """
    w0 = 2.0 * math.pi * f0
    T = 1.0 / fs
    sig = w0 / (2.0 * Q)
    wd = w0 * math.sqrt(1.0 - 1.0 / (4.0 * Q * Q))
    E = math.exp(-sig * T)
    c = math.cos(wd * T)
    s = math.sin(wd * T)
    p12 = E * s / wd
    p11 = E * (c + sig / wd * s)
    out[0] = p11
    out[1] = p12
    out[2] = -w0 * w0 * p12
    out[3] = E * (c - sig / wd * s)
    g = fs * w0
    out[4] = g * (1.0 - p11) / (w0 * w0)
    out[5] = g * p12


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
def _modulate(x, s, c, bits, q):
    for k in range(x.shape[0]):
        v, qq = sd_step(x[k], s, c)
        bits[k] = v
        q[k] = qq


def modulate(x: np.ndarray, c: float = 0.5, state: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Run the modulator on x (V) from ``state`` (zeros); returns (bits int8, q float64)."""
    x = np.ascontiguousarray(x, dtype=float)
    s = np.zeros(2) if state is None else state
    bits = np.empty(x.shape[0])
    q = np.empty(x.shape[0])
    _modulate(x, s, float(c), bits, q)
    return bits.astype(np.int8), q

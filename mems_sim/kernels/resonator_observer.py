"""Sixth-order Kalman observer of a resonator read through a one-bit sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using digital
Kalman observer", Sec. 2 eqs. (2)-(6), Sec. 5 eq. (13).  The observed system is eq. (13),

    v = STF (H u + b) + NTF w,

with v the bit stream (+-1), u the pulses [V], b white output noise [V] at the
modulator input and w the quantisation error e = v - q of the comparator,
modelled as white with variance ``quantization_var``.  State (6), all in V:

    X = [y, (dy/dt)/w0m,  t1, t2,  n1, n2]

(resonator position and velocity scaled by the model's w0m = 2 pi f0 so that
every state is O(1 V); STF and NTF in controllable canonical form with the
common denominator 1 - z^-1 + 0.5 z^-2).  In the form of eq. (2) with the
noise vector nu(k) = [f(k) thermomechanical force (V), b(k) (V), w(k) (V)]:

    X(k+1) = A X(k) + B u(k) + Gn nu(k),      v(k) = C X(k) + w(k)

    F = Gn Qn Gn^T,  G = quantization_var,  M = E[Gn nu(k) w(k)] = Gn[:, 2] quantization_var

(the joint covariance M of eq. (2) comes from w(k) driving both the NTF state and,
through the NTF's unit direct feed-through, the measurement).  The position
estimate is eq. (13), second: [C_res 0 0 0 0] X(k|k), C_res = [1, 0].

Quantisation-noise variance: the one-bit quantiser with levels +-1 is
modelled as an additive error of unit gain (the paper's eqs. (11)-(12)); the
default is the uniform step-Delta model Delta^2/12 with Delta = 2, i.e. 1/3 V^2
(measured var(e) in the non-overloaded loop: 0.33-0.35 V^2).  For a comparator
input q of Gaussian shape with std s, E[(sign q - q)^2] = 1 - 2 s sqrt(2/pi) + s^2.
Because e is correlated with q (corr ~ -0.9 when overloaded), an optional
statistical (Bussgang) linearisation v = kappa q + w with kappa = sqrt(2/pi)/s and
var(w) = 1 - 2/pi is offered (``quantizer_gain``, :func:`bussgang_quantizer`); it
changes STF/NTF to kappa L0/(1 - kappa L1), 1/(1 - kappa L1) (see ``_sd_blocks``)
and removes most of the f0 bias of the adaptive observer.

Recursion (predictor form with the cross term, per sample k):

    S = C P C^T + G,  nu = v(k) - C Xp
    X(k|k) = Xp + P C^T / S nu,          P(k|k) = P - P C^T C P / S
    L = (A P C^T + M) / S
    Xp <- A Xp + B u(k) + L nu,          P <- A P A^T + F - L L^T S

with B u(k) generalised to the exact term of sub-sample pulses (height u, fired at s T,
width w T; :func:`mems_sim.devices.resonator_models.interval_input`), the same function the device
uses, so the known input stays exact whatever the pulse timing (:func:`add_pulse_input`).

The steady-state path uses the a-priori P of the filter DARE
(``scipy.linalg.solve_discrete_are(A^T, C^T, F, G, s=M)``) and fixed gains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg

from mems_sim.devices.resonator_models import interval_input, next_spill, resonator_zoh_np
from mems_sim.kernels.divergence import covariance_ok, state_ok

__all__ = [
    "ss_step6",
    "ObserverModel",
    "observer_model",
    "KalmanObserver",
    "check_bits",
    "check_outputs",
    "predicted_error_acf",
    "check_pulse_timing",
    "add_pulse_input",
    "steady_state_gains",
    "DEFAULT_QUANTIZATION_VAR",
    "bussgang_quantizer",
    "BUSSGANG_GAIN",
    "BUSSGANG_VAR",
    "BUSSGANG_Q_STD",
]

#: Delta^2/12 with the one-bit step Delta = 2 (levels +-1 V), V^2.
DEFAULT_QUANTIZATION_VAR = 1.0 / 3.0
#: Comparator-input std of the modulator in the default loops when not overloaded
#: (measured 0.63-0.67 V: amplitude 0.25 V + 0.25 V noise, or 0.5 V + 0.05 V), V.
BUSSGANG_Q_STD = 0.64


def bussgang_quantizer(q_std: float = BUSSGANG_Q_STD) -> tuple[float, float]:
    """Statistical linearisation of the one-bit quantiser, v = kappa q + w (Bussgang).

    For a Gaussian comparator input q of std s: kappa = E[v q]/E[q^2] = sqrt(2/pi)/s and
    w = v - kappa q is uncorrelated with q, var(w) = 1 - 2/pi = 0.363 V^2.

    Args:
        q_std: comparator-input std s, V.
    Returns:
        (kappa -, var(w) V^2).
    """
    return math.sqrt(2.0 / math.pi) / q_std, 1.0 - 2.0 / math.pi


BUSSGANG_GAIN, BUSSGANG_VAR = bussgang_quantizer()


@dataclass(frozen=True)
class ObserverModel:
    """The 6th-order model of eq. (13) in the form of eq. (2).

    Attributes:
        A (6,6), B (6,) pulse input [per V], C (6,) bit output, C_pos (6,) = [1,0,0,0,0,0].
        Gn (6,3) noise input matrix for nu = [force noise, output noise b, quantisation w].
        Qn (3,3) diag covariance of nu, V^2.
        F (6,6) process covariance, G (scalar) measurement variance, M (6,) cross-covariance.
        quantization_var: variance of w, V^2. f0 (Hz), Q, fs (Hz), w0 (rad/s, velocity scale),
        sd_feedforward: STF feed-in c (see :mod:`mems_sim.devices.resonator_models`).
        gam: (2,) one-sample ZOH input vector Gam(T) of the resonator in physical
        coordinates [V/V, V/s/V] (the pulse term before velocity scaling).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    C_pos: np.ndarray
    Gn: np.ndarray
    Qn: np.ndarray
    F: np.ndarray
    G: float
    M: np.ndarray
    quantization_var: float
    f0: float
    Q: float
    fs: float
    w0: float
    sd_feedforward: float
    gam: np.ndarray | None = None


def _sd_blocks(c: float, kappa: float = 1.0):
    """Canonical STF/NTF blocks for a quantiser modelled as v = kappa q + w.

    With the loop filters L0 = (c z^-1 + (0.5 - c) z^-2)/(1 - z^-1)^2 (input) and
    L1 = (-z^-1 + 0.5 z^-2)/(1 - z^-1)^2 (feedback) of the modulator,
    D = (1 - z^-1)^2 - kappa L1 (1 - z^-1)^2 = 1 - (2 - kappa) z^-1 + (1 - kappa/2) z^-2,
    STF = kappa (c z^-1 + (0.5 - c) z^-2)/D, NTF = (1 - z^-1)^2/D;
    kappa = 1 gives eqs. (11)-(12).
    """
    a1, a2 = -(2.0 - kappa), 1.0 - 0.5 * kappa
    Ad = np.array([[-a1, -a2], [1.0, 0.0]])
    c_stf = kappa * np.array([c, 0.5 - c])
    # NTF = 1 + ((-2 - a1) z^-1 + (1 - a2) z^-2)/D
    c_ntf = np.array([-2.0 - a1, 1.0 - a2])
    return Ad, c_stf, c_ntf


def observer_model(
    f0: float,
    Q: float,
    fs: float,
    output_noise_std: float = 0.0,
    state_noise_std: float = 0.0,
    quantization_var: float | None = None,
    sd_feedforward: float = 0.5,
    velocity_scale: float | None = None,
    quantizer_gain: float = 1.0,
) -> ObserverModel:
    """Build the 6-state model (eqs. (2), (7)-(13)).

    Args:
        f0: resonator natural frequency in the model, Hz (0 < f0 < fs/2).
        Q: quality factor (> 0.5).
        fs: sample rate, Hz.
        output_noise_std: std of b, white noise at the modulator input, V.
        state_noise_std: std of the thermomechanical force noise added to the
            pulse input u each sample (ZOH), V.
        quantization_var: variance of w, V^2 (None: 1/3).
        sd_feedforward: modulator STF feed-in c (0.5: eq. (11)).
        velocity_scale: rad/s dividing the velocity state (None: 2 pi f0).
        quantizer_gain: kappa of the quantiser model v = kappa q + w (1: the paper's
            unit-gain model, eqs. (11)-(12)).
    Returns:
        :class:`ObserverModel`.
    """
    if not (fs > 0 and 0 < f0 < fs / 2 and Q > 0.5):
        raise ValueError(
            f"observer model needs fs > 0, 0 < f0 < fs/2 and Q > 0.5; got "
            f"fs = {fs!r} Hz, f0 = {f0!r} Hz, Q = {Q!r}"
        )
    qv = DEFAULT_QUANTIZATION_VAR if quantization_var is None else float(quantization_var)
    w0 = 2.0 * math.pi * f0 if velocity_scale is None else float(velocity_scale)
    Phi, Gam = resonator_zoh_np(f0, Q, fs)
    T = np.diag([1.0, 1.0 / w0])
    Phi_s = T @ Phi @ np.linalg.inv(T)
    Gam_s = T @ Gam
    Ad, c_stf, c_ntf = _sd_blocks(sd_feedforward, quantizer_gain)
    A = np.zeros((6, 6))
    A[0:2, 0:2] = Phi_s
    A[2:4, 2:4] = Ad
    A[4:6, 4:6] = Ad
    A[2, 0] = 1.0  # STF input = y(k) (+ b(k))
    B = np.zeros(6)
    B[0:2] = Gam_s
    C = np.concatenate([[0.0, 0.0], c_stf, c_ntf])
    C_pos = np.array([1.0, 0, 0, 0, 0, 0])
    Gn = np.zeros((6, 3))
    Gn[0:2, 0] = Gam_s
    Gn[2, 1] = 1.0
    Gn[4, 2] = 1.0
    Qn = np.diag([float(state_noise_std) ** 2, float(output_noise_std) ** 2, qv])
    F = Gn @ Qn @ Gn.T
    M = Gn[:, 2] * qv
    return ObserverModel(
        A=A,
        B=B,
        C=C,
        C_pos=C_pos,
        Gn=Gn,
        Qn=Qn,
        F=F,
        G=qv,
        M=M,
        quantization_var=qv,
        f0=float(f0),
        Q=float(Q),
        fs=float(fs),
        w0=w0,
        sd_feedforward=float(sd_feedforward),
        gam=Gam.copy(),
    )


# Frame checks: one pass of a small (vectorisable) kernel per array instead of several numpy
# temporaries (the observers take 1000-sample frames at 1 kHz).
@numba.njit(cache=True)
def _count_bad_bits(bf):
    """Number of values of bf that are not +1 or -1."""
    nbad = 0
    for i in range(bf.shape[0]):
        nbad += abs(bf[i]) != 1.0
    return nbad


@numba.njit(cache=True)
def _all_finite(x):
    """True if every value of the 1-D array x is finite."""
    nbad = 0
    for i in range(x.shape[0]):
        nbad += not abs(x[i]) < math.inf
    return nbad == 0


@numba.njit(cache=True)
def _timing_fault(pulses, s, w):
    """0: valid pulse timing; 1: a start or width not finite; 2: where a pulse is fired
    (pulses != 0), a start outside [0, 1) or a width outside (0, 1] (fractions of T)."""
    nonfinite = 0
    outside = 0
    for i in range(s.shape[0]):
        si = s[i]
        wi = w[i]
        nonfinite += not ((abs(si) < math.inf) & (abs(wi) < math.inf))
        outside += (pulses[i] != 0.0) & ((si < 0.0) | (si >= 1.0) | (wi <= 0.0) | (wi > 1.0))
    return 1 if nonfinite else (2 if outside else 0)


def check_bits(bits, pulses) -> tuple[np.ndarray, np.ndarray]:
    """Validate a frame: bits only +-1 (float64 out), pulses finite, same length.

    Raises:
        ValueError: naming the +-1 convention, or the shape/finite problem.
    """
    b = np.asarray(bits)
    u = np.asarray(pulses, dtype=float)
    if b.ndim != 1 or u.ndim != 1 or b.shape != u.shape:
        raise ValueError(
            f"bits and pulses must be 1-D arrays of equal length; got shapes "
            f"{b.shape} and {u.shape}"
        )
    bf = b.astype(float)
    if _count_bad_bits(bf):
        bad = ~((bf == 1.0) | (bf == -1.0))
        i = int(np.argmax(bad))
        raise ValueError(
            f"bit stream must use the one-bit convention +1/-1 (+1: comparator "
            f"input >= 0, -1: < 0); got {b[i]!r} at index {i} "
            f"({int(bad.sum())} invalid values)"
        )
    if not _all_finite(u):
        raise ValueError("pulses must be finite (V)")
    return np.ascontiguousarray(bf), np.ascontiguousarray(u)


def check_outputs(outputs, pulses) -> tuple[np.ndarray, np.ndarray]:
    """Validate a frame of a real-valued modulator output (the linear-Gaussian stand-in of the
    quantiser, v = q + w): finite values, pulses finite, same length.

    Raises:
        ValueError: shape or non-finite values.
    """
    v = np.asarray(outputs, dtype=float)
    u = np.asarray(pulses, dtype=float)
    if v.ndim != 1 or u.ndim != 1 or v.shape != u.shape:
        raise ValueError(
            f"outputs and pulses must be 1-D arrays of equal length; got shapes "
            f"{v.shape} and {u.shape}"
        )
    if not (_all_finite(v) and _all_finite(u)):
        raise ValueError("modulator outputs and pulses must be finite (V)")
    return np.ascontiguousarray(v), np.ascontiguousarray(u)


def check_pulse_timing(
    pulses: np.ndarray, starts, widths, fs: float
) -> tuple[np.ndarray, np.ndarray]:
    """Validate the sub-sample timing of the pulses and express it in sample periods T.

    Args:
        pulses: (n,) heights, V (validated by :func:`check_bits`).
        starts: (n,) firing offset of each pulse after its sample instant, s (None: 0,
            pulses on the sample instants).
        widths: (n,) pulse widths, s (None: T = 1/fs, the one-sample ZOH pulse of eq. (8)).
        fs: sample rate, Hz.
    Returns:
        (starts, widths) as float64 fractions of T.
    Raises:
        ValueError: bad shape, non-finite values, or s outside [0, 1) / w outside (0, 1]
            where a pulse is fired.
    """
    n = pulses.shape[0]
    s = np.zeros(n) if starts is None else np.asarray(starts, dtype=float) * fs
    w = np.ones(n) if widths is None else np.asarray(widths, dtype=float) * fs
    if s.shape != (n,) or w.shape != (n,):
        raise ValueError(
            f"pulse starts/widths must have the pulses' shape ({n},); got {s.shape} and {w.shape}"
        )
    fault = _timing_fault(pulses, s, w)
    if fault == 1:
        raise ValueError("pulse starts/widths must be finite (fractions of the sample period)")
    if fault == 2:
        raise ValueError("pulse start must be in [0, T) and width in (0, T] (T = 1/fs)")
    return np.ascontiguousarray(s), np.ascontiguousarray(w)


# ----------------------------------------------------------------- numba kernels
@numba.njit(cache=True)
def add_pulse_input(xp, f0, Q, fs, w0s, gam, spill, u, s, w, eff, z, wc):
    """Add the exact sub-sample pulse term to the predicted resonator states, in place.

    xp[0:2] += [e0, e1/w0s] with e = :func:`mems_sim.devices.resonator_models.interval_input` (the
    tail of the previous pulse carried in ``spill`` plus the pulse u fired at s T,
    width w T); ``spill`` is then advanced.  w0s: velocity scale of the state, rad/s.
    wc: (3,) width cache of ``interval_input`` (wc[0] = -1 initially).
    """
    if u == 0.0 and spill[0] == 0.0:
        return
    interval_input(f0, Q, fs, gam, spill[0], spill[1], u, s, w, eff, z, wc)
    xp[0] += eff[0]
    xp[1] += eff[1] / w0s
    next_spill(u, s, w, spill)


@numba.njit(cache=True)
def predicted_output(xp, P, C, G, PC):
    """Predicted bit yhat = C X(k|k-1) and innovation variance S = C P C' + G; fills PC = P C'."""
    n = xp.shape[0]
    S = G
    yhat = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * C[j]
        PC[i] = acc
        yhat += C[i] * xp[i]
    for i in range(n):
        S += C[i] * PC[i]
    return yhat, S


@numba.njit(cache=True)
def state_predict(xp, A, B, L, u, nu, tmp):
    """Predictor-form state update in place: X <- A X + B u + L nu (tmp is scratch (n,))."""
    n = xp.shape[0]
    for i in range(n):
        acc = B[i] * u + L[i] * nu
        for j in range(n):
            acc += A[i, j] * xp[j]
        tmp[i] = acc
    for i in range(n):
        xp[i] = tmp[i]


@numba.njit(cache=True)
def kf_update(xp, P, C, G, Cp, v, xf, PC):
    """Measurement update at k; fills xf = X(k|k), PC = P C^T; returns (nu, S, pos, pos_var)."""
    n = xp.shape[0]
    yhat, S = predicted_output(xp, P, C, G, PC)
    nu = v - yhat
    pos = 0.0
    cpc = 0.0
    cpp = 0.0
    for i in range(n):
        xf[i] = xp[i] + PC[i] / S * nu
        pos += Cp[i] * xf[i]
        cpc += Cp[i] * PC[i]
        for j in range(n):
            cpp += Cp[i] * P[i, j] * Cp[j]
    return nu, S, pos, cpp - cpc * cpc / S


@numba.njit(cache=True)
def kf_predict(xp, P, A, B, F, M, u, nu, S, PC, L, AP, tmp):
    """Time update with the cross term: Xp <- A Xp + B u + L nu, P <- A P A' + F - L L' S."""
    n = xp.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * PC[j]
        L[i] = (acc + M[i]) / S
    state_predict(xp, A, B, L, u, nu, tmp)
    cov_predict(P, A, F, L, S, AP)


@numba.njit(cache=True)
def cov_predict(P, A, F, L, S, AP):
    """Covariance time update with the process/measurement cross term, in place:
    P <- A P A' + F - L L' S (predictor form of the Kalman filter with correlated noises,
    Colinet et al. eq. 2 with joint covariance M; L = (A P C' + M)/S). AP is scratch (n, n)."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for m in range(n):
                acc += A[i, m] * P[m, j]
            AP[i, j] = acc
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for m in range(n):
                acc += AP[i, m] * A[j, m]
            val = acc + F[i, j] - L[i] * L[j] * S
            P[i, j] = val
            P[j, i] = val


# ------------------------------------------------- structured kernels (6-state model, EKF)
# The matrices of eq. (2) for the model of eq. (13), and the Jacobian of the adaptive
# observer (:mod:`mems_estimation.filters.resonator_adaptive_observer`, states 6.. its
# parameters), have a fixed pattern of exact zeros and ones:
#
#   rows 0-1  resonator:   A[r, 0], A[r, 1] (Phi_s) and the parameter columns A[r, 6:]
#   row 2     STF state:   A[2, 0] = 1 (input y), A[2, 2], A[2, 3]   (Ad row 0)
#   row 3     STF delay:   A[3, 2] = 1
#   row 4     NTF state:   A[4, 4], A[4, 5]                          (Ad row 0)
#   row 5     NTF delay:   A[5, 4] = 1
#   rows 6..  parameters:  A[a, a] = 1 (random walks)
#   C non-zero on states 2-5 only, M on state 4 only, C_pos = [1, 0, ...];
#   F zero outside F[0:2, 0:2], F[2, 2], F[4, 4] and F[a, a], a >= 6; B >= 0.
#
# The kernels below are the generic loops above (:func:`predicted_output`, :func:`kf_update`,
# :func:`kf_predict`, :func:`cov_predict`) without the terms these zeros contribute and with
# the unit products written as the factor itself.  The remaining terms are added in the
# generic loops' order from the same initial value (+0.0, or G): a sum started at +0.0 is
# never -0.0 (round to nearest), so adding an omitted term, an exact +-0 for finite operands,
# leaves it unchanged, and 1.0 * x == x.  The results are therefore equal bit for bit to
# the generic loops' for finite values (the core tests of these kernels check it; once a
# filter has diverged to inf/NaN the non-finite values may differ).  A P, an intermediate,
# is formed without the leading +0.0: it differs at most in the sign of a zero, which the
# sums of (A P) A' (started at +0.0) do not see.  They are inlined into the per-sample
# loops (a call with array arguments costs more than the arithmetic).  Numba invalidates a
# cached kernel only when the text of its own source file changes, not when a function it
# inlines or calls from another file does: after editing these, clear the cached kernels
# of mems_sim/devices/resonator.py and mems_estimation/filters/resonator_adaptive_observer.py
# (their files under NUMBA_CACHE_DIR), or the old code stays in use.


@numba.njit(cache=True, inline="always")
def predicted_output_sd(xp, P, C, G, PC):
    """:func:`predicted_output` for C non-zero on the modulator states 2-5 only (any number
    of states >= 6): yhat = C X(k|k-1), S = C P C' + G (eq. (2)); fills PC = P C'."""
    c2 = C[2]
    c3 = C[3]
    c4 = C[4]
    c5 = C[5]
    for i in range(xp.shape[0]):
        PC[i] = 0.0 + P[i, 2] * c2 + P[i, 3] * c3 + P[i, 4] * c4 + P[i, 5] * c5
    yhat = 0.0 + c2 * xp[2] + c3 * xp[3] + c4 * xp[4] + c5 * xp[5]
    S = G + c2 * PC[2] + c3 * PC[3] + c4 * PC[4] + c5 * PC[5]
    return yhat, S


@numba.njit(cache=True, inline="always")
def kf_update6(xp, P, C, G, v, PC):
    """:func:`kf_update` for the 6-state model (C_pos = [1, 0, 0, 0, 0, 0]): measurement
    update at k, X(k|k) = Xp + P C'/S nu; fills PC = P C'.

    Returns:
        (nu, S, position y(k|k), its variance C_pos P(k|k) C_pos', X(k|k)[1] the scaled
        velocity).
    """
    yhat, S = predicted_output_sd(xp, P, C, G, PC)
    nu = v - yhat
    xf0 = xp[0] + PC[0] / S * nu
    xf1 = xp[1] + PC[1] / S * nu
    cpc = 0.0 + PC[0]
    return nu, S, 0.0 + xf0, (0.0 + P[0, 0]) - cpc * cpc / S, xf1


@numba.njit(cache=True, inline="always")
def predictor_gain_sd(A, M, PC, S, L):
    """Predictor gain L = (A P C' + M)/S of the cross-term filter (Colinet et al. eq. (2))
    for the structured A (any number of states >= 6; M non-zero on state 4 only);
    PC = P C'."""
    pc0 = PC[0]
    pc1 = PC[1]
    pc2 = PC[2]
    pc4 = PC[4]
    n = PC.shape[0]
    s0 = 0.0 + A[0, 0] * pc0 + A[0, 1] * pc1
    s1 = 0.0 + A[1, 0] * pc0 + A[1, 1] * pc1
    for a in range(6, n):
        s0 += A[0, a] * PC[a]
        s1 += A[1, a] * PC[a]
    L[0] = s0 / S
    L[1] = s1 / S
    L[2] = (0.0 + pc0 + A[2, 2] * pc2 + A[2, 3] * PC[3]) / S
    L[3] = (0.0 + pc2) / S
    L[4] = (0.0 + A[4, 4] * pc4 + A[4, 5] * PC[5] + M[4]) / S
    L[5] = (0.0 + pc4) / S
    for a in range(6, n):
        L[a] = (0.0 + PC[a]) / S


@numba.njit(cache=True, inline="always")
def kf_predict6(xp, P, A, F, M, nu, S, PC, L):
    """:func:`kf_predict` for the 6-state model with u = 0 (the pulses enter through
    :func:`add_pulse_input`; B >= 0, so B u = +0): Xp <- A Xp + L nu,
    P <- A P A' + F - L L' S (Colinet et al. eq. (2) with the cross term M,
    L = (A P C' + M)/S; :func:`cov_predict6`).  L (6,) is scratch."""
    predictor_gain_sd(A, M, PC, S, L)
    x0 = xp[0]
    x1 = xp[1]
    x2 = xp[2]
    x3 = xp[3]
    x4 = xp[4]
    x5 = xp[5]
    xp[0] = 0.0 + L[0] * nu + A[0, 0] * x0 + A[0, 1] * x1
    xp[1] = 0.0 + L[1] * nu + A[1, 0] * x0 + A[1, 1] * x1
    xp[2] = 0.0 + L[2] * nu + x0 + A[2, 2] * x2 + A[2, 3] * x3
    xp[3] = 0.0 + L[3] * nu + x2
    xp[4] = 0.0 + L[4] * nu + A[4, 4] * x4 + A[4, 5] * x5
    xp[5] = 0.0 + L[5] * nu + x4
    cov_predict6(P, A, F, L, S)


@numba.njit(cache=True, inline="always")
def cov_predict_sd(P, A, F, L, S, AP):
    """:func:`cov_predict` for the structured A: the 6-state model (n = 6) or the adaptive
    observer's Jacobian with its parameter states 6.. (f0, Q): P <- A P A' + F - L L' S in
    place (Colinet et al. eq. (2) with the cross term; L = (A P C' + M)/S).  AP (n, n) is
    scratch."""
    n = P.shape[0]
    a00 = A[0, 0]
    a01 = A[0, 1]
    a10 = A[1, 0]
    a11 = A[1, 1]
    a22 = A[2, 2]
    a23 = A[2, 3]
    a44 = A[4, 4]
    a45 = A[4, 5]
    # A P; rows 3, 5 and 6.. of A pick rows 2, 4 and 6.. of P
    for m in range(n):
        p0 = P[0, m]
        p1 = P[1, m]
        p2 = P[2, m]
        p4 = P[4, m]
        s0 = a00 * p0 + a01 * p1
        s1 = a10 * p0 + a11 * p1
        for a in range(6, n):
            s0 += A[0, a] * P[a, m]
            s1 += A[1, a] * P[a, m]
        AP[0, m] = s0
        AP[1, m] = s1
        AP[2, m] = p0 + a22 * p2 + a23 * P[3, m]
        AP[3, m] = p2
        AP[4, m] = a44 * p4 + a45 * P[5, m]
        AP[5, m] = p4
        for a in range(6, n):
            AP[a, m] = P[a, m]
    # (A P) A' + F - L L' S: upper triangle (i <= j) by the rows j of A, mirrored
    for j in range(2):  # resonator rows (and their parameter columns)
        aj0 = A[j, 0]
        aj1 = A[j, 1]
        for i in range(j + 1):
            acc = 0.0 + AP[i, 0] * aj0 + AP[i, 1] * aj1
            for a in range(6, n):
                acc += AP[i, a] * A[j, a]
            val = acc + F[i, j] - L[i] * L[j] * S
            P[i, j] = val
            P[j, i] = val
    for i in range(3):  # STF state, A[2] = [1, 0, a22, a23, 0, ...]
        val = (0.0 + AP[i, 0] + AP[i, 2] * a22 + AP[i, 3] * a23) + F[i, 2] - L[i] * L[2] * S
        P[i, 2] = val
        P[2, i] = val
    for i in range(4):  # STF delay, A[3] = e_2; F[:, 3] = 0
        val = (0.0 + AP[i, 2]) - L[i] * L[3] * S
        P[i, 3] = val
        P[3, i] = val
    for i in range(5):  # NTF state, A[4] = [0, 0, 0, 0, a44, a45, 0, ...]
        val = (0.0 + AP[i, 4] * a44 + AP[i, 5] * a45) + F[i, 4] - L[i] * L[4] * S
        P[i, 4] = val
        P[4, i] = val
    for i in range(6):  # NTF delay, A[5] = e_4; F[:, 5] = 0
        val = (0.0 + AP[i, 4]) - L[i] * L[5] * S
        P[i, 5] = val
        P[5, i] = val
    for j in range(6, n):  # parameters (random walks), A[j] = e_j
        for i in range(j + 1):
            val = (0.0 + AP[i, j]) + F[i, j] - L[i] * L[j] * S
            P[i, j] = val
            P[j, i] = val


@numba.njit(cache=True, inline="always")
def cov_predict6(P, A, F, L, S):
    """:func:`cov_predict_sd` for the 6-state model (n = 6): P <- A P A' + F - L L' S in
    place (Colinet et al. eq. (2) with the cross term; L = (A P C' + M)/S), units V^2 (the
    velocity scaled to V).

    The same floating-point operations in the same order as :func:`cov_predict_sd`, so the
    same floats for any P (symmetric or not): the entries of the old P that the result
    depends on are held in scalars (``p<row><column>``), and so are the entries of A P
    that it uses (``u``, ``v``, ``w``, ``x``: rows 0, 1, 2 and 4; rows 3 and 5 of A P are
    rows 2 and 4 of P), instead of the scratch array that the compiler had to store and
    reload around every write of P.
    """
    a00 = A[0, 0]
    a01 = A[0, 1]
    a10 = A[1, 0]
    a11 = A[1, 1]
    a22 = A[2, 2]
    a23 = A[2, 3]
    a44 = A[4, 4]
    a45 = A[4, 5]
    p00 = P[0, 0]
    p01 = P[0, 1]
    p02 = P[0, 2]
    p03 = P[0, 3]
    p04 = P[0, 4]
    p05 = P[0, 5]
    p10 = P[1, 0]
    p11 = P[1, 1]
    p12 = P[1, 2]
    p13 = P[1, 3]
    p14 = P[1, 4]
    p15 = P[1, 5]
    p20 = P[2, 0]
    p22 = P[2, 2]
    p23 = P[2, 3]
    p24 = P[2, 4]
    p25 = P[2, 5]
    p30 = P[3, 0]
    p32 = P[3, 2]
    p33 = P[3, 3]
    p34 = P[3, 4]
    p35 = P[3, 5]
    p44 = P[4, 4]
    p45 = P[4, 5]
    p54 = P[5, 4]
    p55 = P[5, 5]
    # rows of A P that are not copies of rows of P (those entries only that the
    # products below use)
    u0 = a00 * p00 + a01 * p10
    u1 = a00 * p01 + a01 * p11
    u2 = a00 * p02 + a01 * p12
    u3 = a00 * p03 + a01 * p13
    u4 = a00 * p04 + a01 * p14
    u5 = a00 * p05 + a01 * p15
    v0 = a10 * p00 + a11 * p10
    v1 = a10 * p01 + a11 * p11
    v2 = a10 * p02 + a11 * p12
    v3 = a10 * p03 + a11 * p13
    v4 = a10 * p04 + a11 * p14
    v5 = a10 * p05 + a11 * p15
    w0 = p00 + a22 * p20 + a23 * p30
    w2 = p02 + a22 * p22 + a23 * p32
    w3 = p03 + a22 * p23 + a23 * p33
    w4 = p04 + a22 * p24 + a23 * p34
    w5 = p05 + a22 * p25 + a23 * p35
    x4 = a44 * p44 + a45 * p54
    x5 = a44 * p45 + a45 * p55
    L0 = L[0]
    L1 = L[1]
    L2 = L[2]
    L3 = L[3]
    L4 = L[4]
    L5 = L[5]
    # (A P) A' + F - L L' S, upper triangle mirrored
    _put6(P, 0, 0, (0.0 + u0 * a00 + u1 * a01) + F[0, 0] - L0 * L0 * S)
    _put6(P, 0, 1, (0.0 + u0 * a10 + u1 * a11) + F[0, 1] - L0 * L1 * S)
    _put6(P, 1, 1, (0.0 + v0 * a10 + v1 * a11) + F[1, 1] - L1 * L1 * S)
    _put6(P, 0, 2, (0.0 + u0 + u2 * a22 + u3 * a23) + F[0, 2] - L0 * L2 * S)
    _put6(P, 1, 2, (0.0 + v0 + v2 * a22 + v3 * a23) + F[1, 2] - L1 * L2 * S)
    _put6(P, 2, 2, (0.0 + w0 + w2 * a22 + w3 * a23) + F[2, 2] - L2 * L2 * S)
    _put6(P, 0, 3, (0.0 + u2) - L0 * L3 * S)
    _put6(P, 1, 3, (0.0 + v2) - L1 * L3 * S)
    _put6(P, 2, 3, (0.0 + w2) - L2 * L3 * S)
    _put6(P, 3, 3, (0.0 + p22) - L3 * L3 * S)
    _put6(P, 0, 4, (0.0 + u4 * a44 + u5 * a45) + F[0, 4] - L0 * L4 * S)
    _put6(P, 1, 4, (0.0 + v4 * a44 + v5 * a45) + F[1, 4] - L1 * L4 * S)
    _put6(P, 2, 4, (0.0 + w4 * a44 + w5 * a45) + F[2, 4] - L2 * L4 * S)
    _put6(P, 3, 4, (0.0 + p24 * a44 + p25 * a45) + F[3, 4] - L3 * L4 * S)
    _put6(P, 4, 4, (0.0 + x4 * a44 + x5 * a45) + F[4, 4] - L4 * L4 * S)
    _put6(P, 0, 5, (0.0 + u4) - L0 * L5 * S)
    _put6(P, 1, 5, (0.0 + v4) - L1 * L5 * S)
    _put6(P, 2, 5, (0.0 + w4) - L2 * L5 * S)
    _put6(P, 3, 5, (0.0 + p24) - L3 * L5 * S)
    _put6(P, 4, 5, (0.0 + x4) - L4 * L5 * S)
    _put6(P, 5, 5, (0.0 + p44) - L5 * L5 * S)


@numba.njit(cache=True, inline="always")
def _put6(P, i, j, val):
    """P[i, j] = P[j, i] = val (a symmetric covariance entry, V^2)."""
    P[i, j] = val
    P[j, i] = val


# nogil: in a one-process graph the recorder's writer thread runs meanwhile
@numba.njit(cache=True, nogil=True)
def _kf_run(bits, pulses, starts, widths, xp, P, A, C, F, G, M, res, gam, spill, pos, var, innov):
    # time-varying filter of the 6-state model (kf_update6 / kf_predict6, equal bit for bit
    # to the generic kf_update / kf_predict); res = [f0, Q, fs, w0 velocity scale] of the model
    PC = np.empty(6)
    L = np.empty(6)
    eff = np.empty(2)
    z = np.empty(6)
    wc = np.full(3, -1.0)
    for k in range(bits.shape[0]):
        nu, S, p, pv, _ = kf_update6(xp, P, C, G, bits[k], PC)
        pos[k] = p
        var[k] = pv
        innov[k] = nu / math.sqrt(S)
        kf_predict6(xp, P, A, F, M, nu, S, PC, L)
        if pulses[k] != 0.0 or spill[0] != 0.0:  # (call guarded: array-argument
            add_pulse_input(
                xp,
                res[0],
                res[1],
                res[2],
                res[3],
                gam,
                spill,
                pulses[k],  # refcounts
                starts[k],
                widths[k],
                eff,
                z,
                wc,
            )


@numba.njit(cache=True, nogil=True)
def _ss_run_innov(
    bits, pulses, starts, widths, xp, A, B, C, L, cpk, sqrtS, res, gam, spill, pos, innov
):
    eff = np.empty(2)
    z = np.empty(6)
    wc = np.full(3, -1.0)
    for k in range(bits.shape[0]):
        yhat = 0.0
        for i in range(xp.shape[0]):
            yhat += C[i] * xp[i]
        innov[k] = (bits[k] - yhat) / sqrtS
        pos[k] = ss_step6(xp, A, B, C, L, cpk, bits[k], 0.0)
        if pulses[k] != 0.0 or spill[0] != 0.0:  # (call guarded: array-argument
            add_pulse_input(
                xp,
                res[0],
                res[1],
                res[2],
                res[3],
                gam,
                spill,
                pulses[k],  # refcounts
                starts[k],
                widths[k],
                eff,
                z,
                wc,
            )


@numba.njit(cache=True, nogil=True)
def _ss_run_states(
    bits, pulses, starts, widths, xp, A, B, C, L, K, sqrtS, res, gam, spill, xf, innov
):
    # steady-state filter keeping the whole a-posteriori state X(k|k) (rows of xf)
    n = xp.shape[0]
    eff = np.empty(2)
    z = np.empty(6)
    wc = np.full(3, -1.0)
    for k in range(bits.shape[0]):
        yhat = 0.0
        for i in range(n):
            yhat += C[i] * xp[i]
        nu = bits[k] - yhat
        innov[k] = nu / sqrtS
        for i in range(n):
            xf[k, i] = xp[i] + K[i] * nu
        ss_step6(xp, A, B, C, L, 0.0, bits[k], 0.0)
        if pulses[k] != 0.0 or spill[0] != 0.0:  # (call guarded: array-argument
            add_pulse_input(
                xp,
                res[0],
                res[1],
                res[2],
                res[3],
                gam,
                spill,
                pulses[k],  # refcounts
                starts[k],
                widths[k],
                eff,
                z,
                wc,
            )


@numba.njit(cache=True)
def ss_step(xp, A, B, C, L, cpk, v, u, tmp):
    """Steady-state step: returns position estimate Cp X(k|k); advances xp with u."""
    n = xp.shape[0]
    yhat = 0.0
    pos0 = xp[0]
    for i in range(n):
        yhat += C[i] * xp[i]
    nu = v - yhat
    state_predict(xp, A, B, L, u, nu, tmp)
    return pos0 + cpk * nu


@numba.njit(cache=True)
def ss_step6(xp, A, B, C, L, cpk, v, u):
    """:func:`ss_step` for the 6-state model, using its sparsity (res 2x2 block, STF and
    NTF companion blocks, A[2,0] = 1 coupling, B only on the resonator, C only on the
    modulator states)."""
    x0 = xp[0]
    x1 = xp[1]
    x2 = xp[2]
    x3 = xp[3]
    x4 = xp[4]
    x5 = xp[5]
    nu = v - (C[2] * x2 + C[3] * x3 + C[4] * x4 + C[5] * x5)
    xp[0] = A[0, 0] * x0 + A[0, 1] * x1 + B[0] * u + L[0] * nu
    xp[1] = A[1, 0] * x0 + A[1, 1] * x1 + B[1] * u + L[1] * nu
    xp[2] = x0 + A[2, 2] * x2 + A[2, 3] * x3 + L[2] * nu
    xp[3] = x2 + L[3] * nu
    xp[4] = A[4, 4] * x4 + A[4, 5] * x5 + L[4] * nu
    xp[5] = x4 + L[5] * nu
    return x0 + cpk * nu


@numba.njit(cache=True)
def _riccati_iterate(A, C, F, G, M, P, iters):
    n = A.shape[0]
    PC = np.empty(n)
    L = np.empty(n)
    AP = np.empty((n, n))
    xp = np.zeros(n)
    tmp = np.empty(n)
    B = np.zeros(n)
    for _ in range(iters):
        S = G
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += P[i, j] * C[j]
            PC[i] = acc
        for i in range(n):
            S += C[i] * PC[i]
        kf_predict(xp, P, A, B, F, M, 0.0, 0.0, S, PC, L, AP, tmp)


def steady_state_gains(model: ObserverModel) -> dict:
    """Steady-state a-priori P (DARE with the cross term M) and the fixed gains.

    Returns:
        dict with P (6,6), S, K (filter gain P C'/S), L (predictor gain (A P C' + M)/S),
        pos_var (steady a-posteriori position variance, V^2), method ("dare"/"iteration").
    """
    A, C, F, G, M = model.A, model.C, model.F, model.G, model.M
    method = "dare"
    try:
        P = scipy.linalg.solve_discrete_are(A.T, C[:, None], F, np.array([[G]]), s=M[:, None])
        S = float(C @ P @ C + G)
        L = (A @ P @ C + M) / S
        resid = A @ P @ A.T + F - np.outer(L, L) * S - P
        if not np.all(np.isfinite(P)) or np.abs(resid).max() > 1e-9 * max(1.0, np.abs(P).max()):
            raise np.linalg.LinAlgError("DARE residual too large")
    except (np.linalg.LinAlgError, ValueError):
        method = "iteration"
        P = np.zeros((6, 6))
        _riccati_iterate(A, C, F, G, M, P, 200000)
    P = 0.5 * (P + P.T)
    S = float(C @ P @ C + G)
    K = P @ C / S
    L = (A @ P @ C + M) / S
    Cp = model.C_pos
    pos_var = float(Cp @ P @ Cp - (Cp @ P @ C) ** 2 / S)
    return {"P": P, "S": S, "K": K, "L": L, "pos_var": max(pos_var, 0.0), "method": method}


def predicted_error_acf(model: ObserverModel, lags: int, component: int = 0) -> np.ndarray:
    """Autocorrelation of the steady-state a-posteriori error the filter predicts, lags 1..lags.

    The error e(k) = X(k) - X(k|k) of a steady-state Kalman filter is not white: it is the
    output of the filter's closed loop driven by the noises (Anderson & Moore 1979, Ch. 4;
    Simon 2006, Sec. 7.1).  With a-priori error eps(k) = X(k) - X(k|k-1), innovation
    nu(k) = C eps(k) + w(k), a-posteriori covariance P+ = (I - K C) P and the predictor form
    of the filter with correlated noises (Colinet et al. eq. 2 with the cross covariance M:
    X(k+1|k) = A X(k|k) + B u(k) + (M/S) nu(k), L = A K + M/S):

        eps(k+1) = (A - L C) eps(k) + Gn n(k) - L w(k)       (noise independent of eps(k))
        e(k)     = (I - K C) eps(k) - K w(k)
        E[eps(k+1) e(k)^T] = A P+ - M K^T        (E[nu e^T] = 0, E[Gn n w] = M)
        E[e(k+m) e(k)^T]   = (I - K C) (A - L C)^(m-1) (A P+ - M K^T),   m >= 1.

    Without the cross term (M = 0, L = A K) this is ((I - K C) A)^m P+, the recursion
    e(k) = (I - K C) A e(k-1) + (I - K C) w - K v.  Returns the ``component``-th diagonal
    entry of E[e(k+m) e(k)^T] divided by that of P+ (component 0: the position).

    Args:
        model: the filter's model. lags: largest lag m (>= 1). component: state index.
    Returns:
        (lags,) predicted autocorrelation at lags 1..lags.
    """
    ss = steady_state_gains(model)
    A, C, M = model.A, model.C, model.M
    n = A.shape[0]
    K, L = ss["K"], ss["L"]
    ikc = np.eye(n) - np.outer(K, C)
    p_post = ikc @ ss["P"]
    p_post = 0.5 * (p_post + p_post.T)
    closed = A - np.outer(L, C)
    col = (A @ p_post - np.outer(M, K))[:, component]
    out = np.empty(int(lags))
    for m in range(int(lags)):
        out[m] = (ikc @ col)[component]
        col = closed @ col
    return out / p_post[component, component]


class KalmanObserver:
    """Sixth-order Kalman observer of eq. (13) (paper Sec. 2 and 5), carried state.

    Args:
        f0: natural frequency assumed by the model, Hz.
        Q: quality factor assumed by the model (> 0.5).
        fs: sample rate, Hz.
        output_noise_std: std of the white noise b at the modulator input, V.
        state_noise_std: std of the thermomechanical force noise (per sample, on u), V.
        quantization_var: variance of the quantisation error w, V^2 (None: 1/3).
        steady_state: use the DARE steady-state gain (fast path; P fixed).
        sd_feedforward: modulator STF feed-in c (0.5: eq. (11)).
        quantizer_gain: kappa of the quantiser model v = kappa q + w (1: paper).
        initial_state: (6,) X(0|-1) (None: zeros = resonator and modulator at rest).
        initial_cov: (6,6) P(0|-1) (None: identity, V^2: resonator and modulator states
            unknown to ~1 V, so the observer may join a running stream).
        linear_output: accept a real-valued modulator output (the device's
            ``quantizer: gaussian`` stand-in, v = q + w) instead of the one-bit +-1 stream.
    """

    def __init__(
        self,
        f0: float,
        Q: float,
        fs: float,
        output_noise_std: float,
        state_noise_std: float,
        quantization_var: float | None = None,
        steady_state: bool = False,
        *,
        sd_feedforward: float = 0.5,
        quantizer_gain: float = 1.0,
        initial_state=None,
        initial_cov=None,
        linear_output: bool = False,
    ) -> None:
        for name, val in (
            ("output_noise_std", output_noise_std),
            ("state_noise_std", state_noise_std),
        ):
            if not (val >= 0 and math.isfinite(val)):
                raise ValueError(f"{name} = {val!r} V must be finite and >= 0")
        self.model = observer_model(
            f0,
            Q,
            fs,
            output_noise_std,
            state_noise_std,
            quantization_var,
            sd_feedforward,
            quantizer_gain=quantizer_gain,
        )
        self.steady_state = bool(steady_state)
        self.linear_output = bool(linear_output)
        self.x0 = np.zeros(6) if initial_state is None else np.array(initial_state, float)
        self.P0 = np.eye(6) if initial_cov is None else np.array(initial_cov, float)
        if self.steady_state:
            ss = steady_state_gains(self.model)
            self.ss = ss
            self.L = np.ascontiguousarray(ss["L"])
            self.cpk = float(self.model.C_pos @ ss["K"])
            self.P0 = ss["P"].copy()
            ikc = np.eye(6) - np.outer(ss["K"], self.model.C)
            ss["P_post"] = 0.5 * (ikc @ ss["P"] + (ikc @ ss["P"]).T)
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        self._res = np.array([self.model.f0, self.model.Q, self.model.fs, self.model.w0])
        self._spill = np.zeros(2)  # tail of a pulse outlasting its sample interval
        self.next_index = 0
        self.resets = 0
        #: normalised innovations nu/sqrt(S) of the last step() call (white, unit variance
        #: if the model is right).
        self.last_innovations = np.empty(0)

    def reset(self) -> None:
        """Re-initialise from the prior: X(0|-1) and P(0|-1) of the constructor (the
        steady-state P on the steady-state path), no pulse tail; the sample count goes on."""
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        self._spill = np.zeros(2)
        self.resets += 1

    #: Largest magnitude of a state [V] the observer may hold: its states are voltages of
    #: the order of the modulator's +-1 V levels, so a state beyond this is a divergence.
    STATE_LIMIT = 1.0e6

    def diverged(self) -> bool:
        """True if the state is not finite or beyond :attr:`STATE_LIMIT`, or the covariance
        not positive definite (:func:`~mems_sim.kernels.divergence.covariance_ok`)."""
        return not (
            state_ok(self.x, self._spill)
            and float(np.max(np.abs(self.x))) <= self.STATE_LIMIT
            and covariance_ok(self.P)
        )

    @property
    def position_var_steady(self) -> float | None:
        """Steady-state position variance, V^2 (steady_state mode only)."""
        return self.ss["pos_var"] if self.steady_state else None

    def step(self, bits, pulses, starts=None, widths=None) -> tuple[np.ndarray, np.ndarray]:
        """Process n samples.

        Args:
            bits: (n,) bit stream, values +1/-1 only.
            pulses: (n,) heights u(k) of the pulses fired in [k T, (k+1) T), V.
            starts: (n,) firing offsets after the sample instant, s (None: 0).
            widths: (n,) pulse widths, s (None: T = 1/fs, i.e. u(k) held from k to k+1
                as in eq. (8)).  The known-input term is exact for any timing
                (:func:`add_pulse_input`).
        Returns:
            (position estimate y(k|k) (n,) V, its variance (n,) V^2).
        Raises:
            ValueError: bits not in {+1, -1} (message names the convention), bad shape or
                bad pulse timing.
        """
        b, u = (check_outputs if self.linear_output else check_bits)(bits, pulses)
        s, w = check_pulse_timing(u, starts, widths, self.model.fs)
        n = b.shape[0]
        pos = np.empty(n)
        m = self.model
        innov = np.empty(n)
        if self.steady_state:
            _ss_run_innov(
                b,
                u,
                s,
                w,
                self.x,
                m.A,
                m.B,
                m.C,
                self.L,
                self.cpk,
                math.sqrt(self.ss["S"]),
                self._res,
                m.gam,
                self._spill,
                pos,
                innov,
            )
            var = np.full(n, self.ss["pos_var"])
        else:
            var = np.empty(n)
            _kf_run(
                b,
                u,
                s,
                w,
                self.x,
                self.P,
                m.A,
                m.C,
                m.F,
                m.G,
                m.M,
                self._res,
                m.gam,
                self._spill,
                pos,
                var,
                innov,
            )
        self.last_innovations = innov
        self.next_index += n
        return pos, var

    def step_states(self, bits, pulses, starts=None, widths=None) -> np.ndarray:
        """:meth:`step` on the steady-state path, returning the whole a-posteriori state.

        Same recursion and carried state as :meth:`step` (the two may be mixed); the
        normalised innovations go to :attr:`last_innovations`, the steady a-posteriori
        covariance is ``(I - K C) P`` of :attr:`ss` (``P_post``).

        Returns:
            (n, 6) X(k|k), V (resonator position, velocity / w0, STF and NTF states).
        Raises:
            ValueError: not built with ``steady_state=True``, or the checks of :meth:`step`.
        """
        if not self.steady_state:
            raise ValueError("step_states needs steady_state=True (fixed gain, fixed P)")
        b, u = (check_outputs if self.linear_output else check_bits)(bits, pulses)
        s, w = check_pulse_timing(u, starts, widths, self.model.fs)
        n = b.shape[0]
        m = self.model
        xf = np.empty((n, 6))
        innov = np.empty(n)
        _ss_run_states(
            b,
            u,
            s,
            w,
            self.x,
            m.A,
            m.B,
            m.C,
            self.L,
            np.ascontiguousarray(self.ss["K"]),
            math.sqrt(self.ss["S"]),
            self._res,
            m.gam,
            self._spill,
            xf,
            innov,
        )
        self.last_innovations = innov
        self.next_index += n
        return xf

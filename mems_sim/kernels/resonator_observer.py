"""Sixth-order Kalman observer of a resonator read through a one-bit sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using digital
Kalman observer", Sec. 2 eqs. (2)-(6), Sec. 5 eq. (13); docs/resonator.md.  The model of eq.
(13) in the form of eq. (2) is :mod:`mems_sim.kernels.resonator_observer_model`, the
per-sample steps :mod:`mems_sim.kernels.resonator_kf_steps`; here the frame checks, the
frame loops (time-varying and steady-state) and :class:`KalmanObserver`, which carries the
state across frames.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mems_sim.kernels.divergence import covariance_ok, state_ok
from mems_sim.kernels.resonator_kf_steps import (
    add_pulse_input,
    kf_predict6,
    kf_update6,
    ss_step6,
)
from mems_sim.kernels.resonator_observer_model import (
    BUSSGANG_GAIN,
    BUSSGANG_Q_STD,
    BUSSGANG_VAR,
    DEFAULT_QUANTIZATION_VAR,
    ObserverModel,
    _sd_blocks,
    bussgang_quantizer,
    observer_model,
    predicted_error_acf,
    steady_state_gains,
)

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
    "_sd_blocks",
]


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


@numba.njit(cache=True, inline="always")
def _pulse_setup(res):
    """The model res = [f0, Q, fs, w0 velocity scale] of :func:`add_pulse_input` in scalars
    and its scratch arrays eff (2,), z (6,) and width cache wc (3,), for a frame loop."""
    return res[0], res[1], res[2], res[3], np.empty(2), np.empty(6), np.full(3, -1.0)


# nogil: in a one-process graph the recorder's writer thread runs meanwhile
@numba.njit(cache=True, nogil=True)
def _kf_run(bits, pulses, starts, widths, xp, P, A, C, F, G, M, res, gam, spill, pos, var, innov):
    # time-varying filter of the 6-state model (kf_update6 / kf_predict6, equal bit for bit
    # to the generic kf_update / kf_predict); res = [f0, Q, fs, w0 velocity scale] of the model
    PC = np.empty(6)
    L = np.empty(6)
    f0, q, fs, w0s, eff, z, wc = _pulse_setup(res)
    for k in range(bits.shape[0]):
        nu, S, p, pv, _ = kf_update6(xp, P, C, G, bits[k], PC)
        pos[k] = p
        var[k] = pv
        innov[k] = nu / math.sqrt(S)
        kf_predict6(xp, P, A, F, M, nu, S, PC, L)
        if pulses[k] != 0.0 or spill[0] != 0.0:  # (call guarded: array-argument refcounts)
            add_pulse_input(
                xp, f0, q, fs, w0s, gam, spill, pulses[k], starts[k], widths[k], eff, z, wc
            )


@numba.njit(cache=True, nogil=True)
def _ss_run_innov(
    bits, pulses, starts, widths, xp, A, B, C, L, cpk, sqrtS, res, gam, spill, pos, innov
):
    f0, q, fs, w0s, eff, z, wc = _pulse_setup(res)
    for k in range(bits.shape[0]):
        yhat = 0.0
        for i in range(xp.shape[0]):
            yhat += C[i] * xp[i]
        innov[k] = (bits[k] - yhat) / sqrtS
        pos[k] = ss_step6(xp, A, B, C, L, cpk, bits[k], 0.0)
        if pulses[k] != 0.0 or spill[0] != 0.0:  # (call guarded: array-argument refcounts)
            add_pulse_input(
                xp, f0, q, fs, w0s, gam, spill, pulses[k], starts[k], widths[k], eff, z, wc
            )


@numba.njit(cache=True, nogil=True)
def _ss_run_states(
    bits, pulses, starts, widths, xp, A, B, C, L, K, sqrtS, res, gam, spill, xf, innov
):
    # steady-state filter keeping the whole a-posteriori state X(k|k) (rows of xf)
    n = xp.shape[0]
    f0, q, fs, w0s, eff, z, wc = _pulse_setup(res)
    for k in range(bits.shape[0]):
        yhat = 0.0
        for i in range(n):
            yhat += C[i] * xp[i]
        nu = bits[k] - yhat
        innov[k] = nu / sqrtS
        for i in range(n):
            xf[k, i] = xp[i] + K[i] * nu
        ss_step6(xp, A, B, C, L, 0.0, bits[k], 0.0)
        if pulses[k] != 0.0 or spill[0] != 0.0:  # (call guarded: array-argument refcounts)
            add_pulse_input(
                xp, f0, q, fs, w0s, gam, spill, pulses[k], starts[k], widths[k], eff, z, wc
            )


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

    def _checked(self, bits, pulses, starts, widths):
        """The frame's outputs, pulses and pulse timing, checked (:func:`check_bits` or
        :func:`check_outputs`, :func:`check_pulse_timing`): (b, u, s, w)."""
        b, u = (check_outputs if self.linear_output else check_bits)(bits, pulses)
        s, w = check_pulse_timing(u, starts, widths, self.model.fs)
        return b, u, s, w

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
        b, u, s, w = self._checked(bits, pulses, starts, widths)
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
        b, u, s, w = self._checked(bits, pulses, starts, widths)
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

"""The 6-state linear-Gaussian model of a resonator read through a one-bit sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using digital
Kalman observer", Sec. 2 eqs. (2)-(6), Sec. 5 eq. (13); docs/resonator.md.  The observed
system is eq. (13), v = STF (H u + b) + NTF w: v the bit stream (+-1), u the pulses [V], b
white output noise [V] at the modulator input, w the quantisation error e = v - q of the
comparator, white with variance ``quantization_var``.  State (6), all in V:

    X = [y, (dy/dt)/w0m,  t1, t2,  n1, n2]

(resonator position and velocity scaled by w0m = 2 pi f0; STF and NTF in controllable
canonical form with the common denominator 1 - z^-1 + 0.5 z^-2).  In the form of eq. (2)
with nu(k) = [f(k) force noise (V), b(k) (V), w(k) (V)]:

    X(k+1) = A X(k) + B u(k) + Gn nu(k),      v(k) = C X(k) + w(k)
    F = Gn Qn Gn^T,  G = quantization_var,  M = E[Gn nu(k) w(k)] = Gn[:, 2] quantization_var

Quantisation-noise variance: the uniform step-Delta model Delta^2/12 with Delta = 2, i.e.
1/3 V^2 (measured var(e) in the non-overloaded loop: 0.33-0.35 V^2); optionally the
statistical (Bussgang) linearisation v = kappa q + w, kappa = sqrt(2/pi)/s, var(w) = 1 - 2/pi
(``quantizer_gain``, :func:`bussgang_quantizer`), which changes STF/NTF to
kappa L0/(1 - kappa L1), 1/(1 - kappa L1) (:func:`_sd_blocks`).  The steady state is the
a-priori P of the filter DARE with the cross term (:func:`steady_state_gains`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg

from mems_sim.kernels.resonator_kf_steps import kf_predict
from mems_sim.kernels.resonator_models import resonator_zoh_np

__all__ = [
    "ObserverModel",
    "observer_model",
    "predicted_error_acf",
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
        sd_feedforward: STF feed-in c (see :mod:`mems_sim.kernels.resonator_models`).
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

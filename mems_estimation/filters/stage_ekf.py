"""EKF motion estimator of the piezo tilt micro-stage (Chen 2018, sec. 3.4.4, eqs. 48-53).

State x = [theta, omega] (rad, rad/s) of the main tilt axis; input the measured drive
voltage u; measurements the feedthrough-cancelled capacitive channels (1 to 4), each
with the single-axis sensor model y_c = h_c(theta) omega, h_c = eta_c dC_c/dtheta
(eqs. 44, 46, 47) and its own identified parameters P_s,c = (eta_c, D_n,c).

Per sample k (eqs. 48-53)::

    x_k^- = A_d x_{k-1} + B_d u_{k-1}               (48)  see indexing note
    P_k^- = A_d P_{k-1} A_d^T + B_d Q B_d^T         (49)
    H_k   = [0, h_c(theta_k^-)]_c                   (50)
    K_k   = P_k^- H^T (H P_k^- H^T + R)^-1          (51)
    x_k   = x_k^- + K_k (y_k - H_k x_k^-)           (52)
    P_k   = P_k^- - K_k H_k P_k^-                   (53)  (printed "K H^T P": misprint)

Indexing: the emulator's DAC holds u_k over [t_k, t_k+1), so the input that moves the
state from k-1 to k is u_{k-1}; eq. (48) writes u_k for the same held value.

Because H has a zero first column, eqs. (51)-(53) reduce exactly (Woodbury) to
O(n_y) scalar work: with g = h^T R^-1 h and s = (R^-1 h)^T (y - h omega^-),
``x += [P_tw, P_ww] s / (1 + P_ww g)`` and ``P -= [P_tw, P_ww]^T [P_tw, P_ww] g/(1+P_ww g)``.
A sample whose measurement is NaN (bias-off period, no cancelled value) gets the time
update only.

Note: H = [0, h(theta)] is the paper's pseudo-linear observation matrix, not the full
Jacobian (which would hold dh/dtheta * omega in the first column); implemented as printed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from mems_sim import bounded_yaml
from mems_sim.devices.stage import stage_matrices
from mems_sim.devices.stage_capacitance import (
    EPS0,
    GL8_NODES,
    GL8_WEIGHTS,
    dcdtheta_single_tan,
)
from mems_sim.kernels.divergence import covariance_ok, state_ok

__all__ = [
    "HEALTH_WINDOW",
    "FAULT_FREE_NIS_MEAN",
    "FAULT_FREE_NIS_DISPERSION",
    "HEALTH_MOMENTS_SOURCE",
    "StageModel",
    "oracle_model",
    "ekf_run",
    "StageEkf",
    "FeedthroughCanceller",
    "cancel_run",
    "output_h",
    "gain_ekf_run",
    "GainAdaptiveStageEkf",
]

#: Samples with a measurement update per window of the innovation consistency monitor:
#: 0.1 s at 625 kHz with the sensing bias on every other drive period (10 verdicts/s).
HEALTH_WINDOW = 31250
#: Fault-free moments of this filter's NIS on the default stage (calibration sweep
#: 1.0-1.3 V at 1700 Hz, 90 trials of 200 periods) with the reference identified model and
#: its four channels, measured with nis_moments (4 degrees of freedom per sample) over
#: windows of HEALTH_WINDOW measured samples on noise seeds 1 and 2 (1.32e7 samples, 6.56e6
#: of them measured, 210 windows): the mean NIS per degree of freedom, above 1 and rising
#: with the drive amplitude (1.07 at 1.0 V, 1.13 at 1.3 V: the model error of the drawn,
#: temperature-dependent stage against the identified model, nearly 1.00 on the idealised
#: stage), and the dispersion of a window sum, which that amplitude dependence dominates
#: (1.6 over windows of 500 samples, 1.9 over 1000, 18 over 31250).
FAULT_FREE_NIS_MEAN = 1.0986
FAULT_FREE_NIS_DISPERSION = 18.0
HEALTH_MOMENTS_SOURCE = (
    "measured: default stage, calibration sweep 1.0-1.3 V at 1700 Hz (90 trials of 200 "
    "periods), reference identified model, 4 channels, noise seeds 1 and 2, 1.32e7 samples "
    "(6.56e6 measured), windows of 31250 measured samples"
)


@dataclass
class StageModel:
    """Identified parameters the estimator runs on (never the emulator's truth).

    wn rad/s, zeta -, b_c rad/s^2/V, fs Hz; per channel: eta (V s... i.e. V/(F/s)),
    gap D_n [m], limits (w1..w4) [m]; R (n_y x n_y) [V^2]; Q [V^2] (input noise of eq. 49);
    alpha, beta: output correction omega = (omega_ekf - beta)/alpha (sec. 3.5.4 last step).
    """

    wn: float
    zeta: float
    b_c: float
    fs: float
    eta: np.ndarray
    gap: np.ndarray
    limits: np.ndarray
    R: np.ndarray
    Q: float
    channels: tuple = ("1A", "1B", "2A", "2B")
    alpha: float = 1.0
    beta: float = 0.0
    eps_r: float = 1.0
    extra: dict = field(default_factory=dict)

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """A_d, B_d of eq. (34) at fs."""
        return stage_matrices(self.wn, self.zeta, self.b_c, 1.0 / self.fs)

    def select(self, channels: Sequence[str]) -> StageModel:
        """Model restricted to a subset of channels (1 to 4)."""
        idx = [self.channels.index(c) for c in channels]
        return StageModel(
            self.wn,
            self.zeta,
            self.b_c,
            self.fs,
            self.eta[idx].copy(),
            self.gap[idx].copy(),
            self.limits[idx].copy(),
            self.R[np.ix_(idx, idx)].copy(),
            self.Q,
            tuple(channels),
            self.alpha,
            self.beta,
            self.eps_r,
            dict(self.extra),
        )


def oracle_model(stage, r_var: float, q: float = 1e-6) -> StageModel:
    """The emulated stage's own truth as an estimator model, labelled ``oracle``: the
    nominal-model path that tests and benchmarks compare against, never the model an
    estimator node runs on (that one is identified from recorded data): wn, zeta, b_c,
    fs, eta, gap and electrode limits of ``stage`` (a
    :class:`mems_sim.devices.stage.MicroStage`), R = r_var I [V^2] over its four
    channels, Q = q [V^2]."""
    return StageModel(
        stage.wn,
        stage.zeta,
        stage.b_c,
        stage.fs,
        stage.eta_true.copy(),
        np.full(4, stage.gap),
        stage.limits.copy(),
        np.eye(4) * r_var,
        q,
    )


@numba.njit(cache=True)
def output_h(theta, eta, gap, lim, eps, out):
    """h_c(theta) = eta_c dC_c/dtheta (eqs. 44, 46) for every channel c [V/(rad/s)]."""
    t = math.tan(theta)
    for c in range(eta.shape[0]):
        out[c] = eta[c] * dcdtheta_single_tan(
            t, gap[c], lim[c, 0], lim[c, 1], lim[c, 3] - lim[c, 2], eps
        )


@numba.njit(cache=True)
def ekf_run(y, u, A, B, Q, Rinv, eta, gap, lim, eps, x, P, uprev, out_x, out_var, out_nis=None):
    """Run eqs. (48)-(53) over n samples (module doc). State carried in x (2,), P (2,2),
    uprev (1,) [V]. y: (n, n_y) V (NaN row -> no update); u: (n,) V; outputs (n, 2).

    ``out_nis`` (n,), when given, receives the normalised innovation squared of each
    sample, nu^T S^-1 nu [-] with nu = y_k - H_k x_k^- and S = H_k P_k^- H_k^T + R
    (Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2), by Woodbury
    nu^T R^-1 nu - P_ww s^2 / (1 + P_ww g); NaN on a sample without update. It only reads
    the update's terms: the estimates are the same with or without it.

    Same arithmetic as :func:`output_h` and the inline update, arranged for speed: x, P,
    the held input and A_d, B_d live in scalars inside the loop (read once, written back
    once per call); the quadrature of h_c(theta) (eq. 46) is tabulated per channel once
    per call (nodes w, weights w0 w, factor eps L h) and tan(theta), 1 + tan^2(theta) are
    computed once per sample, so every h_c is the one of :func:`output_h` bit for bit."""
    n = y.shape[0]
    ny = y.shape[1]
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    b0, b1 = B[0], B[1]
    BQ0 = B[0] * B[0] * Q
    BQ1 = B[0] * B[1] * Q
    BQ2 = B[1] * B[1] * Q
    # eq. (46) quadrature tables of dcdtheta_single_tan per channel
    nodes = np.empty((ny, 8))
    weights = np.empty((ny, 8))
    scale = np.empty(ny)
    for c in range(ny):
        hw = 0.5 * (lim[c, 1] - lim[c, 0])
        mw = 0.5 * (lim[c, 1] + lim[c, 0])
        for a in range(8):
            nodes[c, a] = mw + hw * GL8_NODES[a]
            weights[c, a] = GL8_WEIGHTS[a] * nodes[c, a]
        scale[c] = eps * (lim[c, 3] - lim[c, 2]) * hw
    h = np.empty(ny)
    r = np.empty(ny)
    x0, x1, up = x[0], x[1], uprev[0]
    q00, q01, q11 = P[0, 0], P[0, 1], P[1, 1]
    for k in range(n):
        # (48)
        t = a00 * x0 + a01 * x1 + b0 * up
        w = a10 * x0 + a11 * x1 + b1 * up
        # (49)
        c00 = a00 * q00 + a01 * q01
        c01 = a00 * q01 + a01 * q11
        c10 = a10 * q00 + a11 * q01
        c11 = a10 * q01 + a11 * q11
        q00 = c00 * a00 + c01 * a01 + BQ0
        q01 = c00 * a10 + c01 * a11 + BQ1
        q11 = c10 * a10 + c11 * a11 + BQ2
        ok = True
        for c in range(ny):
            if not math.isfinite(y[k, c]):
                ok = False
        if ok:
            # (50): h_c = eta_c dC_c/dtheta (eqs. 44, 46), as output_h
            tt = math.tan(t)
            sec2 = 1.0 + tt * tt
            for c in range(ny):
                acc = 0.0
                dn = gap[c]
                for a in range(8):
                    d = dn - nodes[c, a] * tt
                    acc += weights[c, a] / (d * d)
                h[c] = eta[c] * (scale[c] * acc * sec2)
            for c in range(ny):
                acc = 0.0
                for d in range(ny):
                    acc += Rinv[c, d] * h[d]
                r[c] = acc
            g = 0.0
            s = 0.0
            for c in range(ny):
                g += r[c] * h[c]
                s += r[c] * (y[k, c] - h[c] * w)
            den = 1.0 + q11 * g
            if out_nis is not None:
                e2 = 0.0
                for c in range(ny):
                    acc = 0.0
                    for d in range(ny):
                        acc += Rinv[c, d] * (y[k, d] - h[d] * w)
                    e2 += (y[k, c] - h[c] * w) * acc
                out_nis[k] = e2 - q11 * s * s / den
            # (51)-(52)
            t += q01 * s / den
            w += q11 * s / den
            # (53)
            f = g / den
            q00, q01, q11 = q00 - q01 * q01 * f, q01 - q01 * q11 * f, q11 - q11 * q11 * f
        elif out_nis is not None:
            out_nis[k] = np.nan
        x0 = t
        x1 = w
        up = u[k]
        out_x[k, 0] = t
        out_x[k, 1] = w
        out_var[k, 0] = q00
        out_var[k, 1] = q11
    x[0] = x0
    x[1] = x1
    P[0, 0] = q00
    P[0, 1] = q01
    P[1, 0] = q01
    P[1, 1] = q11
    uprev[0] = up


def _run_kernel(
    kernel, f, noise, y, u, n_states: int, correction, nis: bool = False
) -> tuple[np.ndarray, ...]:
    """One call of a stage EKF kernel (:func:`ekf_run`, :func:`gain_ekf_run`) on a frame.

    f: the filter (its model, A, B, Rinv, eps and the carried x, P, uprev); noise: the
    kernel's noise arguments after B (Q [V^2], and Qg for the gain state); y (n, n_y),
    u (n,) as in :meth:`StageEkf.step`; correction: (alpha, beta) of
    :func:`_output_correction`, or None; nis: also the NIS per sample (:func:`ekf_run`
    only). Returns states and variances (n, n_states), and the NIS (n,) with ``nis``."""
    y = np.ascontiguousarray(np.atleast_2d(y), float)
    u = np.ascontiguousarray(u, float)
    n = y.shape[0]
    out_x = np.empty((n, n_states))
    out_v = np.empty((n, n_states))
    m = f.model
    eta = np.asarray(m.eta, float)
    gap = np.asarray(m.gap, float)
    lim = np.ascontiguousarray(m.limits, float)
    args = (y, u, f.A, f.B, *noise, f.Rinv, eta, gap, lim, f.eps, f.x, f.P, f.uprev, out_x, out_v)
    if nis:
        out_nis = np.empty(n)
        kernel(*args, out_nis)
    else:
        kernel(*args)
    if correction is not None:
        _output_correction(out_x, out_v, *correction)
    return (out_x, out_v, out_nis) if nis else (out_x, out_v)


def _output_correction(x: np.ndarray, var: np.ndarray, alpha: float, beta: float) -> None:
    """omega = (omega_ekf - beta) / alpha in place (sec. 3.5.4 last step), its variance
    scaled by 1/alpha^2; column 1 of the (n, n_states) arrays."""
    if alpha != 1.0 or beta != 0.0:
        x[:, 1] = (x[:, 1] - beta) / alpha
        var[:, 1] /= alpha**2


class StageEkf:
    """Streaming EKF over frames (state carried).

    Args:
        model: identified :class:`StageModel`.
        p0: initial covariance diag (theta^2, omega^2).
    """

    def __init__(self, model: StageModel, p0: tuple[float, float] = (1e-6, 1.0)) -> None:
        self.model = model
        self.A, self.B = model.matrices()
        self.Rinv = np.ascontiguousarray(np.linalg.inv(np.atleast_2d(model.R)))
        self.eps = EPS0 * model.eps_r
        self.p0 = tuple(float(v) for v in p0)
        self.resets = 0
        self.x = np.zeros(2)
        self.P = np.diag(np.asarray(p0, float))
        self.uprev = np.zeros(1)

    def reset(self) -> None:
        """Re-initialise from the prior: the stage at rest (x = 0, held input 0), P = P0."""
        self.x = np.zeros(2)
        self.P = np.diag(np.asarray(self.p0, float))
        self.uprev = np.zeros(1)
        self.resets += 1

    def start_forced(self, u: np.ndarray, f_drive: np.ndarray, periods: int = 8) -> None:
        """Re-initialise at the forced steady state of the model under the coming drive,
        P = P0: the prior of a stage that has been driven, unseen, for much longer than
        its time constant 1/(zeta wn) (a long gap).

        The drive u_k [V] (first samples of the coming frame, at most ``periods`` periods
        of the frequency ``f_drive[0]`` [Hz] it starts with) is fitted by least squares as
        u_k = Re(U z^k) + c, z = exp(j 2 pi f / fs). The steady state of the discrete model
        x_k = A_d x_{k-1} + B_d u_{k-1} (eqs. 34, 48) is x_k = Re(X z^k) + X_0 with
        X = (z I - A_d)^-1 B_d U and X_0 = (I - A_d)^-1 B_d c; the carried state is its
        value at k = -1 (state and held input before the first coming sample). Without a
        drive frequency (f <= 0) or with fewer than 8 samples only the constant part is
        used.
        """
        u = np.asarray(u, float)
        f = float(f_drive[0]) if len(f_drive) else 0.0
        n = len(u)
        if f > 0.0:
            other = np.flatnonzero(np.asarray(f_drive) != f_drive[0])
            n = min(n if other.size == 0 else int(other[0]), int(periods * self.model.fs / f))
        k = np.arange(n)
        if f > 0.0 and n >= 8:
            w = 2.0 * math.pi * f / self.model.fs
            M = np.column_stack([np.cos(w * k), np.sin(w * k), np.ones(n)])
            (a, b, c), *_ = np.linalg.lstsq(M, u[:n], rcond=None)
            z, U = complex(math.cos(w), math.sin(w)), complex(a, -b)
        else:
            z, U, c = 1.0 + 0.0j, 0.0j, float(np.mean(u[:n])) if n else 0.0
        self.reset()
        B = np.asarray(self.B, float).reshape(2)
        X = np.linalg.solve(z * np.eye(2) - self.A, B * U)
        X0 = np.linalg.solve(np.eye(2) - self.A, B * c)
        self.x[:] = (X / z).real + X0
        self.uprev[:] = (U / z).real + c

    def diverged(self) -> bool:
        """True if the state is not finite, the covariance is not positive definite
        (:func:`~mems_sim.kernels.divergence.covariance_ok`) or the tilt is not inside
        (-pi/2, pi/2) (where the sensor model h(theta), through tan(theta), is defined)."""
        return not (
            state_ok(self.x, self.uprev) and covariance_ok(self.P) and abs(self.x[0]) < math.pi / 2
        )

    def time_update(self, n: int, chunk: int = 65536) -> None:
        """Time updates only (no measurement) over n samples with the drive 0 after the
        held one (a gap), in chunks of at most ``chunk`` samples (bounded memory)."""
        nch = self.model.eta.shape[0]
        while n > 0:
            m = min(n, chunk)
            self.step(np.full((m, nch), np.nan), np.zeros(m))
            n -= m

    def step(
        self, y: np.ndarray, u: np.ndarray, corrected: bool = True, nis: bool = False
    ) -> tuple[np.ndarray, ...]:
        """Estimates (n, 2) [rad, rad/s] and variances (n, 2) for measurements y (n, n_y)
        and drive u (n,). ``corrected`` applies the identified output correction to omega
        (and scales its variance by 1/alpha^2). ``nis``: also the normalised innovation
        squared (n,) [-] of each sample, nu^T S^-1 nu with S = H P^- H^T + R (chi-square
        with n_y degrees of freedom for a consistent filter; Bar-Shalom, Li & Kirubarajan
        2001, Sec. 5.4.2), NaN on a sample without measurement update; the estimates are
        the same bit for bit with it."""
        m = self.model
        corr = (m.alpha, m.beta) if corrected else None
        return _run_kernel(ekf_run, self, (float(m.Q),), y, u, 2, corr, nis)


@numba.njit(cache=True)
def gain_ekf_run(y, u, A, B, Q, Qg, Rinv, eta, gap, lim, eps, x, P, uprev, out_x, out_var):
    """Eqs. (48)-(53) with the actuator gain as a third state (:class:`GainAdaptiveStageEkf`).

    x = [theta, omega, g] carried in x (3,), P (3, 3), uprev (1,) [V]; the model input is
    g b_c u (g = 1: the identified b_c), g a random walk of variance Qg per sample [-].
    Jacobian of (48): F = [[A_d, B_d u_{k-1}], [0, 0, 1]]; input noise B_d g^2 Q B_d^T.
    H = [0, h_c(theta), 0] as in eq. (50), so the update is the scalar one of
    :func:`ekf_run` along the omega column of P. Outputs (n, 3) states and variances.

    The measurement terms (finite check, R^-1 h, g, s) repeat :func:`ekf_run`'s inline
    code on purpose: moving them into a shared njit function made the 2-state kernel
    30-40 % slower (10 vs 15 M samples/s, inlined or not)."""
    n = y.shape[0]
    ny = y.shape[1]
    h = np.empty(ny)
    r = np.empty(ny)
    F = np.zeros((3, 3))
    F[0, 0], F[0, 1], F[1, 0], F[1, 1], F[2, 2] = A[0, 0], A[0, 1], A[1, 0], A[1, 1], 1.0
    T = np.empty((3, 3))
    M = np.empty((3, 3))
    c = np.empty(3)
    for k in range(n):
        ue = uprev[0]
        gk = x[2]
        t = A[0, 0] * x[0] + A[0, 1] * x[1] + B[0] * gk * ue
        w = A[1, 0] * x[0] + A[1, 1] * x[1] + B[1] * gk * ue
        F[0, 2] = B[0] * ue
        F[1, 2] = B[1] * ue
        for i in range(3):
            for j in range(3):
                T[i, j] = F[i, 0] * P[0, j] + F[i, 1] * P[1, j] + F[i, 2] * P[2, j]
        for i in range(3):
            for j in range(3):
                M[i, j] = T[i, 0] * F[j, 0] + T[i, 1] * F[j, 1] + T[i, 2] * F[j, 2]
        qg = gk * gk * Q
        M[0, 0] += B[0] * B[0] * qg
        M[0, 1] += B[0] * B[1] * qg
        M[1, 0] += B[0] * B[1] * qg
        M[1, 1] += B[1] * B[1] * qg
        M[2, 2] += Qg
        ok = True
        for cc in range(ny):
            if not math.isfinite(y[k, cc]):
                ok = False
        if ok:
            output_h(t, eta, gap, lim, eps, h)
            for cc in range(ny):
                acc = 0.0
                for d in range(ny):
                    acc += Rinv[cc, d] * h[d]
                r[cc] = acc
            gs = 0.0
            s = 0.0
            for cc in range(ny):
                gs += r[cc] * h[cc]
                s += r[cc] * (y[k, cc] - h[cc] * w)
            den = 1.0 + M[1, 1] * gs
            for i in range(3):
                c[i] = M[i, 1]
            t += c[0] * s / den
            w += c[1] * s / den
            gk += c[2] * s / den
            f = gs / den
            for i in range(3):
                for j in range(3):
                    M[i, j] -= c[i] * c[j] * f
        x[0] = t
        x[1] = w
        x[2] = gk
        for i in range(3):
            for j in range(3):
                P[i, j] = M[i, j]
            out_var[k, i] = M[i, i]
        uprev[0] = u[k]
        out_x[k, 0] = t
        out_x[k, 1] = w
        out_x[k, 2] = gk


class GainAdaptiveStageEkf:
    """Stage EKF that also estimates the actuator gain g (b_c -> g b_c), a study of how
    the estimator could follow a piezo whose gain drifts between identification and use
    (``bench_stage_ekf.py --drift``); not one of the thesis' estimators.

    Args:
        model: identified :class:`StageModel` (its Q is the input noise, V^2).
        gain_rw: random-walk density of g [1/sqrt(s)] (default 1e-3: g may wander 0.1 %
            in a second); Qg = gain_rw^2 / fs per sample.
        p0: initial covariance diag (theta^2 [rad^2], omega^2 [(rad/s)^2], g^2 [-]).
        output_correction: (alpha, beta) applied to omega; default the model's (they were
            identified for the 2-state filter, so pass ones fitted for this one).
        gain0: initial g [-] (e.g. the converged g of an earlier run, with a small p0[2]).
    """

    def __init__(
        self,
        model: StageModel,
        gain_rw: float = 1e-3,
        p0: tuple[float, float, float] = (1e-6, 1.0, 1e-4),
        output_correction: tuple[float, float] | None = None,
        gain0: float = 1.0,
    ) -> None:
        if not (math.isfinite(gain_rw) and gain_rw >= 0.0):
            raise ValueError(f"gain_rw {gain_rw!r} 1/sqrt(s) must be >= 0")
        if not (math.isfinite(gain0) and gain0 > 0.0):
            raise ValueError(f"gain0 {gain0!r} must be > 0")
        self.model = model
        self.A, self.B = model.matrices()
        self.Rinv = np.ascontiguousarray(np.linalg.inv(np.atleast_2d(model.R)))
        self.eps = EPS0 * model.eps_r
        self.Qg = gain_rw * gain_rw / model.fs
        self.alpha, self.beta = output_correction or (model.alpha, model.beta)
        self.x = np.array([0.0, 0.0, float(gain0)])
        self.P = np.diag(np.asarray(p0, float))
        self.uprev = np.zeros(1)

    def step(
        self, y: np.ndarray, u: np.ndarray, corrected: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """States (n, 3) [rad, rad/s, -] and their variances for measurements y (n, n_y)
        [V] and drive u (n,) [V]; ``corrected`` applies (alpha, beta) to omega."""
        corr = (self.alpha, self.beta) if corrected else None
        return _run_kernel(gain_ekf_run, self, (float(self.model.Q), self.Qg), y, u, 3, corr)


@numba.njit(cache=True)
def cancel_run(y, vb, fd, fs, hist_y, hist_on, out):
    """Bias on/off feedthrough cancellation (sec. 3.5.4): for a bias-on sample k,
    out_k = y_k - y_off(t_k - 1/f_drive) (linear interpolation between the two bias-off
    samples around t_k - T); NaN when those samples are not both bias-off.
    hist_*: the last m samples before this frame (carried by the caller)."""
    m = hist_y.shape[0]
    n = y.shape[0]
    nch = y.shape[1]
    for k in range(n):
        if vb[k] <= 0.0 or not (fd[k] > 0.0):
            for c in range(nch):
                out[k, c] = np.nan
            continue
        # j = k - d with d = fs/f_drive; split so that the weights do not depend on k
        # (frame-wise and one-shot runs give bit-identical results)
        d = fs / fd[k]
        dc = math.ceil(d)
        i0 = k - int(dc)
        fr = dc - d
        good = i0 + 1 < k and i0 >= -m
        if good:
            on0 = vb[i0] if i0 >= 0 else hist_on[m + i0]
            on1 = vb[i0 + 1] if i0 + 1 >= 0 else hist_on[m + i0 + 1]
            good = on0 <= 0.0 and on1 <= 0.0
        for c in range(nch):
            if good:
                a = y[i0, c] if i0 >= 0 else hist_y[m + i0, c]
                b = y[i0 + 1, c] if i0 + 1 >= 0 else hist_y[m + i0 + 1, c]
                out[k, c] = y[k, c] - ((1.0 - fr) * a + fr * b)
            else:
                out[k, c] = np.nan


class FeedthroughCanceller:
    """Streaming wrapper of :func:`cancel_run` (keeps ``history`` samples, >= one period).

    Args:
        n_channels: channels; fs: sample rate Hz; history: samples kept (>= fs/f_min + 2).
        enabled: False passes y through on every sample (no cancellation, bias always on).
    """

    def __init__(
        self, n_channels: int, fs: float, history: int = 4096, enabled: bool = True
    ) -> None:
        self.fs = float(fs)
        self.enabled = enabled
        self.hy = np.zeros((history, n_channels))
        self.hon = np.ones(history)

    def reset(self) -> None:
        """Forget the history (as new: no bias-off samples yet, so the next period gives
        no cancelled value)."""
        self.hy = np.zeros_like(self.hy)
        self.hon = np.ones_like(self.hon)

    def step(self, y: np.ndarray, v_bias: np.ndarray, f_drive: np.ndarray) -> np.ndarray:
        """Cancelled measurements (n, n_ch) [V]; NaN where no update is possible."""
        y = np.ascontiguousarray(y, float)
        if not self.enabled:
            out = y.copy()
            out[np.asarray(v_bias) <= 0] = np.nan
            return out
        out = np.empty_like(y)
        cancel_run(
            y,
            np.ascontiguousarray(v_bias, float),
            np.ascontiguousarray(f_drive, float),
            self.fs,
            self.hy,
            self.hon,
            out,
        )
        m = self.hy.shape[0]
        if y.shape[0] >= m:
            self.hy = y[-m:].copy()
            self.hon = np.ascontiguousarray(v_bias[-m:], float).copy()
        else:
            self.hy = np.concatenate([self.hy[y.shape[0] :], y])
            self.hon = np.concatenate([self.hon[y.shape[0] :], np.asarray(v_bias, float)])
        return out


def model_to_dict(m: StageModel) -> dict[str, Any]:
    """Plain dict (YAML-able) of a :class:`StageModel`."""
    return {
        "wn_rad_s": float(m.wn),
        "zeta": float(m.zeta),
        "b_c": float(m.b_c),
        "sample_rate_hz": float(m.fs),
        "channels": list(m.channels),
        "eta": [float(v) for v in m.eta],
        "gap_m": [float(v) for v in m.gap],
        "limits_m": [[float(v) for v in row] for row in m.limits],
        "R_v2": [[float(v) for v in row] for row in np.atleast_2d(m.R)],
        "Q_v2": float(m.Q),
        "alpha": float(m.alpha),
        "beta_rad_s": float(m.beta),
        "eps_r": float(m.eps_r),
        "extra": {k: (float(v) if np.isscalar(v) else v) for k, v in m.extra.items()},
    }


def model_from_dict(d: Mapping[str, Any]) -> StageModel:
    """Inverse of :func:`model_to_dict`; raises ValueError on missing/invalid entries."""
    try:
        m = StageModel(
            float(d["wn_rad_s"]),
            float(d["zeta"]),
            float(d["b_c"]),
            float(d["sample_rate_hz"]),
            np.array(d["eta"], float),
            np.array(d["gap_m"], float),
            np.array(d["limits_m"], float),
            np.array(d["R_v2"], float),
            float(d["Q_v2"]),
            tuple(d["channels"]),
            float(d.get("alpha", 1.0)),
            float(d.get("beta_rad_s", 0.0)),
            float(d.get("eps_r", 1.0)),
            dict(d.get("extra", {})),
        )
    except (KeyError, TypeError) as exc:
        raise ValueError(f"stage model parameters incomplete or malformed: {exc}") from None
    n = len(m.channels)
    vals = [m.wn, m.zeta, m.b_c, m.fs, m.Q, m.alpha, *m.eta, *m.gap, *m.R.ravel()]
    if not all(math.isfinite(v) for v in vals):
        raise ValueError("stage model parameters contain non-finite values")
    if (
        m.eta.shape != (n,)
        or m.gap.shape != (n,)
        or m.limits.shape != (n, 4)
        or m.R.shape != (n, n)
    ):
        raise ValueError("stage model parameter shapes do not match the channel list")
    if not (m.wn > 0 and 0 < m.zeta < 1 and m.fs > 0 and m.Q >= 0 and np.all(m.gap > 0)):
        raise ValueError("stage model parameters out of range (wn, fs, gaps > 0; 0<zeta<1)")
    return m


def save_model(m: StageModel, path: str) -> None:
    """Write the identified parameters as YAML (the estimator's parameter file), whole and
    never through a symbolic link (:func:`mems_sim.bag.output_paths.write_output`;
    BagWriteError)."""
    from pathlib import Path

    import yaml

    from mems_sim.bag.output_paths import write_output

    text = yaml.safe_dump(model_to_dict(m), sort_keys=False)
    write_output(path, lambda tmp: Path(tmp).write_text(text), overwrite=True)


def load_model(path: str) -> StageModel:
    """Read a parameter YAML; FileNotFoundError / ValueError with a clear message."""
    import os

    if not path or not os.path.isfile(path):
        raise FileNotFoundError(
            f"stage parameter YAML not found: {path!r} (run the identification first)"
        )
    import yaml

    try:
        d = bounded_yaml.load_file(path)
    except yaml.YAMLError as exc:
        raise ValueError(f"stage parameter YAML {path!r}: {bounded_yaml.problem(exc)}") from None
    if not isinstance(d, dict):
        raise ValueError(f"stage parameter YAML {path!r} is not a mapping")
    try:
        return model_from_dict(d)
    except (KeyError, TypeError, IndexError) as exc:  # a missing or mistyped entry
        name = type(exc).__name__
        raise ValueError(f"stage parameter YAML {path!r}: {name} {exc}") from None

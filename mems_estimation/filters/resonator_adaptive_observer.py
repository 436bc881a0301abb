"""Adaptive (joint state-parameter) Kalman observer of the sigma-delta resonator.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator using digital
Kalman observer", Sec. 7-8: "a non-linear adaptive Kalman observer: the unknown state
variables are the system coefficients together with the original state variables" (their
announced future work).  This module implements it as an extended Kalman filter (EKF) over
the 6 states of :mod:`mems_sim.kernels.resonator_observer` augmented with

    d = f0/f0_init - 1                  (random walk, std f0_random_walk_ppm*1e-6 per sample)
    r = Q/Q_init - 1   (estimate_q)     (random walk, std q_random_walk_ppm*1e-6 per sample)

The resonator block is re-discretised every sample at the current estimate
(closed-form ZOH, :func:`mems_sim.devices.resonator_models.resonator_zoh`) and its Jacobian
with respect to d (and r) is taken by a central difference of that closed form
(step 1e-7, relative error ~1e-9).  The modulator part and the noise model
(F, G, M with the cross-covariance of eq. (2)) are those of the linear observer;
the velocity state is scaled by the fixed w_ref = 2 pi f0_init.  By default the
quantiser is linearised statistically (Bussgang gain, see
:func:`mems_sim.kernels.resonator_observer.bussgang_quantizer`): with the paper's
unit-gain model the f0 estimate is biased by ~+100 ppm because the one-bit
error is correlated with the signal (measured; ~+13 ppm on a truly linear
white-noise model of the same loop).

Start-up and steps: the parameters are held for ``warmup_periods`` while the
states converge, and an innovation monitor re-opens the parameter covariance
when the normalised innovation power stays high (a step of f0), see the
constructor arguments.

Why an EKF and not a UKF: the only nonlinearity is the dependence of the
one-sample transition on f0 (and Q), smooth and nearly bilinear over a sample
(the per-sample phase 2 pi f0/fs changes by 5e-4 rad for a 1e-3 error at
f0 = 0.05 fs), and the measurement is linear; the EKF costs one Jacobian column
per parameter, while a UKF would need 2n+1 = 15-17 sigma points, each with its
own exp/sin/cos discretisation, per sample at MHz rates.

Recursion per sample (a-priori form with the cross term, J = df/dX at X(k|k)):

    S = C P C' + G,  nu = v(k) - C Xp,  X(k|k) = Xp + P C'/S nu
    Xp <- f(X(k|k), u(k)) + M nu / S,   L = (J P C' + M)/S,   P <- J P J' + F(k) - L L' S

f includes the exact pulse term of sub-sample pulses (fired at s T, width w T) at the
current f0 estimate, :func:`mems_sim.devices.resonator_models.interval_input`; its f0 (and Q) derivative
enters J by the same central difference.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mems_sim.devices.resonator_models import interval_input, next_spill, resonator_zoh_t
from mems_sim.kernels.divergence import covariance_ok, state_ok
from mems_sim.kernels.resonator_observer import (
    BUSSGANG_GAIN,
    BUSSGANG_VAR,
    DEFAULT_QUANTIZATION_VAR,
    KalmanObserver,
    _sd_blocks,
    check_bits,
    check_pulse_timing,
    cov_predict_sd,
    predicted_output_sd,
    predictor_gain_sd,
)

__all__ = ["AdaptiveObserver"]

_H = 1e-7


@numba.njit(cache=True, inline="always")
def _res_scaled(f0, Q, fs, wref, out):
    """Scaled resonator transition: out = [P11, P12*wref, P21/wref, P22, G1, G2/wref]
    (:func:`mems_sim.devices.resonator_models.resonator_zoh_t` over T = 1/fs; inlined: three
    calls per sample)."""
    z = resonator_zoh_t(f0, Q, fs, 1.0 / fs)
    out[0] = z[0]
    out[1] = z[1] * wref
    out[2] = z[2] / wref
    out[3] = z[3]
    out[4] = z[4]
    out[5] = z[5] / wref


@numba.njit(cache=True)
def _pulse_scaled(f0, Q, fs, wref, r, spill, u, s, w, out, z, g):
    """Scaled exact pulse term of the interval (see mems_sim.devices.resonator_models.interval_input) at
    the model (f0, Q); r: scaled transition from :func:`_res_scaled` (for Gam(T))."""
    g[0] = r[4]
    g[1] = r[5] * wref
    g[2] = -1.0  # no width cache: f0 changes every call
    interval_input(f0, Q, fs, g[0:2], spill[0], spill[1], u, s, w, out, z, g[2:5])
    out[1] /= wref


@numba.njit(cache=True)
def _ekf_run(
    bits,
    pulses,
    starts,
    widths,
    spill,
    xp,
    P,
    f0i,
    Qi,
    fs,
    wref,
    Asd,
    C,
    G,
    qv,
    sb2,
    sf2,
    rw2,
    rq2,
    est_q,
    k0,
    warm,
    aux,
    alpha,
    thresh,
    reset_var,
    pos,
    pvar,
    f0o,
    f0v,
):
    n = xp.shape[0]
    PC = np.empty(n)
    xf = np.empty(n)
    J = np.zeros((n, n))
    F = np.zeros((n, n))
    Mv = np.zeros(n)
    Mv[4] = qv
    L = np.empty(n)
    JP = np.empty((n, n))
    r0 = np.empty(6)
    rp = np.empty(6)
    rm = np.empty(6)
    z = np.empty(6)
    # constant parts of J
    for i in range(2, 6):
        for j in range(n):
            J[i, j] = 0.0
    J[2, 2] = Asd[0, 0]
    J[2, 3] = Asd[0, 1]
    J[3, 2] = Asd[1, 0]
    J[3, 3] = Asd[1, 1]
    J[4, 4] = Asd[0, 0]
    J[4, 5] = Asd[0, 1]
    J[5, 4] = Asd[1, 0]
    J[5, 5] = Asd[1, 1]
    J[2, 0] = 1.0
    for i in range(6, n):
        J[i, i] = 1.0
    saved = np.zeros(2)
    e0 = np.zeros(2)
    ep = np.zeros(2)
    em = np.zeros(2)
    g = np.empty(5)
    for k in range(bits.shape[0]):
        frozen = k0 + k < warm
        if frozen:
            # warm-up: parameters held (treated as known) while the states converge
            for a in range(6, n):
                saved[a - 6] = P[a, a]
                for j in range(n):
                    P[a, j] = 0.0
                    P[j, a] = 0.0
        # ---- update
        yhat, S = predicted_output_sd(xp, P, C, G, PC)
        nu = bits[k] - yhat
        # innovation monitor: exponential mean of nu^2/S; a jump of f0 (or Q) shows up as
        # a sustained excess -> re-open the parameter covariance (once per window)
        aux[0] += alpha * (nu * nu / S - aux[0])
        if aux[1] > 0.0:
            aux[1] -= 1.0
        elif thresh > 0.0 and not frozen and aux[0] > thresh:
            for a in range(6, n):
                if P[a, a] < reset_var[a - 6]:
                    P[a, a] = reset_var[a - 6]
            aux[0] = 1.0
            aux[1] = 1.0 / alpha
            aux[2] += 1.0
            _, S = predicted_output_sd(xp, P, C, G, PC)
        for i in range(n):
            xf[i] = xp[i] + PC[i] / S * nu
        pos[k] = xf[0]
        pvar[k] = P[0, 0] - PC[0] * PC[0] / S
        f0o[k] = f0i * (1.0 + xf[6])
        f0v[k] = f0i * f0i * (P[6, 6] - PC[6] * PC[6] / S)
        # ---- Jacobian and mean at X(k|k)
        d = xf[6]
        r = xf[7] if est_q else 0.0
        f0 = f0i * (1.0 + d)
        Qc = Qi * (1.0 + r)
        if f0 <= 0.0:
            f0 = 1e-6 * f0i
        if f0 >= 0.5 * fs:
            f0 = 0.4999 * fs
        if Qc <= 0.5:
            Qc = 0.5000001
        u = pulses[k]
        pulse = u != 0.0 or spill[0] != 0.0
        if not pulse:
            for i in range(2):
                e0[i] = 0.0
                ep[i] = 0.0
                em[i] = 0.0
        _res_scaled(f0, Qc, fs, wref, r0)
        if pulse:
            _pulse_scaled(f0, Qc, fs, wref, r0, spill, u, starts[k], widths[k], e0, z, g)
        y0 = xf[0]
        y1 = xf[1]
        _res_scaled(f0 + f0i * _H, Qc, fs, wref, rp)
        if pulse:
            _pulse_scaled(f0 + f0i * _H, Qc, fs, wref, rp, spill, u, starts[k], widths[k], ep, z, g)
        _res_scaled(f0 - f0i * _H, Qc, fs, wref, rm)
        if pulse:
            _pulse_scaled(f0 - f0i * _H, Qc, fs, wref, rm, spill, u, starts[k], widths[k], em, z, g)
        J[0, 6] = ((rp[0] - rm[0]) * y0 + (rp[1] - rm[1]) * y1 + (ep[0] - em[0])) / (2 * _H)
        J[1, 6] = ((rp[2] - rm[2]) * y0 + (rp[3] - rm[3]) * y1 + (ep[1] - em[1])) / (2 * _H)
        if est_q:
            _res_scaled(f0, Qc + Qi * _H, fs, wref, rp)
            if pulse:
                _pulse_scaled(
                    f0, Qc + Qi * _H, fs, wref, rp, spill, u, starts[k], widths[k], ep, z, g
                )
            _res_scaled(f0, Qc - Qi * _H, fs, wref, rm)
            if pulse:
                _pulse_scaled(
                    f0, Qc - Qi * _H, fs, wref, rm, spill, u, starts[k], widths[k], em, z, g
                )
            J[0, 7] = ((rp[0] - rm[0]) * y0 + (rp[1] - rm[1]) * y1 + (ep[0] - em[0])) / (2 * _H)
            J[1, 7] = ((rp[2] - rm[2]) * y0 + (rp[3] - rm[3]) * y1 + (ep[1] - em[1])) / (2 * _H)
        if pulse:
            next_spill(u, starts[k], widths[k], spill)
        J[0, 0] = r0[0]
        J[0, 1] = r0[1]
        J[1, 0] = r0[2]
        J[1, 1] = r0[3]
        # process covariance F(k)
        F[0, 0] = r0[4] * r0[4] * sf2
        F[0, 1] = r0[4] * r0[5] * sf2
        F[1, 0] = F[0, 1]
        F[1, 1] = r0[5] * r0[5] * sf2
        F[2, 2] = sb2
        F[4, 4] = qv
        F[6, 6] = rw2
        if est_q:
            F[7, 7] = rq2
        # ---- mean prediction
        xp[0] = r0[0] * y0 + r0[1] * y1 + e0[0]
        xp[1] = r0[2] * y0 + r0[3] * y1 + e0[1]
        t2 = xf[2]
        t4 = xf[4]
        xp[2] = Asd[0, 0] * t2 + Asd[0, 1] * xf[3] + y0
        xp[3] = t2
        xp[4] = Asd[0, 0] * t4 + Asd[0, 1] * xf[5] + qv * nu / S
        xp[5] = t4
        for i in range(6, n):
            xp[i] = xf[i]
        # ---- covariance prediction (predictor form with the cross term; J has the
        # pattern of the 6-state model's A plus the parameter columns J[0:2, 6:] and the
        # random-walk rows, which the structured kernels use)
        predictor_gain_sd(J, Mv, PC, S, L)
        cov_predict_sd(P, J, F, L, S, JP)
        if frozen:
            for a in range(6, n):
                for j in range(n):
                    P[a, j] = 0.0
                    P[j, a] = 0.0
                P[a, a] = saved[a - 6]


class AdaptiveObserver:
    """EKF over [resonator (2), STF (2), NTF (2), d = f0/f0_init - 1 (, r = Q/Q_init - 1)].

    Args:
        f0_init: initial f0 estimate, Hz (0 < f0_init < fs/2).
        Q: quality factor (initial value when estimate_q), > 0.5.
        fs: sample rate, Hz.
        output_noise_std: std of b at the modulator input, V.
        state_noise_std: thermomechanical force-noise std (per sample, on u), V.
        f0_random_walk_ppm: std of the per-sample random walk of f0, ppm of f0_init.
        estimate_q: also estimate Q (8th state).
        f0_init_std: initial std of f0/f0_init - 1 (fraction).
        q_init_std: initial std of Q/Q_init - 1 (fraction), estimate_q only.
        q_random_walk_ppm: per-sample random walk std of Q, ppm of Q_init.
        sd_feedforward: modulator STF feed-in c (0.5: eq. (11)).
        quantizer_gain: kappa of the quantiser model v = kappa q + w.  Default: the
            Bussgang gain sqrt(2/pi)/0.64 = 1.247 (comparator-input std 0.64 V measured in
            the non-overloaded loops); 1 is the paper's unit-gain model, which leaves a
            steady f0 bias of ~+70..125 ppm (the quantisation error is correlated with the
            signal).
        quantization_var: variance of w, V^2 (None: 1 - 2/pi = 0.363 for the Bussgang
            model, 1/3 for quantizer_gain = 1).
        initial_position_std: initial std of the resonator position/velocity states, V.
        warmup_periods: the parameters are held (not updated) for this many periods of
            f0_init at the start, while the state estimate converges; adapting them from
            an unconverged state makes the EKF jump by several % (measured).
        reset_threshold: innovation monitor: when the exponential mean (time constant
            reset_window_periods periods) of nu^2/S exceeds this, the parameter variances
            are raised to reset_std^2 (fraction^2) so that a step of f0 is re-acquired in
            a few hundred periods instead of the random walk's ~10^4; 0 disables it.
        reset_window_periods: time constant of the monitor, periods of f0_init.
        reset_std: parameter std (fraction) after a reset.
    """

    def __init__(
        self,
        f0_init: float,
        Q: float,
        fs: float,
        output_noise_std: float,
        state_noise_std: float,
        f0_random_walk_ppm: float = 0.2,
        estimate_q: bool = False,
        *,
        f0_init_std: float = 0.05,
        q_init_std: float = 0.1,
        q_random_walk_ppm: float = 0.0,
        quantization_var: float | None = None,
        sd_feedforward: float = 0.5,
        quantizer_gain: float = BUSSGANG_GAIN,
        initial_position_std: float = 1.0,
        warmup_periods: float = 50.0,
        reset_threshold: float = 1.5,
        reset_window_periods: float = 20.0,
        reset_std: float = 0.01,
    ) -> None:
        if not (fs > 0 and 0 < f0_init < fs / 2 and Q > 0.5):
            raise ValueError(
                f"need fs > 0, 0 < f0_init < fs/2 and Q > 0.5; got fs = {fs!r} Hz, "
                f"f0_init = {f0_init!r} Hz, Q = {Q!r}"
            )
        for name, val in (
            ("output_noise_std", output_noise_std),
            ("state_noise_std", state_noise_std),
            ("f0_random_walk_ppm", f0_random_walk_ppm),
            ("q_random_walk_ppm", q_random_walk_ppm),
            ("f0_init_std", f0_init_std),
            ("q_init_std", q_init_std),
        ):
            if not (val >= 0 and math.isfinite(val)):
                raise ValueError(f"{name} = {val!r} must be finite and >= 0")
        self.f0_init, self.Q, self.fs = float(f0_init), float(Q), float(fs)
        self.estimate_q = bool(estimate_q)
        if quantization_var is None:
            quantization_var = DEFAULT_QUANTIZATION_VAR if quantizer_gain == 1.0 else BUSSGANG_VAR
        self.qv = float(quantization_var)
        self.wref = 2.0 * math.pi * self.f0_init
        Ad, c_stf, c_ntf = _sd_blocks(sd_feedforward, quantizer_gain)
        self.Asd = np.ascontiguousarray(Ad)
        n = 8 if self.estimate_q else 7
        self.C = np.zeros(n)
        self.C[2:4] = c_stf
        self.C[4:6] = c_ntf
        self.x = np.zeros(n)
        self.P = np.zeros((n, n))
        self.P[0, 0] = self.P[1, 1] = initial_position_std**2
        for i in range(2, 6):
            self.P[i, i] = 1.0  # modulator states unknown (may join a running stream)
        self.P[6, 6] = f0_init_std**2
        if self.estimate_q:
            self.P[7, 7] = q_init_std**2
        self.sb2 = float(output_noise_std) ** 2
        self.sf2 = float(state_noise_std) ** 2
        self.rw2 = (f0_random_walk_ppm * 1e-6) ** 2
        self.rq2 = (q_random_walk_ppm * 1e-6) ** 2
        self.warm = int(round(warmup_periods * self.fs / self.f0_init))
        self._warm_end = self.warm  # sample index until which the parameters are held
        self.alpha = 1.0 / max(1.0, reset_window_periods * self.fs / self.f0_init)
        self.thresh = float(reset_threshold)
        self.reset_var = np.full(2, float(reset_std) ** 2)
        self._aux = np.array([1.0, 0.0, 0.0])
        self._spill = np.zeros(2)  # tail of a pulse outlasting its sample interval
        self.next_index = 0
        self.x0 = self.x.copy()
        self.P0 = self.P.copy()
        self.divergence_resets = 0

    def reset(self) -> None:
        """Re-initialise from the prior: state (f0 = f0_init) and covariance of the
        constructor, innovation monitor and pulse tail cleared; the parameters are held
        again for the warm-up (the sample count goes on)."""
        self._warm_end = self.next_index + self.warm
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        self._aux = np.array([1.0, 0.0, self._aux[2]])
        self._spill = np.zeros(2)
        self.divergence_resets += 1

    def diverged(self) -> bool:
        """True if the state is not finite, a voltage state is beyond
        :attr:`KalmanObserver.STATE_LIMIT`, the covariance is not positive definite
        (:func:`~mems_sim.kernels.divergence.covariance_ok`) or f0 is not inside (0, fs/2)."""
        f0 = self.f0_init * (1.0 + self.x[6])
        return not (
            state_ok(self.x, self._spill, self._aux)
            and float(np.max(np.abs(self.x[:6]))) <= KalmanObserver.STATE_LIMIT
            and covariance_ok(self.P)
            and 0.0 < f0 < self.fs / 2
        )

    @property
    def resets(self) -> int:
        """Number of parameter-covariance resets by the innovation monitor so far."""
        return int(self._aux[2])

    @property
    def f0(self) -> float:
        """Current (a-priori) f0 estimate, Hz."""
        return self.f0_init * (1.0 + self.x[6])

    @property
    def quality_factor(self) -> float:
        """Current Q estimate (the fixed Q unless estimate_q)."""
        return self.Q * (1.0 + self.x[7]) if self.estimate_q else self.Q

    def step(self, bits, pulses, starts=None, widths=None):
        """Process n samples.

        Args:
            bits: (n,) +1/-1 bit stream. pulses: (n,) heights of the pulses fired in
            [k T, (k+1) T), V.  starts, widths: (n,) their firing offsets and widths, s
            (None: 0 and T, the one-sample ZOH pulses of eq. (8)); the pulse term is exact
            at the current f0 estimate (:func:`mems_sim.devices.resonator_models.interval_input`).
        Returns:
            (position (n,) V, position variance (n,) V^2, f0 (n,) Hz, f0 variance (n,) Hz^2),
            all a-posteriori at k.
        Raises:
            ValueError: bits not in {+1, -1} (message names the convention) or bad shape.
        """
        b, u = check_bits(bits, pulses)
        s, w = check_pulse_timing(u, starts, widths, self.fs)
        n = b.shape[0]
        pos, pv, f0, f0v = (np.empty(n) for _ in range(4))
        _ekf_run(
            b,
            u,
            s,
            w,
            self._spill,
            self.x,
            self.P,
            self.f0_init,
            self.Q,
            self.fs,
            self.wref,
            self.Asd,
            self.C,
            self.qv,
            self.qv,
            self.sb2,
            self.sf2,
            self.rw2,
            self.rq2,
            self.estimate_q,
            self.next_index,
            self._warm_end,
            self._aux,
            self.alpha,
            self.thresh,
            self.reset_var,
            pos,
            pv,
            f0,
            f0v,
        )
        self.next_index += n
        return pos, pv, f0, f0v

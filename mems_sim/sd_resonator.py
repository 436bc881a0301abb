"""Pulse-actuated micro-resonator read through a one-bit second-order sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator
using digital Kalman observer" (seed
``colinet_pulse_resonator_sigma_delta_kalman_observer.md``): resonator eqs. (7)-(9),
modulator eqs. (10)-(12), observer loop eq. (13) and Fig. 4, simulation set-up
Sec. 6 (f0 = 0.05 fs, Q = 100, output noise of the order of the signal).
Models and unit conventions are in :mod:`mems_sim.sd_models` (position and
pulses in volts at the modulator input, H(s) = fs*w0/(s^2 + s w0/Q + w0^2)).

Per sample k (all carried across frames)::

    x(k)   = y(k) + b(k)                         b ~ N(0, output_noise_std^2)   [V]
    v(k), q(k) = modulator(x(k))                 eqs. (10)-(12), v in {-1, +1}
    s(k)   = position signal used by the controller (see below)
    u(k)   = pulse_amplitude * sign(s(k) - s(k-1))   if sign s(k) != sign s(k-1), else 0
             (one pulse per zero crossing, lasting one sample, sign = direction of motion;
             sign(z) = +1 for z >= 0)
    [y, dy/dt](k+1) = Phi(f0(k)) [y, dy/dt](k) + Gam(f0(k)) (u(k) + f(k)),
                                                 f ~ N(0, state_noise_std^2) [V]

Start-up (both modes): the resonator and the modulator start at rest (all
states 0) and a single kick u(0) = +pulse_amplitude is applied at k = 0 of the
device; from k = 1 the controller rule above applies.

Controller ``mode``:

* ``"observer"`` (Fig. 4): s(k) = y(k|k), the position estimate of the
  6-state Kalman observer (:class:`mems_estimation.kalman_observer.KalmanObserver`
  model) run in the loop on v(k) and the applied pulses.
* ``"comparator"`` (Fig. 1, naive loop), ``comparator_input``:
  ``"resonator"`` (default): s(k) = y(k) + b(k), the one-bit comparator of Fig. 1
  on the noisy resonator output (the modulator still produces the bit stream);
  ``"bitstream"``: s(k) = sum of the last ``comparator_window`` bits v(k-W+1..k)
  (W odd, so s is never 0; W = 1 is the raw bit stream).  The bit-stream variant
  never builds up oscillation even without noise (measured amplitude < 0.006 V for
  W = 1..21: the modulator's idle pattern makes the decoded sign toggle almost every
  sample), so it cannot show the effect of the noise; the default is Fig. 1's loop,
  which oscillates like the observer loop without noise and fails with it.

f0(t) = f0_hz * (1 + f0_drift_ppm_per_s*1e-6*t) * (1 + f0_step_fraction if t >= f0_step_time_s),
t = k/fs; the resonator is re-discretised (closed-form ZOH) whenever f0 changes.

Default pulse amplitude: with one pulse per half period, the steady amplitude A
obeys A = A exp(-pi/(2Q)) + U cos(phi) (phi: the phase lag of the sampled
crossing, ~pi f0/fs on average) -> U = A (1 - exp(-pi/(2Q)))/cos(pi f0/fs) ~ 0.0079 V
for A = 0.5 V at Q = 100 (measured steady amplitude: see tests).

Determinism: ``np.random.SeedSequence(seed).spawn(2)`` -> one PCG64 stream for b,
one for f; drawn frame by frame, so frames concatenate bit-identically.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, NamedTuple

import numba
import numpy as np

from mems_sim.params import ParameterError, ParamSpec, resolve
from mems_sim.sd_models import resonator_zoh, sd_step
from mems_estimation.kalman_observer import (DEFAULT_QUANTIZATION_VAR, kf_predict, kf_update,
                                             observer_model, ss_step6,
                                             steady_state_gains)

__all__ = ["RESONATOR_SPECS", "validate_params", "SdFrame", "SdResonatorDevice",
           "default_pulse_amplitude"]

_FS = 1.0e6
_F0 = 0.05 * _FS
_Q = 100.0
_A_TARGET = 0.5


def default_pulse_amplitude(amplitude: float = _A_TARGET, Q: float = _Q,
                            f0_over_fs: float = 0.05) -> float:
    """U = A (1 - exp(-pi/(2Q))) / cos(pi f0/fs), V (see module doc)."""
    return amplitude * -math.expm1(-math.pi / (2.0 * Q)) / math.cos(math.pi * f0_over_fs)


_U = round(default_pulse_amplitude(), 6)

RESONATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("sample_rate_hz", _FS, "Hz", "sample rate fs of the modulator and the digital loop",
              "issue 6 default 1 MHz (the paper works in units of fs)", min=0.0, max=1.0e10,
              min_exclusive=True),
    ParamSpec("f0_hz", _F0, "Hz", "resonator natural frequency f0 (must be < fs/2)",
              "Colinet Sec. 6: f0 = 0.05 fs (oversampling ratio 20)", min=0.0, max=5.0e9,
              min_exclusive=True),
    ParamSpec("quality_factor", _Q, "-", "quality factor Q of eq. (7) (> 0.5: underdamped)",
              "Colinet Sec. 6: Q = 100", min=0.5, max=1.0e7, min_exclusive=True),
    ParamSpec("pulse_amplitude", _U, "V",
              "pulse height U (one sample long), normalised input volts of eq. (7)",
              "chosen for a steady amplitude ~0.5 V: U = A(1-exp(-pi/2Q))/cos(pi f0/fs), A = 0.5 V",
              min=0.0, max=1.0, min_exclusive=True),
    ParamSpec("output_noise_std", 0.0, "V", "std of white noise b added at the resonator output "
              "(modulator input)", "Colinet Sec. 6: 'of the order of the signal' (scenarios set "
              "~0.5 V); default 0", min=0.0, max=10.0),
    ParamSpec("state_noise_std", 0.0, "V", "std of thermomechanical force noise added to u each "
              "sample (process noise f of eq. (2))", "Colinet Sec. 7; default 0 (paper's Fig. 5)",
              min=0.0, max=1.0),
    ParamSpec("mode", "observer", "-", "pulse controller: zero crossings of the Kalman estimate "
              "(observer, Fig. 4) or of the decoded bit stream (comparator, Fig. 1)",
              "Colinet Figs. 1 and 4", choices=("comparator", "observer")),
    ParamSpec("comparator_input", "resonator", "-", "comparator mode: signal whose zero "
              "crossings fire the pulses: the noisy resonator output y+b (Fig. 1's one-bit "
              "comparator) or the decoded bit stream", "Colinet Fig. 1 (see module doc)",
              choices=("resonator", "bitstream")),
    ParamSpec("comparator_window", 5, "samples", "comparator mode: bits summed to decode the "
              "position (odd; 1 = raw bit stream)", "simplest boxcar decoder; 5 samples = 1/4 "
              "period at f0 = 0.05 fs", min=1, max=1001),
    ParamSpec("f0_drift_ppm_per_s", 0.0, "ppm/s", "linear drift of the true f0",
              "scenario knob; default none", min=-1.0e6, max=1.0e6),
    ParamSpec("f0_step_fraction", 0.0, "-", "relative step of the true f0 at f0_step_time_s",
              "scenario knob (acceptance: +0.02)", min=-0.5, max=0.5),
    ParamSpec("f0_step_time_s", 0.0, "s", "time of the f0 step (ignored if the fraction is 0)",
              "scenario knob", min=0.0, max=1.0e9),
    ParamSpec("observer_f0_error", 0.0, "-", "fractional error of f0 in the observer's model",
              "Colinet Sec. 7, Fig. 6: 5 % error", min=-0.5, max=0.5),
    ParamSpec("observer_state_noise_std", 0.0, "V", "force-noise std the observer assumes",
              "Colinet Sec. 7: F = 0 when the state noise is absent", min=0.0, max=1.0),
    ParamSpec("observer_initial_std", 0.0, "V", "std of the observer's initial resonator "
              "position/velocity uncertainty (0: it knows the rest start)",
              "start-up rule of this device (resonator at rest at k = 0)", min=0.0, max=10.0),
    ParamSpec("quantization_var", DEFAULT_QUANTIZATION_VAR, "V^2",
              "quantisation-error variance assumed by the observer",
              "Delta^2/12 with Delta = 2 V (one-bit +-1 V)", min=0.0, max=10.0,
              min_exclusive=True),
    ParamSpec("quantizer_gain", 1.0, "-", "quantiser gain kappa assumed by the in-loop observer "
              "(v = kappa q + w; 1: paper's eqs. (11)-(12))", "Bussgang alternative: "
              "sqrt(2/pi)/0.64 = 1.247 (mems_estimation.kalman_observer.bussgang_quantizer)",
              min=0.0, max=10.0, min_exclusive=True),
    ParamSpec("sd_feedforward", 0.5, "-", "modulator input feed-in c into the 2nd integrator "
              "(0.5: STF of eq. (11); 0: plain double loop, STF 0.5 z^-2/D)",
              "Colinet eqs. (10)-(12), see mems_sim.sd_models", min=0.0, max=0.5),
    ParamSpec("fast", True, "-", "steady-state (DARE) gain for the in-loop observer",
              "speed option; the exact time-varying gain otherwise", ),
)


def validate_params(p: Mapping[str, Any]) -> None:
    """Cross-parameter checks of a resolved parameter dict.

    Raises:
        ParameterError: f0 (or f0 after the step) >= fs/2, or an even comparator window.
    """
    fs, f0 = p["sample_rate_hz"], p["f0_hz"]
    if not f0 < fs / 2:
        raise ParameterError(f"parameter 'f0_hz' = {f0!r} is out of range: must be below "
                             f"sample_rate_hz/2 = {fs / 2!r} Hz (Nyquist)")
    f1 = f0 * (1.0 + p["f0_step_fraction"])
    if not f1 < fs / 2:
        raise ParameterError(f"parameter 'f0_step_fraction' = {p['f0_step_fraction']!r} is out "
                             f"of range: f0 after the step ({f1!r} Hz) must be below "
                             f"sample_rate_hz/2 = {fs / 2!r} Hz")
    fm = f0 * (1.0 + p["observer_f0_error"])
    if not fm < fs / 2:
        raise ParameterError(f"parameter 'observer_f0_error' = {p['observer_f0_error']!r} is out "
                             f"of range: the observer's f0 ({fm!r} Hz) must be below fs/2")
    if p["comparator_window"] % 2 == 0:
        raise ParameterError(f"parameter 'comparator_window' = {p['comparator_window']!r} is "
                             f"invalid: must be odd (so the decoded signal is never 0)")


class SdFrame(NamedTuple):
    """One frame of the device.

    bits: (n,) int8 in {-1, +1} modulator output.  pulses: (n,) applied u(k), V
    (0 or +-pulse_amplitude; u(k) acts from k to k+1).  position: (n,) true y(k), V.
    velocity: (n,) true dy/dt(k), V/s.  f0: (n,) true f0 used from k to k+1, Hz.
    estimate: (n,) observer position estimate y(k|k), V (NaN in comparator mode).
    estimate_var: (n,) its variance, V^2 (NaN in comparator mode).
    """

    bits: np.ndarray
    pulses: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    f0: np.ndarray
    estimate: np.ndarray
    estimate_var: np.ndarray


@numba.njit(cache=True)
def _device_run(k0, n, fs, f0_base, Q, drift, step_frac, step_time, U, c_ff,
                out_noise, force_noise, st, zoh, sd, win, xp, P, A, B, C, Cp, F, G, M,
                Lss, cpk, ss_var, obs_mode, fast,
                bits, pulses, pos, vel, f0o, est, estv):
    # st = [y, ydot, s_prev, f0_cur, win_sum, win_pos]
    nx = xp.shape[0]
    xf = np.empty(nx)
    PC = np.empty(nx)
    L = np.empty(nx)
    AP = np.empty((nx, nx))
    tmp = np.empty(nx)
    W = win.shape[0]
    varying = drift != 0.0 or step_frac != 0.0
    nu = 0.0
    S = 1.0
    for i in range(n):
        k = k0 + i
        if varying:
            t = k / fs
            f0 = f0_base * (1.0 + drift * 1e-6 * t)
            if step_frac != 0.0 and t >= step_time:
                f0 = f0 * (1.0 + step_frac)
            if f0 != st[3]:
                resonator_zoh(f0, Q, fs, zoh)
                st[3] = f0
        else:
            f0 = f0_base
        y = st[0]
        yd = st[1]
        x_in = y + out_noise[i]
        v, q = sd_step(x_in, sd, c_ff)
        # position signal used by the controller
        if obs_mode:
            if fast:
                s_sig = ss_step6(xp, A, B, C, Lss, cpk, v, 0.0)
                sv = ss_var
            else:
                nu, S, s_sig, sv = kf_update(xp, P, C, G, Cp, v, xf, PC)
            est[i] = s_sig
            estv[i] = sv
        elif W == 0:
            s_sig = x_in
            est[i] = np.nan
            estv[i] = np.nan
        else:
            j = int(st[5])
            st[4] += v - win[j]
            win[j] = v
            st[5] = (j + 1) % W
            s_sig = st[4]
            est[i] = np.nan
            estv[i] = np.nan
        u = 0.0
        if k == 0:
            u = U
        else:
            sp = st[2]
            if (s_sig >= 0.0) != (sp >= 0.0):
                u = U if s_sig > sp else -U
        st[2] = s_sig
        if obs_mode:
            if fast:
                # ss_step advanced xp with u = 0; add the pulse effect B u
                for m in range(nx):
                    xp[m] += B[m] * u
            else:
                kf_predict(xp, P, A, B, F, M, u, nu, S, PC, L, AP, tmp)
        force = u + force_noise[i]
        st[0] = zoh[0] * y + zoh[1] * yd + zoh[4] * force
        st[1] = zoh[2] * y + zoh[3] * yd + zoh[5] * force
        bits[i] = v
        pulses[i] = u
        pos[i] = y
        vel[i] = yd
        f0o[i] = f0


class SdResonatorDevice:
    """Pulse-actuated resonator + one-bit sigma-delta + pulse controller, carried state.

    Args:
        params: overrides of :data:`RESONATOR_SPECS`; validated (ParameterError names
            the parameter, value and range; cross checks by :func:`validate_params`).
        seed: run seed for ``np.random.SeedSequence``.
    """

    def __init__(self, params: Mapping[str, Any] | None = None, seed: int = 0) -> None:
        p = resolve(RESONATOR_SPECS, params)
        validate_params(p)
        self.params = p
        self.seed = int(seed)
        gens = [np.random.Generator(np.random.PCG64(s))
                for s in np.random.SeedSequence(self.seed).spawn(2)]
        self._gen_b, self._gen_f = gens
        fs, f0, Q = p["sample_rate_hz"], p["f0_hz"], p["quality_factor"]
        self._zoh = np.empty(6)
        resonator_zoh(f0, Q, fs, self._zoh)
        self._st = np.array([0.0, 0.0, 0.0, f0, float(p["comparator_window"]), 0.0])
        # bit history (sum starts at +W); an empty window selects the analog comparator
        self._win = np.ones(p["comparator_window"] if p["comparator_input"] == "bitstream" else 0)
        self._sd = np.zeros(2)
        self.observer_mode = p["mode"] == "observer"
        self.model = observer_model(f0 * (1.0 + p["observer_f0_error"]), Q, fs,
                                    p["output_noise_std"], p["observer_state_noise_std"],
                                    p["quantization_var"], p["sd_feedforward"],
                                    quantizer_gain=p["quantizer_gain"])
        s0 = p["observer_initial_std"] ** 2
        self._xp = np.zeros(6)
        self._P = np.diag([s0, s0, 0.0, 0.0, 0.0, 0.0])
        if p["fast"]:
            ss = steady_state_gains(self.model)
            self._L = np.ascontiguousarray(ss["L"])
            self._cpk = float(self.model.C_pos @ ss["K"])
            self._ss_var = ss["pos_var"]
        else:
            self._L = np.zeros(6)
            self._cpk = 0.0
            self._ss_var = 0.0
        self._next = 0

    @property
    def next_index(self) -> int:
        """Index of the next sample to be produced."""
        return self._next

    @property
    def fs(self) -> float:
        """Sample rate, Hz."""
        return self.params["sample_rate_hz"]

    def step(self, n: int) -> SdFrame:
        """Produce the next n samples (see module doc for the per-sample equations)."""
        n = int(n)
        if n < 0:
            raise ValueError(f"n = {n} must be >= 0")
        p = self.params
        sb, sf = p["output_noise_std"], p["state_noise_std"]
        b = self._gen_b.standard_normal(n) * sb if sb > 0 else np.zeros(n)
        f = self._gen_f.standard_normal(n) * sf if sf > 0 else np.zeros(n)
        bits = np.empty(n)
        pulses = np.empty(n)
        pos = np.empty(n)
        vel = np.empty(n)
        f0o = np.empty(n)
        est = np.empty(n)
        estv = np.empty(n)
        m = self.model
        _device_run(self._next, n, p["sample_rate_hz"], p["f0_hz"], p["quality_factor"],
                    p["f0_drift_ppm_per_s"], p["f0_step_fraction"], p["f0_step_time_s"],
                    p["pulse_amplitude"], p["sd_feedforward"], b, f, self._st, self._zoh,
                    self._sd, self._win, self._xp, self._P, m.A, m.B, m.C, m.C_pos, m.F, m.G,
                    m.M, self._L, self._cpk, self._ss_var, self.observer_mode, p["fast"],
                    bits, pulses, pos, vel, f0o, est, estv)
        self._next += n
        return SdFrame(bits.astype(np.int8), pulses, pos, vel, f0o, est, estv)

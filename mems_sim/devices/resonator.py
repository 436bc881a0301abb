"""Pulse-actuated micro-resonator read through a one-bit second-order sigma-delta ADC.

Source: Colinet, Galayko & Juillard, "Pulse-actuated micromechanical resonator
using digital Kalman observer": resonator eqs. (7)-(9),
modulator eqs. (10)-(12), observer loop eq. (13) and Fig. 4, simulation set-up
Sec. 6 (f0 = 0.05 fs, Q = 100, output noise of the order of the signal).
Models and unit conventions are in :mod:`mems_sim.kernels.resonator_models` (position and
pulses in volts at the modulator input, H(s) = fs*w0/(s^2 + s w0/Q + w0^2)).

Per sample k (all carried across frames)::

    x(k)   = y(k) + b(k)                         b ~ N(0, output_noise_std^2)   [V]
    v(k), q(k) = modulator(x(k))                 eqs. (10)-(12), v in {-1, +1}
    s(k)   = position signal used by the controller (see below)
    u(k)   = pulse_amplitude * sign(s(k) - s(k-1))   if sign s(k) != sign s(k-1), else 0
             (``on_sample`` timing: one pulse per zero crossing fired at the sample
             instant, sign = direction of motion; sign(z) = +1 for z >= 0)
    [y, dy/dt](k+1) = Phi(f0(k)) [y, dy/dt](k) + g(k) + Gam(f0(k)) f(k),
                                                 f ~ N(0, state_noise_std^2) [V]

where g(k) is the exact effect of the pulse force (height u, width pulse_width_s, fired
at t_p = k T + s(k) T) over the interval: :func:`mems_sim.kernels.resonator_models.interval_input`
(the impulse response integrated over the part of the pulse inside the interval, the
tail outlasting it carried into the next one).  With pulse_width_s = T and s = 0 this is
the one-sample ZOH pulse Gam u(k) of eqs. (8)-(9).

Pulse timing (``pulse_timing``, observer mode; the comparator loop is always
``on_sample`` since the naive loop has no predictor):

* ``"sub_sample"`` (default): the pulse driver is timed by a clock much faster than
  the ADC (taken as continuous).  At each sample the controller takes the observer's
  a-posteriori estimate [y, dy/dt](k|k), predicts its free response with the model
  (eq. (7)) and, if it crosses zero within (w/2, 1 + w/2] T (w = pulse width / T),
  fires the pulse at s = t_c - w/2 so that the pulse is centred on the predicted
  crossing t_c (closed-form zero of the damped sinusoid,
  :func:`mems_sim.kernels.resonator_models.next_crossing`).  A crossing that an estimate update has
  moved before the window (sign of the prediction at w/2 differs from the sign expected
  at the end of the previous window) fires at once (s = 0).  This is the paper's claim
  that "the generated pulses happen exactly at the equilibrium position instants"
  (Sec. 6), which one-sample pulses at 20 samples per period cannot achieve (|x| up to
  sin(2 pi f0/fs) = 31 % of the amplitude at the first sample after a crossing).
* ``"on_sample"``: the rule above on s(k) = y(k|k), the pulse fired at the sample
  instant (s = 0); with pulse_width_s = 1/fs this is the original one-sample loop.

The observer's known-input model uses the same exact pulse term (model f0), so with
the exact model the estimate stays exact.  Truth also records the position at each
pulse's start (firing instant, at the start sample) and at its centre (at the sample
whose interval contains the centre).

Start-up (both modes): the resonator and the modulator start at rest (all
states 0) and a single kick u(0) = +pulse_amplitude is applied at k = 0 of the
device; from k = 1 the controller rule above applies.

Controller ``mode``:

* ``"observer"`` (Fig. 4): s(k) = y(k|k), the position estimate of the
  6-state Kalman observer (:class:`mems_sim.kernels.resonator_observer.KalmanObserver`
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

Default pulse amplitude: a pulse of height U and width w T adds about U w (V) to the
amplitude (the velocity jump fs w0 U w T over w0); with one pulse per half period the
steady amplitude A obeys A = A exp(-pi/(2Q)) + U w cos(phi) (phi: the phase of the pulse
centre from the crossing: 0 for sub-sample timing, ~pi f0/fs on average on sample
instants) -> U = A (1 - exp(-pi/(2Q)))/(w cos(phi)): 0.156 V for A = 0.5 V, Q = 100,
w = 0.05 (the default 50 ns pulses at 1 MHz), sub-sample.  Default width: short pulses
(the paper's premise, Sec. 1) so that the position stays within 0.8 % of the amplitude
over the whole pulse (pi f0/fs w = 0.008).

Quantiser (``quantizer``): ``one_bit`` (eqs. (10)-(12)) or ``gaussian``, its linear-Gaussian
stand-in v = q + w with w ~ N(0, quantization_var) white, in the same loop (the observer's
model of eq. (13) is then exact; the output is real-valued).

Determinism: ``np.random.SeedSequence(seed).spawn(2)`` -> one PCG64 stream for b,
one for f (and, with the stand-in, child 2 of the same sequence for w); drawn frame by frame,
so frames concatenate bit-identically.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numba
import numpy as np

from mems_sim.devices.resonator_specs import RESONATOR_SPECS, default_pulse_amplitude
from mems_sim.kernels.resonator_kf_steps import add_pulse_input, kf_predict6, kf_update6, ss_step6
from mems_sim.kernels.resonator_models import (
    interval_input,
    next_crossing,
    next_spill,
    resonator_zoh,
    resonator_zoh_dt,
    resonator_zoh_t,
    sd_step,
    sd_step_standin,
    segment_response,
)
from mems_sim.kernels.resonator_observer_model import (
    observer_model,
    steady_state_gains,
)
from mems_sim.params import (
    ParameterError,
    resolve,
)

__all__ = [
    "LOOP_MODEL_KEYS",
    "RESONATOR_SPECS",
    "validate_params",
    "SdFrame",
    "SdResonatorDevice",
    "default_pulse_amplitude",
]

#: The parameters a bench identification gives the in-loop observer's model
#: (RESONATOR_SPECS names): what an identified model's YAML holds.
LOOP_MODEL_KEYS = ("f0_hz", "quality_factor")


def validate_params(p: Mapping[str, Any]) -> None:
    """Cross-parameter checks of a resolved parameter dict.

    Raises:
        ParameterError: f0 (or f0 after the step) >= fs/2, a pulse longer than 1/fs, or an
            even comparator window.
    """
    fs, f0 = p["sample_rate_hz"], p["f0_hz"]
    if not f0 < fs / 2:
        raise ParameterError(
            f"parameter 'f0_hz' = {f0!r} is out of range: must be below "
            f"sample_rate_hz/2 = {fs / 2!r} Hz (Nyquist)"
        )
    f1 = f0 * (1.0 + p["f0_step_fraction"])
    if not f1 < fs / 2:
        raise ParameterError(
            f"parameter 'f0_step_fraction' = {p['f0_step_fraction']!r} is out "
            f"of range: f0 after the step ({f1!r} Hz) must be below "
            f"sample_rate_hz/2 = {fs / 2!r} Hz"
        )
    fm = f0 * (1.0 + p["observer_f0_error"])
    if not fm < fs / 2:
        raise ParameterError(
            f"parameter 'observer_f0_error' = {p['observer_f0_error']!r} is out "
            f"of range: the observer's f0 ({fm!r} Hz) must be below fs/2"
        )
    if not p["pulse_width_s"] * fs <= 1.0 + 1e-12:
        raise ParameterError(
            f"parameter 'pulse_width_s' = {p['pulse_width_s']!r} is out of "
            f"range: must be in (0, 1/sample_rate_hz = {1.0 / fs!r}] s"
        )
    if p["comparator_window"] % 2 == 0:
        raise ParameterError(
            f"parameter 'comparator_window' = {p['comparator_window']!r} is "
            f"invalid: must be odd (so the decoded signal is never 0)"
        )


class SdFrame(NamedTuple):
    """One frame of the device.

    bits: (n,) int8 in {-1, +1} modulator output (float64 v = q + w with the
    ``quantizer: gaussian`` stand-in).  pulses: (n,) height u(k) of the pulse
    fired in [k T, (k+1) T), V (0 or +-pulse_amplitude).  pulse_start: (n,) its firing
    offset after the sample instant, s (0 where no pulse).  pulse_width: (n,) its width, s
    (0 where no pulse).  position: (n,) true y(k), V.  velocity: (n,) true dy/dt(k), V/s.
    f0: (n,) true f0 used from k to k+1, Hz.  estimate: (n,) observer position estimate
    y(k|k), V (NaN in comparator mode).  estimate_var: (n,) its variance, V^2 (NaN in
    comparator mode).  x_pulse_start: (n,) true position at the firing instant of the
    pulse fired in interval k, V (0 where none).  x_pulse_center: (n,) true position at the
    centre of a pulse whose centre falls in [k T, (k+1) T), V (0 where none).
    """

    bits: np.ndarray
    pulses: np.ndarray
    pulse_start: np.ndarray
    pulse_width: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    f0: np.ndarray
    estimate: np.ndarray
    estimate_var: np.ndarray
    x_pulse_start: np.ndarray
    x_pulse_center: np.ndarray


@numba.njit(cache=True)
def _position_at(f0, Q, fs, y, yd, t, spill_u, spill_end, u, s, w, f, o2, z):
    """True position at t*T (0 <= t <= 1) inside an interval from the state [y, yd] at its
    start: free response Phi(t T) plus the force segments acting in it (previous pulse's
    tail, the new pulse, the ZOH force noise f), each by :func:`segment_response`."""
    resonator_zoh_dt(f0, Q, fs, t / fs, z)
    pos = z[0] * y + z[1] * yd
    if spill_u != 0.0:
        segment_response(f0, Q, fs, 0.0, spill_end, t, o2, z)
        pos += spill_u * o2[0]
    if u != 0.0:
        segment_response(f0, Q, fs, s, min(s + w, 1.0), t, o2, z)
        pos += u * o2[0]
    if f != 0.0:
        segment_response(f0, Q, fs, 0.0, 1.0, t, o2, z)
        pos += f * o2[0]
    return pos


@numba.njit(cache=True)
def _pulse_cache(f0, Q, fs, width, cache, o):
    """Per-f0 constants of a pulse of width w T (exact, closed-form exponentials), written
    to cache[o:o+15] = [f0, Phi(w/2 T) (4), Gam(w/2 T) (2), Phi(T) Phi(-w T) (4),
    Phi((1 - w) T) Gam(w T) (2), fs/w0, fs w0]."""
    h = resonator_zoh_t(f0, Q, fs, 0.5 * width / fs)
    cache[o] = f0
    for m in range(6):
        cache[o + 1 + m] = h[m]
    p = resonator_zoh_t(f0, Q, fs, 1.0 / fs)
    zw = resonator_zoh_t(f0, Q, fs, width / fs)
    idet = 1.0 / (zw[0] * zw[3] - zw[1] * zw[2])
    i11, i12, i21, i22 = zw[3] * idet, -zw[1] * idet, -zw[2] * idet, zw[0] * idet
    cache[o + 7] = p[0] * i11 + p[1] * i21
    cache[o + 8] = p[0] * i12 + p[1] * i22
    cache[o + 9] = p[2] * i11 + p[3] * i21
    cache[o + 10] = p[2] * i12 + p[3] * i22
    r = resonator_zoh_t(f0, Q, fs, (1.0 - width) / fs)
    cache[o + 11] = r[0] * zw[4] + r[1] * zw[5]
    cache[o + 12] = r[2] * zw[4] + r[3] * zw[5]
    w0 = 2.0 * math.pi * f0
    cache[o + 13] = fs / w0
    cache[o + 14] = fs * w0


@numba.njit(cache=True)
def _pulse_simple(f0, Q, fs, width, f0m, Qm, w0m, y, yd, f, u, s0, obs_mode, st, xp, cache):
    """Interval with a pulse wholly inside it and no tail of a previous one (the common
    case; kept out of the main loop with few array arguments, since it runs on every pulse).

    Exact: Phi((1 - s - w) T) = [Phi(T) Phi(-w T)] Phi(-s T), one matrix exponential
    Phi(s T) per pulse, the rest cached per f0 (:func:`_pulse_cache`; truth at cache[0:15],
    observer model at cache[15:30]).  Adds the observer model's pulse term to the predicted
    state xp (observer mode) and propagates the true state st piecewise over [0, s)
    (force f), the two halves of the pulse (f + u) and [s + w, 1) (f).
    Returns (true position at the firing instant, at the pulse centre), V."""
    if cache[0] != f0:
        _pulse_cache(f0, Q, fs, width, cache, 0)
    if s0 == 0.0:  # on-sample pulse: Phi(0) = I, Gam(0) = 0
        zs = (1.0, 0.0, 0.0, 1.0, 0.0, 0.0)
    else:
        zs = resonator_zoh_t(f0, Q, fs, s0 / fs)
    idet = 1.0 / (zs[0] * zs[3] - zs[1] * zs[2])
    if obs_mode:
        if cache[15] < 0.0:
            _pulse_cache(f0m, Qm, fs, width, cache, 15)
        if f0m == f0 and Qm == Q:
            zm = zs
            idm = idet
        elif s0 == 0.0:
            zm = (1.0, 0.0, 0.0, 1.0, 0.0, 0.0)
            idm = 1.0
        else:
            zm = resonator_zoh_t(f0m, Qm, fs, s0 / fs)
            idm = 1.0 / (zm[0] * zm[3] - zm[1] * zm[2])
        # Phi_m(-s T) [Phi_m((1 - w) T) Gam_m(w T)] u
        xp[0] += (zm[3] * cache[26] - zm[1] * cache[27]) * idm * u
        xp[1] += (-zm[2] * cache[26] + zm[0] * cache[27]) * idm * u / w0m
    a0 = zs[0] * y + zs[1] * yd + zs[4] * f
    a1 = zs[2] * y + zs[3] * yd + zs[5] * f
    x_s = a0
    fu = f + u
    c0 = cache[1] * a0 + cache[2] * a1 + cache[5] * fu
    c1 = cache[3] * a0 + cache[4] * a1 + cache[6] * fu
    x_c = c0
    a0 = cache[1] * c0 + cache[2] * c1 + cache[5] * fu
    a1 = cache[3] * c0 + cache[4] * c1 + cache[6] * fu
    i11 = zs[3] * idet
    i12 = -zs[1] * idet
    i21 = -zs[2] * idet
    i22 = zs[0] * idet
    r11 = cache[7] * i11 + cache[8] * i21
    r12 = cache[7] * i12 + cache[8] * i22
    r21 = cache[9] * i11 + cache[10] * i21
    r22 = cache[9] * i12 + cache[10] * i22
    # Gam(r T) from Phi(r T): Gam1 = (fs/w0) (1 - Phi11), Gam2 = fs w0 Phi12
    st[0] = r11 * a0 + r12 * a1 + cache[13] * (1.0 - r11) * f
    st[1] = r21 * a0 + r22 * a1 + cache[14] * r12 * f
    return x_s, x_c


@numba.njit(cache=True)
def _pulse_general(
    f0, Q, fs, width, f0m, Qm, w0m, y, yd, f, u, s0, obs_mode, st, zoh, carry, xp, gam_m
):
    """Interval with a tail of the previous pulse and/or a pulse outlasting it (rare):
    :func:`mems_sim.kernels.resonator_models.interval_input` for the observer model's pulse term and the
    truth, :func:`_position_at` for the true positions at the pulse instants (the centre
    possibly in the next interval: carry[4]).  Returns (x at firing, x at a centre), V."""
    z = np.empty(6)
    o2 = np.empty(2)
    eff = np.empty(2)
    sp = np.empty(2)
    wc = np.full(3, -1.0)
    x_s = 0.0
    x_c = 0.0
    if obs_mode and (u != 0.0 or carry[2] != 0.0):
        sp[0] = carry[2]
        sp[1] = carry[3]
        add_pulse_input(xp, f0m, Qm, fs, w0m, gam_m, sp, u, s0, width, eff, z, wc)
        carry[2] = sp[0]
        carry[3] = sp[1]
    if carry[4] >= 0.0:
        x_c = _position_at(f0, Q, fs, y, yd, carry[4], carry[0], carry[1], 0.0, 0.0, 1.0, f, o2, z)
        carry[4] = -1.0
    if u != 0.0:
        x_s = _position_at(f0, Q, fs, y, yd, s0, carry[0], carry[1], 0.0, 0.0, 1.0, f, o2, z)
        tcen = s0 + 0.5 * width
        if tcen <= 1.0:
            x_c = _position_at(f0, Q, fs, y, yd, tcen, carry[0], carry[1], u, s0, width, f, o2, z)
        else:
            carry[4] = tcen - 1.0
    gam_t = np.empty(2)
    gam_t[0] = zoh[4]
    gam_t[1] = zoh[5]
    wc[0] = -1.0
    interval_input(f0, Q, fs, gam_t, carry[0], carry[1], u, s0, width, eff, z, wc)
    sp[0] = carry[0]
    sp[1] = carry[1]
    next_spill(u, s0, width, sp)
    carry[0] = sp[0]
    carry[1] = sp[1]
    st[0] = zoh[0] * y + zoh[1] * yd + eff[0] + zoh[4] * f
    st[1] = zoh[2] * y + zoh[3] * yd + eff[1] + zoh[5] * f
    return x_s, x_c


# nogil: in a one-process graph the recorder's writer thread runs meanwhile
@numba.njit(cache=True, nogil=True)
def _device_run(
    k0,
    n,
    fs,
    f0_base,
    Q,
    drift,
    step_frac,
    step_time,
    U,
    width,
    sub_sample,
    c_ff,
    out_noise,
    force_noise,
    quant_noise,
    st,
    zoh,
    sd,
    win,
    xp,
    P,
    A,
    B,
    C,
    F,
    G,
    M,
    Lss,
    Kss,
    ss_var,
    obs_mode,
    fast,
    res_m,
    gam_m,
    pred,
    carry,
    bits,
    pulses,
    starts,
    widths,
    pos,
    vel,
    f0o,
    est,
    estv,
    x_start,
    x_center,
):
    # st = [y, ydot, s_prev (sign state in sub-sample mode), f0_cur, win_sum, win_pos]
    # carry = [truth spill u, truth spill end, observer spill u, observer spill end,
    #          pending pulse centre in the next interval (T, -1 none)]
    # pred = [Phi11(w/2), Phi12(w/2), Phi11(1 + w/2), Phi12(1 + w/2)] of the observer model
    PC = np.empty(6)
    L = np.empty(6)
    cache = np.full(30, -1.0)  # pulse constants: truth [0:15], observer model [15:30]
    W = win.shape[0]
    varying = drift != 0.0 or step_frac != 0.0
    f0m, Qm, w0m = res_m[0], res_m[1], res_m[3]
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
        if quant_noise.shape[0]:
            v, q = sd_step_standin(x_in, sd, c_ff, quant_noise[i])
        else:
            v, q = sd_step(x_in, sd, c_ff)
        # position signal used by the controller
        xf1 = 0.0
        if obs_mode:
            if fast:
                nu = v - (C[2] * xp[2] + C[3] * xp[3] + C[4] * xp[4] + C[5] * xp[5])
                s_sig = xp[0] + Kss[0] * nu
                xf1 = xp[1] + Kss[1] * nu
                sv = ss_var
            else:
                nu, S, s_sig, sv, xf1 = kf_update6(xp, P, C, G, v, PC)
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
        # ---- pulse decision: height u, firing offset s0 (fraction of T)
        u = 0.0
        s0 = 0.0
        if k == 0:
            u = U
            st[2] = 1.0
        elif obs_mode and sub_sample:
            # predict the estimate's free response over the window (w/2, 1 + w/2] T whose
            # crossing puts the centre of a pulse fired in [k, k+1) T on the crossing
            vd = xf1 * w0m
            up_lo = pred[0] * s_sig + pred[1] * vd >= 0.0
            up_hi = pred[2] * s_sig + pred[3] * vd >= 0.0
            was_up = st[2] > 0.0
            if up_lo != was_up:
                # the crossing moved before this window (estimate update): fire at once
                u = U if up_lo else -U
            elif up_hi != up_lo:
                tc = next_crossing(f0m, Qm, fs, s_sig, vd, 0.5 * width, 1.0 + 0.5 * width)
                if tc >= 0.0:
                    s0 = min(max(tc - 0.5 * width, 0.0), 1.0 - 1e-12)
                u = U if up_hi else -U
            st[2] = 1.0 if up_hi else -1.0
        else:
            sp = st[2]
            if (s_sig >= 0.0) != (sp >= 0.0):
                u = U if s_sig > sp else -U
            st[2] = s_sig
        # ---- observer time update (pulse term added below), truth update
        f = force_noise[i]
        if obs_mode:
            if fast:
                ss_step6(xp, A, B, C, Lss, 0.0, v, 0.0)
            else:
                kf_predict6(xp, P, A, F, M, nu, S, PC, L)
        quiet = carry[0] == 0.0 and carry[2] == 0.0 and carry[4] < 0.0
        if u == 0.0 and quiet:
            x_start[i] = 0.0
            x_center[i] = 0.0
            st[0] = zoh[0] * y + zoh[1] * yd + zoh[4] * f
            st[1] = zoh[2] * y + zoh[3] * yd + zoh[5] * f
        elif quiet and s0 + width <= 1.0:
            x_start[i], x_center[i] = _pulse_simple(
                f0, Q, fs, width, f0m, Qm, w0m, y, yd, f, u, s0, obs_mode, st, xp, cache
            )
        else:
            x_start[i], x_center[i] = _pulse_general(
                f0, Q, fs, width, f0m, Qm, w0m, y, yd, f, u, s0, obs_mode, st, zoh, carry, xp, gam_m
            )
        bits[i] = v
        pulses[i] = u
        starts[i] = s0 / fs
        widths[i] = width / fs if u != 0.0 else 0.0
        pos[i] = y
        vel[i] = yd
        f0o[i] = f0


class SdResonatorDevice:
    """Pulse-actuated resonator + one-bit sigma-delta + pulse controller, carried state.

    Args:
        params: overrides of :data:`RESONATOR_SPECS`; validated (ParameterError names
            the parameter, value and range; cross checks by :func:`validate_params`):
            the device as built (one draw of a batch, at its temperature).
        seed: run seed for ``np.random.SeedSequence``.
        nominal: the designer's values (default: ``params``): the in-loop observer's
            model (f0, Q) is designed from them, not from the device as built.
    """

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        seed: int = 0,
        nominal: Mapping[str, Any] | None = None,
    ) -> None:
        p = resolve(RESONATOR_SPECS, params)
        validate_params(p)
        self.params = p
        nom = p if nominal is None else resolve(RESONATOR_SPECS, nominal)
        self.seed = int(seed)
        gens = [
            np.random.Generator(np.random.PCG64(s))
            for s in np.random.SeedSequence(self.seed).spawn(2)
        ]
        self._gen_b, self._gen_f = gens
        # third child of the same seed sequence: the stand-in quantiser's noise
        self._gen_w = np.random.Generator(
            np.random.PCG64(np.random.SeedSequence(self.seed, spawn_key=(2,)))
        )
        fs, f0, Q = p["sample_rate_hz"], p["f0_hz"], p["quality_factor"]
        self._zoh = np.empty(6)
        resonator_zoh(f0, Q, fs, self._zoh)
        self._st = np.array([0.0, 0.0, 0.0, f0, float(p["comparator_window"]), 0.0])
        # bit history (sum starts at +W); an empty window selects the analog comparator
        self._win = np.ones(p["comparator_window"] if p["comparator_input"] == "bitstream" else 0)
        self._sd = np.zeros(2)
        self.observer_mode = p["mode"] == "observer"
        self.model = observer_model(
            nom["f0_hz"] * (1.0 + p["observer_f0_error"]),
            nom["quality_factor"],
            fs,
            p["output_noise_std"],
            p["observer_state_noise_std"],
            p["quantization_var"],
            p["sd_feedforward"],
            quantizer_gain=p["quantizer_gain"],
        )
        s0 = p["observer_initial_std"] ** 2
        self._xp = np.zeros(6)
        self._P = np.diag([s0, s0, 0.0, 0.0, 0.0, 0.0])
        if p["fast"]:
            ss = steady_state_gains(self.model)
            self._L = np.ascontiguousarray(ss["L"])
            self._K = np.ascontiguousarray(ss["K"])
            self._ss_var = ss["pos_var"]
        else:
            self._L = np.zeros(6)
            self._K = np.zeros(6)
            self._ss_var = 0.0
        m = self.model
        self.width = p["pulse_width_s"] * fs  # fraction of T
        self.sub_sample = self.observer_mode and p["pulse_timing"] == "sub_sample"
        self._res_m = np.array([m.f0, m.Q, m.fs, m.w0])
        # free-response rows Phi(w/2 T)[0, :] and Phi((1 + w/2) T)[0, :] of the model
        z = np.empty(6)
        self._pred = np.empty(4)
        resonator_zoh_dt(m.f0, m.Q, fs, 0.5 * self.width / fs, z)
        self._pred[0:2] = z[0:2]
        resonator_zoh_dt(m.f0, m.Q, fs, (1.0 + 0.5 * self.width) / fs, z)
        self._pred[2:4] = z[0:2]
        self._carry = np.array([0.0, 0.0, 0.0, 0.0, -1.0])
        self._zeros = np.zeros(0)
        self._next = 0

    def retune(self, params: Mapping[str, Any]) -> None:
        """The device's physical parameters moved (a temperature change): the resonator
        (f0, Q) follows ``params`` from the next sample on, re-discretised; the state, the
        modulator, the in-loop observer (the designer's model) and the noise streams are
        kept."""
        p = resolve(RESONATOR_SPECS, params)
        validate_params(p)
        self.params = p
        resonator_zoh(p["f0_hz"], p["quality_factor"], p["sample_rate_hz"], self._zoh)
        self._st[3] = p["f0_hz"]
        if p["f0_drift_ppm_per_s"] != 0.0 or p["f0_step_fraction"] != 0.0:
            self._st[3] = np.nan  # a varying f0: re-discretised at the next sample

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
        if sf > 0:
            f = self._gen_f.standard_normal(n) * sf
        else:  # shared read-only zeros (speed)
            if self._zeros.shape[0] < n:
                self._zeros = np.zeros(n)
            f = self._zeros[:n]
        standin = p["quantizer"] == "gaussian"
        wq = (
            self._gen_w.standard_normal(n) * math.sqrt(p["quantization_var"])
            if standin
            else np.zeros(0)
        )
        out = np.empty((11, n))  # rows: the SdFrame fields, in order
        m = self.model
        fs = p["sample_rate_hz"]
        _device_run(
            self._next,
            n,
            fs,
            p["f0_hz"],
            p["quality_factor"],
            p["f0_drift_ppm_per_s"],
            p["f0_step_fraction"],
            p["f0_step_time_s"],
            p["pulse_amplitude"],
            self.width,
            self.sub_sample,
            p["sd_feedforward"],
            b,
            f,
            wq,
            self._st,
            self._zoh,
            self._sd,
            self._win,
            self._xp,
            self._P,
            m.A,
            m.B,
            m.C,
            m.F,
            m.G,
            m.M,
            self._L,
            self._K,
            self._ss_var,
            self.observer_mode,
            p["fast"],
            self._res_m,
            m.gam,
            self._pred,
            self._carry,
            *out,
        )
        self._next += n
        bits = out[0]
        return SdFrame(bits if standin else bits.astype(np.int8), *out[1:])

"""The f0 derivatives of the sigma-delta resonator's closed-form discretisation, for the
adaptive observer's Jacobian (Colinet, Galayko & Juillard, eqs. (7)-(9) differentiated).

:func:`_zoh_dlog_t` gives the closed-form ZOH over an interval with its logarithmic f0
derivative at fixed Q (Phi and Gam differentiated in closed form; agrees with a
Richardson-extrapolated central difference to ~1e-11), from the same exp/sin/cos as the
transition itself; :func:`_pulse_dlog` forms the exact pulse term of sub-sample pulses with
its f0 derivative (the product rule on the two sub-sample discretisations of each pulse
segment). The velocity is scaled by the observer's fixed w_ref = 2 pi f0_init [rad/s].
"""

from __future__ import annotations

import numba

from mems_sim.kernels.resonator_models import (
    interval_input,
    resonator_zoh_parts,
    resonator_zoh_t,
)

#: Relative step of the central difference in Q (estimate_q).
_H = 1e-7


@numba.njit(cache=True, inline="always")
def _res_scaled(f0, Q, fs, wref, out):
    """Scaled resonator transition: out = [P11, P12*wref, P21/wref, P22, G1, G2/wref]
    (:func:`mems_sim.kernels.resonator_models.resonator_zoh_t` over T = 1/fs; inlined: three
    calls per sample)."""
    _scaled_into(resonator_zoh_t(f0, Q, fs, 1.0 / fs), 0, wref, out)


@numba.njit(cache=True, inline="always")
def _scaled_into(z, k, wref, out):
    """out = z[k:k+6] = [P11, P12, P21, P22, G1, G2] with the velocity scaled by wref [rad/s]:
    [P11, P12*wref, P21/wref, P22, G1, G2/wref]."""
    out[0] = z[k]
    out[1] = z[k + 1] * wref
    out[2] = z[k + 2] / wref
    out[3] = z[k + 3]
    out[4] = z[k + 4]
    out[5] = z[k + 5] / wref


@numba.njit(cache=True, inline="always")
def _zoh_dlog_t(f0, Q, fs, dt):
    """Closed-form ZOH of eq. (7) over dt and its logarithmic f0 derivative at fixed Q, fs, dt.

    The first six values are those of
    :func:`mems_sim.kernels.resonator_models.resonator_zoh_t` (Colinet, Galayko &
    Juillard, eqs. (7)-(9); the same operations, so the same floats):
    [Phi11 (1), Phi12 (s), Phi21 (1/s), Phi22 (1), Gam1 (1), Gam2 (1/s)].  The last six
    are f0 d/df0 of each (same units), by differentiating that closed form: with
    w0 = 2 pi f0, sigma = w0/(2Q), wd = w0 sqrt(1 - 1/(4Q^2)), a = sigma dt, th = wd dt,
    kappa = sigma/wd (independent of f0), E = exp(-a), C = E cos th, S = E sin th,
    a and th are proportional to f0, so f0 d/df0 maps E -> -a E, cos th -> -th sin th,
    sin th -> th cos th, and

        f0 dPhi11/df0 = -a Phi11 + th (kappa C - S)
        f0 dPhi12/df0 = -(1 + a) Phi12 + dt C
        f0 dPhi21/df0 = -w0^2 ((1 - a) Phi12 + dt C)          (Phi21 = -w0^2 Phi12)
        f0 dPhi22/df0 = -a Phi22 - th (S + kappa C)
        f0 dGam1/df0  = -(fs/w0) (f0 dPhi11/df0 + 1 - Phi11)   (Gam1 = fs (1 - Phi11)/w0)
        f0 dGam2/df0  = fs w0 (dt C - a Phi12)                 (Gam2 = fs w0 Phi12)

    One exp/sin/cos set for both (the central difference it replaces needed three).
    dt = 0 gives Phi = I, Gam = 0 and zero derivatives.

    Args:
        f0: natural frequency, Hz (> 0). Q: quality factor (> 0.5). fs: sample rate, Hz.
        dt: duration, s (>= 0).
    """
    w0, sig, wd, E, c, s, p11, p12, p22, g = resonator_zoh_parts(f0, Q, fs, dt)
    a = sig * dt
    th = wd * dt
    kap = sig / wd
    Ec = E * c
    Es = E * s
    d11 = th * (kap * Ec - Es) - a * p11
    d12 = dt * Ec - (1.0 + a) * p12
    d21 = -w0 * w0 * ((1.0 - a) * p12 + dt * Ec)
    d22 = -a * p22 - th * (Es + kap * Ec)
    dg1 = -fs / w0 * (d11 + (1.0 - p11))
    dg2 = g * (dt * Ec - a * p12)
    return (
        p11,
        p12,
        -w0 * w0 * p12,
        p22,
        g * (1.0 - p11) / (w0 * w0),
        g * p12,
        d11,
        d12,
        d21,
        d22,
        dg1,
        dg2,
    )


@numba.njit(cache=True, inline="always")
def _res_scaled_dlog(f0, Q, fs, wref, out, dout):
    """:func:`_res_scaled` (the same floats) and f0 d/df0 of it at fixed Q, analytic
    (:func:`_zoh_dlog_t` with dt = T = 1/fs).  The Jacobian column with respect to
    d = f0/f0_init - 1 is (f0_init/f0) times f0 d/df0 (d/dd = f0_init d/df0).

    Args:
        f0 (Hz), Q, fs (Hz): model. wref: velocity scale 2 pi f0_init, rad/s.
        out: (6,) [P11, P12*wref, P21/wref, P22, G1, G2/wref].  dout: (6,) f0 d out/df0
            (same units as out).
    """
    z = _zoh_dlog_t(f0, Q, fs, 1.0 / fs)
    _scaled_into(z, 0, wref, out)
    _scaled_into(z, 6, wref, dout)


@numba.njit(cache=True, inline="always")
def _seg_val_dlog(f0, Q, fs, dt_gam, dt_phi):
    """Phi(dt_phi) Gam(dt_gam), the response dt_phi after its end to a unit force held for
    dt_gam (eqs. (7)-(9) over sub-sample durations; the operations of
    :func:`mems_sim.kernels.resonator_models.segment_response`, so the same floats), and
    f0 d/df0 of it at fixed Q by the product rule on :func:`_zoh_dlog_t`.

    Args:
        f0 (Hz), Q, fs (Hz): model. dt_gam, dt_phi: durations, s.
    Returns:
        (dy (V), d(dy/dt) (V/s), f0 d/df0 of each) per V of force.
    """
    A = _zoh_dlog_t(f0, Q, fs, dt_gam)
    B = _zoh_dlog_t(f0, Q, fs, dt_phi)
    v0 = B[0] * A[4] + B[1] * A[5]
    v1 = B[2] * A[4] + B[3] * A[5]
    d0 = B[6] * A[4] + B[0] * A[10] + B[7] * A[5] + B[1] * A[11]
    d1 = B[8] * A[4] + B[2] * A[10] + B[9] * A[5] + B[3] * A[11]
    return v0, v1, d0, d1


@numba.njit(cache=True)
def _pulse_dlog(f0, Q, fs, g1, g2, dg1, dg2, spill_u, spill_end, u, s, w, out):
    """Exact pulse term of one sample interval and f0 d/df0 of it at fixed Q.

    The term is that of :func:`mems_sim.kernels.resonator_models.interval_input` (Colinet,
    Galayko & Juillard, eqs. (7)-(9) integrated over the pulse: a pulse of height u fired at
    s T of width w T contributes Phi((1 - s - w) T) Gam(w T) u if it ends inside the
    interval, Gam((1 - s) T) u if it outlasts it, Gam(T) u for a one-sample pulse; the tail
    [0, e T) of the previous pulse, e = min(spill_end, 1), contributes
    Phi((1 - e) T) Gam(e T) spill_u), with the same cases and operations, so the same
    floats; its derivative comes from the same exp/sin/cos (:func:`_seg_val_dlog`), where a
    central difference needed the term twice more.

    Args:
        f0 (Hz), Q, fs (Hz): model. g1 (1), g2 (1/s): the one-sample Gam(T); dg1, dg2:
        f0 dGam(T)/df0 (:func:`_zoh_dlog_t`). spill_u (V), spill_end (fraction of T):
        previous pulse's tail. u (V), s, w (fractions of T): new pulse.
        out: (4,) filled with [dy (V), d(dy/dt) (V/s)] and f0 d/df0 of each.
    """
    v0 = 0.0
    v1 = 0.0
    d0 = 0.0
    d1 = 0.0
    if u != 0.0:
        if s == 0.0 and w == 1.0:
            v0 = g1 * u
            v1 = g2 * u
            d0 = dg1 * u
            d1 = dg2 * u
        else:
            if s + w <= 1.0:  # whole pulse inside
                a0, a1, b0, b1 = _seg_val_dlog(f0, Q, fs, w / fs, (1.0 - s - w) / fs)
            else:  # outlasts the interval: its part [s, 1)
                a0, a1, b0, b1 = _seg_val_dlog(f0, Q, fs, (1.0 - s) / fs, 0.0)
            v0 = a0 * u
            v1 = a1 * u
            d0 = b0 * u
            d1 = b1 * u
    if spill_u != 0.0:
        e = spill_end if spill_end < 1.0 else 1.0
        a0, a1, b0, b1 = _seg_val_dlog(f0, Q, fs, e / fs, (1.0 - e) / fs)
        v0 = v0 + spill_u * a0
        v1 = v1 + spill_u * a1
        d0 += spill_u * b0
        d1 += spill_u * b1
    out[0] = v0
    out[1] = v1
    out[2] = d0
    out[3] = d1


@numba.njit(cache=True)
def _pulse_scaled(f0, Q, fs, wref, r, spill, u, s, w, out, z, g):
    """Scaled exact pulse term of the interval (see mems_sim.kernels.resonator_models.interval_input) at
    the model (f0, Q); r: scaled transition from :func:`_res_scaled` (for Gam(T))."""
    g[0] = r[4]
    g[1] = r[5] * wref
    g[2] = -1.0  # no width cache: f0 changes every call
    interval_input(f0, Q, fs, g[0:2], spill[0], spill[1], u, s, w, out, z, g[2:5])
    out[1] /= wref

"""Piezo tilt micro-stage with rotational parallel-plate capacitive sensing (emulator core).

Source: Y. Chen, "High-accuracy Motion Estimation for MEMS Devices with Capacitive
Sensors", PhD thesis, U. Michigan 2018, chapter 3:
stage tilt mode eqs. (31)-(34), Table 3.3; capacitance eqs. (35)-(47), Tables A.1/A.2;
transimpedance readout eqs. (28)-(30); feedthrough cancellation sec. 3.5.4;
off-axis rejection eqs. (56)-(57); LDV reference sec. 3.5.2 / 3.5.4.

Per stage sample k (sample period dt = 1/fs, everything carried across frames)::

    u(k)        drive voltage the DAC holds over [t_k, t_k+1)  (sinusoid, schedule)
    x(k+1)      = A_d x(k) + B_d (u(k) + w(k))         main axis, exact ZOH of eqs. (31)-(33)
    x_off(k+1)  = A_d x_off(k) + B_d c_off (u(k) + w(k))   off axis (coupling c_off)
    y_c(k)      = -V_b(k) R_s dC_c/dt (k)  + feedthrough_c(k) + n_c(k)     eq. (30), per channel
    dC_c/dt     = dC/dtheta_X * omega_X + dC/dtheta_Y * omega_Y            eq. (43), dual-axis C
    feedthrough = -R_s C_ft,c du/dt (the parasitic capacitance C_ft from the drive to the
                  amplifier input carries a current C_ft du/dt; du/dt of the DAC's
                  reconstruction (analog) output, i.e. of the continuous sinusoid)
    code_c(k)   = round(y_c(k) / lsb) clipped to the ADC range (ideal ADC, the default), or
                  the code of channel c's converter with static errors (offset, gain, INL,
                  DNL, missing codes; :mod:`mems_sim.devices.stage_readout`)

``V_b`` is the sensing bias: ON on odd drive periods, OFF on even ones (period index =
floor(drive phase / 2 pi)); schedule changes take effect only at the start of an even
(bias-off) period, so each bias-on period is preceded by a bias-off period with the same
drive, and ``y_on(t) - y_off(t - T)`` cancels the feedthrough exactly (sec. 3.5.4).

Main axis convention: the stage tilts about Y (theta_Y, the paper's main axis of eq. 38);
the four channels 1A/1B/2A/2B sense theta_Y; the off axis is theta_X.

Misprints found in the source (the physics is implemented):

* Table A.1, channel 2A: ``w2 = 0.5W - W_SA - W_SB`` gives w2 < w1 (negative area). The
  outer right stator mirrors 1A: ``[0.5W - W_SA, 0.5W]``.
* Eq. (46): the leading minus sign is wrong; integrating eq. (40) with theta_X = 0 gives
  ``C = +eps (w4-w3)/tan(theta) * ln((D_n - w1 tan)/(D_n - w2 tan))`` (> 0 for w2 > w1).
* Eq. (42): the ``- w_Y tan(theta_X)`` term cancels in the four-term sum of eq. (41)
  (any separable term does); eq. (41) itself suffers catastrophic cancellation for small
  angles (1/(tan tan)), so the emulator evaluates eq. (40) by Gauss-Legendre quadrature
  and its derivatives with the w_Y integral in closed form (cancellation-free series) and
  Gauss-Legendre in w_X (exact to < 1e-11 relative for the gap modulation here, tested
  against a 16 x 16 quadrature).
* Eq. (56): E_y is a voltage and the motion ratio is dimensionless; E_y is normalised by
  the RMS of the single-axis signal.

Electronic noise (never tuned to a result) is the sum of the documented physical sources
of the transimpedance readout (:mod:`mems_sim.devices.stage_readout`), plus the ADC's own
quantisation (codes are rounded).  The transimpedance bandwidth is
assumed >> fs, so no signal phase lag is modelled.

Temperature (on by default; linear in T - T_ref): D_n(T) = D_n0 (1 + gap_tempco (T -
T_ref)) (the paper re-identifies D_n at 35.7 C, sec. 3.5.3/3.6.3, but gives no
coefficient: the default is an assumption); wn -30 ppm/K (silicon's Young's modulus about
-60 ppm/K, Hopcroft, Nix & Kenny, JMEMS 19(2) 2010, and wn ~ sqrt(E)); actuator gain b_c
+0.1 %/K (soft PZT d31, order +0.1 %/K near room temperature, Zhang, Wang, Kim & Cross,
J. Appl. Phys. 75(1) 1994); R_s, so eta, +25 ppm/K (thin-film resistor class, Vishay
TNPW). Table 3.3 gives wn, zeta, b_c at room temperature only. Manufacturing spread drawn
from ``device_seed`` (:func:`draw_spread`): zeta +-10 %, stator Y registration +-0.5 um,
channel gain mismatch. ``idealised`` restores the drift-free stage of Table 3.3 (no
coefficient on wn, b_c, eta; nominal zeta and registration; D_n still moves).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numba
import numpy as np

from mems_sim.devices.stage_capacitance import (
    _GL_W,
    _GL_X,
    EPS0,
    _grad_xy,
    _layout_extent,
    _tilt_terms,
    channel_limits,
    dcdtheta_single,
    dcdtheta_single_tan,
    dual_axis_capacitance,
    dual_axis_gradient,
    single_axis_dcdtheta,
)
from mems_sim.devices.stage_readout import (
    K_BOLTZMANN,
    channel_converters,
    convert_channels,
    readout_noise_std,
    requantize,
)
from mems_sim.devices.stage_specs import STAGE_SPECS, draw_spread, validate_params
from mems_sim.params import ParameterError, resolve

__all__ = [
    "STAGE_SPECS",
    "CHANNELS",
    "EPS0",
    "K_BOLTZMANN",
    "stage_matrices",
    "channel_limits",
    "dual_axis_capacitance",
    "dual_axis_gradient",
    "single_axis_dcdtheta",
    "dcdtheta_single",
    "dcdtheta_single_tan",
    "readout_noise_std",
    "off_axis_rejection",
    "DriveSchedule",
    "StageFrame",
    "MicroStage",
    "steady_amplitude",
    "validate_params",
    "LdvReference",
    "gap_at",
    "draw_spread",
    "off_axis_rejection_worst",
    "leakage_slope",
    "record",
]

CHANNELS = ("1A", "1B", "2A", "2B")


def gap_at(p: Mapping[str, Any], temperature_c: float | None = None) -> float:
    """D_n(T) = D_n0 (1 + gap_tempco (T - T_ref)), m."""
    t = p["temperature_c"] if temperature_c is None else temperature_c
    return p["neutral_gap_m"] * (1.0 + p["gap_tempco_per_k"] * (t - p["ref_temperature_c"]))


def stage_matrices(wn: float, zeta: float, b_c: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation (A_d, B_d) of eqs. (31)-(33) over dt (eq. 34), closed form.

    Args: wn rad/s, zeta -, b_c rad/s^2/V, dt s. Returns A_d (2x2), B_d (2,) [rad/V, rad/s/V].
    Valid for 0 < zeta < 1.
    """
    wd = wn * math.sqrt(1.0 - zeta * zeta)
    e = math.exp(-zeta * wn * dt)
    c, s = math.cos(wd * dt), math.sin(wd * dt)
    A = np.array(
        [
            [e * (c + zeta * wn / wd * s), e * s / wd],
            [-e * wn * wn / wd * s, e * (c - zeta * wn / wd * s)],
        ]
    )
    # B = A_c^-1 (A_d - I) B_c with A_c^-1 = [[-2 zeta/wn, -1/wn^2], [1, 0]]
    B = np.array([(1.0 - A[0, 0]) / (wn * wn) * b_c, A[1, 0] * (-1.0 / (wn * wn)) * b_c])
    return A, B


@numba.njit(cache=True)
def _readout(
    thx,
    thy,
    omx,
    omy,
    vb,
    fd,
    phs,
    seg,
    sega,
    dn,
    lim,
    eps,
    glx,
    glw,
    gain_rs,
    ft_rs,
    feedthrough,
    noise,
    noise_std,
    inv_lsb,
    code_max,
    y,
    codes,
):
    """Fused per-sample readout of eq. (30) for all channels (module doc):
    y_c = -V_b R_s g_c (dC_c/dtheta_X omega_X + dC_c/dtheta_Y omega_Y) - R_s C_ft,c du/dt
    + sigma n_c, codes = rint(y / lsb) clipped. gain_rs[c] = R_s g_c, ft_rs[c] = R_s C_ft,c;
    noise (n, nch) standard normal. Returns the number of clipped samples. No allocation.
    Serial on purpose: a prange version is 2x faster on an idle 2-core machine but 2-4x
    slower when the cores are shared (thread barriers under oversubscription)."""
    n = thx.shape[0]
    nch = lim.shape[0]
    nseg = sega.shape[0]
    sat = 0
    two_pi = 2.0 * math.pi
    wxmax, wymax = _layout_extent(lim)
    for i in range(n):
        tx, ty, sx, sy, small = _tilt_terms(thx[i], thy[i], dn, wxmax, wymax)
        dudt = 0.0
        if feedthrough:
            s = seg[i]
            a = sega[s] if s < nseg else 0.0
            dudt = two_pi * fd[i] * a * math.cos(two_pi * phs[i])
        for c in range(nch):
            gx, gy = _grad_xy(tx, ty, sx, sy, small, dn, lim, c, eps, glx, glw)
            dcdt = gx * omx[i] + gy * omy[i]
            v = -(vb[i] * gain_rs[c]) * dcdt - ft_rs[c] * dudt + noise[i, c] * noise_std
            y[i, c] = v
            q = np.rint(v * inv_lsb)
            if q > code_max or q < -code_max:
                sat += 1
                q = min(max(q, -code_max - 1.0), code_max)
            codes[i, c] = np.int32(q)
    return sat


def off_axis_rejection(
    theta_main: np.ndarray,
    omega_main: np.ndarray,
    ratio: float,
    gap_m: float,
    limits: np.ndarray,
    eta: float = 1.0,
    theta_off: np.ndarray | None = None,
    omega_off: np.ndarray | None = None,
) -> float:
    """R_off of eqs. (56)-(57): 1 - E_y / ratio for off-axis motion ``ratio`` times the
    main-axis motion (in phase), or the given ``theta_off``/``omega_off`` (whose amplitude
    ratio to the main axis is ``ratio``).

    E_y = RMS(y_single - y_dual) / RMS(y_single), all channels pooled: the leaked signal
    as a fraction of the single-axis signal (module doc, eq. 56 units). Under this reading
    a sensor equally sensitive to both axes leaks E_y = ratio and rejects nothing (R_off =
    0); a perfect one leaks nothing (R_off = 1). y_single from eqs. (46)-(47) (theta_X =
    0), y_dual from eqs. (40)-(45).
    """
    tx = ratio * theta_main if theta_off is None else np.asarray(theta_off, float)
    wx = ratio * omega_main if omega_off is None else np.asarray(omega_off, float)
    y_single = _single_axis_signal(theta_main, omega_main, gap_m, limits, eta)
    return _rejection(y_single, theta_main, omega_main, tx, wx, ratio, gap_m, limits, eta)


def _single_axis_signal(theta_main, omega_main, gap_m, limits, eta) -> np.ndarray:
    """eta dC/dtheta omega of the single-axis model eqs. (46)-(47), (n, nch)."""
    y_single = np.empty((np.size(theta_main), limits.shape[0]))
    for c in range(limits.shape[0]):
        w1, w2, w3, w4 = limits[c]
        hs = np.array([dcdtheta_single(t, gap_m, w1, w2, w4 - w3, EPS0) for t in theta_main])
        y_single[:, c] = eta * hs * omega_main
    return y_single


def _rejection(y_single, theta_main, omega_main, tx, wx, ratio, gap_m, limits, eta) -> float:
    """1 - E_y / ratio with the dual-axis signal of eqs. (40)-(45) (module doc)."""
    g = dual_axis_gradient(tx, theta_main, gap_m, limits)
    y_dual = eta * (g[:, :, 0] * wx[:, None] + g[:, :, 1] * omega_main[:, None])
    e_y = np.sqrt(np.mean((y_single - y_dual) ** 2)) / np.sqrt(np.mean(y_single**2))
    return float(1.0 - e_y / ratio)


def off_axis_rejection_worst(
    amplitude_rad: float,
    freq_hz: float,
    ratio: float,
    gap_m: float,
    limits: np.ndarray,
    phases_deg: Sequence[float] = tuple(range(0, 181, 5)),
    samples: int = 2000,
) -> tuple[float, float]:
    """Worst R_off (:func:`off_axis_rejection`) over the off-axis phase: main axis
    ``amplitude sin(2 pi f t)``, off axis ``ratio amplitude sin(2 pi f t + phi)`` for phi
    in ``phases_deg`` (0-180 deg covers every case: phi + 180 is the mirrored motion).
    Returns (R_off, phi [deg] where it is worst)."""
    ph = 2 * np.pi * np.arange(samples) / samples
    w = 2 * np.pi * freq_hz
    th, om = amplitude_rad * np.sin(ph), amplitude_rad * w * np.cos(ph)
    ys = _single_axis_signal(th, om, gap_m, limits, 1.0)
    worst = (math.inf, 0.0)
    for phi in phases_deg:
        a = math.radians(phi)
        tx = ratio * amplitude_rad * np.sin(ph + a)
        wx = ratio * amplitude_rad * w * np.cos(ph + a)
        worst = min(worst, (_rejection(ys, th, om, tx, wx, ratio, gap_m, limits, 1.0), float(phi)))
    return worst


def leakage_slope(
    amplitude_rad: float,
    freq_hz: float,
    gap_m: float,
    limits: np.ndarray,
    ratios: Sequence[float] = (0.01, 0.03, 0.1, 0.3),
    phase_deg: float = 0.0,
) -> float:
    """Log-log slope of the leaked signal E_y = ratio (1 - R_off) against the off-axis
    ratio (least squares): 2 for the symmetric layout of Table A.2 (second order), 1 with
    a stator misregistration in Y that dominates (first order)."""
    ph = 2 * np.pi * np.arange(2000) / 2000
    w = 2 * np.pi * freq_hz
    th, om = amplitude_rad * np.sin(ph), amplitude_rad * w * np.cos(ph)
    a = math.radians(phase_deg)
    ys = _single_axis_signal(th, om, gap_m, limits, 1.0)
    e = [
        r
        * (
            1.0
            - _rejection(
                ys,
                th,
                om,
                r * amplitude_rad * np.sin(ph + a),
                r * amplitude_rad * w * np.cos(ph + a),
                r,
                gap_m,
                limits,
                1.0,
            )
        )
        for r in ratios
    ]
    return float(np.polyfit(np.log(ratios), np.log(e), 1)[0])


def steady_amplitude(p: Mapping[str, Any], freq_hz: float, amp_v: float) -> float:
    """Steady tilt amplitude |b_c U / (wn^2 - w^2 + 2j zeta wn w)| [rad] of eqs. (31)-(33)."""
    wn = 2 * math.pi * p["natural_freq_hz"]
    w = 2 * math.pi * freq_hz
    return p["b_c"] * amp_v / abs(wn * wn - w * w + 2j * p["damping_ratio"] * wn * w)


class DriveSchedule:
    """Piecewise drive: list of segments (frequency Hz, amplitude V, number of drive periods).

    A segment lasts a whole, even number of periods so that every segment starts with a
    bias-off period (module doc). Zero amplitude is allowed (zero-input data for R).
    """

    def __init__(self, segments: Sequence[tuple[float, float, int]]) -> None:
        segs = []
        for i, (f, a, n) in enumerate(segments):
            if not (math.isfinite(f) and f > 0):
                raise ParameterError(f"drive segment {i}: frequency {f!r} Hz must be > 0")
            if not (math.isfinite(a) and a >= 0):
                raise ParameterError(f"drive segment {i}: amplitude {a!r} V must be >= 0")
            n = int(n)
            if n < 2 or n % 2:
                raise ParameterError(f"drive segment {i}: {n!r} periods must be even and >= 2")
            segs.append((float(f), float(a), n))
        if not segs:
            raise ParameterError("drive schedule is empty")
        self.segments = segs

    @classmethod
    def frequency_sweep(cls, f_lo=1711.0, f_hi=1719.0, step=1.0, amp=0.8, periods=400):
        """Stepped-sine sweep for identification (Table 3.2 row 1: 1711-1719 Hz, 0.8 V)."""
        n = int(round((f_hi - f_lo) / step)) + 1
        return cls([(f_lo + i * step, amp, periods) for i in range(n)])

    @classmethod
    def amplitude_sweep(cls, a_lo=1.0, a_hi=1.3, n_trials=7, freq=1700.0, periods=200):
        """Amplitude sweep for calibration (Table 3.2 row 3: 1700 Hz, 1.0-1.3 V)."""
        amps = np.linspace(a_lo, a_hi, n_trials)
        return cls([(freq, float(a), periods) for a in amps])

    def check_safe(self, p: Mapping[str, Any]) -> None:
        """Refuse a schedule whose steady tilt amplitude exceeds ``safe_tilt_rad``."""
        for i, (f, a, _) in enumerate(self.segments):
            th = steady_amplitude(p, f, a)
            # steady-state amplitude; the start-up transient of this lightly damped mode
            # stays below about twice it, and the gap closes only at 0.0138 rad
            if th > p["safe_tilt_rad"]:
                raise ParameterError(
                    f"drive segment {i} ({f} Hz, {a} V): steady tilt amplitude {th:.3g} rad "
                    f"exceeds safe_tilt_rad = {p['safe_tilt_rad']!r} rad"
                )

    def duration_s(self) -> float:
        """Total duration [s]."""
        return sum(n / f for f, _, n in self.segments)


class StageFrame(NamedTuple):
    """One frame. y: (n, 4) analog readout [V]; codes: (n, 4) int ADC codes; u: (n,) drive V;
    v_bias: (n,) bias V; f_drive: (n,) Hz; theta/omega: (n, 2) truth [rad, rad/s], columns
    (main, off); ldv: (n,) LDV omega of the main axis [rad/s]; segment: (n,) int segment index;
    phase: (n,) drive phase within the period [cycles]; saturated: number of clipped samples."""

    y: np.ndarray
    codes: np.ndarray
    u: np.ndarray
    v_bias: np.ndarray
    f_drive: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    ldv: np.ndarray
    segment: np.ndarray
    phase: np.ndarray
    saturated: int


@numba.njit(cache=True)
def _simulate(
    n,
    fs,
    segf,
    sega,
    segn,
    st,
    A,
    B,
    coup,
    wnoise,
    u,
    vb,
    fd,
    th,
    om,
    seg,
    phs,
    switching,
    v_bias,
    applied,
    frac,
):
    """Drive generator + stage dynamics over n samples; st = [theta, omega, thx, omx, phase,
    seg_idx, period_in_seg]. Phase in cycles since the start of the current segment (phs),
    and its fraction of a period (frac: numpy's ``phs % 1.0``); vb: the bias (V_bias or 0);
    applied: the drive incl. the amplifier noise wnoise, held over each sample."""
    nseg = segf.shape[0]
    for i in range(n):
        s = int(st[5])
        if s < nseg:
            f = segf[s]
            a = sega[s]
        else:
            f = segf[nseg - 1]
            a = 0.0
        ph = st[4]
        uu = a * math.sin(2.0 * math.pi * ph)
        per = int(math.floor(ph))
        on = 1.0
        if switching:
            on = 1.0 if (per % 2) == 1 else 0.0
        u[i] = uu
        phs[i] = ph
        # numpy's remainder(ph, 1.0) bit for bit (np.floor: a float, unlike math.floor)
        frac[i] = ph - np.floor(ph)
        vb[i] = on * v_bias
        fd[i] = f
        seg[i] = s
        th[i, 0] = st[0]
        om[i, 0] = st[1]
        th[i, 1] = st[2]
        om[i, 1] = st[3]
        ue = uu + wnoise[i]
        applied[i] = ue
        t0 = A[0, 0] * st[0] + A[0, 1] * st[1] + B[0] * ue
        t1 = A[1, 0] * st[0] + A[1, 1] * st[1] + B[1] * ue
        st[0] = t0
        st[1] = t1
        ue2 = coup * ue
        t0 = A[0, 0] * st[2] + A[0, 1] * st[3] + B[0] * ue2
        t1 = A[1, 0] * st[2] + A[1, 1] * st[3] + B[1] * ue2
        st[2] = t0
        st[3] = t1
        ph += f / fs
        if s < nseg and ph >= segn[s]:
            ph -= segn[s]
            st[5] = s + 1
        st[4] = ph


@numba.njit(cache=True)
def _ldv_run(th, om, u, hist, a10, a11, b1, bias, noise, noise_std, out):
    """LDV output of :meth:`MicroStage._ldv` over k = th.size samples: sample i is
    ``a10 theta + a11 omega + b1 u`` of the sample m = hist.shape[1] before it (the first m
    from ``hist``, the (3, m) history of theta, omega, u), + bias (+ noise[i] noise_std
    if noise_std > 0); then the history becomes the last m samples."""
    k = th.shape[0]
    m = hist.shape[1]
    for i in range(k):
        if i < m:
            t = hist[0, i]
            o = hist[1, i]
            v = hist[2, i]
        else:
            t = th[i - m]
            o = om[i - m]
            v = u[i - m]
        y = a10 * t + a11 * o + b1 * v
        y = y + bias
        if noise_std > 0:
            y = y + noise[i] * noise_std
        out[i] = y
    if k:
        # read index k + j >= j: every entry is read before it is overwritten
        for j in range(m):
            q = k + j
            if q < m:
                hist[0, j] = hist[0, q]
                hist[1, j] = hist[1, q]
                hist[2, j] = hist[2, q]
            else:
                hist[0, j] = th[q - m]
                hist[1, j] = om[q - m]
                hist[2, j] = u[q - m]


class MicroStage:
    """Stage + drive generator + 4-channel capacitive readout + ADC + LDV, carried state.

    Args:
        params: overrides of :data:`STAGE_SPECS` (validated).
        schedule: :class:`DriveSchedule` (checked against ``safe_tilt_rad``).
        seed: run seed (np.random.SeedSequence -> noise streams).
        fixed: names of parameters set explicitly, never drawn from ``device_seed``
            (default: the keys of ``params``). The parameters with a spread
            (``damping_ratio``, ``stator_offset_y_m``) are drawn around their value from
            ``device_seed`` unless ``idealised`` (:func:`draw_spread`).
    """

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        schedule: DriveSchedule | None = None,
        seed: int = 0,
        fixed: Sequence[str] | None = None,
    ) -> None:
        p = resolve(STAGE_SPECS, params)
        validate_params(p)
        self.nominal = dict(p)
        if not p["idealised"]:
            p = draw_spread(p, set(params or {}) if fixed is None else set(fixed))
        self.params = p
        #: tilt-mode damping ratio of this device (drawn, Table 3.3 nominal)
        self.zeta = p["damping_ratio"]
        self.fs = p["sample_rate_hz"]
        self.schedule = schedule or DriveSchedule.amplitude_sweep()
        self.schedule.check_safe(p)
        ss = np.random.SeedSequence(int(seed))
        gn, gw, gl = [np.random.Generator(np.random.PCG64(s)) for s in ss.spawn(3)]
        gmis = np.random.Generator(np.random.PCG64(p["device_seed"]))
        self._gen_noise, self._gen_w, self._gen_ldv = gn, gw, gl
        self.limits = channel_limits(p)  # as built (stator misregistration included)
        #: the electrode layout as designed (Table A.1/A.2), what an estimator knows
        self.design_limits = channel_limits(p, design=True)
        self.gain = 1.0 + p["channel_gain_mismatch"] * gmis.standard_normal(4)
        self.c_ft = p["feedthrough_cap_f"] * np.array([0.8, 1.1, 0.9, 1.2])
        self._ft_rs = p["r_s_ohm"] * self.c_ft
        self.temperature_c = p["temperature_c"]
        self._update_dynamics()
        wn = self.wn
        self.noise_std = readout_noise_std(p)
        self.lsb = p["adc_full_scale_v"] / 2 ** (p["adc_bits"] - 1)
        self.code_max = 2 ** (p["adc_bits"] - 1) - 1
        #: One converter per channel with the ADC static errors (stage_readout module doc);
        #: None when they are all 0 (the fused kernel's ideal ADC, bit for bit).
        self.converters = channel_converters(p, len(CHANNELS))
        self.w_std = p["drive_noise_density"] * math.sqrt(self.fs / 2)
        segs = np.array(self.schedule.segments, float)
        self._segf, self._sega = segs[:, 0].copy(), segs[:, 1].copy()
        self._segn = segs[:, 2].copy()
        self._st = np.zeros(7)
        self._next = 0
        #: Scheduled sensor faults (mems_sim.hardware.sensor_faults) on the readout voltages
        #: of CHANNELS before the ADC; None: no faults.
        self.faults = None
        d = p["ldv_delay_s"] * self.fs
        self._ldv_m = int(math.ceil(d))
        self._ldv_hist = np.zeros((3, self._ldv_m))
        self._ldv_AB = stage_matrices(wn, self.zeta, self.b_c, (self._ldv_m - d) / self.fs)

    def tempcos(self) -> tuple[float, float, float]:
        """(wn, b_c, R_s) temperature coefficients in effect [1/K]: the parameters, or 0
        when ``idealised``."""
        p = self.params
        if p["idealised"]:
            return 0.0, 0.0, 0.0
        return p["freq_tempco_per_k"], p["b_c_tempco_per_k"], p["readout_gain_tempco_per_k"]

    def _update_dynamics(self) -> None:
        """wn(T), b_c(T), R_s(T) (linear tempcos) and the ZOH matrices (eq. 34) at fs."""
        p = self.params
        dt_k = self.temperature_c - p["ref_temperature_c"]
        c_f, c_b, c_r = self.tempcos()
        self.wn = 2 * math.pi * p["natural_freq_hz"] * (1.0 + c_f * dt_k)
        self.b_c = p["b_c"] * (1.0 + c_b * dt_k)
        self._gain_rs = p["r_s_ohm"] * (1.0 + c_r * dt_k) * self.gain
        self.eta_true = -p["v_bias"] * self._gain_rs
        self.A, self.B = stage_matrices(self.wn, self.zeta, self.b_c, 1.0 / self.fs)
        if hasattr(self, "_ldv_m"):
            d = p["ldv_delay_s"] * self.fs
            self._ldv_AB = stage_matrices(self.wn, self.zeta, self.b_c, (self._ldv_m - d) / self.fs)

    @property
    def next_index(self) -> int:
        """Index of the next sample."""
        return self._next

    @property
    def finished(self) -> bool:
        """True once the whole schedule has been produced."""
        return self._st[5] >= len(self._segf)

    def total_samples(self) -> int:
        """Samples of the whole schedule (phase accumulation exact to the sample)."""
        return int(math.ceil(self.schedule.duration_s() * self.fs))

    def set_temperature(self, temperature_c: float) -> None:
        """Temperature input (moves D_n; wn, b_c, R_s with their tempcos unless idealised;
        module doc)."""
        spec = {s.name: s for s in STAGE_SPECS}["temperature_c"]
        self.temperature_c = spec.validate(float(temperature_c))
        self._update_dynamics()

    @property
    def gap(self) -> float:
        """Current true D_n [m]."""
        return gap_at(self.params, self.temperature_c)

    def _buffer(self, name: str, shape) -> np.ndarray:
        """A float64 scratch array of ``shape`` kept across frames (never returned)."""
        buf = self.__dict__.get(name)
        if buf is None or buf.shape != shape:
            buf = np.empty(shape)
            setattr(self, name, buf)
        return buf

    def step(self, n: int) -> StageFrame:
        """Produce the next n samples (module doc)."""
        n = int(n)
        if n < 0:
            raise ValueError(f"n = {n} must be >= 0")
        p = self.params
        u = np.empty(n)
        vb = np.empty(n)
        fd = np.empty(n)
        th = np.empty((n, 2))
        om = np.empty((n, 2))
        seg = np.empty(n, np.int64)
        phase = np.empty(n)
        applied = np.empty(n)
        phs = self._buffer("_phs_buf", (n,))
        if self.w_std > 0:
            w = self._gen_w.standard_normal(out=self._buffer("_w_buf", (n,)))
            w *= self.w_std
        else:
            w = np.zeros(n)
        _simulate(
            n,
            self.fs,
            self._segf,
            self._sega,
            self._segn,
            self._st,
            self.A,
            self.B,
            p["off_axis_coupling"],
            w,
            u,
            vb,
            fd,
            th,
            om,
            seg,
            phs,
            p["bias_switching"],
            float(p["v_bias"]),
            applied,
            phase,
        )
        # dual-axis sensor (main axis = Y, off axis = X), transimpedance readout, feedthrough
        # (du/dt of the generator's continuous sinusoid a sin(2 pi phase)), noise and ADC in
        # one pass (:func:`_readout`)
        noise = self._gen_noise.standard_normal(out=self._buffer("_noise_buf", (n, 4)))
        y = np.empty((n, 4))
        codes = np.empty((n, 4), np.int32)
        sat = _readout(
            th[:, 1],
            th[:, 0],
            om[:, 1],
            om[:, 0],
            vb,
            fd,
            phs,
            seg,
            self._sega,
            self.gap,
            self.limits,
            EPS0 * p["eps_r"],
            _GL_X,
            _GL_W,
            self._gain_rs,
            self._ft_rs,
            bool(p["feedthrough_enabled"]),
            noise,
            self.noise_std,
            1.0 / self.lsb,
            float(self.code_max),
            y,
            codes,
        )
        if self.faults:
            y = self.faults.apply(y, self._next)
        if self.converters is not None:
            codes, sat = convert_channels(self.converters, y)
        elif self.faults:
            codes, sat = requantize(y, 1.0 / self.lsb, float(self.code_max))
        self.last_applied = applied  # drive incl. amplifier noise, held over each sample
        ldv = self._ldv(th[:, 0], om[:, 0], applied)
        self._next += n
        return StageFrame(y, codes, u, vb, fd, th, om, ldv, seg, phase, sat)

    def _ldv(self, theta: np.ndarray, omega: np.ndarray, u: np.ndarray) -> np.ndarray:
        """LDV reference (sec. 3.5.2/3.5.4): main-axis omega(t - tau) + bias + white noise.

        The delayed rate is exact: the state at sample k - m (m = ceil(tau fs)) is propagated
        with its held input over the fractional time m/fs - tau (ZOH, eq. 34).
        """
        p = self.params
        k = omega.size
        Af, Bf = self._ldv_AB
        std = float(p["ldv_noise_std"])
        noise = self._gen_ldv.standard_normal(out=self._buffer("_ldv_buf", (k,))) if std > 0 else u
        out = np.empty(k)
        _ldv_run(
            theta,
            omega,
            u,
            self._ldv_hist,
            float(Af[1, 0]),
            float(Af[1, 1]),
            float(Bf[1]),
            float(p["ldv_bias"]),
            noise,
            std,
            out,
        )
        return out


class LdvReference:
    """Namespace doc: the LDV reference lives in :meth:`MicroStage._ldv` (truth + noise +
    6.9 us delay + constant bias, sec. 3.5.4); it is used for identification only."""


def record(stage: MicroStage, gyro=None, frame: int = 65536, n: int | None = None) -> dict:
    """Run ``stage`` (and an optional :class:`mems_sim.devices.stage_gyro.MemsGyro` on it) to the end
    of its schedule (or n samples) and return concatenated arrays (offline use: tests,
    identification, benchmarks). Keys: y [V, ADC-decoded], u, u_applied, v_bias, f_drive,
    phase, segment, cycle (period counter), theta, omega (n, 2), ldv; gyro_t, gyro_value,
    gyro_true, gyro_phase, gyro_cycle, gyro_segment when a gyro is given."""
    total = stage.total_samples() if n is None else int(n)
    parts: dict[str, list] = {}
    g_parts: dict[str, list] = {}
    done = 0
    while done < total:
        m = min(frame, total - done)
        k0 = stage.next_index
        f = stage.step(m)
        for key, val in (
            ("y", f.codes * stage.lsb),
            ("u", f.u),
            ("u_applied", stage.last_applied),
            ("v_bias", f.v_bias),
            ("f_drive", f.f_drive),
            ("phase", f.phase),
            ("segment", f.segment),
            ("theta", f.theta),
            ("omega", f.omega),
            ("ldv", f.ldv),
        ):
            parts.setdefault(key, []).append(val)
        if gyro is not None:
            gyro.temperature_c = stage.temperature_c
            g = gyro.step(
                k0,
                stage.fs,
                f.theta[:, 0],
                f.omega[:, 0],
                stage.last_applied,
                stage.wn,
                stage.zeta,
                stage.b_c,
            )
            g_parts.setdefault("gyro_t", []).append(g.t)
            g_parts.setdefault("gyro_value", []).append(g.value)
            g_parts.setdefault("gyro_true", []).append(g.omega_true)
        done += m
    out = {k: np.concatenate(v) for k, v in parts.items()}
    ph = out["phase"]
    out["cycle"] = np.concatenate([[0], np.cumsum(np.diff(ph) < 0)])
    out["fs"] = stage.fs
    out["temperature_c"] = stage.temperature_c
    if gyro is not None:
        out.update({k: np.concatenate(v) for k, v in g_parts.items()})
        kk = np.clip(np.floor(out["gyro_t"] * stage.fs).astype(np.int64), 0, ph.size - 1)
        frac = out["gyro_t"] * stage.fs - kk
        out["gyro_phase"] = (ph[kk] + frac * out["f_drive"][kk] / stage.fs) % 1.0
        out["gyro_cycle"] = out["cycle"][kk]
        out["gyro_segment"] = out["segment"][kk]
        out["gyro_k_true"] = gyro.scale_factor()
    return out

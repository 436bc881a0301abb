"""Streaming estimation of the shared-electrode micro-scanner on AMDM frames (Chen 2018,
"High-accuracy Motion Estimation for MEMS Devices with Capacitive Sensors", chapter 5):
drive alignment to the chain delay, the EKF or UKF with acquisition, and the per-period phase
shift and amplitude with their RMSE (eqs. (109)-(110), Table 5.3).

h(theta) is even: both filters may track the mirror image of theta; the phase (time from a
drive peak to the next extremum of theta, in [0, pi) of the motion period) and the amplitude
|theta| at the extrema are sign-invariant.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from mems_estimation.filters.scanner_amdm_ekf import ekf_run
from mems_estimation.filters.scanner_amdm_model import (
    resolve_estimator,
    scanner_model,
)
from mems_estimation.filters.scanner_amdm_ukf import ukf_run, ukf_weights
from mems_sim.kernels.divergence import covariance_ok, state_ok
from mems_sim.params import ParameterError


class DriveAligner:
    """Mean square of the applied voltage over each filter step, at the delayed times.

    Sample k of the AMDM stream describes t_k - delay; the filter step ending at k needs
    <V^2> over [t_{k-1} - delay, t_k - delay]: V_dr interpolated between drive samples
    (4-point Lagrange; linear interpolation flattens the drive peaks and biased the phase by
    ~0.05 deg), Simpson's rule, plus the carrier's V_c0^2/2.  Before the first drive sample
    V_dr(t_0) is used.
    """

    def __init__(self, delay_samples: float, carrier_ms: float) -> None:
        if not (delay_samples >= 0 and math.isfinite(delay_samples)):
            raise ParameterError(
                f"parameter 'chain_delay_s' gives {delay_samples!r} samples: allowed [0, inf)"
            )
        self.d = float(delay_samples)
        self.vc2 = float(carrier_ms)
        self._hist = np.zeros(0)
        self._hist0 = 0
        self._prev_v = None

    def _interp(self, s: np.ndarray) -> np.ndarray:
        """V_dr at fractional history positions s (4-point Lagrange, indices clamped)."""
        h = self._hist
        i = np.floor(s).astype(np.int64)
        f = s - i
        last = h.size - 1
        v = np.zeros_like(s)
        for off, w in (
            (-1, -f * (f - 1) * (f - 2) / 6.0),
            (0, (f + 1) * (f - 1) * (f - 2) / 2.0),
            (1, -(f + 1) * f * (f - 2) / 2.0),
            (2, (f + 1) * f * (f - 1) / 6.0),
        ):
            v += w * h[np.clip(i + off, 0, last)]
        return v

    def push(self, first: int, v: np.ndarray) -> np.ndarray:
        """Add drive samples first..first+n-1 [V]; return <V^2> (n,) for the same indices.

        <V^2>_k over [s_{k-1}, s_k], s = k - delay: Simpson's rule on the interpolated drive
        (end points and mid point), plus V_c0^2/2.
        """
        v = np.asarray(v, dtype=float)
        n = v.size
        if self._hist.size == 0:
            self._hist0 = first
        self._hist = np.concatenate((self._hist, v))
        k = first + np.arange(n)
        s = np.maximum(k - self.d - self._hist0, 0.0)
        sm = np.maximum(k - 0.5 - self.d - self._hist0, 0.0)
        vd = self._interp(s)
        vm = self._interp(sm)
        prev = np.concatenate(([vd[0] if self._prev_v is None else self._prev_v], vd[:-1]))
        self._prev_v = float(vd[-1])
        keep = int(math.ceil(self.d)) + 4
        if self._hist.size > keep:
            cut = self._hist.size - keep
            self._hist = self._hist[cut:]
            self._hist0 += cut
        return (prev * prev + 4.0 * vm * vm + vd * vd) / 6.0 + self.vc2


class ScannerFilter:
    """Streaming EKF or UKF on AMDM frames (state carried across frames), with acquisition.

    Acquisition (symmetry breaking): h is even and the dynamics odd, so x = 0 is a fixed
    point of the UKF (symmetric sigma points about 0 give P_xy = 0 exactly: no gain, ever)
    and below ~0.03 rad the motion is not observable at the paper's R.  The filter therefore
    waits ("acquiring", output x = 0 with the initial variances) until the AC SNR of y over
    one motion period exceeds ``acquire_snr``; it then starts at the largest |theta| of that
    period (theta from the positive root of h on 5-sample-smoothed y, omega = 0: an
    extremum) and runs forward ("tracking").  If the tracked mean falls inside one standard
    deviation of the origin (x^T P^-1 x < 1) for a whole period, the motion is lost and the
    filter goes back to acquiring.

    Args:
        kind: ``"ekf"`` or ``"ukf"``.
        params: overrides of :data:`ESTIMATOR_SPECS` (validated).
    """

    def __init__(self, kind: str, params: Mapping[str, Any] | None = None) -> None:
        if kind not in ("ekf", "ukf"):
            raise ParameterError(f"parameter 'kind' = {kind!r} is invalid: allowed 'ekf', 'ukf'")
        self.kind = kind
        self.p = p = resolve_estimator(params)
        self.model = scanner_model(p)
        self.wm, self.wc, self.gamma = ukf_weights(2, p["ukf_alpha"], p["ukf_beta"], p["ukf_kappa"])
        self.P0 = np.diag([p["initial_angle_std"] ** 2, p["initial_rate_std"] ** 2])
        self.x = np.zeros(2)
        self.P = self.P0.copy()
        wn = math.sqrt(p["spring_constant"] / p["inertia"])
        self.window = max(8, int(round(2.0 * math.pi / wn * p["sample_rate_hz"])))
        self.tracking = False
        self.acquisitions = 0
        self.pd_failures = 0
        self.samples = 0
        self.last_snr = math.nan
        self.resets = 0
        self._by = np.zeros(0)
        self._bv = np.zeros(0)

    def reset(self) -> None:
        """Re-initialise from the prior: x = 0, P = P0, acquiring (no buffered samples)."""
        self.x = np.zeros(2)
        self.P = self.P0.copy()
        self.tracking = False
        self._by = np.zeros(0)
        self._bv = np.zeros(0)
        self.resets += 1

    def start(self, x, P) -> None:
        """Start tracking from a given state x (2,) [rad, rad/s] and covariance P (2,2) (e.g. a
        deliberately wrong start: time to acquire, :func:`time_to_acquire`)."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        if x.shape != (2,) or P.shape != (2, 2) or not (state_ok(x) and covariance_ok(P)):
            raise ParameterError(
                "start state must be finite (2,) with a positive definite (2,2) covariance: "
                f"{x!r}, {P!r}"
            )
        self.x = x.copy()
        self.P = P.copy()
        self.tracking = True
        self._by = np.zeros(0)
        self._bv = np.zeros(0)

    def diverged(self) -> bool:
        """True if the state is not finite or the covariance not positive definite
        (:func:`~mems_sim.kernels.divergence.covariance_ok`)."""
        return not (state_ok(self.x, self._by, self._bv) and covariance_ok(self.P))

    def theta_abs(self, y: np.ndarray) -> np.ndarray:
        """|theta| from the positive root of h(theta) = y [rad] (clipped to [0, 2 theta_0])."""
        m = self.model.meas
        c = ((np.asarray(y, dtype=float) - m[4]) / m[3] - m[2]) / m[0]
        c = np.clip(c, math.exp(-4.0), 1.0)
        return m[1] * np.sqrt(-np.log(c))

    def run_frame(self, y, v2, predict_first, ox, op, on) -> int:
        """One call of the kernel (:func:`ekf_run` or :func:`ukf_run`) on a block: x and P
        carried in place, outputs into ox (n,2), op (n,3), on (n,). Returns the number of
        repaired covariances (also added to ``pd_failures``)."""
        md = self.model
        head = (y, v2, self.x, self.P, md.Phi, md.Gam, md.Q, md.meas, md.J, md.R, md.T)
        if self.kind == "ekf":
            bad = ekf_run(*head, predict_first, ox, op, on)
        else:
            bad = ukf_run(*head, self.wm, self.wc, self.gamma, predict_first, ox, op, on)
        self.pd_failures += int(bad)
        return int(bad)

    def _acquire(self, y, v2, ox, op, on) -> None:
        """Look for the first motion period in the buffered + new samples; start there."""
        n = y.size
        by = np.concatenate((self._by, y))
        bv = np.concatenate((self._bv, v2))
        off = by.size - n  # index of y[0] in the buffer
        W = self.window
        R = self.model.R
        if by.size >= W:
            c1 = np.concatenate(([0.0], np.cumsum(by)))
            c2 = np.concatenate(([0.0], np.cumsum(by * by)))
            mean = (c1[W:] - c1[:-W]) / W
            var = (c2[W:] - c2[:-W]) / W - mean * mean
            snr = (var - R) / R  # window ending at buffer index e = i + W - 1
            self.last_snr = float(snr[-1])
            hit = np.flatnonzero(snr > self.p["acquire_snr"])
            if hit.size:
                e0 = hit[0]
                ys = np.convolve(by, np.ones(5) / 5.0, mode="same")
                th = self.theta_abs(ys[e0 : e0 + W])
                ip = e0 + int(np.argmax(th))
                self.x[:] = (th[ip - e0], 0.0)
                self.P[:] = self.P0
                self.tracking = True
                self.acquisitions += 1
                self._by = np.zeros(0)
                self._bv = np.zeros(0)
                rest = slice(ip + 1, by.size)
                tail_y, tail_v = by[rest], bv[rest]
                k = tail_y.size
                tx, tp, tn = np.empty((k, 2)), np.empty((k, 3)), np.empty(k)
                self.run_frame(
                    np.ascontiguousarray(tail_y), np.ascontiguousarray(tail_v), True, tx, tp, tn
                )
                # publish the part that belongs to this frame
                j0 = max(ip + 1 - off, 0)
                s0 = j0 + off - (ip + 1)
                ox[j0:] = tx[s0:]
                op[j0:] = tp[s0:]
                on[j0:] = tn[s0:]
                if 0 <= ip - off < n:
                    ox[ip - off] = (th[ip - e0], 0.0)
                return
        self._by = by[-(W - 1) :] if W > 1 else np.zeros(0)
        self._bv = bv[-(W - 1) :] if W > 1 else np.zeros(0)

    def step(self, y: np.ndarray, v2: np.ndarray) -> dict[str, np.ndarray]:
        """Filter one frame. y (n,) [V]; v2 (n,) <V^2> [V^2] (:class:`DriveAligner`).

        Returns:
            dict ``x`` (n,2) [rad, rad/s], ``p`` (n,3) (P_tt, P_ww, P_tw), ``nis`` (n,),
            ``tracking`` (bool: the filter tracked motion at the end of the frame).
        """
        y = np.ascontiguousarray(y, dtype=float)
        v2 = np.ascontiguousarray(v2, dtype=float)
        n = y.size
        ox = np.zeros((n, 2))
        op = np.empty((n, 3))
        op[:] = (self.P0[0, 0], self.P0[1, 1], 0.0)
        on = np.zeros(n)
        if n:
            if self.tracking:
                self.run_frame(y, v2, True, ox, op, on)
                W = min(self.window, n)
                det = op[-W:, 0] * op[-W:, 1] - op[-W:, 2] ** 2
                q = (
                    op[-W:, 1] * ox[-W:, 0] ** 2
                    - 2 * op[-W:, 2] * ox[-W:, 0] * ox[-W:, 1]
                    + op[-W:, 0] * ox[-W:, 1] ** 2
                ) / det
                if n >= self.window and np.all(q < 1.0):
                    self.tracking = False
                    self.x[:] = 0.0
                    self.P[:] = self.P0
            else:
                self._acquire(y, v2, ox, op, on)
        self.samples += n
        return dict(x=ox, p=op, nis=on, tracking=self.tracking)


class PeriodEvents(NamedTuple):
    """Per-extremum results: t [s] (time of the extremum of theta), phase [rad] in [0, pi)
    (time from the previous drive peak / motion period x 2 pi), amplitude [rad] (|theta|
    at the extremum), and their variances (from the filter covariance; 0 for truth)."""

    t: np.ndarray
    phase: np.ndarray
    amplitude: np.ndarray
    var_t: np.ndarray
    var_phase: np.ndarray
    var_amplitude: np.ndarray


def _parabola(xm, x0, xp):
    """Vertex offset delta (samples) and value of the parabola through (-1, xm), (0, x0), (1, xp)."""
    den = xm - 2.0 * x0 + xp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(den != 0, 0.5 * (xm - xp) / den, 0.0)
    d = np.clip(d, -0.5, 0.5)
    return d, x0 - 0.25 * (xm - xp) * d


def _parabola_1(xm: float, x0: float, xp: float) -> tuple[float, float]:
    """:func:`_parabola` of one triple in Python floats (the same operations, equal bit for
    bit; a tenth of the time of the array version on scalars)."""
    den = xm - 2.0 * x0 + xp
    d = 0.5 * (xm - xp) / den if den != 0 else 0.0
    d = -0.5 if d < -0.5 else (0.5 if d > 0.5 else d)  # np.clip: NaN stays NaN
    return d, x0 - 0.25 * (xm - xp) * d


class PhaseAmplitudeTracker:
    """Streaming per-period phase shift and amplitude (Sec. 5.5.3, eqs. (109)-(110)).

    Drive peaks: local maxima of the drive samples (parabolic sub-sample interpolation).
    Angle extrema: |theta| maxima between Schmitt-trigger sign changes of theta (hysteresis
    +-``min_amplitude``/2, so wiggles below the motion floor make no extrema), parabolic
    interpolation; the first (possibly truncated) half-cycle is skipped.  For each extremum
    at t_e: phase = 2 pi (t_e - t_d)/T_m with t_d the last drive peak <= t_e and
    T_m = 2 x (drive period), i.e. in [0, pi): sign-invariant (module doc).

    Args:
        min_amplitude: [rad]. fs: sample rate of theta and drive [Hz].
        theta_offset_s: time of theta sample k is k/fs - theta_offset_s (chain delay).
    """

    def __init__(self, min_amplitude: float, fs: float, theta_offset_s: float = 0.0) -> None:
        self.h = 0.5 * float(min_amplitude)
        self.fs = float(fs)
        self.off = float(theta_offset_s)
        self._buf_k0 = None
        self._bx = np.zeros(0)
        self._bv = np.zeros((0, 2))
        self._sign = 0
        self._skip = True
        self._dv = np.zeros(0)
        self._dv_k0 = None
        self.drive_peaks: list[float] = []
        self.last_event_index = None

    def push_drive(self, first: int, v: np.ndarray) -> None:
        """Add drive samples first.. [V]; record the drive peaks now resolvable."""
        v = np.asarray(v, dtype=float)
        if self._dv_k0 is None:
            self._dv_k0 = first
        buf = np.concatenate((self._dv, v))
        if buf.size >= 3:
            a, b, c = buf[:-2], buf[1:-1], buf[2:]
            idx = np.flatnonzero((b > a) & (b >= c))
            d, _ = _parabola(a[idx], b[idx], c[idx])
            self.drive_peaks.extend(((self._dv_k0 + idx + 1 + d) / self.fs).tolist())
            self._dv = buf[-2:]
            self._dv_k0 += buf.size - 2
        else:
            self._dv = buf

    def push_theta(
        self,
        first: int,
        theta: np.ndarray,
        p_tt: np.ndarray | None = None,
        p_ww: np.ndarray | None = None,
    ) -> PeriodEvents:
        """Add theta samples first.. (and their variances); return completed extrema."""
        theta = np.asarray(theta, dtype=float)
        n = theta.size
        var = np.zeros((n, 2)) if p_tt is None else np.column_stack([p_tt, p_ww])
        if self._buf_k0 is None:
            self._buf_k0 = first
        x = np.concatenate((self._bx, theta))
        vv = np.concatenate((self._bv, var))
        k0 = self._buf_k0
        s = np.where(x > self.h, 1, np.where(x < -self.h, -1, 0))
        # forward fill of the armed sign, seeded with the carried one
        idx = np.where(s != 0, np.arange(x.size), -1)
        idx = np.maximum.accumulate(idx)
        armed = np.where(idx >= 0, s[np.maximum(idx, 0)], self._sign)
        prev = np.concatenate(([self._sign], armed[:-1]))
        flips = np.flatnonzero((armed != prev) & (prev != 0))
        ev = []
        start = 0
        for f in flips:
            seg_sign = prev[f]
            if self._skip:
                self._skip = False
            else:
                seg = x[start:f] * seg_sign
                if seg.size:
                    i = start + int(np.argmax(seg))
                    if 0 < i < x.size - 1:
                        d, val = _parabola_1(
                            float(x[i - 1] * seg_sign),
                            float(x[i] * seg_sign),
                            float(x[i + 1] * seg_sign),
                        )
                    else:
                        d, val = 0.0, x[i] * seg_sign
                    ev.append(
                        (
                            (k0 + i + float(d)) / self.fs - self.off,
                            float(val),
                            vv[i, 0],
                            vv[i, 1],
                            k0 + i,
                        )
                    )
            start = f
        if x.size and armed[-1] == 0 and self._sign == 0:
            start = x.size  # nothing armed yet: drop
        self._sign = int(armed[-1]) if x.size else self._sign
        # keep the open segment (bounded: at most 4 s of samples is never needed; cap)
        keep_from = max(start - 1, 0)
        if x.size - keep_from > 100000:
            keep_from = x.size - 100000
        self._bx = x[keep_from:]
        self._bv = vv[keep_from:]
        self._buf_k0 = k0 + keep_from
        out = self._events(ev)
        # drop drive peaks no pending extremum can refer to (keep two before the open segment)
        t_open = self._buf_k0 / self.fs - self.off
        j = int(np.searchsorted(self.drive_peaks, t_open)) - 2
        if j > 0:
            del self.drive_peaks[:j]
        return out

    def _events(self, ev) -> PeriodEvents:
        t, ph, am, vt, vp, va = [], [], [], [], [], []
        dp = self.drive_peaks  # ascending (peaks are >= 1 sample apart)
        for te, amp, ptt, pww, kidx in ev:
            j = bisect.bisect_right(dp, te) - 1  # np.searchsorted(dp, te, side="right") - 1
            if j < 1:
                continue
            td, T = dp[j], dp[j] - dp[j - 1]
            if not (0 < T and te - td < 1.5 * T):
                continue
            Tm = 2.0 * T
            wm = 2.0 * math.pi / Tm
            var_t = pww / (wm * wm * max(amp, 1e-12)) ** 2
            t.append(te)
            ph.append(2.0 * math.pi * ((te - td) % T) / Tm)
            am.append(amp)
            vt.append(var_t)
            vp.append(var_t * wm * wm)
            va.append(ptt)
            self.last_event_index = kidx
        return PeriodEvents(*(np.asarray(a, dtype=float) for a in (t, ph, am, vt, vp, va)))


def concat_events(parts: list[PeriodEvents]) -> PeriodEvents:
    """Concatenate event batches."""
    if not parts:
        return PeriodEvents(*(np.zeros(0) for _ in range(6)))
    return PeriodEvents(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in PeriodEvents._fields)
    )


def match_events(est: PeriodEvents, ref: PeriodEvents, max_dt: float):
    """Pair each estimated extremum with the nearest reference extremum within ``max_dt`` [s].

    Returns:
        (t, phase_error [rad] wrapped to [-pi/2, pi/2) (phase is defined mod pi),
        amplitude_error [rad]) for the matched pairs.
    """
    if est.t.size == 0 or ref.t.size == 0:
        z = np.zeros(0)
        return z, z, z
    j = np.clip(np.searchsorted(ref.t, est.t), 1, ref.t.size - 1)
    j = np.where(np.abs(ref.t[j - 1] - est.t) < np.abs(ref.t[j] - est.t), j - 1, j)
    ok = np.abs(ref.t[j] - est.t) <= max_dt
    dph = np.mod(est.phase[ok] - ref.phase[j[ok]] + math.pi / 2, math.pi) - math.pi / 2
    return est.t[ok], dph, est.amplitude[ok] - ref.amplitude[j[ok]]


def event_rmse(est: PeriodEvents, ref: PeriodEvents, max_dt: float, t_min: float = 0.0):
    """RMSE of phase and amplitude [rad] over matched extrema with t >= t_min (eqs. (109)-(110))
    and the number of pairs."""
    t, dph, dam = match_events(est, ref, max_dt)
    sel = t >= t_min
    if not np.any(sel):
        return math.nan, math.nan, 0
    return (
        float(np.sqrt(np.mean(dph[sel] ** 2))),
        float(np.sqrt(np.mean(dam[sel] ** 2))),
        int(sel.sum()),
    )


def time_to_acquire(err: np.ndarray, tol: float, fs: float) -> float:
    """Time [s] from the first sample until |err| stays below ``tol`` to the end of the record
    (0 if it never leaves; nan if it is still above at the last sample)."""
    a = np.abs(np.asarray(err, dtype=float))
    if a.size == 0 or not a[-1] < tol:
        return math.nan
    out = np.flatnonzero(~(a < tol))
    return 0.0 if out.size == 0 else (int(out[-1]) + 1) / float(fs)


class AcquisitionStudy(NamedTuple):
    """Filters started with a wrong angle (:func:`acquisition_study`), one entry per start.

    start: sample index of the start. sign: +1 (angle too large) or -1 (too small).
    time: time to acquire [s] (nan: not acquired in the window). rmse: theta RMSE over the
    whole window [rad] (sign-invariant error). final_rmse: over its last third [rad].
    """

    start: np.ndarray
    sign: np.ndarray
    time: np.ndarray
    rmse: np.ndarray
    final_rmse: np.ndarray


def acquisition_study(
    kind: str,
    params: Mapping[str, Any] | None,
    y: np.ndarray,
    v2: np.ndarray,
    theta_ref: np.ndarray,
    omega_ref: np.ndarray,
    starts,
    dtheta: float,
    n: int,
    tol: float,
) -> AcquisitionStudy:
    """Time to acquire from an initial angle error: at each start k the filter begins at
    theta_ref[k] +- dtheta, omega_ref[k], with the covariance diag(dtheta^2,
    initial_rate_std^2) (the error is one standard deviation: an honest prior), and runs
    over y[k+1 : k+1+n].  The error is sign-invariant, min(|x - theta|, |x + theta|) (h is
    even); acquired once it stays below ``tol`` (:func:`time_to_acquire`).

    Args:
        y, v2: AMDM samples [V] and <V^2> per step [V^2] (:class:`DriveAligner`).
        theta_ref, omega_ref: the reference at the instants y describes [rad, rad/s].
        starts: sample indices. dtheta [rad] > 0. n: samples per run. tol [rad].
    """
    if not (dtheta > 0 and tol > 0 and n > 0):
        raise ParameterError(f"dtheta, tol and n must be > 0: {dtheta!r}, {tol!r}, {n!r}")
    f = ScannerFilter(kind, params)
    rows = []
    for k in starts:
        k = int(k)
        if not (0 <= k and k + 1 + n <= y.size):
            raise ParameterError(f"start {k} + {n} samples exceeds the record ({y.size})")
        for sg in (1, -1):
            f.start(
                (theta_ref[k] + sg * dtheta, omega_ref[k]),
                np.diag([dtheta * dtheta, f.p["initial_rate_std"] ** 2]),
            )
            sl = slice(k + 1, k + 1 + n)
            x = f.step(y[sl], v2[sl])["x"][:, 0]
            th = theta_ref[sl]
            e = np.minimum(np.abs(x - th), np.abs(x + th))
            rows.append(
                (
                    k,
                    sg,
                    time_to_acquire(e, tol, f.p["sample_rate_hz"]),
                    float(np.sqrt(np.mean(e * e))),
                    float(np.sqrt(np.mean(e[-(n // 3 or 1) :] ** 2))),
                )
            )
    cols = list(zip(*rows)) if rows else [()] * 5
    return AcquisitionStudy(*(np.asarray(c, dtype=float) for c in cols))


def ac_snr(y: np.ndarray, noise_var: float) -> float:
    """Signal-to-noise ratio of the AC part of y: (var(y) - R)/R (<= ~0: no motion)."""
    y = np.asarray(y, dtype=float)
    if y.size < 2:
        return math.nan
    return float((np.var(y) - noise_var) / noise_var)

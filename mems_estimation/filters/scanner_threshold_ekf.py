"""Plain and threshold-aided (hybrid) EKF for the chapter-4 micro-scanner.

Source: Y. Chen, "High-accuracy Motion Estimation for MEMS Devices with Capacitive Sensors",
PhD thesis, U. Michigan 2018, chapter 4: process model eqs. (68)-(70), measurement eq. (71)
y_cap = h_cap(theta) omega, Table 4.1 (EKF with the hybrid sensing scheme: at a threshold
detection the measurement theta = theta_th with variance R_theta,th is stacked on the y_cap
update).

State x = [theta (rad), omega (rad/s)].  Per sample k (Ts = 1/fs)::

    predict   x_k^- = Phi x_{k-1} + Gam * tau(theta_{k-1}, V_{k-1}) / J
              P_k^- = G P_{k-1} G^T + Q,  G = Phi + Gam [tau_theta/J, 0],
              tau = 1/2 dC_dr/dtheta V^2 (eq. (67)), tau_theta = 1/2 d2C_dr/dtheta2 V^2
    update    y_k = h(theta) omega + n,  h = -R_s V_bias dC_s/dtheta,   R = R_cap
              H = [h'(theta) omega, h(theta)]     (full Jacobian; Table 4.1 prints [0, h],
                                                   selectable with jacobian='paper')
    detection theta(t_c + delta Ts) = theta_th + e,  H_th = [1, delta Ts],  R = R_theta,th

Jacobian (default 'paper' = Table 4.1's H = [0, h]): Table 4.1 drops dh/dtheta * omega.
Measured on scenario scanner_threshold (seed 0, drifted analog map): with the full Jacobian
the plain EKF's theta RMSE is 0.56 mrad against 4.1 mrad with [0, h], and the threshold
update then adds < 1 % -- the y_cap zero crossing at theta_th already carries the crossing
time.  The hybrid's gain reported for Table 4.3 is that of the paper's filter.

Deviation from eq. (70), documented: (70) is the forward-Euler map.  At Ts = 2 us and
wn = 2 pi 624.6 Hz its spurious growth per step (|eig| - 1 ~ wn^2 Ts^2 / 2 = 3.1e-5)
cancels ~60 % of the physical decay per step (zeta wn Ts = 5.2e-5), so here Phi = expm(A Ts)
and Gam = int_0^Ts expm(A s) ds [0, 1]^T (exact zero-order hold of the linear part, the
torque held over the step like the DAQ's drive); Q = Gam Gam^T sigma_tau^2 / J^2 for a
white torque sigma_tau held per sample.

Covariance update: Joseph form, so P stays symmetric positive definite.  Table 4.1's
stacked update with diagonal R is done as two scalar updates with both Jacobians taken at
the prior -- algebraically identical to the stacked form.

Late detections (hybrid): the causal detector issues the detection of sample c at sample
k = c + L.  The filter keeps a ring buffer of the last ``lag`` priors (x_i^-, P_i^-), y_i,
V_i; at the detection it restores x_c^-, P_c^-, applies the stacked update at c and
re-propagates c+1..k with the stored y and V (re-propagation / fixed-lag scheme).  The
estimates written for samples c..k are overwritten, so the *final* output of sample i is
fixed once i + lag has been processed; the *real-time* output (x_i as known at time i) is
kept separately.

Detection angle: the DOG peak marks the maximum of dy_cap/dt, not theta_th itself.  In free
motion (omega^2 = wn^2 (A^2 - theta^2), omega' = -wn^2 theta) dy/dt ~ F(theta) =
h'(theta) (A^2 - theta^2) - h(theta) theta, whose maximum theta*(A) -> theta_th only for
A >> theta0; at A ~ theta0 and theta_th != 0 it lies between 0 and theta_th (bias measured
~ -1..-4 mrad at SNR <= 5).  With detection_angle='peak_slope' the filter uses theta*(A) at the
prior amplitude A = sqrt(theta^2 + omega^2/wn^2) (maximised on a grid + parabola) as the
measured angle; 'threshold' is Table 4.1's theta_th.

Innovation gate: a detection whose normalised innovation |nu|/sqrt(S) exceeds ``gate`` is
rejected and counted (spurious detections at low SNR).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from mems_estimation.filters.scanner_threshold_detector import Detections
from mems_estimation.filters.scanner_threshold_kernels import (
    DetectionArrays,
    DetectionOptions,
    LagBuffer,
    RunOutputs,
    aug_run,
    ekf_run,
)
from mems_estimation.filters.scanner_threshold_specs import (
    EKF_SPECS,
    ScannerModel,
    model_from_device,
    scanner_model,
    zoh_matrices,
)
from mems_sim.kernels.divergence import covariance_ok, state_ok
from mems_sim.params import resolve

__all__ = [
    "EKF_SPECS",
    "ScannerModel",
    "scanner_model",
    "EkfResult",
    "run_ekf",
    "StreamingScannerEkf",
    "zoh_matrices",
    "signal_snr",
    "model_from_device",
]


def _detection_arrays(det: Detections) -> DetectionArrays:
    """The kernels' contiguous view of a frame's detections (index and arrival int64)."""
    return DetectionArrays(
        np.ascontiguousarray(det.index, np.int64),
        np.ascontiguousarray(det.arrival, np.int64),
        np.ascontiguousarray(det.delta, np.float64),
        np.ascontiguousarray(det.timing_var, np.float64),
    )


class EkfResult(NamedTuple):
    """Whole-record EKF output.

    theta, omega: final estimates (fixed-lag, detections applied at the sample they
    refer to) [rad], [rad/s]. P: (n, 3) [P_tt, P_to, P_oo] of the final estimates.
    theta_rt, omega_rt: real-time estimates.  applied / gated / too_late: detection counts.
    min_det: smallest det(P) (or diagonal) seen (> 0: PD throughout).  max_p_theta: largest P_tt.
    """

    theta: np.ndarray
    omega: np.ndarray
    P: np.ndarray
    theta_rt: np.ndarray
    omega_rt: np.ndarray
    applied: int
    gated: int
    too_late: int
    min_det: float
    max_p_theta: float
    comb: np.ndarray | None = None


class StreamingScannerEkf:
    """Frame-by-frame (hybrid) EKF. Without detections it is the plain EKF of Table 4.1.

    Outputs of :meth:`process` are final estimates delayed by ``lag`` samples (rows for
    indices ``first_out .. first_out + n - 1``); :meth:`flush` returns the remainder.
    """

    def __init__(self, overrides: Mapping[str, Any] | None = None, x0=(0.0, 0.0)):
        self.p = resolve(EKF_SPECS, overrides)
        self.m = scanner_model(self.p)
        self.options = DetectionOptions(
            self.p["r_theta_mode"] == "canny",
            self.p["detection_angle"] == "peak_slope",
            2.0 * math.pi * self.p["model_natural_freq_hz"],
            self.p["gate"],
            self.p["use_subsample"],
        )
        L = int(self.p["lag"])
        self.lag = L
        self.x0 = np.array(x0, dtype=float)
        self.P0 = np.array(
            [self.p["initial_theta_std"] ** 2, 0.0, self.p["initial_omega_std"] ** 2]
        )
        self.comb = bool(self.p["estimate_comb"])
        # final outputs not yet released (indices k-L..k-1): none yet
        self._start(np.full((L, 2), np.nan), np.full((L, 3), np.nan))
        self.stats = np.array([0.0, 0.0, 0.0, np.inf, 0.0])
        self._adapt = np.array(
            [
                self.p["r_cap_adapt_rate"] if self.p["r_cap_mode"] == "adaptive" else 0.0,
                self.p["r_cap_scale_max"],
                self.p["gate"] ** 2,
            ]
        )
        #: [running mean of the detections' NIS, current R_cap scale]
        self.ad = np.array([1.0, 1.0])
        self.next_index = 0
        #: first sample index after the last :meth:`reset` (detections of earlier samples
        #: are too late: their priors are gone)
        self.valid_from = 0
        self.resets = 0

    def _start(self, tx: np.ndarray, tP: np.ndarray) -> None:
        """The prior (x0, P0), an empty fixed-lag buffer, the pending final rows (tx (L, 2),
        tP (L, 3)) and, with ``estimate_comb``, the 4-state filter's prior."""
        L = self.lag
        self.x = self.x0.copy()
        self.P = self.P0.copy()
        self._bx = np.zeros((L, 2))
        self._bP = np.zeros((L, 3))
        self._by = np.zeros(L)
        self._bv = np.zeros(L)
        self._tx = tx
        self._tP = tP
        if self.comb:
            self._init_comb()

    def _init_comb(self) -> None:
        """Prior of the 4-state filter z = [theta, omega, log gain, log width]."""
        L = self.lag
        self.z = np.array([*self.x0, 0.0, 0.0])
        self.PP = np.diag(
            [
                self.P0[0],
                self.P0[2],
                self.p["comb_gain_std"] ** 2,
                self.p["comb_width_std"] ** 2,
            ]
        )
        self._bz = np.zeros((L, 4))
        self._bPP = np.zeros((L, 4, 4))
        self._tz = np.tile(self.z, (L, 1))
        q = self.p["comb_drift_std"] ** 2 / self.p["sample_rate_hz"]
        self._qc = np.array([q, q])
        #: gain and width multipliers of the sensing comb of the rows last returned
        self.comb_final = np.ones((0, 2))

    def reset(self) -> None:
        """Re-initialise from the prior (x0, P0) at the current sample index: the pending
        final rows become the prior, the fixed-lag buffer is emptied, and detections of
        samples before now are counted too late."""
        L = self.lag
        self._start(np.tile(self.x0, (L, 1)), np.tile(self.P0, (L, 1)))
        self.valid_from = self.next_index
        self.resets += 1

    def diverged(self) -> bool:
        """True if the state or the pending final rows are not finite, or the covariance is
        not positive definite (:func:`~mems_sim.kernels.divergence.covariance_ok`)."""
        P = self.P
        return not (
            state_ok(self.x, self._bx[: min(self.next_index, self.lag)])
            and covariance_ok(np.array([[P[0], P[1]], [P[1], P[2]]]))
        )

    def process(self, y: np.ndarray, v: np.ndarray, det: Detections | None = None):
        """Filter one frame. y [V], v [V] (drive held over each sample), detections issued
        within this frame (arrival in range).

        Returns:
            (first_index, x_final (m,2), P_final (m,3), x_realtime (n,2)): the final rows
            are for samples first_index.. (lag samples behind; m = n, minus leading
            negatives at the start of the run).
        """
        y = np.ascontiguousarray(y, dtype=np.float64)
        v = np.ascontiguousarray(v, dtype=np.float64)
        n = y.shape[0]
        if v.shape != y.shape:
            raise ValueError("y and v must have the same length")
        det = Detections.empty() if det is None else det
        if self.valid_from > 0 and det.index.size:
            late = det.index < self.valid_from
            if np.any(late):
                self.stats[2] += int(np.count_nonzero(late))
                det = Detections(*(q[~late] for q in det))
        L = self.lag
        k0 = self.next_index
        ox = np.empty((L + n, 2))
        oP = np.empty((L + n, 3))
        ox[:L] = self._tx
        oP[:L] = self._tP
        rx = np.empty((n, 2))
        if self.comb:
            return self._process_comb(y, v, det, k0, ox, oP, rx)
        ekf_run(
            y,
            v,
            k0,
            _detection_arrays(det),
            self.options,
            self.m,
            self.x,
            self.P,
            LagBuffer(self._bx, self._bP, self._by, self._bv),
            RunOutputs(k0 - L, ox, oP, rx, self.stats),
            self._adapt,
            self.ad,
        )
        self._tx = ox[n:].copy()
        self._tP = oP[n:].copy()
        self.next_index += n
        first = k0 - L
        skip = max(0, -first)
        return first + skip, ox[skip:n], oP[skip:n], rx

    def _process_comb(self, y, v, det, k0, ox, oP, rx):
        """:meth:`process` of the 4-state filter (``estimate_comb``)."""
        L = self.lag
        n = y.shape[0]
        oz = np.empty((L + n, 4))
        oz[:L] = self._tz
        aug_run(
            y,
            v,
            k0,
            _detection_arrays(det),
            self.options,
            self.m,
            self._qc,
            self.z,
            self.PP,
            LagBuffer(self._bz, self._bPP, self._by, self._bv),
            RunOutputs(k0 - L, oz, oP, rx, self.stats),
        )
        ox[:] = oz[:, :2]
        self._tz = oz[n:].copy()
        self._tx = ox[n:].copy()
        self._tP = oP[n:].copy()
        self.x = self.z[:2].copy()
        self.P = np.array([self.PP[0, 0], self.PP[0, 1], self.PP[1, 1]])
        self.next_index += n
        first = k0 - L
        skip = max(0, -first)
        self.comb_final = np.exp(oz[skip:n, 2:])
        return first + skip, ox[skip:n], oP[skip:n], rx

    def flush(self):
        """Remaining final rows (last ``lag`` samples): (first_index, x, P)."""
        L = self.lag
        first = self.next_index - L
        skip = max(0, -first)
        if self.comb:
            self.comb_final = np.exp(self._tz[skip:, 2:])
        return first + skip, self._tx[skip:].copy(), self._tP[skip:].copy()

    @property
    def counts(self) -> dict[str, float]:
        """Detections applied / gated / too late, smallest det(P), largest P_theta."""
        s = self.stats
        return {
            "applied": int(s[0]),
            "gated": int(s[1]),
            "too_late": int(s[2]),
            "min_det": float(s[3]),
            "max_p_theta": float(s[4]),
        }


def run_ekf(
    y: np.ndarray,
    v: np.ndarray,
    overrides: Mapping[str, Any] | None = None,
    detections: Detections | None = None,
    x0=(0.0, 0.0),
    frame: int | None = None,
) -> EkfResult:
    """Run the (hybrid) EKF over a whole record (in frames of ``frame`` samples if given).

    Detections with ``arrival`` = ``index`` (offline) are applied immediately at their sample.
    """
    f = StreamingScannerEkf(overrides, x0)
    n = len(y)
    det = Detections.empty() if detections is None else detections
    step = n if frame is None else int(frame)
    xs, Ps, rts, cs = [], [], [], []
    for a in range(0, n, max(step, 1)):
        b = min(n, a + step)
        sel = (det.arrival >= a) & (det.arrival < b)
        _, xf, Pf, rx = f.process(y[a:b], v[a:b], Detections(*(q[sel] for q in det)))
        xs.append(xf)
        Ps.append(Pf)
        rts.append(rx)
        cs.append(f.comb_final if f.comb else None)
    _, xf, Pf = f.flush()
    xs.append(xf)
    Ps.append(Pf)
    cs.append(f.comb_final if f.comb else None)
    X = np.concatenate(xs)[:n]
    PP = np.concatenate(Ps)[:n]
    R = np.concatenate(rts)
    c = f.counts
    return EkfResult(
        X[:, 0],
        X[:, 1],
        PP,
        R[:, 0],
        R[:, 1],
        c["applied"],
        c["gated"],
        c["too_late"],
        c["min_det"],
        c["max_p_theta"],
        np.concatenate(cs)[:n] if f.comb else None,
    )


def signal_snr(y: np.ndarray, noise_std: float) -> float:
    """Estimated SNR of a y_cap record: (mean(y^2) - sigma_n^2) / sigma_n^2 (>= 0)."""
    y = np.asarray(y, dtype=float)
    return max(0.0, float(np.mean(y * y)) / noise_std**2 - 1.0)

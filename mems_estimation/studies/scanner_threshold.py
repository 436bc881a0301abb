"""The chapter-4 threshold study: seeded ring-down trials, the drift grid and the PCRB.

Source: Y. Chen, PhD thesis, U. Michigan 2018, Sec. 4.4.1 and 4.6 (experiment, error
definitions, eq. (76)); Tichavsky, Muravchik & Nehorai 1998 (PCRB).  Runs the emulator
(:mod:`mems_sim.devices.scanner`), the online detector and the filters of
:mod:`mems_estimation.filters.scanner_threshold_ekf`, ROS-free; scenario
``scanner_threshold``, docs/scanner.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numba
import numpy as np

from mems_estimation.filters.scanner_threshold_detector import Detections
from mems_estimation.filters.scanner_threshold_ekf import EkfResult, run_ekf
from mems_estimation.filters.scanner_threshold_kernels import cov_predict, scalar_update
from mems_estimation.filters.scanner_threshold_specs import (
    EKF_SPECS,
    model_from_device,
    zoh_matrices,
)
from mems_estimation.identification.scanner_threshold_identification import (
    MAX_PSD_DELAY_S,
    MODEL_KEYS,
    cutoff_index,
    identify,
    ringdown_fit,
)
from mems_sim.params import resolve

__all__ = [
    "DRIFTED_SENSOR",
    "DRIFT_GRID",
    "pcrb_theta",
    "snr_segments",
    "detection_errors",
    "rmse",
    "ThresholdTrial",
    "threshold_trial",
    "HYBRID",
    "BASELINE",
    "TUNING_SEEDS",
    "EVALUATION_SEEDS",
    "drift_evaluation",
    "grid_trial",
    "hold_frequency",
    "bench_record",
    "bench_identification",
    "identified_parameters",
    "oracle_parameters",
]

#: Device deviation used by the threshold study: the sensing comb drifted (temperature,
#: Sec. 4.2.1) away from the identified analog map -- gain C0 +20 %, width theta0 +10 % --
#: while the angle of maximum overlap theta_th (geometric symmetry) is unchanged.
DRIFTED_SENSOR = {"sense_gain_drift": 0.2, "sense_width_drift": 0.1}

#: The drift grid of the sensing comb (gain +-20 %, width +-10 %): nominal and four corners,
#: as (name, sense_gain_drift, sense_width_drift).
DRIFT_GRID = (
    ("nominal", 0.0, 0.0),
    ("gain+20_width+10", 0.2, 0.1),
    ("gain+20_width-10", 0.2, -0.1),
    ("gain-20_width+10", -0.2, 0.1),
    ("gain-20_width-10", -0.2, -0.1),
)


@numba.njit(cache=True)
def _pcrb_run(th, om, v, Phi, Gam, Qt, J, dc0, dth0, thth, gain, sc0, sth0, rcap, P, out):
    """Riccati recursion of the PCRB at the true states (see :func:`pcrb_theta`)."""
    n = th.shape[0]
    for k in range(n):
        if k > 0:
            x = th[k - 1]
            dacc = 0.0
            v2 = v[k - 1] * v[k - 1]
            if v2 != 0.0:
                u = (x - thth) / dth0
                dacc = 0.5 * (2.0 * dc0 / (dth0 * dth0) * (2.0 * u * u - 1.0) * math.exp(-u * u))
                dacc *= v2 / J
            P[0], P[1], P[2] = cov_predict(P[0], P[1], P[2], Phi, Gam, Qt, dacc)
        u = (th[k] - thth) / sth0
        e = math.exp(-u * u)
        h = gain * 2.0 * sc0 * u / sth0 * e
        hp = -gain * (2.0 * sc0 / (sth0 * sth0) * (2.0 * u * u - 1.0) * e)
        # information update J = J^- + H^T H / R, H = [h' omega, h], done in covariance form
        scalar_update(np.zeros(2), P, hp * om[k], h, 0.0, rcap)
        out[k] = P[0]


def pcrb_theta(
    theta: np.ndarray,
    omega: np.ndarray,
    drive: np.ndarray,
    device_p: Mapping[str, Any],
    initial_theta_std: float = 0.2,
    initial_omega_std: float = 800.0,
) -> np.ndarray:
    """Posterior Cramér-Rao bound of theta [rad^2] per sample for the device ``device_p``.

    Tichavský, Muravchik, Nehorai, "Posterior Cramér-Rao bounds for discrete-time nonlinear
    filtering", IEEE TSP 46(5), 1998: the Fisher information of x_k obeys
    J_{k+1} = D22 - D21 (J_k + D11)^-1 D12 (their eq. (21)); for additive Gaussian noise
    D11 = E[F^T Q^-1 F], D12 = -E[F^T] Q^-1, D22 = Q^-1 + E[H^T R^-1 H] (their Sec. III-A),
    F, H the Jacobians of the transition and measurement at the true state.  Where F does
    not depend on the state distribution (the ring-down is linear) this is, by the matrix
    inversion lemma, J_{k+1} = (Q + F J_k^-1 F^T)^-1 + E[H^T R^-1 H] (their linear-Gaussian
    case), which also holds for the singular Q of a torque held per sample; the prior J_0
    is that of the filters.  Here the expectations over x_k are taken at the run's true
    state (the spread of trajectories from the device's torque noise is far below the
    bound's scale), so the recursion is the Riccati recursion evaluated at the truth.  The
    model is the *device's own* (its sensing comb with its drift, its torque noise as Q,
    its sigma_n as R): the bound of an estimator that knows the device.

    Args:
        theta, omega: true states [rad], [rad/s]; drive: v held over each sample [V];
        device_p: the device's spec dict (``resolve_scanner``).
    """
    from mems_sim.devices.scanner import scanner_params

    sp = scanner_params(device_p)
    fs = device_p["sample_rate_hz"]
    wn = 2.0 * math.pi * device_p["natural_freq_hz"]
    Phi, Gam = zoh_matrices(wn, device_p["damping_ratio"], 1.0 / fs)
    Qt = np.outer(Gam, Gam) * (device_p["torque_noise_std"] / sp.J) ** 2
    P = np.array([initial_theta_std**2, 0.0, initial_omega_std**2])
    out = np.empty(len(theta))
    _pcrb_run(
        np.ascontiguousarray(theta, np.float64),
        np.ascontiguousarray(omega, np.float64),
        np.ascontiguousarray(drive, np.float64),
        Phi,
        Gam,
        Qt,
        sp.J,
        sp.drive_c0,
        sp.drive_theta0,
        sp.theta_th,
        device_p["sense_resistance"] * device_p["bias_voltage"],
        sp.sense_c0,
        sp.sense_theta0,
        max(device_p["noise_std"] ** 2, 1e-30),
        P,
        out,
    )
    return out


def snr_segments(
    y_clean: np.ndarray,
    noise_std: float,
    start: int,
    fs: float,
    targets=(85.0, 22.0, 5.0, 1.0),
    window_s: float = 0.005,
):
    """Split the ring-down (from sample ``start``) into segments of SNR about ``targets``.

    SNR(t) = mean(y_clean^2)/sigma_n^2 over a centred ``window_s`` window (signal power over
    noise power).  Boundaries at the geometric means of consecutive targets; the first
    segment ends where SNR falls below sqrt(t0 t1), the last where it falls below t_last/2.
    Returns a list of (lo, hi, mean SNR) (a segment is empty, lo == hi, if never reached).
    """
    y = np.asarray(y_clean[start:], dtype=float)
    w = max(1, int(window_s * fs))
    pw = np.convolve(y * y, np.ones(w) / w, mode="same") / noise_std**2
    bounds = [math.sqrt(a * b) for a, b in zip(targets[:-1], targets[1:])] + [targets[-1] / 2]
    segs, lo = [], 0
    for b in bounds:
        below = np.where(pw[lo:] < b)[0]
        hi = lo + (int(below[0]) if below.size else pw.shape[0] - lo)
        snr = float(np.mean(y[lo:hi] ** 2) / noise_std**2) if hi > lo else float("nan")
        segs.append((start + lo, start + hi, snr))
        lo = hi
    return segs


def detection_errors(
    theta: np.ndarray, det: Detections, theta_th: float, use_delta: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(e_theta [rad], e_t [samples]) of detections against the true angle record.

    e_theta = theta(t_c + delta Ts) - theta_th (linear interpolation); e_t = detected time minus
    the true crossing time of theta_th nearest to it (Sec. 4.6.1 definitions).
    """
    th = np.asarray(theta, dtype=float)
    c = np.asarray(det.index, dtype=np.int64)
    dl = np.asarray(det.delta, dtype=float) if use_delta else np.zeros(c.shape[0])
    c1 = np.minimum(c + 1, th.shape[0] - 1)
    e_th = th[c] + dl * (th[c1] - th[c]) - theta_th
    s = th - theta_th
    cross = np.where(np.sign(s[:-1]) != np.sign(s[1:]))[0]
    tc = cross + s[cross] / (s[cross] - s[cross + 1])
    if tc.size == 0:
        return e_th, np.full(c.shape[0], np.nan)
    td = c + dl
    j = np.clip(np.searchsorted(tc, td), 1, tc.size - 1) if tc.size > 1 else np.zeros(c.size, int)
    near = (
        np.where(np.abs(tc[j - 1] - td) < np.abs(tc[j] - td), tc[j - 1], tc[j])
        if tc.size > 1
        else tc[j]
    )
    return e_th, td - near


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """sqrt(mean((a - b)^2)) -- eq. (76)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return float(np.sqrt(np.mean(d * d))) if d.size else float("nan")


class ThresholdTrial(NamedTuple):
    """One seeded ring-down trial (device record, online detections, plain and hybrid EKF)."""

    device: Any
    record: Any
    detections: Detections
    plain: EkfResult
    hybrid: EkfResult
    segments: list


def threshold_trial(
    seed: int,
    device_overrides: Mapping[str, Any] | None = None,
    ekf_overrides: Mapping[str, Any] | None = None,
    detector_overrides: Mapping[str, Any] | None = None,
    frame: int = 1000,
) -> ThresholdTrial:
    """Run the chapter-4 experiment on the emulator (Sec. 4.4.1 / 4.6).

    The device is the chapter-4 scanner with ``device_overrides`` (default: the drifted
    sensing comb :data:`DRIFTED_SENSOR`); both filters use the *identified* (nominal) model
    (:func:`model_from_device` of the default spec) plus ``ekf_overrides``; the online
    detector runs frame by frame and the hybrid filter receives its detections late
    (re-propagation). Segments: :func:`snr_segments` of the ring-down.
    """
    from mems_estimation.filters.scanner_threshold_detector import OnlineThresholdDetector
    from mems_sim.devices.scanner import MicroScannerDevice, resolve_scanner

    dev = MicroScannerDevice(
        DRIFTED_SENSOR if device_overrides is None else device_overrides, seed=seed
    )
    rec = dev.step(dev.total_samples)
    det_p = dict(detector_overrides or {})
    det_p.setdefault("noise_std", max(dev.p["noise_std"], 1e-9))
    det = OnlineThresholdDetector(**det_p)
    n = rec.y.shape[0]
    D = Detections.concat([det.process(rec.y[a : a + frame]) for a in range(0, n, frame)])
    P = model_from_device(resolve_scanner({}), **dict(ekf_overrides or {}))
    plain = run_ekf(rec.y, rec.drive, P, frame=frame)
    hyb = run_ekf(rec.y, rec.drive, P, detections=D, frame=frame)
    segs = snr_segments(rec.y_clean, max(dev.p["noise_std"], 1e-9), dev.plan.cutoff, dev.fs)
    return ThresholdTrial(dev, rec, D, plain, hyb, segs)


#: The hybrid as redesigned for the drift grid: full Jacobian, the sensing comb's gain and
#: width estimated with the state, the peak-slope angle with its correction as variance.
HYBRID = dict(jacobian="full", estimate_comb=True, detection_angle="peak_slope")
#: The baseline: the plain EKF with the full measurement Jacobian (shipped tuning).
BASELINE = dict(jacobian="full")
#: Noise seeds used to choose the design (q_torque_std, comb estimation, detection
#: variance); never used to evaluate it.
TUNING_SEEDS = (101, 102)
#: Noise seeds of the drift-grid evaluation.
EVALUATION_SEEDS = (1, 2, 3, 4, 5)


#: The thesis' programme: its hold at 1250 Hz (twice the 625 Hz motion of Table 4.2) for
#: the mirror it identified at 624.6 Hz (Sec. 4.4.1-4.4.2).
PAPER_HOLD_HZ, PAPER_NATURAL_HZ = 1250.0, 624.6
#: Smallest ring-down amplitude [rad] of the bench run for a usable sensing-comb map: below
#: about the comb's width (0.05 rad) the map is nearly linear in theta and only
#: C0/theta0^2 is seen (measured: a 0.07 rad ring-down put C0 +270 %, theta0 +96 %).
MIN_BENCH_AMPLITUDE = 0.1


def hold_frequency(natural_freq_hz: float) -> float:
    """Hold (and sweep-end) frequency [Hz] of the drive programme for a mirror identified at
    ``natural_freq_hz``: the thesis' 1250 Hz scaled by natural_freq_hz / 624.6 Hz, to the
    0.1 Hz of a function generator's setting."""
    return round(PAPER_HOLD_HZ * natural_freq_hz / PAPER_NATURAL_HZ, 1)


def bench_record(device: Mapping[str, Any], seed: int, adc=None) -> dict:
    """One bench run of ``device`` (a spec dict of the emulator's table; ROS-free core, noise
    seed ``seed``): drive ``v`` [V], ``y`` [V] (``adc(y)`` if given: the converter the
    emulator node puts in front), PSD reference ``psd`` [rad], ``fs`` [Hz]."""
    from mems_sim.devices.scanner import MicroScannerDevice

    dev = MicroScannerDevice(device, seed=seed)
    rec = dev.step(dev.total_samples)
    y = rec.y if adc is None else adc(rec.y)
    return dict(v=rec.drive, y=y, psd=rec.psd, fs=dev.fs)


def bench_identification(
    device: Mapping[str, Any], seed: int, adc=None, search: bool = True
) -> dict:
    """Identification on the bench (Sec. 4.4.2) of ``device`` before the drift (its sensing
    comb as the analog map was identified: no ``sense_*_drift``). With ``search``, a first
    run of the programme gives wn from its PSD ring-down and the hold moves to
    :func:`hold_frequency` (the resonance search: the sweep must find the drawn device's
    parametric resonance); a run with that programme (noise seed ``seed`` + 1) gives the
    model (:func:`~mems_estimation.identification.scanner_threshold_identification.identify`).
    Returns ``model`` (the parameter YAML's content) and ``hold_hz``. ValueError when the
    device shows no usable motion or a fit fails."""
    from mems_sim.devices.scanner import resolve_scanner

    dev = resolve_scanner(dict(device, sense_gain_drift=0.0, sense_width_drift=0.0))
    fn = math.nan
    if search:
        rec = bench_record(dev, seed, adc)
        start = cutoff_index(rec["v"]) + int(math.ceil(MAX_PSD_DELAY_S * rec["fs"]))
        fn = ringdown_fit(rec["psd"], rec["fs"], start).wn / (2.0 * math.pi)
        dev = resolve_scanner(dict(dev, sweep_end_hz=hold_frequency(fn)))
    rec = bench_record(dev, seed + 1, adc)
    fs = rec["fs"]
    cut = cutoff_index(rec["v"])
    amp = float(np.abs(rec["psd"][cut : cut + int(0.01 * fs)]).max())
    if amp < MIN_BENCH_AMPLITUDE:
        raise ValueError(
            f"ring-down amplitude {amp:.3g} rad < {MIN_BENCH_AMPLITUDE} rad with the hold at "
            f"{dev['sweep_end_hz']:g} Hz: the drive programme does not reach the parametric "
            "resonance"
        )
    model = identify(
        rec["v"],
        rec["y"],
        rec["psd"],
        fs,
        int(round(dev["hold_time_s"] * fs)),
        dev["sense_resistance"],
        dev["bias_voltage"],
    )
    model["identification"].update(
        search_natural_freq_hz=fn, hold_hz=float(dev["sweep_end_hz"]), bench_amplitude_rad=amp
    )
    return dict(model=model, hold_hz=float(dev["sweep_end_hz"]))


def identified_parameters(model: Mapping[str, Any], **overrides) -> dict[str, Any]:
    """The EKF's parameters (:data:`EKF_SPECS`, resolved) with the identified ``model``."""
    return resolve(EKF_SPECS, dict({k: model[k] for k in MODEL_KEYS}, **overrides))


def oracle_parameters(**overrides) -> dict[str, Any]:
    """The ``oracle`` EKF parameters: the emulator's nominal table (the truth model of the
    nominal device), for comparison only."""
    from mems_sim.devices.scanner import resolve_scanner

    return model_from_device(resolve_scanner({}), **overrides)


def drift_evaluation(th, om, y, v, D, dp: dict, segs, P: dict | None = None) -> dict:
    """Hybrid vs the full-Jacobian EKF on one record, with the device's PCRB; ``P``: the
    filters' parameters (identified, :func:`identified_parameters`; None: the ``oracle``).

    Returns per segment (the ring-down segments, then overall): theta RMSE of the baseline
    (full-Jacobian plain EKF), the hybrid (:data:`HYBRID`, with the detections ``D``), the
    same design without detections, Table 4.1's EKF (``[0, h]``); the PCRB (root of the
    mean bound over the segment, :func:`pcrb_theta` for the device ``dp``); the mean and
    std of the detection error e_theta,th = theta(t_c) - theta_th per segment.
    """
    P = oracle_parameters() if P is None else P
    allseg = list(segs) + [(segs[0][0], segs[-1][1], math.nan)]

    def per_seg(est):
        return [rmse(est[lo:hi], th[lo:hi]) if hi > lo else math.nan for lo, hi, _ in allseg]

    out = dict(
        base=per_seg(run_ekf(y, v, dict(P, **BASELINE), frame=5000).theta),
        paper=per_seg(run_ekf(y, v, P, frame=5000).theta),
        hyb=per_seg(run_ekf(y, v, dict(P, **HYBRID), detections=D, frame=5000).theta),
        comb_plain=per_seg(run_ekf(y, v, dict(P, **HYBRID), frame=5000).theta),
    )
    b = pcrb_theta(th, om, v, dp)
    out["pcrb"] = [
        float(np.sqrt(np.mean(b[lo:hi]))) if hi > lo else math.nan for lo, hi, _ in allseg
    ]
    e, et = detection_errors(th, D, dp["threshold_angle"])
    bias = []
    for lo, hi, _ in allseg:
        m = (D.index >= lo) & (D.index < hi) & (np.abs(et) < 50)
        bias.append((float(e[m].mean()), float(e[m].std())) if m.sum() > 1 else (math.nan,) * 2)
    out["det_bias"] = bias
    out["snr"] = [snr for _, _, snr in segs]
    return out


#: The bench runs' noise seed: the run seed plus this (never the evaluation run's noise).
BENCH_SEED_OFFSET = 1_000_000


def grid_trial(seed: int, gain_drift: float, width_drift: float, oracle: bool = False) -> dict:
    """:func:`drift_evaluation` on an emulator record (ROS-free): the chapter-4 scanner with
    the sensing comb drifted by ``gain_drift``/``width_drift``, the online detector at
    sigma_DOG = 45 (Sec. 4.6.1: large sigma_DOG better), noise seed ``seed``; the filters'
    model identified on the bench before the drift (:func:`bench_identification`, noise
    seeds from ``seed`` + :data:`BENCH_SEED_OFFSET`), or the nominal table's (``oracle``).
    The result has ``hold_hz``, the programme's hold frequency."""
    from mems_estimation.filters.scanner_threshold_detector import OnlineThresholdDetector
    from mems_sim.devices.scanner import MicroScannerDevice, resolve_scanner

    drift = {"sense_gain_drift": gain_drift, "sense_width_drift": width_drift}
    P, hold = None, None
    if not oracle:
        bench = bench_identification(resolve_scanner({}), seed + BENCH_SEED_OFFSET)
        P, hold = identified_parameters(bench["model"]), bench["hold_hz"]
        drift["sweep_end_hz"] = hold
    dev = MicroScannerDevice(drift, seed=seed)
    rec = dev.step(dev.total_samples)
    det = OnlineThresholdDetector(dog_sigma=45.0)
    n = rec.y.shape[0]
    D = Detections.concat([det.process(rec.y[a : a + 5000]) for a in range(0, n, 5000)])
    segs = snr_segments(rec.y_clean, dev.p["noise_std"], dev.plan.cutoff, dev.fs)
    out = drift_evaluation(rec.theta, rec.omega, rec.y, rec.drive, D, dev.p, segs, P)
    out["hold_hz"] = hold
    return out

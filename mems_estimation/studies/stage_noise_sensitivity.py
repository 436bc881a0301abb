"""Sensitivity of the in-situ gyro scale-factor calibration to the capacitive readout noise,
split by mechanism (Chen 2018 sec. 3.6, Fig. 3.16, for the project's calibration design).

The thesis' Fig. 3.16 plots the standard deviation of the scale-factor calibration error
[ppm] against the sensor noise variance for three mechanisms through which the noise acts:
errors of the identified sensor gap D_n, of the identified sensor gain G (here eta, eq. 44)
and the direct ("stochastic") influence of the noise on the EKF (eqs. 48-53) with a perfectly
identified model. Its finding: the identification errors dominate the stochastic error.

This module repeats the experiment for the calibration design of
:mod:`mems_estimation.identification.stage_insitu` at the temperature of use T2 (the thesis'
35.7 C, where D_n and eta are re-identified with the LDV-like reference, eq. 55): per
calibration sweep the stage model's response at the drive frequency is re-measured from the
capacitive channels (wn, b_c of eqs. 31-34 corrected), the EKF runs on the corrected model
with alpha = 1, beta = 0 and eq. (27) gives the gyro scale factor from the trials'
peak-to-peak rates.

Noise sweep: the readout's RMS electronic noise (the emulator's ``readout_noise_scale``, a
factor on the per-sample standard deviation sigma_y of the transimpedance channels) is
scaled by ``s``, so the noise variance by s^2. All other noise sources are off (LDV rate
noise, drive-amplifier noise); the ADC quantisation (16 bits) stays. The noise draws of a
seed are the same standard normals at every level (common random numbers), so the curves
are smooth in s.

A sensitivity analysis reads the emulator's truth (as the thesis' does): the "perfectly
identified" model is built from the device's true parameters at T2 (wn, zeta, b_c, D_n,
eta per channel, electrode layout, LDV delay), and a noise-free copy of the calibration sweep
(the same motion: with the drive noise off the readout noise is the only random input)
stands for the noise-free data. Per seed and level, each mechanism makes exactly one input
of the design's pipeline noisy, everything else noise-free and true:

``dn``        D_n per channel identified (crest-to-trough distance, eq. 55 a) from a noisy
              LDV training sweep at T2; eta true.
``eta``       eta per channel identified (amplitude match, eq. 55 b) from the noisy training
              sweep with the true D_n.
``dn_eta``    both identified jointly, as the design does (eta follows D_n and partly
              compensates its error).
``insitu``    the in-situ phasor fit (eqs. 44, 46-47, 34) on the noisy calibration channels;
              the EKF fed the noise-free channels.
``ekf``       the stochastic error: the EKF (the design's model-driven Q) fed the noisy
              channels, true model (corrected from the noise-free channels).
``ekf_md``    as ``ekf`` with the thesis' measurement-driven Q (its one-step formula of sec.
              3.5.4, Q ~ 8 V^2 on this emulator): the filter follows the channels.
``design``    end to end: (D_n, eta) identified, phasor fit and EKF on the noisy data.

The scale-factor error of one run is eq. (27) against the gyro's noise-free rates (the
emulator's true rate at the gyro's sample times, times k_I = 1: the gyro's own noise is no
part of this study) relative to eq. (27) with the stage's true rate on the same samples:
``ppm = (k_hat / k_ref - 1) 1e6``. The reported figure per mechanism and level is the
standard deviation of ppm over the seeds (its mean is the method bias, reported apart).

Covariance-based prediction of the stochastic error (the thesis' "based on EKF error
covariance"): each trial's peak-to-peak rate error is taken as the difference of two
independent errors with the EKF's posterior variance P_ww (eq. 53) at crest and trough, and
propagated through eq. (27) (:func:`eq27_rel_slope_std`). This is the single-sample reading
(no credit for the averaging over the trial's periods in the peak-to-peak reduction), so it
bounds a white error from above; the estimate errors of the EKF are correlated in time, so
the measured spread is the figure to rely on.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mems_estimation.filters.stage_ekf import StageEkf, StageModel
from mems_estimation.identification.stage_gyro_calibration import T2, Plan, calibrate
from mems_estimation.identification.stage_identification import (
    _predicted,
    cancelled,
    identify_sensor,
)
from mems_estimation.identification.stage_insitu import (
    correct_model,
    phasors_from_harmonics,
    pooled_response,
    trial_harmonics,
)
from mems_estimation.studies.stage_sf_curve import training_fits
from mems_sim.devices.stage import DriveSchedule, MicroStage, record
from mems_sim.devices.stage_gyro import MemsGyro

__all__ = [
    "NOISE_SCALES",
    "EVAL_SEEDS",
    "MECHANISMS",
    "IDENTIFICATION",
    "Q_MODEL_DRIVEN",
    "Q_MEASUREMENT_DRIVEN",
    "stream_seed",
    "study_stage_params",
    "cancelled_noise_variance",
    "eq27_rel_slope_std",
    "std_interval",
    "true_model",
    "eta_given_gap",
    "NoiseFreeSweep",
    "noise_free_sweep",
    "design_sf_ppm",
    "sensitivity_cell",
    "covariance_prediction_ppm",
    "LevelSummary",
    "summarise",
    "noise_sensitivity_study",
]

#: factors s on the readout's RMS noise (noise variance s^2 times the default's: 0.25x-16x)
NOISE_SCALES = (0.5, 1.0, 2.0, 4.0)
#: evaluation seeds (seed 1, on which the project's designs were tuned, excluded)
EVAL_SEEDS = (2, 3, 4, 5, 6, 7, 8, 9)
#: mechanisms in table order (module doc)
MECHANISMS = ("dn", "eta", "dn_eta", "insitu", "ekf", "ekf_md", "design")
#: the identification mechanisms (Fig. 3.16's D_n and G curves, and their joint effect)
IDENTIFICATION = ("dn", "eta", "dn_eta")
#: input-noise variance Q [V^2] of eq. (49) of the design's EKF: the reference-based
#: selection of the identification ends at the model-driven limit (~1e-13 V^2)
Q_MODEL_DRIVEN = 1e-13
#: the thesis' one-step Q [V^2] (sec. 3.5.4) on this emulator: it measures the LDV's white
#: noise (8.2 V^2 identified at the training temperature on seed 2, short plan), so the
#: EKF follows the channels
Q_MEASUREMENT_DRIVEN = 8.0


def stream_seed(seed: int, temperature_c: float, k: int) -> int:
    """Run seed of record ``k`` (0 training sweep, 1 calibration sweep, 2 gyro) of the study:
    distinct for every (seed, 0.01 C, k) and apart from the other stage studies' seeds. The
    same at every noise level (common random numbers)."""
    return 1_000_000_000 + int(seed) * 1_000_000 + int(round(temperature_c * 100)) * 10 + int(k)


def study_stage_params(
    noise_scale: float, temperature_c: float = T2, stage_params: dict | None = None
) -> dict:
    """Stage parameters of the study: readout noise x ``noise_scale`` (on the RMS), LDV rate
    noise and drive-amplifier noise off, at ``temperature_c`` [C]."""
    return dict(
        stage_params or {},
        readout_noise_scale=float(noise_scale),
        ldv_noise_std=0.0,
        drive_noise_density=0.0,
        temperature_c=float(temperature_c),
    )


def cancelled_noise_variance(sigma: float, fs: float, f_drive: float, lsb: float = 0.0) -> float:
    """Per-sample variance [V^2] of a feedthrough-cancelled channel (sec. 3.5.4) for white
    readout noise of RMS ``sigma`` [V]: y_k - ((1 - r) y_j + r y_j+1), the bias-off value one
    drive period earlier interpolated linearly with r = ceil(d) - d, d = fs / f_drive, so
    sigma^2 (1 + (1 - r)^2 + r^2) (+ the ADC's quantisation lsb^2/12 on each of the three
    samples, weighted alike). This is R_cc of the perfectly identified model (eq. 51)."""
    d = fs / f_drive
    r = math.ceil(d) - d
    w = 1.0 + (1.0 - r) ** 2 + r**2
    return w * (sigma * sigma + lsb * lsb / 12.0)


def eq27_rel_slope_std(omega_ref_pp: Sequence[float], sigma_pp: Sequence[float] | float) -> float:
    """Relative standard deviation of the eq. (27) slope k_I|S caused by independent errors
    of standard deviation sigma_pp,i [rad/s] on the reference's peak-to-peak rates
    omega_S,pp,i (errors in the regressor W of eqs. 24-27), to first order:
    dk/k = -sum (x_i - xbar) d_i / S, S = sum (x_i - xbar)^2, so
    std(dk/k) = sqrt(sum (x_i - xbar)^2 sigma_i^2) / S (sigma / sqrt(S) for equal sigma)."""
    x = np.asarray(omega_ref_pp, float)
    s = np.broadcast_to(np.asarray(sigma_pp, float), x.shape)
    dx = x - x.mean()
    S = float(dx @ dx)
    return float(math.sqrt(float(np.sum(dx * dx * s * s))) / S)


def std_interval(std: float, n: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided confidence interval of a standard deviation ``std`` estimated from ``n``
    Gaussian samples (ddof 1): std sqrt((n-1)/chi2_{1-a/2}), std sqrt((n-1)/chi2_{a/2})."""
    from scipy.stats import chi2

    a = 1.0 - level
    k = n - 1
    return (
        float(std * math.sqrt(k / chi2.ppf(1.0 - a / 2.0, k))),
        float(std * math.sqrt(k / chi2.ppf(a / 2.0, k))),
    )


def true_model(stage: MicroStage, R: float, Q: float = Q_MODEL_DRIVEN) -> StageModel:
    """The perfectly identified model of the device at its current temperature (reads the
    emulator's truth): wn, zeta, b_c (eqs. 31-34), eta and D_n per channel (eqs. 44, 46-47),
    the as-built electrode layout, R = ``R`` I [V^2], Q [V^2], alpha = 1, beta = 0, the true
    LDV delay."""
    return StageModel(
        float(stage.wn),
        float(stage.zeta),
        float(stage.b_c),
        float(stage.fs),
        np.asarray(stage.eta_true, float).copy(),
        np.full(4, float(stage.gap)),
        np.asarray(stage.limits, float).copy(),
        np.eye(4) * float(R),
        float(Q),
        extra={"ldv_delay_s": float(stage.params["ldv_delay_s"])},
    )


def eta_given_gap(fits, gaps: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """eta per channel by the least-squares amplitude match of eq. (55 b) with D_n = ``gaps``
    [m] fixed (the second half of the identification of the sensor parameters): eta_c =
    sum <Y_c, P_c> / sum <P_c, P_c> over the trials' harmonics 1..6, Y the cancelled channel,
    P = dC/dtheta(theta_ref; D_n) omega_ref (eqs. 46-47) from the reference motion."""
    out = np.empty(len(gaps))
    for c, g in enumerate(gaps):
        num = den = 0.0
        for f in fits:
            pr = _predicted(f, float(g), limits[c])
            num += float(np.dot(f.y[1:, c], pr[1:]))
            den += float(np.dot(pr[1:], pr[1:]))
        out[c] = num / den
    return out


def _sf_ref(rec: dict) -> float:
    """Eq. (27) slope with the stage's true rate against the gyro's noise-free rates."""
    return calibrate(rec, rec["omega"][:, 0], gyro_key="gyro_true")["scale_factor"]


def _calibration_record(params: dict, plan: Plan, seed: int, temperature_c: float) -> dict:
    stage = MicroStage(
        params,
        DriveSchedule.amplitude_sweep(n_trials=plan.cal_trials, periods=plan.cal_periods),
        seed=stream_seed(seed, temperature_c, 1),
    )
    gyro = MemsGyro(seed=stream_seed(seed, temperature_c, 2), temperature_c=temperature_c)
    return record(stage, gyro)


@dataclass
class NoiseFreeSweep:
    """The noise-free calibration sweep at the study temperature and what every cell
    reuses: record, cancelled channels, the trials' harmonics (in-situ step 1), the true
    stage (parameters at the temperature) and the reference slope of eq. (27)."""

    temperature_c: float
    plan: Plan
    stage_params: dict
    rec: dict
    yc: np.ndarray
    harmonics: list
    stage: MicroStage
    sf_ref: float
    extra: dict = field(default_factory=dict)


def noise_free_sweep(
    plan: Plan, temperature_c: float = T2, stage_params: dict | None = None
) -> NoiseFreeSweep:
    """Record the noise-free calibration sweep once (see :class:`NoiseFreeSweep`)."""
    p0 = study_stage_params(0.0, temperature_c, stage_params)
    rec = _calibration_record(p0, plan, 0, temperature_c)
    yc = cancelled(rec)
    harm = trial_harmonics(yc, rec["u"], rec["phase"], rec["segment"], rec["f_drive"])
    return NoiseFreeSweep(
        temperature_c,
        plan,
        dict(stage_params or {}),
        rec,
        yc,
        harm,
        MicroStage(p0),
        _sf_ref(rec),
    )


def design_sf_ppm(
    model: StageModel, harmonics: list, y_ekf: np.ndarray, rec: dict, sf_ref: float
) -> tuple[float, dict]:
    """The design's steps on one calibration sweep with the given inputs: Theta per trial
    from ``harmonics`` through the sensor model of ``model`` (eqs. 44, 46-47), pooled
    response G, wn and b_c corrected (eq. 34), EKF (eqs. 48-53, alpha = 1, beta = 0) on
    ``y_ekf``, eq. (27) against the gyro's noise-free rates. Returns (SF error [ppm]
    relative to ``sf_ref``, dict with the corrected model, x, var, cal)."""
    ph = phasors_from_harmonics(harmonics, model)
    G = pooled_response(ph)
    f = float(np.median([p["f"] for p in ph]))
    m = correct_model(model, G, f)
    x, var = StageEkf(m).step(y_ekf, rec["u"], corrected=False)
    cal = calibrate(rec, x[:, 1], gyro_key="gyro_true")
    return (cal["scale_factor"] / sf_ref - 1.0) * 1e6, {"model": m, "x": x, "var": var, "cal": cal}


def covariance_prediction_ppm(
    rec: dict, var_omega: np.ndarray, pairs: list[dict], settle_fraction: float = 0.5
) -> float:
    """Covariance-based prediction of the stochastic SF error [ppm] (module doc): per trial
    the mean posterior variance P_ww [rad^2/s^2] of the bias-on samples within +-15 stage
    samples of the crest and of the trough (settled part), sigma_pp = sqrt(P_crest +
    P_trough), propagated by :func:`eq27_rel_slope_std` with the trials' peak-to-peak
    rates."""
    fs = rec["fs"]
    sig, xs = [], []
    on = rec["v_bias"] > 0
    for p in pairs:
        idx = np.flatnonzero(rec["segment"] == p["segment"])
        idx = idx[int(settle_fraction * idx.size) :]
        f = float(np.median(rec["f_drive"][idx]))
        hw = 15.5 * f / fs
        tot = 0.0
        for p0 in (p["phase_max"], p["phase_min"]):
            d = (rec["phase"][idx] - p0 + 0.5) % 1.0 - 0.5
            sel = (np.abs(d) <= hw) & on[idx]
            tot += float(np.mean(var_omega[idx][sel]))
        sig.append(math.sqrt(tot))
        xs.append(p["stage_pp"])
    return eq27_rel_slope_std(xs, sig) * 1e6


def sensitivity_cell(nf: NoiseFreeSweep, noise_scale: float, seed: int) -> dict:
    """One Monte Carlo cell (noise level, seed): the SF error [ppm] of every mechanism of
    the module doc, the covariance-based predictions of ``ekf`` and ``ekf_md`` [ppm], the
    identified sensor parameters and the cell's run time [s]."""
    t0 = time.perf_counter()
    T, plan = nf.temperature_c, nf.plan
    ps = study_stage_params(noise_scale, T, nf.stage_params)
    st = nf.stage
    sigma = MicroStage(ps).noise_std
    R = cancelled_noise_variance(sigma, st.fs, nf.rec["f_drive"][0], st.lsb)
    mt = true_model(st, R)
    # identification of the sensor parameters from a noisy LDV training sweep (eq. 55)
    fits = training_fits(ps, T, plan, stream_seed(seed, T, 0), mt.extra["ldv_delay_s"])
    gaps, etas, _ = identify_sensor(fits, mt.limits)
    etas_tg = eta_given_gap(fits, mt.gap, mt.limits)
    # the noisy calibration sweep (same motion as the noise-free one)
    rec = _calibration_record(ps, plan, seed, T)
    yc = cancelled(rec)
    harm = trial_harmonics(yc, rec["u"], rec["phase"], rec["segment"], rec["f_drive"])

    def with_sensor(gap=None, eta=None, Q=None):
        m = copy.deepcopy(mt)
        if gap is not None:
            m.gap = np.asarray(gap, float).copy()
        if eta is not None:
            m.eta = np.asarray(eta, float).copy()
        if Q is not None:
            m.Q = float(Q)
        return m

    nf_in = (nf.harmonics, nf.yc, nf.rec, nf.sf_ref)
    runs = {
        "dn": (with_sensor(gap=gaps), *nf_in),
        "eta": (with_sensor(eta=etas_tg), *nf_in),
        "dn_eta": (with_sensor(gap=gaps, eta=etas), *nf_in),
        "insitu": (mt, harm, nf.yc, nf.rec, nf.sf_ref),
        "ekf": (mt, nf.harmonics, yc, rec, nf.sf_ref),
        "ekf_md": (with_sensor(Q=Q_MEASUREMENT_DRIVEN), nf.harmonics, yc, rec, nf.sf_ref),
        "design": (with_sensor(gap=gaps, eta=etas), harm, yc, rec, nf.sf_ref),
    }
    ppm, cov = {}, {}
    for name, args in runs.items():
        ppm[name], info = design_sf_ppm(*args)
        if name in ("ekf", "ekf_md"):
            cov[name] = covariance_prediction_ppm(rec, info["var"][:, 1], info["cal"]["pairs"])
    return {
        "noise_scale": float(noise_scale),
        "seed": int(seed),
        "sigma_v": float(sigma),
        "R_v2": float(R),
        "ppm": ppm,
        "cov_ppm": cov,
        "gap_rel_error": gaps / mt.gap - 1.0,
        "eta_rel_error": etas / mt.eta - 1.0,
        "eta_tg_rel_error": etas_tg / mt.eta - 1.0,
        "seconds": time.perf_counter() - t0,
    }


@dataclass
class LevelSummary:
    """Per noise level: std [ppm] (ddof 1) and mean [ppm] of each mechanism over the seeds,
    their 95 % intervals of the std, the RMS of the covariance predictions [ppm], the
    root-sum-square of the design's independent contributions (joint identification,
    in-situ fit, EKF) [ppm], and the noise figures (sigma_y [V], variance [V^2])."""

    noise_scale: float
    sigma_v: float
    n: int
    std: dict
    mean: dict
    interval: dict
    cov_pred: dict
    rss: float

    @property
    def variance_v2(self) -> float:
        """Per-sample readout noise variance sigma_y^2 [V^2]."""
        return self.sigma_v**2


def summarise(cells: list[dict]) -> list[LevelSummary]:
    """Per noise level (ascending) the statistics of :class:`LevelSummary` over the seeds."""
    out = []
    for s in sorted({c["noise_scale"] for c in cells}):
        cs = [c for c in cells if c["noise_scale"] == s]
        n = len(cs)
        std, mean, ival = {}, {}, {}
        for m in MECHANISMS:
            v = np.array([c["ppm"][m] for c in cs])
            std[m] = float(np.std(v, ddof=1)) if n > 1 else math.nan
            mean[m] = float(np.mean(v))
            ival[m] = std_interval(std[m], n) if n > 1 else (math.nan, math.nan)
        cov = {
            k: float(math.sqrt(np.mean([c["cov_ppm"][k] ** 2 for c in cs])))
            for k in ("ekf", "ekf_md")
        }
        rss = math.sqrt(std["dn_eta"] ** 2 + std["insitu"] ** 2 + std["ekf"] ** 2)
        out.append(LevelSummary(s, cs[0]["sigma_v"], n, std, mean, ival, cov, rss))
    return out


def noise_sensitivity_study(
    noise_scales: Sequence[float] = NOISE_SCALES,
    seeds: Sequence[int] = EVAL_SEEDS,
    plan: Plan | None = None,
    temperature_c: float = T2,
    stage_params: dict | None = None,
    progress=None,
) -> dict:
    """The whole study (module doc): the noise-free sweep, then every (level, seed) cell.
    ``plan`` defaults to :meth:`Plan.short` (4 training trials of 120 periods, 4 calibration
    trials of 400 periods). ``progress``: optional callable(cell) after each cell. Returns
    dict(cells, summary (list of :class:`LevelSummary`), baseline_ppm (the method bias of
    the noise-free pipeline with the true model), seconds, plan, temperature_c, seeds)."""
    t0 = time.perf_counter()
    plan = plan or Plan.short()
    nf = noise_free_sweep(plan, temperature_c, stage_params)
    st = nf.stage
    R0 = cancelled_noise_variance(
        MicroStage(study_stage_params(1.0, temperature_c, stage_params)).noise_std,
        st.fs,
        nf.rec["f_drive"][0],
        st.lsb,
    )
    base, _ = design_sf_ppm(true_model(st, R0), nf.harmonics, nf.yc, nf.rec, nf.sf_ref)
    cells = []
    for s in noise_scales:
        for seed in seeds:
            c = sensitivity_cell(nf, s, seed)
            cells.append(c)
            if progress is not None:
                progress(c)
    return {
        "cells": cells,
        "summary": summarise(cells),
        "baseline_ppm": float(base),
        "sf_ref": float(nf.sf_ref),
        "seconds": time.perf_counter() - t0,
        "plan": plan,
        "temperature_c": float(temperature_c),
        "seeds": tuple(int(s) for s in seeds),
        "noise_std_default_v": float(
            MicroStage(study_stage_params(1.0, temperature_c, stage_params)).noise_std
        ),
    }

"""In-situ correction of the stage model from the capacitive channels (Chen 2018 ch. 3 stage,
sensor eqs. 44-47; a calibration design for a stage that drifts with temperature).

Why: the stage EKF (eqs. 48-53) with a model-driven Q takes its scale from the identified
stage model (wn, b_c of eqs. 31-34), which drifts with temperature (silicon's Young's
modulus moves wn, the piezo's d31 moves b_c); with the thesis' measurement-driven Q it
takes it from the sensor, but its theta wanders with the readout noise and each trial's
peak-to-peak rate carries its own error of a few hundred ppm, which the affine fit of
eq. 27 amplifies by mean/spread of the rates (~2.5 over 1.0-1.3 V).

Design (per calibration sweep, at the temperature of use):

1. The stage is linear and the drive a sinusoid, so in each trial's steady state
   theta(t) = Re(Theta e^{j 2 pi f t}) exactly (the drive amplifier's noise aside); only
   the sensor is nonlinear. Per trial, the feedthrough-cancelled channels (sec. 3.5.4) are
   reduced to their harmonics 1..6 of the drive (least squares over every settled bias-on
   sample: the readout noise averages over ~10^5 samples) and Theta is fitted by
   Gauss-Newton so that the harmonics of y_c = h_c(theta) omega (eqs. 44, 46-47, the
   sensor parameters eta_c, D_n,c of the model) match them, weighted by 1/R_cc.
2. Linearity ties the trials together: the complex response G = Theta/U at the drive
   frequency is one number for every amplitude, pooled as sum(Theta U*)/sum(|U|^2).
3. The stage model is corrected so that its discrete response (eq. 34, ZOH:
   X = (z I - A_d)^-1 B_d U, z = e^{j 2 pi f/fs}) equals G: wn from the phase (zeta kept),
   then b_c from the magnitude. The EKF then runs model-driven on the corrected model, so
   the rates of the trials keep the ratio of their drive amplitudes (no per-trial scatter)
   while their common scale is the sensor's: the capacitive channels carry the result.

The scale of the result rests on the sensor parameters (eta, D_n) in use (the point of the
thesis' Fig. 3.16): identified at the training temperature, or re-identified with the
reference at the temperature of use (the thesis' procedure). Without a reference at the
temperature of use, (theta, D_n, eta) -> (s theta, s D_n, s eta) leaves every channel's
signal unchanged (C(s theta; s D_n) = C(theta; D_n)/s for tan(theta) ~ theta), so a drift of
D_n is not observable from the channels.
"""

from __future__ import annotations

import copy
import math

import numba
import numpy as np
from scipy.optimize import brentq

from mems_estimation.filters.stage_ekf import StageModel, output_h
from mems_estimation.identification.stage_identification import harmonic_fit
from mems_sim.devices.stage import stage_matrices
from mems_sim.devices.stage_capacitance import EPS0

__all__ = [
    "trial_harmonics",
    "phasors_from_harmonics",
    "sensor_phasors",
    "pooled_response",
    "model_response",
    "correct_model",
    "insitu_correct",
]

GRID = 512


@numba.njit(cache=True)
def _signal_grid(a, b, f, eta, gap, lim, eps, ph, out):
    """y_c(phase) = h_c(theta) omega (eqs. 44, 46-47) for theta = a cos + b sin of 2 pi ph."""
    h = np.empty(eta.shape[0])
    w = 2.0 * math.pi * f
    for i in range(ph.shape[0]):
        c = math.cos(2.0 * math.pi * ph[i])
        s = math.sin(2.0 * math.pi * ph[i])
        th = a * c + b * s
        om = w * (-a * s + b * c)
        output_h(th, eta, gap, lim, eps, h)
        for k in range(eta.shape[0]):
            out[i, k] = h[k] * om


def _predicted_harmonics(p, f, model: StageModel, ph) -> np.ndarray:
    out = np.empty((ph.size, model.eta.size))
    _signal_grid(
        float(p[0]),
        float(p[1]),
        float(f),
        np.asarray(model.eta, float),
        np.asarray(model.gap, float),
        np.ascontiguousarray(model.limits, float),
        EPS0 * model.eps_r,
        ph,
        out,
    )
    return harmonic_fit(out, ph)[1:]


def _fit_theta(yh: np.ndarray, f: float, model: StageModel, p0, weights) -> tuple:
    """Gauss-Newton for (a, b) [rad] of theta = a cos + b sin against the harmonics yh
    (2 n_harm, n_ch); returns (a, b, weighted residual RMS)."""
    ph = (np.arange(GRID) + 0.5) / GRID
    p = np.array(p0, float)
    wt = np.sqrt(weights)[None, :]
    for _ in range(30):
        r = ((yh - _predicted_harmonics(p, f, model, ph)) * wt).ravel()
        J = np.empty((r.size, 2))
        for i in range(2):
            d = np.zeros(2)
            d[i] = 1e-7 * max(abs(p[0]) + abs(p[1]), 1e-6)
            J[:, i] = (
                (
                    _predicted_harmonics(p + d, f, model, ph)
                    - _predicted_harmonics(p - d, f, model, ph)
                )
                * wt
            ).ravel() / (2 * d[i])
        step, *_ = np.linalg.lstsq(J, r, rcond=None)
        p = p + step
        if np.max(np.abs(step)) < 1e-13:
            break
    r = ((yh - _predicted_harmonics(p, f, model, ph)) * wt).ravel()
    return float(p[0]), float(p[1]), float(math.sqrt(np.mean(r * r)))


def trial_harmonics(
    y_cancel: np.ndarray,
    u: np.ndarray,
    phase: np.ndarray,
    segment: np.ndarray,
    f_drive: np.ndarray,
    settle_fraction: float = 0.5,
) -> list[dict]:
    """Per trial (segment) of a constant sinusoidal drive: the drive's complex amplitude U
    [V] (relative to e^{j 2 pi phase}) and the harmonics 1..6 of the cancelled channels
    (least squares over the settled, bias-on samples; module doc, step 1, first half).
    Independent of the sensor parameters, so computed once per sweep. Returns dicts
    (segment, f [Hz], U, yh (2 n_harm, n_ch) [V])."""
    out = []
    for s in np.unique(segment):
        idx = np.flatnonzero(segment == s)
        idx = idx[int(settle_fraction * idx.size) :]
        f = float(np.median(f_drive[idx]))
        cu = harmonic_fit(u[idx], phase[idx], 1)
        U = complex(cu[1], -cu[2])
        if not (f > 0) or abs(U) <= 0:
            continue
        yy = y_cancel[idx]
        on = np.all(np.isfinite(yy), axis=1)
        if on.sum() < 100:
            continue
        yh = harmonic_fit(yy[on], phase[idx][on])[1:]
        out.append({"segment": int(s), "f": f, "U": U, "yh": yh})
    return out


def phasors_from_harmonics(harmonics: list[dict], model: StageModel) -> list[dict]:
    """Theta [rad] of each trial fitted through the sensor model (eqs. 44, 46-47) with the
    sensor parameters (eta_c, D_n,c) of ``model`` to the harmonics of
    :func:`trial_harmonics` (module doc, step 1, second half; weights 1/R_cc). Returns
    dicts (segment, f [Hz], U, Theta, residual)."""
    Rd = np.diag(np.atleast_2d(model.R))
    weights = 1.0 / (Rd * np.mean(1.0 / Rd))
    A, B = model.matrices()
    out = []
    for h in harmonics:
        f, U = h["f"], h["U"]
        z = complex(math.cos(2 * math.pi * f / model.fs), math.sin(2 * math.pi * f / model.fs))
        X = np.linalg.solve(z * np.eye(2) - A, np.asarray(B, float).reshape(2) * U)
        a, b, res = _fit_theta(h["yh"], f, model, (X[0].real, -X[0].imag), weights)
        out.append(
            {"segment": h["segment"], "f": f, "U": U, "Theta": complex(a, -b), "residual": res}
        )
    return out


def sensor_phasors(
    y_cancel: np.ndarray,
    u: np.ndarray,
    phase: np.ndarray,
    segment: np.ndarray,
    f_drive: np.ndarray,
    model: StageModel,
    settle_fraction: float = 0.5,
) -> list[dict]:
    """Per trial (segment) of a constant sinusoidal drive: the complex amplitudes of the
    drive U [V] and of the tilt Theta [rad] fitted from the channels (module doc, step 1),
    both relative to e^{j 2 pi phase}. Only the settled part (after ``settle_fraction``
    of the trial) and bias-on samples with a cancelled value are used. Returns dicts
    (segment, f [Hz], U, Theta, residual)."""
    return phasors_from_harmonics(
        trial_harmonics(y_cancel, u, phase, segment, f_drive, settle_fraction), model
    )


def pooled_response(phasors: list[dict]) -> complex:
    """G = sum(Theta U*) / sum(|U|^2) [rad/V] over the trials (module doc, step 2)."""
    num = sum(p["Theta"] * p["U"].conjugate() for p in phasors)
    den = sum(abs(p["U"]) ** 2 for p in phasors)
    return complex(num / den)


def model_response(wn: float, zeta: float, b_c: float, f: float, fs: float) -> complex:
    """theta/u of the ZOH-discretised stage (eq. 34) at f [Hz]: (z I - A_d)^-1 B_d [rad/V]."""
    A, B = stage_matrices(wn, zeta, b_c, 1.0 / fs)
    z = complex(math.cos(2 * math.pi * f / fs), math.sin(2 * math.pi * f / fs))
    return complex(np.linalg.solve(z * np.eye(2) - A, np.asarray(B, float).reshape(2))[0])


def correct_model(model: StageModel, G: complex, f: float, span: float = 0.05) -> StageModel:
    """The model with wn and b_c such that its response at f equals G (module doc, step 3);
    zeta kept. ``span``: relative search interval of wn. ValueError if no wn within it
    matches the phase."""
    target = math.atan2(G.imag, G.real)

    def dphase(wn):
        g = model_response(wn, model.zeta, 1.0, f, model.fs)
        return (math.atan2(g.imag, g.real) - target + math.pi) % (2 * math.pi) - math.pi

    lo, hi = model.wn * (1 - span), model.wn * (1 + span)
    try:
        wn = brentq(dphase, lo, hi, xtol=1e-9 * model.wn)
    except ValueError:
        raise ValueError("in-situ correction: no natural frequency matches the phase") from None
    m = copy.deepcopy(model)
    m.wn = float(wn)
    m.b_c = float(abs(G) / abs(model_response(wn, model.zeta, 1.0, f, model.fs)))
    m.extra = dict(model.extra, insitu_wn_ratio=m.wn / model.wn, insitu_b_c_ratio=m.b_c / model.b_c)
    return m


def insitu_correct(
    model: StageModel,
    y_cancel: np.ndarray,
    u: np.ndarray,
    phase: np.ndarray,
    segment: np.ndarray,
    f_drive: np.ndarray,
    settle_fraction: float = 0.5,
) -> tuple[StageModel, dict]:
    """Steps 1-3 of the module doc on one calibration sweep: (corrected model, report with
    the per-trial phasors, the pooled response G, the relative scatter of the trials'
    Theta/U about it and the trials' harmonics, reusable by :func:`phasors_from_harmonics`
    for other sensor parameters)."""
    harm = trial_harmonics(y_cancel, u, phase, segment, f_drive, settle_fraction)
    ph = phasors_from_harmonics(harm, model)
    if len(ph) < 1:
        raise ValueError("in-situ correction: no trial with a settled drive")
    G = pooled_response(ph)
    scatter = np.array([abs(p["Theta"] / p["U"] / G) - 1 for p in ph])
    f = float(np.median([p["f"] for p in ph]))
    m = correct_model(model, G, f)
    return m, {"phasors": ph, "G": G, "scatter": scatter, "f": f, "harmonics": harm}

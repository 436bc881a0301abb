"""Parameter table and model numbers of the chapter-4 micro-scanner's (hybrid) EKF.

Source: Y. Chen, PhD thesis, U. Michigan 2018, chapter 4 (process model eqs. (68)-(70),
measurement eq. (71), Table 4.2); the filter is
:mod:`mems_estimation.filters.scanner_threshold_ekf`, docs/scanner.md.  The model's defaults
are the device's (:data:`mems_sim.devices.scanner.SCANNER_SPECS`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from scipy.linalg import expm

from mems_sim.devices.scanner import SCANNER_SPECS
from mems_sim.params import ParameterError, ParamSpec, resolve

__all__ = ["EKF_SPECS", "ScannerModel", "scanner_model", "zoh_matrices", "model_from_device"]

_DEV = {s.name: s.default for s in SCANNER_SPECS}

EKF_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "model_natural_freq_hz",
        _DEV["natural_freq_hz"],
        "Hz",
        "wn/2pi of the filter's model",
        "Chen 2018 Sec. 4.4.2 (identified 624.6 Hz)",
        min=1.0,
        max=1.0e6,
    ),
    ParamSpec(
        "model_damping_ratio",
        _DEV["damping_ratio"],
        "-",
        "zeta of the filter's model",
        "Chen 2018 Sec. 4.4.2 (identified 0.0066)",
        min=0.0,
        max=1.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "model_inertia",
        _DEV["inertia"],
        "kg m^2",
        "J of the model (drive torque only)",
        "device design value (mems_sim.devices.scanner)",
        min=0.0,
        max=1.0e-6,
        min_exclusive=True,
    ),
    ParamSpec(
        "model_threshold_angle",
        _DEV["threshold_angle"],
        "rad",
        "theta_th of the model",
        "Chen 2018 Sec. 4.4.2 (calibrated 0.0037 rad)",
        min=-0.1,
        max=0.1,
    ),
    ParamSpec(
        "model_sense_c0",
        _DEV["sense_c0"],
        "F",
        "C0 of the sensing-comb model (105)",
        "identified profile (Fig. 4.5(b) analogue)",
        min=0.0,
        max=1.0e-9,
        min_exclusive=True,
    ),
    ParamSpec(
        "model_sense_theta0",
        _DEV["sense_theta0"],
        "rad",
        "theta0 of the sensing-comb model",
        "identified profile",
        min=1.0e-4,
        max=1.0,
    ),
    ParamSpec(
        "model_drive_c0",
        _DEV["drive_c0"],
        "F",
        "C0 of the driving-comb model",
        "device design value",
        min=0.0,
        max=1.0e-9,
    ),
    ParamSpec(
        "model_drive_theta0",
        _DEV["drive_theta0"],
        "rad",
        "theta0 of the driving-comb model",
        "device design value",
        min=1.0e-4,
        max=1.0,
    ),
    ParamSpec(
        "sense_resistance",
        10.0e6,
        "Ohm",
        "R_s",
        "Table 4.2",
        min=0.0,
        max=1.0e12,
        min_exclusive=True,
    ),
    ParamSpec(
        "bias_voltage", 10.0, "V", "V_bias", "Table 4.2", min=0.0, max=1.0e3, min_exclusive=True
    ),
    ParamSpec("sample_rate_hz", 500.0e3, "Hz", "fs", "Table 4.2", min=1.0e3, max=1.0e9),
    ParamSpec(
        "r_cap",
        0.0435**2,
        "V^2",
        "R_cap, variance of the y_cap noise",
        "Table 4.2: sigma_n = 0.0435 V",
        min=0.0,
        max=1.0e4,
        min_exclusive=True,
    ),
    ParamSpec(
        "r_theta_th",
        1.0e-7,
        "rad^2",
        "R_theta,th: variance of e_theta,th ('fixed') or its "
        "floor added to the eq. (65) term ('canny')",
        "tuned on a calibration seed (Sec. 4.2.3: estimated offline)",
        min=0.0,
        max=1.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "q_torque_std",
        1.0e-9,
        "N m",
        "std of the white torque assumed as process noise (held per sample)",
        "tuned: covers the model error (the device's own 2e-12 N m makes the filter "
        "overconfident, P_tt ~ 1e-13 rad^2 against mrad errors)",
        min=0.0,
        max=1.0e-3,
    ),
    ParamSpec(
        "initial_theta_std",
        0.2,
        "rad",
        "prior std of theta",
        "chosen (covers 0.15 rad)",
        min=0.0,
        max=10.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "initial_omega_std",
        800.0,
        "rad/s",
        "prior std of omega",
        "chosen (covers 0.15 rad x 2 pi 625 Hz)",
        min=0.0,
        max=1.0e6,
        min_exclusive=True,
    ),
    ParamSpec(
        "jacobian",
        "paper",
        "-",
        "measurement Jacobian: full [h' omega, h] or Table 4.1's [0, h]",
        "Chen 2018 Table 4.1",
        choices=("full", "paper"),
    ),
    ParamSpec(
        "lag",
        512,
        "samples",
        "fixed-lag buffer for late detections (>= detector latency)",
        "chosen (detector latency 300 samples)",
        min=1,
        max=1_000_000,
    ),
    ParamSpec(
        "gate",
        5.0,
        "-",
        "innovation gate for detections, in innovation std",
        "chosen",
        min=0.0,
        max=1.0e6,
        min_exclusive=True,
    ),
    ParamSpec(
        "r_theta_mode",
        "canny",
        "-",
        "R_theta,th per detection: 'fixed' (r_theta_th) or "
        "'canny' (eq. (65) timing variance of the detection x (omega Ts)^2 + r_theta_th)",
        "Chen 2018 eq. (65), Sec. 4.2.3",
        choices=("fixed", "canny"),
    ),
    ParamSpec(
        "detection_angle",
        "peak_slope",
        "-",
        "angle assumed at a detection: 'threshold' "
        "(theta_th, Table 4.1) or 'peak_slope' (the angle where dy_cap/dt of the model peaks "
        "for the current amplitude; -> theta_th at large amplitude)",
        "physics of eq. (71) (see module doc)",
        choices=("threshold", "peak_slope"),
    ),
    ParamSpec(
        "r_cap_mode",
        "fixed",
        "-",
        "R_cap of the y_cap update: 'fixed' (r_cap) or 'adaptive' (r_cap x the running mean "
        "of the detections' normalised innovation squared, clipped to [1, r_cap_scale_max])",
        "covariance matching (Mehra 1972) on the threshold detections",
        choices=("fixed", "adaptive"),
    ),
    ParamSpec(
        "r_cap_adapt_rate",
        0.05,
        "-",
        "weight of one detection in the running mean of the NIS ('adaptive')",
        "chosen: ~20 detections (10 periods)",
        min=0.0,
        max=1.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "r_cap_scale_max",
        64.0,
        "-",
        "largest R_cap scale ('adaptive')",
        "tuned on tuning seeds",
        min=1.0,
        max=1.0e6,
    ),
    ParamSpec(
        "estimate_comb",
        False,
        "-",
        "estimate the sensing comb's gain C0 and width theta0 with the state (4-state EKF: "
        "log gain and log width as random walks)",
        "joint state-parameter EKF (Ljung 1979); the drift-invariant theta_th (Sec. 4.2.1) "
        "anchors the angle scale",
    ),
    ParamSpec(
        "comb_gain_std",
        0.2 / math.sqrt(3.0),
        "-",
        "prior std of the log gain of the sensing comb",
        "uniform +-20 % spread of the comb gain (assumed)",
        min=0.0,
        max=10.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "comb_width_std",
        0.1 / math.sqrt(3.0),
        "-",
        "prior std of the log width of the sensing comb",
        "uniform +-10 % spread of the comb width (assumed)",
        min=0.0,
        max=10.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "comb_drift_std",
        0.0,
        "1/sqrt(s)",
        "random-walk std of the comb's log gain and log width (temperature drift)",
        "chosen (constant over a run)",
        min=0.0,
        max=1.0e3,
    ),
    ParamSpec(
        "use_subsample",
        True,
        "-",
        "use the detector's sub-sample offset delta "
        "(H_th = [1, delta Ts]); false: theta_c = theta_th as in Table 4.1",
        "extension of Table 4.1",
    ),
)


class ScannerModel(NamedTuple):
    """Numbers used by the kernels (SI)."""

    Phi: np.ndarray  # (2, 2)
    Gam: np.ndarray  # (2,) response to unit angular acceleration held over Ts
    Q: np.ndarray  # (2, 2)
    J: float
    theta_th: float
    sc0: float
    sth0: float
    dc0: float
    dth0: float
    gain: float  # R_s V_bias
    r_cap: float
    r_th: float
    Ts: float
    full_jac: bool


def zoh_matrices(wn: float, zeta: float, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Phi = expm(A Ts), Gam = int_0^Ts expm(A s) ds [0,1]^T for A = [[0,1],[-wn^2,-2 zeta wn]]."""
    A = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    M = np.zeros((3, 3))
    M[:2, :2] = A
    M[1, 2] = 1.0
    E = expm(M * Ts)
    return E[:2, :2].copy(), E[:2, 2].copy()


def scanner_model(p: Mapping[str, Any]) -> ScannerModel:
    """:class:`ScannerModel` from a resolved :data:`EKF_SPECS` dict."""
    wn = 2.0 * math.pi * p["model_natural_freq_hz"]
    Ts = 1.0 / p["sample_rate_hz"]
    if not p["model_natural_freq_hz"] < p["sample_rate_hz"] / 2:
        raise ParameterError(
            f"parameter 'model_natural_freq_hz' = {p['model_natural_freq_hz']!r}"
            f" is out of range: must be below sample_rate_hz/2"
        )
    Phi, Gam = zoh_matrices(wn, p["model_damping_ratio"], Ts)
    J = p["model_inertia"]
    Q = np.outer(Gam, Gam) * (p["q_torque_std"] / J) ** 2
    return ScannerModel(
        Phi,
        Gam,
        Q,
        J,
        p["model_threshold_angle"],
        p["model_sense_c0"],
        p["model_sense_theta0"],
        p["model_drive_c0"],
        p["model_drive_theta0"],
        p["sense_resistance"] * p["bias_voltage"],
        p["r_cap"],
        p["r_theta_th"],
        Ts,
        p["jacobian"] == "full",
    )


def model_from_device(device_p: Mapping[str, Any], **overrides) -> dict[str, Any]:
    """EKF parameter dict whose model equals a device spec dict (nominal/identified model)."""
    m = {
        "model_natural_freq_hz": device_p["natural_freq_hz"],
        "model_damping_ratio": device_p["damping_ratio"],
        "model_inertia": device_p["inertia"],
        "model_threshold_angle": device_p["threshold_angle"],
        "model_sense_c0": device_p["sense_c0"],
        "model_sense_theta0": device_p["sense_theta0"],
        "model_drive_c0": device_p["drive_c0"],
        "model_drive_theta0": device_p["drive_theta0"],
        "sense_resistance": device_p["sense_resistance"],
        "bias_voltage": device_p["bias_voltage"],
        "sample_rate_hz": device_p["sample_rate_hz"],
        "r_cap": max(device_p["noise_std"] ** 2, 1e-12),
    }
    m.update(overrides)
    return resolve(EKF_SPECS, m)

"""Bench identification of the shared-electrode scanner's filter model (Chen 2018 ch. 5).

ROS-free.  The bench releases the mirror from a set angle with the drive off and records the
AMDM output y [V] (eq. (108): y = a (C_0 exp(-(theta/theta_0)^2) + C_b) + b).  For small
angles y ~ const - a C_0 theta^2/theta_0^2, and theta^2 of the free ring-down
theta = A exp(-zeta w_n t) cos(w_d t) carries a damped sinusoid at 2 w_d decaying at
2 zeta w_n.  :func:`ringdown_fit` fits that damped sinusoid
(``scipy.optimize.least_squares``) and gives w_n and zeta; :func:`identify` turns them into
the filter's spring constant and damping with the design inertia (only w_n = sqrt(k/J) and
zeta = b/(2 sqrt(J k)) enter the normalised dynamics of eqs. (82)-(84) the filter runs).

The comb is mapped as the thesis maps it (Sec. 5.5.1): the AMDM output of a large-swing
ring-down against a reference angle (its optical sensing, Fig. 5.5) gives C_0 and theta_0 of
the Gaussian model (eq. (105)) by :func:`comb_fit`, the chain (circuit gain and bias, the
calibrated square-law curve) being the electronics' known design.

Identified: ``spring_constant``, ``damping`` (through w_n, zeta), ``cap_c0``, ``cap_theta0``.
Kept from the design values the caller passes (the Table 5.2 design, never a drawn
device's): ``inertia``, ``cap_cb`` and the chain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.optimize

from mems_estimation.filters.scanner_amdm_model import filter_measurement
from mems_estimation.identification.model_yaml import load_model, save_model

#: The parameters the identification YAML holds (the estimator's ESTIMATOR_SPECS names):
#: the dynamics from the ring-downs, the comb from the capacitance map.
MODEL_KEYS = ("inertia", "spring_constant", "damping", "cap_c0", "cap_theta0")


def comb_fit(theta_ref, y, p: Mapping[str, Any]) -> dict[str, float]:
    """The capacitance map (Chen 2018 Sec. 5.5.1 with the Gaussian model of eq. (105)):
    C_0 and theta_0 of C_s = C_0 exp(-(theta/theta_0)^2) + C_b by least squares of the
    AMDM output against the filters' measurement function h(theta_ref) (eq. (106) with the
    chain's square-law curve), the chain and C_b held at ``p``.

    Args:
        theta_ref: (n,) reference angle at the instants ``y`` describes (t_k - chain delay)
            [rad]; it must sweep a good part of theta_0 (a large-swing ring-down).
        y: (n,) AMDM output [V].
        p: estimator parameters: the start values ``cap_c0`` [F] and ``cap_theta0`` [rad],
            ``cap_cb`` [F] and the chain (``circuit_gain``, ``circuit_bias``,
            ``chain_square_gain``, ``chain_tangent_capacitance``, ``chain_offset``).

    Returns:
        ``cap_c0`` [F], ``cap_theta0`` [rad] and ``rms_residual`` [V].

    Raises:
        ValueError: sizes differ, too few samples, or the fit does not converge.
    """
    th = np.asarray(theta_ref, dtype=float)
    y = np.asarray(y, dtype=float)
    if th.shape != y.shape or th.ndim != 1 or th.size < 100:
        raise ValueError(
            f"theta_ref and y must be equal 1-d arrays of >= 100 samples: {th.shape}, {y.shape}"
        )
    c0, t0 = float(p["cap_c0"]), float(p["cap_theta0"])
    if np.max(np.abs(th)) < 0.5 * t0:
        raise ValueError(
            f"the reference swing {np.max(np.abs(th)):.3g} rad is too small to map a comb of "
            f"theta_0 {t0:.3g} rad (>= theta_0 / 2)"
        )

    def residual(x):
        return filter_measurement(th, dict(p, cap_c0=x[0] * c0, cap_theta0=x[1] * t0)) - y

    fit = scipy.optimize.least_squares(residual, np.ones(2), x_scale="jac")
    if not fit.success or min(fit.x) <= 0:
        raise ValueError(f"capacitance map failed: {fit.message}")
    return dict(
        cap_c0=float(fit.x[0] * c0),
        cap_theta0=float(fit.x[1] * t0),
        rms_residual=float(np.sqrt(np.mean(fit.fun**2))),
    )


def ringdown_fit(y: np.ndarray, fs: float, f_guess: float) -> dict[str, float]:
    """Fit y[k] = c + exp(-s t) (a cos(w t) + b sin(w t)) + d exp(-s t), t = k / fs, to a
    ring-down record of the AMDM output (the 2 w_d line of theta^2, module doc).

    Args:
        y: AMDM output after the release [V], 1-D.
        fs: sample rate of ``y`` [Hz].
        f_guess: start value of the line's frequency w/(2 pi) [Hz] (e.g. the spectrum's peak).

    Returns:
        dict with ``omega_n`` [rad/s], ``zeta`` [-], ``omega_d`` [rad/s], ``line_hz`` [Hz]
        (w / 2 pi), ``rms_residual`` [V].

    Raises:
        ValueError: the record is too short or the fit does not converge to a decaying line.
    """
    y = np.asarray(y, dtype=float)
    if y.ndim != 1 or y.size < 200:
        raise ValueError(f"ring-down record of {y.size} samples is too short (>= 200)")
    t = np.arange(y.size) / float(fs)
    w0 = 2.0 * math.pi * float(f_guess)

    def model(x):
        c, a, b, d, s, w = x
        e = np.exp(-s * t)
        return c + e * (a * np.cos(w * t) + b * np.sin(w * t) + d)

    # linear start values at the guessed frequency and a decay of 1/(record length)
    s0 = 3.0 / t[-1]
    e = np.exp(-s0 * t)
    basis = np.column_stack([np.ones_like(t), e * np.cos(w0 * t), e * np.sin(w0 * t), e])
    lin, *_ = np.linalg.lstsq(basis, y, rcond=None)
    x0 = np.array([*lin, s0, w0])
    fit = scipy.optimize.least_squares(lambda x: model(x) - y, x0, x_scale="jac")
    c, a, b, d, s, w = fit.x
    if not fit.success or s <= 0 or w <= 0 or math.hypot(a, b) == 0:
        raise ValueError(f"ring-down fit failed: {fit.message}")
    omega_d = 0.5 * w
    sigma = 0.5 * s  # zeta w_n
    omega_n = math.sqrt(omega_d**2 + sigma**2)
    return dict(
        omega_n=float(omega_n),
        zeta=float(sigma / omega_n),
        omega_d=float(omega_d),
        line_hz=float(w / (2.0 * math.pi)),
        rms_residual=float(np.sqrt(np.mean(fit.fun**2))),
    )


def spectral_peak(y: np.ndarray, fs: float, band: tuple[float, float]) -> float:
    """Frequency [Hz] of the largest Hann-windowed spectral line of ``y`` [V] (sampled at
    ``fs`` [Hz]) inside ``band`` = (low, high) [Hz]."""
    y = np.asarray(y, dtype=float) - np.mean(y)
    spec = np.abs(np.fft.rfft(y * np.hanning(y.size)))
    f = np.fft.rfftfreq(y.size, 1.0 / fs)
    m = (f > band[0]) & (f < band[1])
    if not m.any():
        raise ValueError(f"band {band} holds no spectral line of a {y.size}-sample record")
    return float(f[m][np.argmax(spec[m])])


def carrier_stiffness(amplitude, design: Mapping[str, Any]):
    """The carrier's electrostatic stiffness [N m/rad] seen by a swing of ``amplitude`` [rad]
    (first-harmonic describing function of the torque (80) with V^2 = V_c0^2/2 on the
    Gaussian comb C = C_0 exp(-(theta/theta_0)^2)): k_c exp(-u/2) (I0(u/2) - I1(u/2)),
    k_c = V_c0^2 C_0 / (2 theta_0^2), u = (amplitude/theta_0)^2.

    Args:
        amplitude: swing amplitude [rad] (scalar or array).
        design: ``carrier_amplitude`` V_c0 [V], ``cap_c0`` C_0 [F], ``cap_theta0`` theta_0 [rad].
    """
    import scipy.special

    th0 = float(design["cap_theta0"])
    kc = float(design["carrier_amplitude"]) ** 2 * float(design["cap_c0"]) / (2.0 * th0 * th0)
    h = 0.5 * (np.asarray(amplitude, dtype=float) / th0) ** 2
    return kc * (scipy.special.i0e(h) - scipy.special.i1e(h))  # i0e = exp(-h) I0(h)


def frequency_fit(
    y: np.ndarray, fs: float, f_guess: float, design: Mapping[str, Any], a0: float, sigma: float
) -> float:
    """The mechanical w_n = sqrt(k/J) [rad/s] from a large-swing ring-down: y fitted as
    c + exp(-s t) (a cos(phi) + b sin(phi) + d) with phi' = 2 sqrt(w_n^2 + k_c(A(t))/J -
    sigma^2), the carrier's stiffness :func:`carrier_stiffness` along A(t) = a0 exp(-sigma t).

    Args:
        y: AMDM output after the release [V], 1-D. fs: its rate [Hz].
        f_guess: start value of the 2 w_d line [Hz].
        design: design ``inertia`` J [kg m^2] and the comb/carrier values of
            :func:`carrier_stiffness`.
        a0: swing amplitude at the record's first sample [rad]. sigma: zeta w_n [1/s] (from
            a small-swing :func:`ringdown_fit`).
    """
    y = np.asarray(y, dtype=float)
    t = np.arange(y.size) / float(fs)
    shift = carrier_stiffness(a0 * np.exp(-sigma * t), design) / float(design["inertia"])
    shift -= sigma * sigma
    first = ringdown_fit(y, fs, f_guess)

    def model(x):
        c, a, b, d, s, wn = x
        w = 2.0 * np.sqrt(wn * wn + shift)
        phi = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) / fs)])
        e = np.exp(-s * t)
        return c + e * (a * np.cos(phi) + b * np.sin(phi) + d)

    s0 = 2.0 * first["zeta"] * first["omega_n"]
    wn0 = math.sqrt(max(first["omega_d"] ** 2 - float(np.mean(shift)), 1.0))
    w = 2.0 * np.sqrt(wn0 * wn0 + shift)
    phi = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) / fs)])
    e = np.exp(-s0 * t)
    basis = np.column_stack([np.ones_like(t), e * np.cos(phi), e * np.sin(phi), e])
    lin, *_ = np.linalg.lstsq(basis, y, rcond=None)
    fit = scipy.optimize.least_squares(
        lambda x: model(x) - y, np.array([*lin, s0, wn0]), x_scale="jac"
    )
    if not fit.success:
        raise ValueError(f"frequency fit failed: {fit.message}")
    return float(fit.x[5])


def identify(
    y_small: np.ndarray,
    y_large: np.ndarray,
    fs: float,
    design: Mapping[str, Any],
    band: tuple[float, float],
    a_large: float,
) -> dict[str, Any]:
    """The filter model from two ring-down records (drive off).

    Args:
        y_small: AMDM output [V] of a small-swing release (the line decays at 2 zeta w_n:
            zeta), 1-D.
        y_large: AMDM output [V] of a large-swing release (w_n, :func:`frequency_fit`).
        fs: their sample rate [Hz].
        design: design values: ``inertia`` J [kg m^2] (kept; k = J w_n^2 and
            b = 2 zeta J w_n, eqs. (82)-(84)) and the comb/carrier of
            :func:`carrier_stiffness`.
        band: search band [Hz] of the 2 w_d line.
        a_large: swing amplitude [rad] at the first sample of ``y_large``.

    Returns:
        dict with :data:`MODEL_KEYS` (J [kg m^2], k [N m/rad], b [N m s/rad]) and
        ``omega_n`` [rad/s], ``zeta`` [-], ``rms_residual`` [V] (small-swing fit).
    """
    small = ringdown_fit(y_small, fs, spectral_peak(y_small, fs, band))
    sigma = small["zeta"] * small["omega_n"]
    wn = frequency_fit(y_large, fs, spectral_peak(y_large, fs, band), design, a_large, sigma)
    return dynamics(float(design["inertia"]), wn, sigma / wn, small["rms_residual"])


def identify_with_reference(
    y: np.ndarray,
    theta_ref: np.ndarray,
    fs: float,
    design: Mapping[str, Any],
    band: tuple[float, float],
) -> dict[str, Any]:
    """The filter model from one large-swing ring-down (drive off) recorded with a
    reference angle, as the thesis fits the decay of its optically measured ring-down
    (Sec. 5.5.1, Fig. 5.6): zeta w_n from the reference's damped sinusoid (linear in theta:
    none of the comb's harmonics that bias a fit of the AMDM output), w_n from the AMDM
    output's 2 w_d line with the carrier's stiffness along the swing (:func:`frequency_fit`).

    Args:
        y: AMDM output [V] after the release, 1-D.
        theta_ref: reference angle [rad] at the instants ``y`` describes, same length.
        fs: their sample rate [Hz].
        design: design ``inertia`` J [kg m^2] and the comb/carrier of
            :func:`carrier_stiffness` (the mapped comb, :func:`comb_fit`).
        band: search band [Hz] of the 2 w_d line.

    Returns:
        dict with :data:`MODEL_KEYS`' dynamics (J [kg m^2], k [N m/rad], b [N m s/rad]),
        ``omega_n`` [rad/s], ``zeta`` [-] and ``rms_residual`` [rad] (the reference's fit).
    """
    th = np.asarray(theta_ref, dtype=float)
    line = spectral_peak(y, fs, band)
    ref = ringdown_fit(th, fs, 0.5 * line)  # its "2 w_d" line is w_d: halves stay halved
    sigma = 2.0 * ref["zeta"] * ref["omega_n"]  # the fit's decay s is sigma itself
    n = max(int(fs / (0.5 * line)), 1)
    a0 = float(np.max(np.abs(th[:n])))
    wn = frequency_fit(y, fs, line, design, a0, sigma)
    return dynamics(float(design["inertia"]), wn, sigma / wn, ref["rms_residual"])


def dynamics(J: float, wn: float, zeta: float, rms_residual: float) -> dict[str, float]:
    """The filter's dynamics (eqs. (82)-(84)) from J [kg m^2], w_n [rad/s] and zeta [-]:
    k = J w_n^2 [N m/rad], b = 2 zeta J w_n [N m s/rad], with the fit's ``rms_residual``."""
    return dict(
        inertia=J,
        spring_constant=J * wn * wn,
        damping=2.0 * zeta * J * wn,
        omega_n=wn,
        zeta=zeta,
        rms_residual=rms_residual,
    )


def average(models: list[Mapping[str, Any]]) -> dict[str, Any]:
    """The mean of :func:`identify` results of repeated releases: w_n [rad/s] and zeta [-]
    averaged, k [N m/rad] and b [N m s/rad] recomputed from them with the design J."""
    if not models:
        raise ValueError("no identification to average")
    return dynamics(
        float(models[0]["inertia"]),
        float(np.mean([m["omega_n"] for m in models])),
        float(np.mean([m["zeta"] for m in models])),
        float(np.mean([m["rms_residual"] for m in models])),
    )


def save_identification(model: Mapping[str, Any], path: str) -> None:
    """Write the identified model (:data:`MODEL_KEYS` and the fit's figures) as the
    estimator's parameter YAML at ``path``, whole and never through a symbolic link
    (:func:`mems_sim.bag.output_paths.write_output`)."""
    save_model(model, path)


def load_identification(path: str) -> dict[str, float]:
    """The model parameters (:data:`MODEL_KEYS`: J [kg m^2], k [N m/rad], b [N m s/rad],
    C_0 [F], theta_0 [rad]) of a YAML written by :func:`save_identification`;
    FileNotFoundError / ValueError."""
    return load_model(path, MODEL_KEYS, "scanner AMDM parameter YAML", positive=True)

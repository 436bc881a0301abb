"""Bench identification of the force-rebalance accelerometer's model (Zhang 2010, ch. 2).

The lab's record: the sensor on a shaker (or a tilt table) driven with a known square wave
of acceleration ``a(t)`` [m/s^2], its readout ``y`` [V] (the demodulated charge amplifier
after the ADC, eq. 2-9) sampled at ``fs`` [Hz], in two configurations of the electronics:

* **carrier only** (the open loop of Fig. 7/14: no bias, no feedback voltage);
* **carrier and bias** ``V_B`` on both rebalance electrodes with no feedback (``v_F = 0``:
  the PI loop with its gains at 0).

The electrostatic spring of the carrier and of the bias softens the suspension
(eq. 2-15 linearised: ``F_el = eps A (V1^2 + 2 V_B^2) x / d0^3`` at ``v_F = 0``), so for
small displacements each configuration is the linear system of eq. (2-1)
``x'' + (b0/m) x' + w_c^2 x = a`` with ``w_c^2 = k/m - eps A (V1^2 + 2 V_B^2)/(m d0^3)``
and the readout ``y = -H x``, ``H = 2 eps A V1/(C4 d0^2)`` (eqs. 2-10, 5-3). The bias
lowers ``w_c^2`` by ``2 (eps A/m) V_B^2/d0^3`` -- the electrostatic spring-softening
measurement of a MEMS bench.

Fit (:func:`response_fit`): output-error least squares (``scipy.optimize.least_squares``)
of both records at once over ``b0/m`` [1/s], ``w^2`` of each configuration [rad^2/s^2]
and ``H`` [V/m], each record's offset solved linearly inside (variable projection, Golub &
Pereyra 1973); the model is simulated by its exact discretisation for an input linear
between samples (``scipy.signal.cont2discrete``, first-order hold), which the bench's
square wave is: every transition is a ramp over one sample period.

Physical model (:func:`physical_model`): the electronics' settings ``V1``, ``C4``, ``V_B``
and the electrode's ``eps A`` (area and dielectric: lithography, not a batch spread) are
the lab's known values; then ``d0 = sqrt(2 eps A V1/(C4 H))``, ``m = eps A /
alpha`` with ``alpha = (w_open^2 - w_bias^2) d0^3 / (2 V_B^2)``, ``b0 = m (b0/m)`` and
``k = m w_open^2 + eps A V1^2/d0^3``. The readout noise is the fit residual's, less the
converter's ``lsb^2/12``, referred to acceleration as the parameter table does (Zhang
section 3.1.2). The Brownian level (the filter's Q) is not identified: it stays the
tuning value it is in the thesis (Table IV sweeps it).

Nothing here reads the emulator's parameter table; the result is the hybrid EKF's parameter
YAML (:func:`save_identification`, read by :func:`load_identification`), loaded by the
``accelerometer_ekf`` node (``params_yaml``) and by the in-loop EKF of the device
(``loop_params_yaml``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import cont2discrete, lfilter, ss2tf

from mems_estimation.identification.model_yaml import save_model
from mems_sim.devices.accelerometer import ACCEL_SPECS, LOOP_MODEL_KEYS
from mems_sim.model_file import load_model

__all__ = [
    "MODEL_KEYS",
    "SQUARE_HALF_PERIOD_S",
    "ResponseFit",
    "square_wave",
    "square_wave_rows",
    "simulate",
    "response_fit",
    "physical_model",
    "identify",
    "save_identification",
    "load_identification",
]

#: The model parameters the identification gives (``ACCEL_SPECS`` names, SI units).
MODEL_KEYS = LOOP_MODEL_KEYS
#: Half period of the bench's square wave [s]: about the slow pole's time constant
#: (b0/k_eff is ~0.7 ms on Table I's device), so that every half period shows both poles
#: and the record is mostly transient. Measured on device draws 1-3 (1 g, 0.1 s per
#: record): at 2.5 ms the settled plateaus, where the parallel-plate nonlinearity
#: (~0.1 % at 1 g) is all the fit sees of the model, bias k and b0 by up to 19 %; at
#: 0.5 ms every error is below 1 %.
SQUARE_HALF_PERIOD_S = 0.5e-3


class ResponseFit(NamedTuple):
    """Result of :func:`response_fit`: b0/m [1/s], w^2 of the carrier-only and the biased
    record [rad^2/s^2], readout gain H [V/m], their standard errors (same units, from
    the Jacobian), residual std of each record [V], samples, evaluations."""

    damping_per_mass: float
    omega2_open: float
    omega2_bias: float
    readout_gain: float
    std_errors: tuple[float, float, float, float]
    residual_std: tuple[float, float]
    n: int
    nfev: int


def square_wave(n: int, fs: float, amplitude: float, half_period_s: float) -> np.ndarray:
    """The bench's input at the sample instants k/fs, k = 0..n-1 [m/s^2]: +-``amplitude``
    starting at 0, switching every ``half_period_s`` [s], each switch a ramp over one sample
    period (the input is linear between samples)."""
    t_rows, a_rows = square_wave_rows(n / fs, fs, amplitude, half_period_s)
    return np.interp(np.arange(n) / fs, t_rows, a_rows)


def square_wave_rows(
    duration_s: float, fs: float, amplitude: float, half_period_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """(time [s], acceleration [m/s^2]) rows of :func:`square_wave` over ``duration_s``, as
    a shaker's profile (linear between rows): 0 for one half period, then +-amplitude
    alternately, every switch from sample instant to the next."""
    half = max(int(round(half_period_s * fs)), 2)
    n = int(math.ceil(duration_s * fs)) + 1
    t, a, level = [0.0], [0.0], 0.0
    sign = 1.0
    for k in range(half, n, half):
        t.append(k / fs)
        a.append(level)
        level = sign * amplitude
        sign = -sign
        t.append((k + 1) / fs)
        a.append(level)
    t.append(max(n / fs, t[-1] + 1.0 / fs))
    a.append(level)
    return np.asarray(t), np.asarray(a)


def simulate(
    accel: np.ndarray, fs: float, damping_per_mass: float, omega2: float, gain: float
) -> np.ndarray:
    """Readout y = -H x [V] of x'' + (b0/m) x' + w^2 x = a from rest (eqs. 2-1, 2-10 small
    signal), exact for an input linear between samples (first-order hold). accel
    [m/s^2] at the sample instants, fs [Hz], b0/m [1/s], w^2 [rad^2/s^2], H [V/m]."""
    a_mat = np.array([[0.0, 1.0], [-omega2, -damping_per_mass]])
    b_mat = np.array([[0.0], [1.0]])
    c_mat = np.array([[-gain, 0.0]])
    ad, bd, cd, dd, _ = cont2discrete((a_mat, b_mat, c_mat, np.zeros((1, 1))), 1.0 / fs, "foh")
    num, den = ss2tf(ad, bd, cd, dd)
    return lfilter(num[0], den, np.asarray(accel, dtype=float))


def response_fit(
    records: Mapping[str, tuple[np.ndarray, np.ndarray]],
    fs: float,
    guess: Mapping[str, float],
) -> ResponseFit:
    """b0/m, w^2 per configuration and H from the two bench records (module doc).

    Args:
        records: ``open`` and ``bias``: (input acceleration [m/s^2], readout [V]) at the
            sample instants, each from rest.
        fs: sample rate [Hz].
        guess: start values ``damping_per_mass`` [1/s], ``omega2_open``, ``omega2_bias``
            [rad^2/s^2] and ``readout_gain`` [V/m] (design values; the fit converges from
            tens of percent).

    Raises:
        ValueError: a record missing, of unequal lengths or too short, or the fit failed.
    """
    for name in ("open", "bias"):
        if name not in records:
            raise ValueError(f"accelerometer bench record {name!r} missing")
        a, y = records[name]
        if len(a) != len(y) or len(a) < 1000:
            raise ValueError(f"accelerometer bench record {name!r}: need >= 1000 paired samples")
    keys = ("damping_per_mass", "omega2_open", "omega2_bias", "readout_gain")
    scale = np.array([abs(float(guess[k])) for k in keys])
    if not np.all(np.isfinite(scale)) or np.any(scale == 0):
        raise ValueError(f"accelerometer bench: start values must be finite and nonzero: {guess}")
    data = [
        (np.asarray(records[n][0], float), np.asarray(records[n][1], float))
        for n in ("open", "bias")
    ]

    def residuals(u):
        th = u * scale
        if np.any(th <= 0):
            return np.full(sum(y.size for _, y in data), 1.0)
        out = []
        for (a, y), w2 in zip(data, (th[1], th[2]), strict=True):
            s = simulate(a, fs, th[0], w2, th[3])
            r = y - s
            out.append(r - r.mean())
        return np.concatenate(out)

    r = least_squares(residuals, np.ones(4), method="lm", x_scale=np.ones(4))
    th = r.x * scale
    if not r.success or np.any(th <= 0) or th[2] >= th[1]:
        raise ValueError(f"accelerometer bench fit failed: {r.message} ({dict(zip(keys, th))})")
    n0 = data[0][1].size
    res = r.fun
    dof = max(res.size - 6, 1)
    s2 = float(res @ res) / dof
    try:
        cov = np.linalg.inv(r.jac.T @ r.jac) * s2
        se = tuple(float(v) for v in np.sqrt(np.clip(np.diag(cov), 0.0, None)) * scale)
    except np.linalg.LinAlgError:
        se = (math.nan,) * 4
    return ResponseFit(
        float(th[0]),
        float(th[1]),
        float(th[2]),
        float(th[3]),
        se,
        (float(np.std(res[:n0])), float(np.std(res[n0:]))),
        int(res.size),
        int(r.nfev),
    )


def physical_model(fit: ResponseFit, design: Mapping[str, float]) -> dict[str, float]:
    """The model parameters (:data:`MODEL_KEYS`) from the fit and the lab's known values
    (module doc). ``design``: ``eps_area`` [F m] (eps0 eps_r A), ``carrier_amplitude`` V1
    [V], ``feedback_capacitor`` C4 [F], ``bias_voltage`` V_B [V] (the bias the biased
    record had), ``adc_lsb`` [V]. ValueError if the softening does not give a mass > 0."""
    ea, v1, c4, vb = (
        float(design[k])
        for k in ("eps_area", "carrier_amplitude", "feedback_capacitor", "bias_voltage")
    )
    d0 = math.sqrt(2.0 * ea * v1 / (c4 * fit.readout_gain))
    alpha = (fit.omega2_open - fit.omega2_bias) * d0**3 / (2.0 * vb * vb)
    if not alpha > 0:
        raise ValueError("accelerometer bench: the bias does not soften the suspension")
    m = ea / alpha
    k = m * fit.omega2_open + ea * v1 * v1 / d0**3
    sigma_v = math.sqrt(max(fit.residual_std[0] ** 2 - float(design["adc_lsb"]) ** 2 / 12.0, 0.0))
    return dict(
        mass=m,
        stiffness=k,
        damping=m * fit.damping_per_mass,
        gap=d0,
        # referred to acceleration through H m/k as the parameter table does (section 3.1.2)
        electronic_accel_std=sigma_v * k / (fit.readout_gain * m),
    )


def identify(
    records: Mapping[str, tuple[np.ndarray, np.ndarray]],
    fs: float,
    design: Mapping[str, float],
    guess: Mapping[str, float],
) -> dict[str, Any]:
    """The hybrid EKF's model from the bench's records (:func:`response_fit`,
    :func:`physical_model`; arguments and units there): {``model``: :data:`MODEL_KEYS`,
    ``fit``: the :class:`ResponseFit`}."""
    fit = response_fit(records, fs, guess)
    return dict(model=physical_model(fit, design), fit=fit)


def save_identification(model: Mapping[str, Any], path: str) -> None:
    """Write the identified model (:data:`MODEL_KEYS`, plus any extra numbers) as the
    hybrid EKF's parameter YAML, whole and never through a symbolic link (BagWriteError)."""
    save_model(model, path)


def load_identification(path: str) -> dict[str, float]:
    """The model parameters (:data:`MODEL_KEYS`, SI units) of a parameter YAML written by
    :func:`save_identification`, each checked against its ``ACCEL_SPECS`` entry;
    FileNotFoundError / ValueError with a clear message."""
    return load_model(path, MODEL_KEYS, "accelerometer parameter YAML", specs=ACCEL_SPECS)

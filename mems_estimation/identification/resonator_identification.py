"""Bench identification of the pulse-actuated resonator's f0 and Q (Colinet et al., Sec. 6).

The lab's record: ring-downs. The device runs in its pulse loop, the pulse driver is
switched off, the resonator rings down freely, and this repeats; recorded are the one-bit
modulator output (``bits`` -1/+1, full scale +-1 V, sampled at ``fs`` [Hz]) of each
ring-down. No position sensor is needed.

Model: after the pulses stop, Colinet eq. (7), H(s) = w0/(s^2 + s w0/Q + w0^2), leaves a
damped sinusoid x(k) = exp(-sigma k) (a cos(wd k) + b sin(wd k)), sigma = w0/(2Q),
wd = w0 sqrt(1 - 1/(4 Q^2)) (w0 in rad per sample, w0 = 2 pi f0/fs). Any linear
time-invariant filter after it -- the modulator's STF (eq. 11, with whatever effective gain
the one-bit quantiser has) and the low-pass that removes the NTF-shaped quantisation noise
(eq. 12) -- keeps sigma and wd and only changes a and b: a ring-down identifies f0 and Q
independently of the modulator's gain and phase, which is why a lab measures them so
(a fit of the driven loop through the STF trades the quantiser's gain against Q).

Fit (:func:`ringdown_fit`): the same causal low-pass (4th-order Butterworth at
:data:`LOWPASS` of the Nyquist rate) on every ring-down, its first :data:`SETTLE` samples
dropped (the filters' transients), then nonlinear least squares
(``scipy.optimize.least_squares``, Levenberg-Marquardt) over f0 [Hz] and Q [-] with each
ring-down's a, b and offset solved linearly inside (variable projection, Golub & Pereyra
1973).

Nothing here reads the emulator's parameter table: the result is the observer's parameter
YAML (:func:`save_identification`, read by :func:`load_identification`), the model the
``resonator_observer`` node loads through its ``params_yaml`` parameter.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import butter, lfilter

from mems_estimation.identification.model_yaml import load_model, save_model
from mems_sim.devices.resonator import LOOP_MODEL_KEYS

__all__ = [
    "MODEL_KEYS",
    "RingdownFit",
    "damped_sinusoid",
    "ringdown_fit",
    "identify",
    "save_identification",
    "load_identification",
]

#: The observer parameters the identification gives (``resonator_observer`` node names).
MODEL_KEYS = LOOP_MODEL_KEYS
#: Cut-off of the low-pass applied to the bits, fraction of the Nyquist rate.
LOWPASS = 0.15
#: Samples dropped at the start of each ring-down (modulator and low-pass transients).
SETTLE = 100


class RingdownFit(NamedTuple):
    """Result of :func:`ringdown_fit`: f0 [Hz], Q [-], residual std [V] of the low-passed
    fit, ring-downs and samples used, least-squares evaluations."""

    f0_hz: float
    quality_factor: float
    residual_std: float
    segments: int
    n: int
    nfev: int


def damped_sinusoid(f0: float, Q: float, fs: float, n: int) -> np.ndarray:
    """(n, 2) columns exp(-sigma k) cos(wd k), exp(-sigma k) sin(wd k), k = 0..n-1: the
    free response of Colinet eq. (7) (module doc). f0 [Hz], Q [-], fs [Hz], n samples."""
    w0 = 2.0 * math.pi * f0 / fs
    sigma = w0 / (2.0 * Q)
    wd = w0 * math.sqrt(max(1.0 - 1.0 / (4.0 * Q * Q), 0.0))
    k = np.arange(n, dtype=float)
    e = np.exp(-sigma * k)
    return np.column_stack([e * np.cos(wd * k), e * np.sin(wd * k)])


def ringdown_fit(
    ringdowns: Sequence[np.ndarray], fs: float, f0_guess: float, q_guess: float
) -> RingdownFit:
    """f0 and Q from ring-downs of the one-bit stream (module doc).

    Args:
        ringdowns: the bits (-1/+1, full scale +-1 V) of each ring-down, from the sample
            the pulse driver was switched off (at least :data:`SETTLE` + 100 samples each).
        fs: sample rate [Hz]. f0_guess: start value of f0 [Hz] (the design value; the fit
            converges from within a few percent). q_guess: start value of Q [-].

    Raises:
        ValueError: no usable ring-down, or the fit failed.
    """
    bl, al = butter(4, LOWPASS)
    segs = [
        lfilter(bl, al, np.asarray(b, dtype=float))[SETTLE:]
        for b in ringdowns
        if len(b) >= SETTLE + 100
    ]
    if not segs:
        raise ValueError(f"no ring-down of at least {SETTLE + 100} samples")

    def residuals(th):
        if not (0.0 < th[0] < fs / 2 and th[1] > 0.5):
            return np.full(sum(y.size for y in segs), 10.0)
        out = []
        for y in segs:
            X = np.column_stack([damped_sinusoid(th[0], th[1], fs, y.size), np.ones(y.size)])
            c, *_ = np.linalg.lstsq(X, y, rcond=None)
            out.append(y - X @ c)
        return np.concatenate(out)

    r = least_squares(
        residuals,
        [float(f0_guess), float(q_guess)],
        x_scale=[0.01 * f0_guess, 0.1 * q_guess],
        method="lm",
    )
    f0, q = (float(v) for v in r.x)
    if not r.success or not (0.0 < f0 < fs / 2 and q > 0.5):
        raise ValueError(f"resonator ring-down fit failed: {r.message} (f0 {f0!r} Hz, Q {q!r})")
    n = sum(y.size for y in segs)
    return RingdownFit(f0, q, float(np.std(r.fun)), len(segs), n, int(r.nfev))


def identify(
    ringdowns: Sequence[np.ndarray], fs: float, f0_guess: float, q_guess: float
) -> dict[str, Any]:
    """The observer's model from the bench's ring-downs (:func:`ringdown_fit`; arguments
    and units there): {``model``: {f0_hz [Hz], quality_factor [-]}, ``fit``: the
    :class:`RingdownFit`}."""
    fit = ringdown_fit(ringdowns, fs, f0_guess, q_guess)
    return dict(model=dict(f0_hz=fit.f0_hz, quality_factor=fit.quality_factor), fit=fit)


def save_identification(model: Mapping[str, Any], path: str) -> None:
    """Write the identified model (:data:`MODEL_KEYS`, plus any extra numbers) as the
    observer's parameter YAML, whole and never through a symbolic link
    (:func:`mems_sim.bag.output_paths.write_output`; BagWriteError)."""
    save_model(model, path)


def load_identification(path: str) -> dict[str, float]:
    """The model parameters (:data:`MODEL_KEYS`: f0_hz [Hz], quality_factor [-]) of a
    parameter YAML written by :func:`save_identification`; FileNotFoundError / ValueError
    with a clear message."""
    return load_model(path, MODEL_KEYS, "resonator parameter YAML", positive=True)

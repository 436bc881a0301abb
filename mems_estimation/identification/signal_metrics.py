"""Output-quality figures shared by scenarios: coherent SNR, error statistics.

Output SNR (used for every controller mode of the accelerometer, Zhang 2010 Tables III
and IV): the output is fitted by least squares with ``c1 sin(w t) + c2 cos(w t) + c0``
at the known input frequency (coherent demodulation over whole periods); the signal
power is ``(c1^2 + c2^2)/2``, the noise power is the variance of the residual at the
output's own sample rate (everything that is not the input tone: noise, harmonics from
nonlinearity, drift). The output's scale factor cancels, so outputs in volts and in
m/s^2 are compared on the same footing.
"""

from __future__ import annotations

import math

import numpy as np


def tone_fit(y: np.ndarray, t: np.ndarray, freq_hz: float) -> tuple[float, float, np.ndarray]:
    """Least-squares tone at ``freq_hz``: (amplitude, phase [rad], residual).

    ``y ~ A sin(2 pi f t + phase) + offset``; y in any unit, t in s.
    """
    w = 2.0 * math.pi * freq_hz
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    c, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return float(math.hypot(c[0], c[1])), float(math.atan2(c[1], c[0])), y - basis @ c


def coherent_snr_db(y: np.ndarray, t: np.ndarray, freq_hz: float) -> float:
    """Output SNR [dB]: fitted tone power over residual variance (module docstring)."""
    amp, _, res = tone_fit(np.asarray(y, float), np.asarray(t, float), freq_hz)
    return 10.0 * math.log10(0.5 * amp * amp / float(np.var(res)))


def batch_mean_stderr(e: np.ndarray, batches: int = 20) -> float:
    """Standard error of the mean of a correlated series by non-overlapping batch means."""
    e = np.asarray(e, float)
    n = e.size // batches
    means = e[: n * batches].reshape(batches, n).mean(axis=1)
    return float(means.std(ddof=1) / math.sqrt(batches))


def consistency(err: np.ndarray, predicted_var: np.ndarray) -> dict:
    """Error statistics against the filter's own covariance (NEES-style, one state).

    Returns mean, its batch-means standard error, std, the predicted std
    ``sqrt(mean(P))``, their ratio and the mean normalised error squared ``mean(e^2/P)``.
    """
    err = np.asarray(err, float)
    pv = np.asarray(predicted_var, float)
    pred = math.sqrt(float(np.mean(pv)))
    return dict(
        mean=float(err.mean()),
        stderr=batch_mean_stderr(err),
        std=float(err.std()),
        predicted_std=pred,
        std_ratio=float(err.std()) / pred,
        nees=float(np.mean(err * err / pv)),
    )

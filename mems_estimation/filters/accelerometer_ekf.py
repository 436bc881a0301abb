"""Streaming hybrid EKF of the force-rebalance accelerometer (Zhang 2010, section 4.2.6,
eqs. 4-48 .. 4-57) as an estimator: a block filter over recorded readout samples.

The per-sample predict/update kernels and the configuration live on the device side
(:mod:`mems_sim.kernels.accelerometer_ekf`) because the device runs the same filter inside
its rebalance loop; the model of a parameter set is :func:`mems_sim.devices.accelerometer.ekf_config`.
"""

from __future__ import annotations

import numba
import numpy as np

from mems_sim.kernels.accelerometer_ekf import (
    HybridEkfConfig,
    ekf_init,
    ekf_predict,
    ekf_update_innovation,
    is_positive_definite,
)
from mems_sim.kernels.divergence import covariance_ok, state_ok

__all__ = [
    "HEALTH_WINDOW",
    "FAULT_FREE_NIS_MEAN",
    "FAULT_FREE_NIS_DISPERSION",
    "HEALTH_MOMENTS_SOURCE",
    "HybridEkf",
    "HybridEkfConfig",
]

#: Samples per window of the innovation consistency monitor (1 ms at 1 MHz): the loop
#: nulls a readout offset within about 20 samples, so the NIS excess of a step is short and
#: a window much longer than that dilutes it (at 10000 samples 3 of 30 steps of 5 innovation
#: standard deviations were detected, at 1000 all 40).
HEALTH_WINDOW = 1000
#: Fault-free moments of this filter's NIS on the nominal device in PI rebalance (defaults
#: of ACCEL_SPECS), measured with nis_moments over windows of HEALTH_WINDOW samples on
#: noise seeds 1 and 2 (2e7 samples): the mean NIS per sample, below 1 (S is about 1 %
#: larger than the innovations' variance), and the dispersion of a window sum.
FAULT_FREE_NIS_MEAN = 0.9908
FAULT_FREE_NIS_DISPERSION = 0.968
HEALTH_MOMENTS_SOURCE = (
    "measured: fault-free PI rebalance, nominal device, noise seeds 1 and 2, 2e7 samples, "
    "windows of 1000"
)


@numba.njit(cache=True)
def _run(y, v_f, dt, q, r, mv, s, pm, est, var, innov, sv, pd):
    """Filter a block: update with y[i], record, predict with v_f[i] (Fig. 17 timing);
    innov[i] and sv[i] are the innovation and its variance S = H P H^T + R (eq. 4-55)."""
    for i in range(y.shape[0]):
        innov[i], sv[i] = ekf_update_innovation(s, pm, y[i], r, mv)
        for j in range(3):
            est[i, j] = s[j]
            var[i, j] = pm[j, j]
        pd[i] = is_positive_definite(pm)
        ekf_predict(s, pm, v_f[i], dt, q, mv)


class HybridEkf:
    """Streaming hybrid EKF: ``run(y, v_f)`` continues from the previous block.

    Args:
        config: :class:`HybridEkfConfig`.
        p0_diag: initial variances of (x, v, a) [m^2, (m/s)^2, (m/s^2)^2] (default: the
            config's).
    """

    def __init__(self, config: HybridEkfConfig, p0_diag=None) -> None:
        self.config = config
        self.p0_diag = config.p0_diag if p0_diag is None else p0_diag
        self.s, self.pm = ekf_init(self.p0_diag)
        self.samples = 0
        self.not_positive_definite = 0
        self.resets = 0

    def reset(self) -> None:
        """Re-initialise the state and covariance from the prior (x0 = 0, P0)."""
        self.s, self.pm = ekf_init(self.p0_diag)
        self.resets += 1

    def diverged(self) -> bool:
        """True if the state is not finite, the covariance is not positive definite
        (:func:`~mems_sim.kernels.divergence.covariance_ok`) or the displacement is not
        inside the gap (|x| < d0: the readout model h(x) has its poles at +-d0)."""
        return not (
            state_ok(self.s) and covariance_ok(self.pm) and abs(self.s[0]) < self.config.model[5]
        )

    def run(self, y: np.ndarray, v_f: np.ndarray) -> dict:
        """Filter readout samples y [V] with the feedback voltages v_f [V] applied after them.

        Returns dict with ``estimate`` (n, 3), ``variance`` (n, 3), ``innovation`` (n,)
        [V], ``innovation_variance`` (n,) [V^2] (its predicted variance
        ``S = h'^2 P00 + R`` from the a-priori covariance, eq. 4-55: ``innovation^2 / S`` is
        the normalised innovation squared) and ``positive_definite`` (n,) of the
        a-posteriori covariance (Sylvester).
        """
        y = np.ascontiguousarray(y, dtype=np.float64)
        v_f = np.ascontiguousarray(v_f, dtype=np.float64)
        n = y.shape[0]
        est = np.empty((n, 3))
        var = np.empty((n, 3))
        innov = np.empty(n)
        sv = np.empty(n)
        pd = np.empty(n, np.bool_)
        c = self.config
        _run(y, v_f, c.dt, c.q, c.r, c.model, self.s, self.pm, est, var, innov, sv, pd)
        self.samples += n
        self.not_positive_definite += int(n - np.count_nonzero(pd))
        return {
            "estimate": est,
            "variance": var,
            "innovation": innov,
            "innovation_variance": sv,
            "positive_definite": pd,
        }

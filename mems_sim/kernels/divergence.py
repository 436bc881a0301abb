"""Divergence test of the recursive filters (Kalman filters and observers): a filter has
diverged when its state is no longer finite or its covariance is no longer positive
definite; its owner then re-initialises it from its prior (each filter's ``reset()``).

The covariance test allows round-off: the diagonal must be positive and the smallest
eigenvalue of the symmetric part not below ``-rtol`` times the largest, so that a filter
whose covariance is nearly singular by construction (a state the measurements determine
almost exactly) is not taken for diverged.
"""

from __future__ import annotations

import numpy as np

__all__ = ["covariance_ok", "state_ok"]


def covariance_ok(P, rtol: float = 1e-9) -> bool:
    """True if the covariance ``P`` (square) is finite, its diagonal positive and its
    smallest eigenvalue not below ``-rtol`` times its largest."""
    P = np.atleast_2d(np.asarray(P, dtype=float))
    if not np.all(np.isfinite(P)) or not np.all(np.diag(P) > 0.0):
        return False
    ev = np.linalg.eigvalsh(0.5 * (P + P.T))
    return bool(ev[0] >= -rtol * ev[-1])


def state_ok(*arrays) -> bool:
    """True if every value of every array is finite."""
    return all(bool(np.all(np.isfinite(np.asarray(a, dtype=float)))) for a in arrays)

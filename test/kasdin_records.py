"""Noise records the project did not generate: allantools' Kasdin & Walter (Proc. IEEE
FCS 1992) generator ``allantools.noise_kasdin.Noise``, its series taken as the rate.

With b = 0, -1, -2 (white, flicker and random-walk rate noise) and tau0 = 1/fs, the
discrete variances qd = N^2 fs, B^2 and K^2/fs give the Allan variance N^2/tau +
(2 ln 2/pi) B^2 + K^2 tau/3 (IEEE Std 952-1997, Annex C; the conversion is derived and
checked against the library by the model-choice tests).
"""

from __future__ import annotations

import numpy as np
from allantools.noise_kasdin import Noise


def kasdin_rate(n: int, fs: float, N: float, B: float, K: float, seed: int) -> np.ndarray:
    """White + flicker + random-walk rate noise of Allan coefficients N [u sqrt(s)],
    B [u], K [u/sqrt(s)]: n samples at fs [Hz], seeded (the generator draws from numpy's
    global state, restored afterwards)."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        out = np.zeros(n)
        for b, qd in ((0, N**2 * fs), (-1, B**2), (-2, K**2 / fs)):
            noise = Noise(nr=n, qd=qd, b=b)
            noise.generateNoise()
            out += noise.time_series
    finally:
        np.random.set_state(state)
    return out

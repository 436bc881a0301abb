"""Independent flicker (1/f) noise channels streamed in blocks, the same samples at any
block size (a device's frames of any length give the same record).

Each channel is the Gauss-Markov ladder of :mod:`mems_sim.hardware.flicker` (van der Ziel
1950; Keshner, Proc. IEEE 70(3), 1982), but every process of every channel draws its
driving noise from a generator of its own (numpy PCG64 children of one seed sequence), so
a block of n samples takes the next n draws of each generator whatever the blocks before
it were; the first-order recursion continues through ``lfilter``'s state
(x[i] = a x[i-1] + b w[i] either way).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from mems_sim.hardware.flicker import FlickerConfig, ar1_coefficients, pole_variances


class FlickerChannels:
    """``channels`` independent flicker terms of one configuration at rate ``fs``.

    Args:
        config: the flicker term (coefficient B in the signal unit, band, poles).
        fs: sample rate [Hz] (f_high at most fs/2).
        channels: number of independent channels, -.
        seed: the seed sequence the channels' generators are spawned from.
    """

    def __init__(
        self, config: FlickerConfig, fs: float, channels: int, seed: np.random.SeedSequence
    ) -> None:
        self.config = config
        self.a, self.b = ar1_coefficients(fs, config)
        k = self.a.shape[0]
        gens = [np.random.Generator(np.random.PCG64(c)) for c in seed.spawn(channels * (k + 1))]
        sd = np.sqrt(pole_variances(config))
        #: (channels, K) last value of every process [signal unit], started stationary.
        self.state = np.stack([sd * gens[j * (k + 1)].standard_normal(k) for j in range(channels)])
        self._drive = [gens[j * (k + 1) + 1 : (j + 1) * (k + 1)] for j in range(channels)]

    def next(self, n: int) -> np.ndarray:
        """The next ``n`` samples of every channel, (n, channels) [signal unit]: per channel
        the K processes added elementwise in the order k = 0 .. K-1."""
        n = int(n)
        out = np.zeros((n, len(self._drive)))
        if n == 0:
            return out
        for j, drive in enumerate(self._drive):
            total = np.zeros(n)
            for k, gen in enumerate(drive):
                a, b = self.a[k], self.b[k]
                x, _ = signal.lfilter(
                    [b], [1.0, -a], gen.standard_normal(n), zi=[a * self.state[j, k]]
                )
                total = total + x
                self.state[j, k] = x[-1]
            out[:, j] = total
        return out

"""Sensor faults of a schedule (:mod:`mems_sim.hardware.fault_schedule`) applied to the
analog values a device's converter digitises, block by block.

:class:`SensorFaultInjector` takes blocks ``(n, channels)`` of consecutive samples, in
the device's units, and returns them with every scheduled sensor fault that overlaps the
block applied, in the order of the schedule:

* ``stuck_at``: the value of the onset sample held (after the faults listed before it);
* ``bias_step`` b: x + b;  ``bias_ramp`` r: x + r (k - k0)/fs;
* ``scale_step`` s: x (1 + s);  ``sign_flip``: -x;
* ``noise_burst`` k: x + sigma sqrt(k^2 - 1) z, so that white noise of standard deviation
  sigma (the channel's, given by the device) becomes k sigma;
* ``spikes`` a at rate lambda: x +- a on a sample with probability lambda/fs;
* ``saturation`` c: x clipped to [-c, c].

The random draws of ``noise_burst`` and ``spikes`` come from a generator per fault and per
aligned chunk of :data:`CHUNK` samples (numpy's PCG64 seeded with the device seed, the
fault's number and the chunk's number), so a sample's draw depends only on its index: the
same faulty samples at any frame size. With no entries the blocks are returned as given
(the same object), so a device without a schedule is bit for bit the device without faults.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from mems_sim.hardware.fault_schedule import ALL_KINDS, FaultEntry

#: Samples per chunk of a fault's random draws, -.
CHUNK = 4096
#: Stream tag of the fault draws in the seed sequence (keeps them apart from device noise).
_FAULT_STREAM = 0xFA17


class LoopTerms(NamedTuple):
    """Per-sample fault terms of one channel inside a loop (:meth:`SensorFaultInjector.loop_terms`):
    gain [-], offset and rail [channel unit], hold (stuck_at entry number + 1, 0: none)."""

    gain: np.ndarray
    offset: np.ndarray
    rail: np.ndarray
    hold: np.ndarray


class SensorFaultInjector:
    """Applies the sensor faults of a schedule to blocks of a device's analog values.

    Args:
        entries: the schedule's entries (those of other families, e.g. dropped samples,
            are left to the device's stream and ignored here).
        fs: sample rate [Hz].
        seed: the device's noise seed, -.
        white_std: per channel, the standard deviation of the channel's white noise per
            sample [channel unit] (``noise_burst`` needs it; None when the device has none).
    """

    def __init__(
        self,
        entries: Sequence[FaultEntry],
        fs: float,
        seed: int,
        white_std: Sequence[float] | None = None,
    ) -> None:
        self.entries = tuple(e for e in entries if ALL_KINDS[e.kind].family == "sensor")
        self.fs = float(fs)
        self.seed = int(seed)
        self.white_std = None if white_std is None else tuple(float(s) for s in white_std)
        if self.white_std is None and any(e.kind == "noise_burst" for e in self.entries):
            raise ValueError("this device gives no white-noise level: no noise_burst faults")
        self._held: dict[int, float] = {}
        self._chunks: dict[tuple[int, int], np.ndarray] = {}

    def __bool__(self) -> bool:
        return bool(self.entries)

    def _draws(self, entry: FaultEntry, k: np.ndarray, rows: int) -> np.ndarray:
        """``rows`` draws per sample index ``k`` of ``entry``'s generator: standard normal
        (``noise_burst``, rows 1) or uniform in [0, 1) (``spikes``, rows 2)."""
        out = np.empty((rows, k.size))
        chunks = k // CHUNK
        for c in np.unique(chunks):
            key = (entry.number, int(c))
            table = self._chunks.get(key)
            if table is None:
                rng = np.random.Generator(
                    np.random.PCG64([self.seed & 0xFFFFFFFF, _FAULT_STREAM, entry.number, int(c)])
                )
                table = (
                    rng.standard_normal((1, CHUNK))
                    if entry.kind == "noise_burst"
                    else rng.random((2, CHUNK))
                )
                self._chunks = {kk: v for kk, v in self._chunks.items() if kk[0] != entry.number}
                self._chunks[key] = table
            sel = chunks == c
            out[:, sel] = table[:, k[sel] - int(c) * CHUNK]
        return out

    def _affine(self, entry: FaultEntry, k: np.ndarray) -> tuple[float, np.ndarray | float]:
        """The affine kinds as ``x -> gain x + offset`` on samples ``k`` of ``entry``: the
        gain [-] and the offset [channel unit] (a scalar or one value per sample)."""
        m = entry.magnitude
        kind = entry.kind
        if kind == "bias_step":
            return 1.0, m
        if kind == "bias_ramp":
            return 1.0, m * ((k - entry.first) / self.fs)
        if kind == "scale_step":
            return 1.0 + m, 0.0
        if kind == "sign_flip":
            return -1.0, 0.0
        if kind == "noise_burst":
            sigma = self.white_std[entry.channel_index] * math.sqrt(m * m - 1.0)
            return 1.0, sigma * self._draws(entry, k, 1)[0]
        if kind == "spikes":
            u = self._draws(entry, k, 2)
            hit = u[0] < entry.rate_hz / self.fs
            return 1.0, np.where(hit, np.where(u[1] < 0.5, -m, m), 0.0)
        raise ValueError(f"{kind!r} is not an affine sensor fault")

    def _apply_one(self, entry: FaultEntry, col: np.ndarray, k: np.ndarray) -> np.ndarray:
        """``col`` (the faulty samples of one channel, sample indices ``k``) with ``entry``."""
        if entry.kind == "stuck_at":
            if k[0] == entry.first or entry.number not in self._held:
                self._held[entry.number] = float(col[0])
            return np.full_like(col, self._held[entry.number])
        if entry.kind == "saturation":
            return np.clip(col, -entry.magnitude, entry.magnitude)
        gain, offset = self._affine(entry, k)
        if gain == 1.0:
            return col + offset
        return col * gain + offset

    def loop_terms(self, first: int, n: int, channel: int = 0) -> LoopTerms:
        """The faults of ``channel`` on samples ``first .. first + n - 1`` as per-sample terms
        for a converter inside a feedback loop, where each sample's analog value exists only
        in the loop: ``y -> hold(clip(gain y + offset, -rail, rail))``.

        The affine kinds (bias step and ramp, scale step, sign flip, noise burst, spikes)
        compose in schedule order, then the lowest active rail of ``saturation`` clips, then
        ``stuck_at`` holds the result of its onset sample (``hold`` is the entry's number
        plus one on its samples, 0 elsewhere; a later entry wins where two overlap).
        """
        gain = np.ones(n)
        offset = np.zeros(n)
        rail = np.full(n, np.inf)
        hold = np.zeros(n, np.int64)
        for entry in self.entries:
            if entry.channel_index != channel:
                continue
            lo, hi = entry.overlap(first, n)
            if lo == hi:
                continue
            if entry.kind == "saturation":
                rail[lo:hi] = np.minimum(rail[lo:hi], entry.magnitude)
            elif entry.kind == "stuck_at":
                hold[lo:hi] = entry.number + 1
            else:
                k = np.arange(first + lo, first + hi, dtype=np.int64)
                g, c = self._affine(entry, k)
                gain[lo:hi] *= g
                offset[lo:hi] = offset[lo:hi] * g + c
        return LoopTerms(gain, offset, rail, hold)

    def apply(self, values: np.ndarray, first: int, columns: slice | None = None) -> np.ndarray:
        """``values`` ``(n, c)`` of samples ``first .. first + n - 1`` with the faults applied.

        Args:
            values: analog values [channel units]; not modified.
            first: sample index of the block's first row, -.
            columns: which of the device's channels the columns are (a slice of the channel
                list; None: all, in order).
        Returns:
            ``values`` itself when no fault overlaps the block, else a modified copy.
        """
        n = values.shape[0]
        lo_col = 0 if columns is None else columns.start or 0
        hi_col = values.shape[1] + lo_col if columns is None else columns.stop
        out = values
        for entry in self.entries:
            if not lo_col <= entry.channel_index < hi_col:
                continue
            lo, hi = entry.overlap(first, n)
            if lo == hi:
                continue
            if out is values:
                out = np.array(values, dtype=float, copy=True)
            j = entry.channel_index - lo_col
            k = np.arange(first + lo, first + hi, dtype=np.int64)
            out[lo:hi, j] = self._apply_one(entry, out[lo:hi, j], k)
        return out

"""A device's sample clock: the physical instants at which sample k is taken.

The stamps stay ``epoch + k / fs`` with fs the nominal output data rate; the clock gives
the real instants, for the truth and for evaluating the physical signal::

    t_k = k_s T + sum_{j=k_s}^{k-1} T / (1 + y_j) + w_k + r_k + J_k,   T = 1 / fs

(k_s the first sample of the stream, 0 by default, so that a constant y gives
t_k = k / f_actual + e_k). The terms, in the vocabulary of IEEE Std 1139-2008 (Standard
Definitions of Physical Quantities for Fundamental Frequency and Time Metrology, Sec. 3:
fractional frequency deviation y, time deviation x = integral of y):

* y_j = 1e-6 (offset + tempco (T_j - T_ref) + rate steps): the fractional frequency
  deviation, so f_actual = fs (1 + y); the frequency offset and its linear temperature
  coefficient (ppm, ppm/K), T_j the device temperature at sample j (degC).
* w_k: white timing error of standard deviation sigma_t, the aperture uncertainty of
  IEEE Std 1241-2010 (Standard for Terminology and Test Methods for Analog-to-Digital
  Converters, term "aperture uncertainty"); it limits a full-scale sine of frequency f to
  SNR = -20 log10(2 pi f sigma_t) dB (Kester, "Converting Oscillator Phase Noise to Time
  Jitter", Analog Devices tutorial MT-008, the jitter-SNR relation).
* r_k: random-walk phase, the time deviation of white frequency noise (IEEE 1139 power law
  S_y(f) = h_0): Var(r_k) = D^2 (k - k_s) T with the diffusion coefficient D = sqrt(h_0/2)
  in s/sqrt(s), the Allan deviation sigma_y(tau) = D / sqrt(tau) (1139, white FM, h_0/(2 tau)).
* J_k: clock jumps (phase steps, s) in effect at sample k.

A clock jump and a rate step are clock state (:meth:`SampleClock.apply_jump`,
:meth:`SampleClock.apply_rate_step`), for fault injection. A fixed drive/sense skew (s)
delays a second channel of the device (:attr:`ClockBlock.skewed_instants_s`).

Portable floats: the generating path uses elementwise arithmetic and sequential
``np.cumsum`` only (no transcendental function of an array, no reduction), and every
sample draws two standard normals whether its terms are on or off, so a seed gives the same
noise for every configuration and a stream in blocks gives the bits of one call.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mems_sim.params import ParameterError, ParamSpec, Spread, draw_device, resolve

__all__ = [
    "CLOCK_SPECS",
    "FAULT_SPECS",
    "SAMPLE_RATE_SPEC",
    "ClockBlock",
    "SampleClock",
    "clock_values",
    "draw_clock_device",
    "fractional_frequency",
    "jitter_snr_db",
]

#: Nominal output data rate of the device (the clock's nominal sample rate).
SAMPLE_RATE_SPEC = ParamSpec(
    "sample_rate_hz",
    1000.0,
    "Hz",
    "nominal sample rate fs: the stamps are epoch + k / fs",
    "the device's output data rate (e.g. ICM-42688-P: 12.5 Hz to 32 kHz)",
    min=0.0,
    max=1.0e9,
    min_exclusive=True,
)

CLOCK_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "clock_frequency_offset_ppm",
        0.0,
        "ppm",
        "fractional frequency offset of the sample clock at T_ref (f_actual = fs (1 + y))",
        "nominal device 0; batch: SiT8008B MEMS oscillator datasheet, frequency stability "
        "+-20/+-25/+-50 ppm options (inclusive of initial tolerance, temperature, supply, load)",
        min=-5.0e4,
        max=5.0e4,
        spread=Spread(
            "uniform",
            50.0,
            relative=False,
            source="SiT8008B datasheet: frequency stability +-50 ppm (widest option); "
            "quartz XOs of IMU boards (e.g. Epson SG-210STF) offer the same grade",
        ),
    ),
    ParamSpec(
        "clock_tempco_ppm_per_k",
        0.0,
        "ppm/K",
        "linear temperature coefficient of the clock frequency around clock_ref_temperature_c",
        "nominal device 0 (a compensated oscillator's frequency-temperature curve is "
        "centred); batch: slope bound of the SiT8008B's +-50 ppm over -40 to 85 degC",
        min=-1.0e3,
        max=1.0e3,
        spread=Spread(
            "uniform",
            0.8,
            relative=False,
            source="assumption: SiT8008B datasheet +-50 ppm over -40 to 85 degC read as a "
            "linear slope bound 50 ppm / 62.5 K = 0.8 ppm/K",
        ),
    ),
    ParamSpec(
        "clock_ref_temperature_c",
        25.0,
        "degC",
        "reference temperature T_ref of the clock's temperature coefficient",
        "datasheets state the initial tolerance at 25 degC (SiT8008B)",
        min=-100.0,
        max=200.0,
    ),
    ParamSpec(
        "clock_jitter_s",
        10.0e-12,
        "s",
        "white (aperture) jitter sigma_t: standard deviation of each sample instant",
        "IEEE Std 1241-2010 aperture uncertainty; assumption: 10 ps rms, between the ps of a "
        "quartz or MEMS XO (SiT8008B, MT-008's examples) and the ns of an on-chip RC clock",
        min=0.0,
        max=1.0e-3,
    ),
    ParamSpec(
        "clock_phase_diffusion",
        1.0e-10,
        "s/sqrt(s)",
        "random-walk phase (white FM) diffusion coefficient D: Var(r_k) = D^2 (k - k_s) / fs",
        "IEEE Std 1139-2008 white FM, sigma_y(tau) = D / sqrt(tau); assumption: Allan "
        "deviation 1e-10 at 1 s, the order of uncompensated quartz and MEMS oscillators",
        min=0.0,
        max=1.0e-2,
    ),
    ParamSpec(
        "clock_skew_s",
        0.0,
        "s",
        "fixed delay of the device's second (sense) channel behind the first (drive)",
        "assumption: 0 (simultaneous sampling); a channel converted after the other on one "
        "multiplexed converter lags by the conversion time",
        min=-1.0,
        max=1.0,
    ),
)

#: Values of the clock faults (state of :class:`SampleClock`, not parameters of the table).
FAULT_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "clock_jump_s",
        0.0,
        "s",
        "phase step of the clock at sample k0: instants k >= k0 move by this much",
        "fault injection: a clock jump (IEEE Std 1139-2008 time deviation step)",
        min=-1.0e3,
        max=1.0e3,
    ),
    ParamSpec(
        "clock_rate_step_ppm",
        0.0,
        "ppm",
        "frequency step of the clock at sample k0: the periods from k0 on change",
        "fault injection: a rate step (IEEE Std 1139-2008 fractional frequency step)",
        min=-1.0e5,
        max=1.0e5,
    ),
)

_FAULTS = {s.name: s for s in FAULT_SPECS}


def clock_values(params: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Defaults of :data:`CLOCK_SPECS` updated with validated ``params``.

    Raises:
        ParameterError: for an unknown name or an out-of-range value.
    """
    return resolve(CLOCK_SPECS, params)


def draw_clock_device(
    values: Mapping[str, Any], device_seed: int | None, fixed: Iterable[str] = ()
) -> dict[str, Any]:
    """One clock of a batch: offset and tempco drawn within their datasheet spreads
    (:func:`~mems_sim.params.draw_device`); ``device_seed`` None or negative: ``values``."""
    return draw_device(CLOCK_SPECS, values, device_seed, fixed=fixed)


def fractional_frequency(
    values: Mapping[str, Any], temperature_c: float | np.ndarray, rate_step_ppm: float = 0.0
) -> float | np.ndarray:
    """Fractional frequency deviation y = 1e-6 (offset + tempco (T - T_ref) + step), the
    IEEE Std 1139-2008 y of the clock; f_actual = fs (1 + y).

    Args:
        values: clock parameters (ppm, ppm/K, degC).
        temperature_c: device temperature T, degC (scalar or per sample).
        rate_step_ppm: rate steps in effect, ppm.
    """
    dt = np.asarray(temperature_c, dtype=float) - values["clock_ref_temperature_c"]
    ppm = (values["clock_frequency_offset_ppm"] + values["clock_tempco_ppm_per_k"] * dt) + (
        rate_step_ppm
    )
    out = 1e-6 * ppm
    return float(out) if np.ndim(out) == 0 else out


def jitter_snr_db(frequency_hz: float, jitter_s: float) -> float:
    """Jitter-limited SNR of a full-scale sine, SNR = -20 log10(2 pi f sigma_t) dB (Kester,
    MT-008, the jitter-SNR relation; IEEE Std 1241-2010 aperture uncertainty).

    Args:
        frequency_hz: sine frequency f, Hz.
        jitter_s: rms aperture jitter sigma_t, s.
    """
    return -20.0 * math.log10(2.0 * math.pi * frequency_hz * jitter_s)


@dataclass(frozen=True)
class ClockBlock:
    """The instants of a block of samples.

    Attributes:
        index: sample indices k (int64).
        stamps_s: k / fs, s after the epoch (what the frames are stamped with).
        error_s: t_k - k / fs, s: the clock's time error (drift, jitter, walk, jumps).
        skew_s: delay of the second channel, s.
    """

    index: np.ndarray
    stamps_s: np.ndarray
    error_s: np.ndarray
    skew_s: float

    @property
    def instants_s(self) -> np.ndarray:
        """Physical instants t_k = k / fs + error, s after the epoch."""
        return self.stamps_s + self.error_s

    @property
    def skewed_instants_s(self) -> np.ndarray:
        """The second channel's instants t_k + skew, s after the epoch."""
        return self.instants_s + self.skew_s


class SampleClock:
    """The sample clock of one device, streamed in blocks of consecutive samples.

    Args:
        sample_rate_hz: nominal sample rate fs, Hz.
        params: overrides of :data:`CLOCK_SPECS` (validated).
        start_index: the first sample index k_s of the stream.

    Raises:
        ParameterError: for an invalid rate or parameter.
    """

    def __init__(
        self,
        sample_rate_hz: float,
        params: Mapping[str, Any] | None = None,
        start_index: int = 0,
    ) -> None:
        self.fs = SAMPLE_RATE_SPEC.validate(sample_rate_hz)
        self.period_s = 1.0 / self.fs
        self.values = clock_values(params)
        self.next_index = int(start_index)
        self._started = False
        self._drift_s = 0.0  # sum of T / (1 + y_j) - T for j < next_index
        self._walk_s = 0.0  # random-walk phase r at the last sample generated
        self._jump_s = 0.0  # jumps in effect at next_index
        self._rate_ppm = 0.0  # rate steps in effect at next_index
        self._events: list[tuple[int, str, float]] = []  # (k0, kind, value), pending

    # -- faults -------------------------------------------------------------------------
    def apply_jump(self, k0: int, jump_s: float) -> None:
        """Clock jump: the instants of samples k >= k0 move by ``jump_s`` (s).

        Raises:
            ParameterError: for a value out of range or a k0 already generated.
        """
        self._schedule(k0, "clock_jump_s", jump_s)

    def apply_rate_step(self, k0: int, step_ppm: float) -> None:
        """Rate step: the clock frequency steps by ``step_ppm`` (ppm) at sample k0, so the
        periods from k0 to k0 + 1 on are T / (1 + y + 1e-6 step); instants up to k0 stay.

        Raises:
            ParameterError: for a value out of range or a k0 already generated.
        """
        self._schedule(k0, "clock_rate_step_ppm", step_ppm)

    def _schedule(self, k0: int, kind: str, value: float) -> None:
        value = _FAULTS[kind].validate(value)
        if isinstance(k0, bool) or not isinstance(k0, (int, np.integer)):
            raise ParameterError(f"{kind} at k0 = {k0!r}: k0 must be an integer sample index")
        if k0 < self.next_index:
            raise ParameterError(
                f"{kind} at k0 = {k0}: samples before {self.next_index} are already "
                "generated; a fault can only act from the next sample on"
            )
        self._events.append((int(k0), kind, value))
        self._events.sort(key=lambda e: e[0])  # stable: same-k0 faults keep their order

    # -- generation ----------------------------------------------------------------------
    def instants(
        self,
        k: np.ndarray,
        rng: np.random.Generator,
        temperature_c: float | np.ndarray | None = None,
    ) -> ClockBlock:
        """The next block of instants.

        Args:
            k: sample indices, consecutive and starting at :attr:`next_index`.
            rng: the device's seeded generator (two standard normals per sample).
            temperature_c: device temperature, degC: None (= T_ref), a scalar, or one value
                per sample (the temperature of period k to k + 1).

        Raises:
            ValueError: for indices that do not continue the stream or a temperature series
                of the wrong length.
        """
        k = self._check_index(k)
        n = k.size
        temp = self._temperature(temperature_c, n)
        rate = self._profile("clock_rate_step_ppm", k, self._rate_ppm)
        jump = self._profile("clock_jump_s", k, self._jump_s)
        y = fractional_frequency(self.values, temp, rate)
        if n and not np.all(y > -1.0):
            raise ParameterError("clock rate steps and offsets stop the clock (1 + y <= 0)")
        drift = self._drift(y)
        white, walk = self._noise(rng, n)
        error = ((drift + walk) + white) + jump
        if n:
            self._rate_ppm, self._jump_s = float(rate[-1]), float(jump[-1])
            self._events = [e for e in self._events if e[0] > k[-1]]
            self.next_index = int(k[-1]) + 1
            self._started = True
        stamps = k.astype(float) / self.fs
        return ClockBlock(k, stamps, error, self.values["clock_skew_s"])

    def _check_index(self, k: np.ndarray) -> np.ndarray:
        k = np.asarray(k)
        if k.ndim != 1 or (k.size and not np.issubdtype(k.dtype, np.integer)):
            raise ValueError(f"sample indices must be a 1-D integer array, got {k.dtype} {k.shape}")
        k = k.astype(np.int64)
        expected = np.arange(self.next_index, self.next_index + k.size, dtype=np.int64)
        if not np.array_equal(k, expected):
            first = int(k[0]) if k.size else None
            raise ValueError(
                f"sample indices must be consecutive from {self.next_index} (the stream's next "
                f"sample), got {k.size} from {first}"
            )
        return k

    def _temperature(self, temperature_c: float | np.ndarray | None, n: int) -> np.ndarray:
        if temperature_c is None:
            return np.full(n, self.values["clock_ref_temperature_c"])
        temp = np.asarray(temperature_c, dtype=float)
        if temp.ndim == 0:
            temp = np.full(n, float(temp))
        if temp.shape != (n,):
            raise ValueError(f"temperature_c must be a scalar or {n} values, got {temp.shape}")
        if n and not np.all(temp >= -273.15):  # also catches NaN
            raise ValueError("temperature_c must be finite and at least -273.15 degC")
        if n and not np.all(np.isfinite(temp)):
            raise ValueError("temperature_c must be finite and at least -273.15 degC")
        return temp

    def _profile(self, kind: str, k: np.ndarray, state: float) -> np.ndarray:
        """Accumulated faults of ``kind`` in effect at each sample of ``k``."""
        out = np.full(k.size, state)
        for k0, what, value in self._events:
            if what == kind and k.size and k0 <= k[-1]:
                out[k0 - int(k[0]) :] += value
        return out

    def _drift(self, y: np.ndarray) -> np.ndarray:
        """x_k = sum_{j<k} (T / (1 + y_j) - T) = -T sum y_j / (1 + y_j), s: the time
        deviation of IEEE Std 1139-2008 (x = integral of y) over the nominal periods."""
        d = -self.period_s * (y / (1.0 + y))
        x = np.cumsum(np.concatenate(([self._drift_s], d)))
        self._drift_s = float(x[-1])
        return x[:-1]

    def _noise(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """White jitter w_k (sd sigma_t) and random-walk phase r_k (increments of sd
        D sqrt(T), r = 0 at the stream's first sample), s."""
        z = rng.standard_normal((n, 2))
        white = self.values["clock_jitter_s"] * z[:, 0]
        inc = (self.values["clock_phase_diffusion"] * math.sqrt(self.period_s)) * z[:, 1]
        if n and not self._started:
            inc[0] = 0.0
        walk = np.cumsum(np.concatenate(([self._walk_s], inc)))[1:]
        if n:
            self._walk_s = float(walk[-1])
        return white, walk

"""Static errors of a real analog-to-digital converter: an explicit code-transition table.

An N-bit converter with two's-complement codes k in [-2^(N-1), 2^(N-1) - 1] (the devices'
quantiser: code = round(x / Q) clipped to that range), code width Q = full_scale / 2^(N-1)
in the input unit (V, or the device's unit), and the static errors of IEEE Std 1241-2010
(IEEE Standard for Terminology and Test Methods for Analog-to-Digital Converters; the same
terms as IEEE Std 1057): transition levels T[k] (the input at which the output changes from
code k - 1 to code k), code bin widths W[k] = T[k + 1] - T[k], differential nonlinearity
DNL[k] = W[k]/Q - 1 and integral nonlinearity INL[k], with gain G and offset V_os taken out
in the form of the standard's independently based gain and offset,
G T[k] + V_os + eps[k] = T_ideal[k], T_ideal[k] = (k - 1/2) Q; the residual is signed here
as the transition's deviation, INL[k] = -eps[k]/Q (the sign of the datasheets and of the
histogram test), and DNL is taken with the gain out, DNL[k] = G W[k]/Q - 1.

In LSB (u = x / Q) the table is built in three steps, each a small function below:

1. code widths of the 2^N - 2 interior codes, w[k] = 1 + DNL_pattern[k], a seeded pattern
   of standard deviation dnl_sd_lsb (from independent transition-level errors, so that its
   running sum stays bounded), widths below 0 set to 0, then scaled so that the total width
   is 2^N - 2 LSB (the end transitions stay ideal); transitions are the first ideal
   transition plus the running sum of the widths;
2. a smooth INL bow added to every transition: a parabola peak (1 - s^2) or a cubic
   peak (3 sqrt(3)/2) s (1 - s^2), s = -1 at the first and +1 at the last transition;
3. gain and offset: t[k] = (u_nonlinear[k] - offset_lsb) / (1 + gain_error).

Sign convention: INL[k] = G T[k]/Q + offset_lsb - (k - 1/2) is the deviation of the
transition from the ideal one after gain and offset (positive: the transition comes late),
so INL[k] = sum of DNL[j] over the interior codes j < k, which is what a code-density
(histogram) test measures (IEEE Std 1241-2010, histogram test with a linear ramp).

A missing code k (a code of zero width) is converter state: its entry and exit transitions
T[k] and T[k + 1] (a run of consecutive missing codes: all of its transitions) are moved to
their midpoint, so the neighbours share its width and nothing else moves;
:meth:`Converter.set_missing` sets and clears such codes at run time (fault injection) and
clearing restores the table bit for bit.

Conversion: code = the number of transitions at or below u (``np.searchsorted``, exact and
deterministic), an input exactly on a transition going to the even one of the two codes
(IEEE 754 roundTiesToEven, as ``np.rint``), so that with every error zero the converter
equals the devices' ``np.rint(x / Q)`` clipped, bit for bit. Two virtual transitions, half a
code below the lowest and above the highest code (moved by gain and offset only), flag
over-range samples as the devices do.

Portability: no numba, no fastmath; the widths are summed with ``np.cumsum`` (a sequential
left-to-right recurrence, one rounding per step in a fixed order) and their total with
``math.fsum`` (exactly rounded, independent of order), never with a pairwise or SIMD
reduction whose order depends on the CPU.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from mems_sim.params import ParameterError, ParamSpec, Spread, draw_device, resolve

__all__ = [
    "ADC_SPECS",
    "DEVICE_MAX_BITS",
    "INL_SHAPES",
    "STATIC_ERRORS",
    "Converter",
    "code_range",
    "device_converters",
    "inl_shape_spec",
    "part_seed",
]

INL_SHAPES = ("parabola", "cubic")
#: Largest resolution: the table holds 2^N + 1 floats.
MAX_BITS = 24
_SAR_12 = (
    "12-bit SAR ADC datasheet, e.g. Microchip MCP3204/3208 (2.7 V 4-channel/8-channel 12-bit "
    "A/D converters with SPI serial interface)"
)

ADC_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "bits",
        12,
        "-",
        "resolution N: 2^N two's-complement codes -2^(N-1) .. 2^(N-1) - 1",
        f"{_SAR_12}: 12 bits",
        min=2,
        max=MAX_BITS,
    ),
    ParamSpec(
        "full_scale",
        1.0,
        "V",
        "half input span: Q = full_scale / 2^(N-1) (V, or the device's input unit)",
        "assumption: a +-1 V bipolar input span; a device sets its own",
        min=0.0,
        max=1.0e12,
        min_exclusive=True,
    ),
    ParamSpec(
        "offset_lsb",
        0.0,
        "LSB",
        "offset error V_os/Q: G T[k]/Q + offset = k - 1/2 + INL[k] (IEEE Std 1241-2010)",
        "nominal part: 0; a batch spreads by the datasheet's maximum offset error",
        min=-256.0,
        max=256.0,
        spread=Spread(
            "uniform",
            3.0,
            relative=False,
            source=f"{_SAR_12}: offset error +-3 LSB max, read as the batch",
        ),
    ),
    ParamSpec(
        "gain_error",
        0.0,
        "-",
        "relative gain error G - 1 (positive: codes grow faster than the input)",
        "nominal part: 0; a batch spreads by the datasheet's maximum gain error",
        min=-0.1,
        max=0.1,
        spread=Spread(
            "uniform",
            5.0 / 4096.0,
            relative=False,
            source=f"{_SAR_12}: gain error +-5 LSB max of 4096 codes = +-1.22e-3, read as "
            "the batch",
        ),
    ),
    ParamSpec(
        "inl_peak_lsb",
        0.5,
        "LSB",
        "peak of the smooth INL bow (parabola: at mid-scale; cubic: at s = -+1/sqrt(3))",
        f"{_SAR_12}: INL +-1 LSB max (B grade); assumption: a typical part half of it",
        min=-16.0,
        max=16.0,
    ),
    ParamSpec(
        "inl_shape",
        "parabola",
        "-",
        "shape of the INL bow in the normalised input s in [-1, 1]",
        "assumption: a parabola (even-order bow) or a cubic (odd-order, S-shaped)",
        choices=INL_SHAPES,
    ),
    ParamSpec(
        "dnl_sd_lsb",
        0.1,
        "LSB",
        "standard deviation of the seeded random code-width pattern DNL[k]",
        f"{_SAR_12}: DNL +-1 LSB max (no missing codes); assumption: 0.1 LSB sd puts the "
        "largest of 4094 codes near 3.5 sd = 0.35 LSB, a 12-bit SAR's typical +-0.5 LSB",
        min=0.0,
        max=0.5,
    ),
    ParamSpec(
        "missing_codes",
        0,
        "-",
        "number of interior codes drawn (seeded) to be missing (zero width)",
        f"{_SAR_12}: no missing codes guaranteed; more are a fault",
        min=0,
        max=2**MAX_BITS - 2,
    ),
    ParamSpec(
        "seed",
        0,
        "-",
        "seed of the DNL pattern and of the missing-code draw",
        "assumption: one converter part per seed",
        min=0,
        max=2**63 - 1,
    ),
)


def code_range(bits: int) -> tuple[int, int]:
    """Two's-complement code range (lowest, highest) = (-2^(N-1), 2^(N-1) - 1); bits: N."""
    return -(2 ** (bits - 1)), 2 ** (bits - 1) - 1


def _rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent generators for the DNL pattern and the missing-code draw of one seed."""
    dnl, missing = np.random.SeedSequence([int(seed), zlib.crc32(b"adc")]).spawn(2)
    return np.random.default_rng(dnl), np.random.default_rng(missing)


def code_widths(n: int, dnl_sd_lsb: float, rng: np.random.Generator) -> np.ndarray:
    """Interior code widths w[k] = 1 + DNL_pattern[k] [LSB], total width n LSB preserved.

    DNL_pattern[k] = e[k + 1] - e[k] from independent transition-level errors e ~
    N(0, dnl_sd_lsb / sqrt(2)) at the n - 1 inner transitions (e = 0 at the first and last
    transition): widths of standard deviation dnl_sd_lsb, adjacent ones correlated -1/2,
    whose running sum (the random part of the INL) stays within about 3.5 dnl_sd_lsb /
    sqrt(2). Independent widths would random-walk the INL to about dnl_sd_lsb sqrt(n)/2
    (3 LSB for 12 bits at 0.1 LSB), beyond the datasheets' +-1 LSB. Widths below 0 are
    set to 0 (a code cannot be narrower than missing) and all are then scaled by
    n / fsum(w) so that the interior codes span exactly their ideal n LSB. With
    dnl_sd_lsb = 0 every width is exactly 1.

    Args:
        n: number of interior codes, 2^N - 2.
        dnl_sd_lsb: standard deviation of a width [LSB].
        rng: the seed's DNL generator (drawn from even when the sd is 0).
    """
    e = np.zeros(n + 1)
    e[1:-1] = (dnl_sd_lsb / math.sqrt(2.0)) * rng.standard_normal(n - 1)
    w = np.maximum(1.0 + np.diff(e), 0.0)
    total = math.fsum(w)  # exactly rounded: the same total whatever the CPU's reduction order
    return w * (n / total) if total != n else w


def inl_bow(n_transitions: int, peak_lsb: float, shape: str) -> np.ndarray:
    """Smooth INL bow at every transition [LSB], zero at the first and last transition.

    s = -1 + 2 i / (n_transitions - 1) for transition i; parabola: peak (1 - s^2) (peak at
    mid-scale); cubic: peak (3 sqrt(3)/2) s (1 - s^2) (extremes +-peak at s = +-1/sqrt(3)).

    Args:
        n_transitions: number of transitions, 2^N - 1.
        peak_lsb: peak value [LSB].
        shape: ``"parabola"`` or ``"cubic"``.
    """
    i = np.arange(n_transitions, dtype=float)
    s = -1.0 + 2.0 * i / (n_transitions - 1)
    if shape == "parabola":
        return peak_lsb * (1.0 - s * s)
    return peak_lsb * (1.5 * math.sqrt(3.0)) * s * (1.0 - s * s)


def nonlinear_transitions(widths: np.ndarray, bow: np.ndarray, lo: int) -> np.ndarray:
    """Transitions in LSB before gain and offset: u[i] = lo + 1/2 + sum_{j < i} w[j] + bow[i].

    ``np.cumsum`` is a sequential recurrence (one rounding per step, in index order), so the
    running sum is the same on every CPU; integer widths sum exactly. The result is made
    non-decreasing (``np.maximum.accumulate``, also sequential) so that a bow steeper than a
    code width cannot reorder the table.

    Args:
        widths: (2^N - 2,) interior code widths [LSB].
        bow: (2^N - 1,) INL bow [LSB].
        lo: lowest code, -2^(N-1).
    """
    first = lo + 0.5
    u = np.empty(widths.size + 1)
    u[0] = first
    u[1:] = first + np.cumsum(widths)
    return np.maximum.accumulate(u + bow)


def apply_gain_offset(u: np.ndarray, offset_lsb: float, gain_error: float) -> np.ndarray:
    """t = (u - offset_lsb) / (1 + gain_error) [LSB of input]: IEEE Std 1241-2010's
    independently based gain and offset, G T[k] + V_os + eps[k] = T_ideal[k], solved for
    T[k] with eps[k] = -Q INL[k] carried by u = T_ideal[k]/Q + INL[k].

    Args:
        u: transitions with the nonlinearity [LSB].
        offset_lsb: V_os / Q [LSB].
        gain_error: G - 1 [-].
    """
    return (u - offset_lsb) / (1.0 + gain_error)


def collapse_missing(t: np.ndarray, missing: Iterable[int], lo: int) -> np.ndarray:
    """The table with every missing code's width given to its neighbours, half each.

    For a run of consecutive missing codes a..b, the transitions T[a] .. T[b + 1] (table
    entries a - lo - 1 .. b - lo) all move to the midpoint of T[a] and T[b + 1]: those codes
    have W = 0 and the codes a - 1 and b + 1 grow by half the run's width each.

    Args:
        t: (2^N - 1,) transitions, T[k] at entry k - lo - 1 [LSB].
        missing: interior codes to be missing.
        lo: lowest code.
    """
    out = t.copy()
    codes = sorted(set(missing))
    start = 0
    while start < len(codes):
        end = start
        while end + 1 < len(codes) and codes[end + 1] == codes[end] + 1:
            end += 1
        ia, ib = codes[start] - lo - 1, codes[end] - lo
        out[ia : ib + 1] = 0.5 * (t[ia] + t[ib])
        start = end + 1
    return out


def search_codes(u: np.ndarray, ext: np.ndarray, below: int) -> np.ndarray:
    """Codes of inputs u [LSB] from a sorted transition table ext, ties to even.

    code = below + #{i: ext[i] <= u}. An input equal to a transition goes to the even one of
    the two codes (IEEE 754 roundTiesToEven, as ``np.rint``); equal to several coincident
    transitions (a run of missing codes), to the code above them if it is even, else to the
    one below, never to a missing code. ``np.searchsorted`` compares floats exactly, so the
    result is the same on every CPU.

    Args:
        u: inputs [LSB].
        ext: sorted transitions [LSB], ext[i] the entry into code below + 1 + i.
        below: the code under the first transition.
    """
    right = np.searchsorted(ext, u, side="right")
    code = below + right.astype(np.int64)
    hit = right > 0
    hit[hit] = ext[right[hit] - 1] == u[hit]
    tie = np.flatnonzero(hit & (code % 2 != 0))
    if tie.size:
        code[tie] = below + np.searchsorted(ext, u[tie], side="left")
    return code


class Converter:
    """An N-bit converter with offset, gain, INL bow, DNL pattern and missing codes.

    Args:
        params: overrides of :data:`ADC_SPECS` (validated; defaults for the rest).
        missing: interior codes to be missing besides the ``missing_codes`` seeded draw.
        device_seed: draw offset and gain of one part of a batch (their
            :class:`~mems_sim.params.Spread`); None: the nominal part. Values given in
            ``params`` are kept.

    Raises:
        ParameterError: an unknown name, a value outside its range, more missing codes
            than interior codes, or a missing code that is not an interior code.
    """

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        *,
        missing: Iterable[int] = (),
        device_seed: int | None = None,
    ) -> None:
        given = dict(params or {})
        values = resolve(ADC_SPECS, given)
        if device_seed is not None:
            values = draw_device(ADC_SPECS, values, device_seed, fixed=given.keys())
        self.params = values
        self.bits = int(values["bits"])
        self.code_min, self.code_max = code_range(self.bits)
        self.lsb = values["full_scale"] / 2.0 ** (self.bits - 1)
        interior = 2**self.bits - 2
        if values["missing_codes"] > interior:
            raise ParameterError(
                f"parameter 'missing_codes' = {values['missing_codes']} is out of range: a "
                f"{self.bits}-bit converter has {interior} interior codes"
            )
        rng_dnl, rng_missing = _rngs(values["seed"])
        widths = code_widths(interior, values["dnl_sd_lsb"], rng_dnl)
        bow = inl_bow(interior + 1, values["inl_peak_lsb"], values["inl_shape"])
        u = nonlinear_transitions(widths, bow, self.code_min)
        self._gain = 1.0 + values["gain_error"]
        self._offset = values["offset_lsb"]
        self._base = apply_gain_offset(u, self._offset, values["gain_error"])
        ends = apply_gain_offset(
            np.array([self.code_min - 0.5, self.code_max + 0.5]),
            self._offset,
            values["gain_error"],
        )
        self._ends = (float(ends[0]), float(ends[1]))
        drawn = rng_missing.choice(interior, size=values["missing_codes"], replace=False)
        self._missing: set[int] = set()
        self.set_missing([int(c) + self.code_min + 1 for c in drawn] + list(missing))

    @classmethod
    def ideal(cls, bits: int, lsb: float) -> Converter:
        """The error-free converter of a device: ``bits`` [-] and code width ``lsb`` [input
        unit]; it reproduces ``np.clip(np.rint(x / lsb), lo, hi)`` bit for bit.

        full_scale = lsb 2^(bits-1) and back are exact (a power-of-two scaling), so the
        converter's Q is ``lsb`` itself.

        Raises:
            ParameterError: out-of-range bits, or a full scale out of range.
        """
        full_scale = float(lsb) * 2.0 ** (int(bits) - 1)
        zero = {"offset_lsb": 0.0, "gain_error": 0.0, "inl_peak_lsb": 0.0, "dnl_sd_lsb": 0.0}
        return cls({"bits": bits, "full_scale": full_scale, **zero})

    # ------------------------------------------------------------------ missing-code state
    @property
    def missing_codes(self) -> tuple[int, ...]:
        """The codes currently made missing (sorted); codes of zero width from the DNL
        pattern itself are not listed (:meth:`zero_width_codes`)."""
        return tuple(sorted(self._missing))

    def set_missing(self, codes: Iterable[int], missing: bool = True) -> None:
        """Make interior ``codes`` missing (``missing`` True) or present again (False).

        Raises:
            ParameterError: a code that is not an interior code (the end codes are open).
        """
        codes = [self._interior_code(c) for c in codes]
        if missing:
            self._missing.update(codes)
        else:
            self._missing.difference_update(codes)
        self._table = collapse_missing(self._base, self._missing, self.code_min)
        self._ext = np.concatenate(([self._ends[0]], self._table, [self._ends[1]]))

    def clear_missing(self, codes: Iterable[int] | None = None) -> None:
        """Make ``codes`` (None: every missing code) present again."""
        self.set_missing(self.missing_codes if codes is None else codes, missing=False)

    def _interior_code(self, code: Any) -> int:
        """``code`` as an int if it is an interior code, else ParameterError."""
        ok = isinstance(code, (int, np.integer)) and not isinstance(code, bool)
        if not ok or not (self.code_min < int(code) < self.code_max):
            raise ParameterError(
                f"missing code {code!r} is invalid: allowed are the interior codes "
                f"[{self.code_min + 1}, {self.code_max - 1}] of a {self.bits}-bit converter"
            )
        return int(code)

    # ------------------------------------------------------------------ the transition table
    @property
    def codes(self) -> np.ndarray:
        """(2^N - 1,) code k entered at each transition T[k]: code_min + 1 .. code_max."""
        return np.arange(self.code_min + 1, self.code_max + 1)

    @property
    def transitions(self) -> np.ndarray:
        """(2^N - 1,) transition levels T[k] [input unit], k = code_min + 1 .. code_max."""
        return self._table * self.lsb

    @property
    def transitions_lsb(self) -> np.ndarray:
        """(2^N - 1,) transition levels T[k]/Q [LSB]."""
        return self._table.copy()

    @property
    def widths_lsb(self) -> np.ndarray:
        """(2^N - 2,) interior code widths W[k]/Q [LSB], k = code_min + 1 .. code_max - 1."""
        return np.diff(self._table)

    @property
    def dnl(self) -> np.ndarray:
        """(2^N - 2,) DNL[k] = G W[k]/Q - 1 [LSB] of the interior codes (gain taken out)."""
        return self._gain * np.diff(self._table) - 1.0

    @property
    def inl(self) -> np.ndarray:
        """(2^N - 1,) INL[k] = G T[k]/Q + offset - (k - 1/2) [LSB], k = code_min + 1 ..
        code_max; INL[k] = sum of DNL over the interior codes below k."""
        return self._gain * self._table + self._offset - (self.codes - 0.5)

    def zero_width_codes(self) -> np.ndarray:
        """Every interior code of zero width: the missing ones and any the DNL made so."""
        return self.codes[:-1][np.diff(self._table) == 0.0]

    # ------------------------------------------------------------------ conversion
    def quantize(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Codes of ``values`` [input unit] and their over-range flags.

        u = values / Q; code = the transitions at or below u counted (ties to even),
        clipped to [code_min, code_max]; saturated where u is beyond the virtual
        transitions below code_min and above code_max. A NaN reads as over-range.

        Returns:
            (codes int32 like ``values``, saturated bool like ``values``).
        """
        u = np.asarray(values, dtype=float) / self.lsb
        flat = u.reshape(-1)
        code = search_codes(flat, self._ext, self.code_min - 1).reshape(u.shape)
        saturated = (code < self.code_min) | (code > self.code_max)
        return np.clip(code, self.code_min, self.code_max).astype(np.int32), saturated

    def convert(self, values: np.ndarray) -> np.ndarray:
        """Codes (int32) of ``values`` [input unit]; :meth:`quantize` without the flags."""
        return self.quantize(values)[0]

    def value(self, codes: np.ndarray) -> np.ndarray:
        """The nominal input of ``codes``: code * Q [input unit] (as the devices report)."""
        return np.asarray(codes) * self.lsb


# ------------------------------------------------------------------ a device's converters
#: A device's ADC static-error parameters (the name after the device's prefix, e.g.
#: ``adc_`` + ``offset_lsb``) and the :data:`ADC_SPECS` parameter each one sets.
STATIC_ERRORS: dict[str, str] = {
    "offset_lsb": "offset_lsb",
    "gain_error": "gain_error",
    "inl_lsb": "inl_peak_lsb",
    "dnl_lsb": "dnl_sd_lsb",
    "missing_codes": "missing_codes",
}
#: Largest resolution of a device's converter model (each channel holds a table of 2^N
#: transitions: 8 MB at 20 bits).
DEVICE_MAX_BITS = 20


def inl_shape_spec(name: str) -> ParamSpec:
    """The parameter ``name`` choosing a device ADC's INL bow shape (:data:`INL_SHAPES`)."""
    return ParamSpec(
        name,
        "parabola",
        "-",
        "shape of the INL bow: parabola (even order, peak at mid-scale) or cubic (odd order)",
        "assumption (the converter model's two shapes)",
        choices=INL_SHAPES,
    )


def part_seed(device_seed: int, tag: str, channel: int) -> int:
    """Seed [-] of one channel's converter of one part (its DNL pattern and missing
    codes): the first 63 bits of ``np.random.SeedSequence([device_seed, crc32(tag),
    channel])``, so every channel of a part and every part have their own."""
    ss = np.random.SeedSequence([int(device_seed), zlib.crc32(tag.encode()), int(channel)])
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(1))


def device_converters(
    p: Mapping[str, Any],
    prefix: str,
    bits: int,
    full_scale: float,
    seeds: Iterable[int],
) -> tuple[Converter, ...] | None:
    """One :class:`Converter` per seed with a device's static errors, or None when every
    error is 0 (the device's ideal quantiser then is its ADC, bit for bit).

    ``p``: the device's parameters, holding ``prefix + name`` for every name of
    :data:`STATIC_ERRORS` [LSB, -] and ``prefix + "inl_shape"``; ``bits`` [-] and
    ``full_scale`` [input unit] of the ADC; ``seeds``: one per channel
    (:func:`part_seed`).

    Raises:
        ParameterError: static errors at more than :data:`DEVICE_MAX_BITS` bits, or more
            missing codes than interior codes (named by the device's parameter).
    """
    if all(p[prefix + name] == 0 for name in STATIC_ERRORS):
        return None
    if bits > DEVICE_MAX_BITS:
        raise ParameterError(
            f"parameter 'bits' = {bits!r} is out of range: with ADC static errors "
            f"({prefix}*) at most {DEVICE_MAX_BITS} (each channel's converter holds a "
            "table of 2^N transitions)"
        )
    missing = p[prefix + "missing_codes"]
    if missing > 2**bits - 2:
        raise ParameterError(
            f"parameter '{prefix}missing_codes' = {missing!r} is out of range: a {bits}-bit "
            f"ADC has {2**bits - 2} interior codes"
        )
    common = {conv: p[prefix + name] for name, conv in STATIC_ERRORS.items()}
    common.update(bits=int(bits), full_scale=float(full_scale), inl_shape=p[prefix + "inl_shape"])
    return tuple(Converter({**common, "seed": int(s)}) for s in seeds)

"""Conversion between numpy sample blocks and the frame messages of mems_msgs.

Frames carry consecutive samples: ``header.stamp`` is the
time of the first sample, derived from its index and the sample rate
(:func:`index_to_ns`: epoch + index / fs), never from the wall clock at
publication, so that recordings are bit-identical across runs with the same epoch.
"""

from __future__ import annotations

import array
from collections.abc import Sequence
from fractions import Fraction
from functools import lru_cache

import numpy as np
from builtin_interfaces.msg import Time

from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate


class FrameError(ValueError):
    """A malformed or non-finite frame (rejected and counted, never used).

    ``reason`` names the kind of fault for the counters of the consumer (``rejected_<reason>``
    on /diagnostics): one of :data:`REJECT_REASONS`.
    """

    def __init__(self, message: str, reason: str = "malformed") -> None:
        super().__init__(message)
        self.reason = reason


#: Kinds of rejected frames: inconsistent fields or sizes, no samples, more samples than the
#: consumer takes, codes outside the declared bit range, non-finite values (or a conversion
#: that overflows), another sample rate, channel set or format than the stream's.
REJECT_REASONS = (
    "malformed",
    "empty",
    "oversized",
    "out_of_range",
    "non_finite",
    "foreign",
)

#: Largest converter resolution an AdcFrame may declare [bits] (codes are int32).
MAX_ADC_BITS = 32


def index_to_ns(index: int, sample_rate_hz: float, t0_ns: int = 0) -> int:
    """Time of sample ``index`` [ns] = t0 + index / fs, exact in integer arithmetic.

    The one definition of sensor time: every stamp of a frame, and the log time a recorder
    gives it, is the run's epoch plus the sample index over the device's own sample rate.

    Args:
        index: sample index (>= 0).
        sample_rate_hz: sample rate [Hz] (> 0), the device's own sample clock.
        t0_ns: time of sample 0 [ns]: the run's epoch (0 in fast simulated runs, the
            graph's time at start in live ones).
    """
    num, den = _rate_fraction(float(sample_rate_hz))
    return t0_ns + (int(index) * 10**9 * den) // num


@lru_cache(maxsize=256)
def _rate_fraction(sample_rate_hz: float) -> tuple[int, int]:
    """(numerator, denominator) of the sample rate as written (its repr), e.g. 625e3 ->
    (625000, 1); cached: a graph has a few rates and stamps every frame with one."""
    rate = Fraction(repr(sample_rate_hz))
    return rate.numerator, rate.denominator


def ns_to_time(ns: int) -> Time:
    """builtin_interfaces/Time from integer nanoseconds."""
    return Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9))


def time_to_ns(stamp: Time) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return int(stamp.sec) * 10**9 + int(stamp.nanosec)


def _typed_array(values, dtype, typecode: str) -> array.array:
    """``array.array`` of the values (what the message fields take without a per-element
    check), copied once from the contiguous numpy buffer."""
    out = array.array(typecode)
    values = np.ascontiguousarray(values, dtype=dtype)
    if values.size:
        out.frombytes(memoryview(values).cast("B"))
    return out


def _int32_array(values: np.ndarray) -> array.array:
    return _typed_array(values, np.int32, "i")


def _float64_array(values: np.ndarray) -> array.array:
    return _typed_array(values, np.float64, "d")


def _fill_frame(
    msg, first_index: int, sample_rate_hz: float, num_samples: int, frame_id: str, t0_ns: int
):
    """Set header (stamp of the first sample), first_sample_index, sample_rate_hz, num_samples."""
    msg.header.stamp = ns_to_time(index_to_ns(first_index, sample_rate_hz, t0_ns))
    msg.header.frame_id = frame_id
    msg.first_sample_index = int(first_index)
    msg.sample_rate_hz = float(sample_rate_hz)
    msg.num_samples = int(num_samples)
    return msg


def _channel_frame(
    msg, what: str, values: np.ndarray, first_index, sample_rate_hz, names, units, frame_id, t0_ns
):
    """``msg`` (an AdcFrame or SignalFrame) with the fields of :func:`_fill_frame` and its
    channel names and units, for ``values`` of shape (n, channels) (``what``: their name in
    the error)."""
    if values.ndim != 2 or values.shape[1] != len(names):
        raise FrameError(f"{what} shape {values.shape} does not match {len(names)} channels")
    msg = _fill_frame(msg, first_index, sample_rate_hz, values.shape[0], frame_id, t0_ns)
    msg.channel_names = list(names)
    msg.channel_units = list(units)
    return msg


def make_adc_frame(
    codes: np.ndarray,
    first_index: int,
    sample_rate_hz: float,
    *,
    bits: int,
    channel_names: Sequence[str],
    channel_units: Sequence[str],
    lsb: Sequence[float],
    full_scale: Sequence[float],
    offset: Sequence[float] | None = None,
    saturated_count: int = 0,
    frame_id: str = "",
    t0_ns: int = 0,
) -> AdcFrame:
    """AdcFrame from integer codes of shape (n, channels)."""
    codes = np.asarray(codes)
    msg = _channel_frame(
        AdcFrame(),
        "codes",
        codes,
        first_index,
        sample_rate_hz,
        channel_names,
        channel_units,
        frame_id,
        t0_ns,
    )
    msg.bits = int(bits)
    msg.lsb = _float64_array(np.asarray(lsb, dtype=float))
    msg.offset = _float64_array(
        np.zeros(len(channel_names)) if offset is None else np.asarray(offset, dtype=float)
    )
    msg.full_scale = _float64_array(np.asarray(full_scale, dtype=float))
    msg.codes = _int32_array(codes)
    msg.saturated_count = int(saturated_count)
    return msg


def make_signal_frame(
    data: np.ndarray,
    first_index: int,
    sample_rate_hz: float,
    *,
    channel_names: Sequence[str],
    channel_units: Sequence[str],
    frame_id: str = "",
    t0_ns: int = 0,
) -> SignalFrame:
    """SignalFrame from float samples of shape (n, channels), SI units."""
    data = np.asarray(data, dtype=float)
    msg = _channel_frame(
        SignalFrame(),
        "data",
        data,
        first_index,
        sample_rate_hz,
        channel_names,
        channel_units,
        frame_id,
        t0_ns,
    )
    msg.data = _float64_array(data)
    return msg


def frame_piece(msg, lo: int, hi: int, t0_ns: int = 0):
    """The samples ``[lo, hi)`` (offsets) of an AdcFrame, SignalFrame or StateEstimate as a
    frame of its own: first index, stamp (:func:`index_to_ns` from ``t0_ns``, the run's
    epoch [ns]) and values of those samples, the format unchanged. An AdcFrame piece's
    ``saturated_count`` is its samples with a code at either end of the code range
    (:func:`code_range`)."""
    kind = type(msg)
    piece = kind()
    for name in kind.get_fields_and_field_types():
        if name not in ("header", "codes", "data", "states", "variances"):
            setattr(piece, name, getattr(msg, name))
    _fill_frame(
        piece,
        int(msg.first_sample_index) + int(lo),
        msg.sample_rate_hz,
        int(hi) - int(lo),
        msg.header.frame_id,
        t0_ns,
    )
    if isinstance(msg, StateEstimate):
        width = len(msg.state_names)
        for name in ("states", "variances"):
            values = np.frombuffer(getattr(msg, name), dtype=np.float64).reshape(-1, width)
            setattr(piece, name, _float64_array(values[lo:hi]))
        return piece
    width = len(msg.channel_names)
    if isinstance(msg, AdcFrame):
        codes = np.frombuffer(msg.codes, dtype=np.int32).reshape(-1, width)[lo:hi]
        piece.codes = _int32_array(codes)
        low, high = code_range(int(msg.bits))
        piece.saturated_count = int(np.count_nonzero(((codes <= low) | (codes >= high)).any(1)))
    else:
        data = np.frombuffer(msg.data, dtype=np.float64).reshape(-1, width)[lo:hi]
        piece.data = _float64_array(data)
    return piece


def make_state_estimate(
    states: np.ndarray,
    variances: np.ndarray,
    first_index: int,
    sample_rate_hz: float,
    *,
    estimator: str,
    state_names: Sequence[str],
    state_units: Sequence[str],
    frame_id: str = "",
    t0_ns: int = 0,
) -> StateEstimate:
    """StateEstimate from states and per-state variances of shape (n, states)."""
    states = np.asarray(states, dtype=float)
    variances = np.asarray(variances, dtype=float)
    if states.shape != variances.shape or states.ndim != 2 or states.shape[1] != len(state_names):
        raise FrameError(
            f"states {states.shape} / variances {variances.shape} do not match "
            f"{len(state_names)} states"
        )
    msg = _fill_frame(
        StateEstimate(), first_index, sample_rate_hz, states.shape[0], frame_id, t0_ns
    )
    msg.estimator = estimator
    msg.state_names = list(state_names)
    msg.state_units = list(state_units)
    msg.states = _float64_array(states)
    msg.variances = _float64_array(variances)
    return msg


def _check_common(msg, values_len: int, what: str) -> int:
    channels = len(msg.channel_names)
    if channels == 0:
        raise FrameError(f"{what}: no channels")
    if len(msg.channel_units) != channels:
        raise FrameError(f"{what}: {len(msg.channel_units)} units for {channels} channels")
    if not np.isfinite(msg.sample_rate_hz) or msg.sample_rate_hz <= 0:
        raise FrameError(f"{what}: sample_rate_hz = {msg.sample_rate_hz} must be finite and > 0")
    if values_len != msg.num_samples * channels:
        raise FrameError(
            f"{what}: {values_len} values for num_samples = {msg.num_samples} x {channels} channels"
        )
    return channels


def code_range(bits: int) -> tuple[int, int]:
    """Smallest and largest code of a ``bits``-bit converter: two's complement
    [-2^(bits-1), 2^(bits-1) - 1]; [-1, 1] for one bit (0/1 and -1/+1 streams).

    Raises:
        FrameError: ``bits`` outside 1..:data:`MAX_ADC_BITS`.
    """
    if not 1 <= bits <= MAX_ADC_BITS:
        raise FrameError(f"AdcFrame: bits = {bits} outside 1..{MAX_ADC_BITS}")
    if bits == 1:
        return -1, 1
    return -(2 ** (bits - 1)), 2 ** (bits - 1) - 1


def adc_codes(msg: AdcFrame) -> np.ndarray:
    """Codes (n, channels) of an AdcFrame after the checks of its fields.

    Raises:
        FrameError: inconsistent sizes, non-positive or non-finite rate/lsb, non-finite
            offset (``malformed``); a code outside the declared bit range
            (``out_of_range``).
    """
    channels = _check_common(msg, len(msg.codes), "AdcFrame")
    if len(msg.lsb) != channels or len(msg.offset) not in (0, channels):
        raise FrameError(f"AdcFrame: lsb/offset need {channels} entries")
    lsb = np.asarray(msg.lsb, dtype=float)
    offset = np.asarray(msg.offset, dtype=float)
    if not (np.all(np.isfinite(lsb)) and np.all(lsb > 0) and np.all(np.isfinite(offset))):
        raise FrameError("AdcFrame: lsb must be finite and > 0, offset finite")
    codes = (
        np.frombuffer(msg.codes, dtype=np.int32)
        if isinstance(msg.codes, array.array)
        else np.asarray(msg.codes, dtype=np.int32)
    )
    lo, hi = code_range(int(msg.bits))
    if codes.size and (codes.min() < lo or codes.max() > hi):
        bad = codes[(codes < lo) | (codes > hi)][:3].tolist()
        one_bit = " (one-bit streams: -1/+1 or 0/1)" if msg.bits == 1 else ""
        raise FrameError(
            f"AdcFrame at {msg.first_sample_index}: codes {bad} outside the declared "
            f"{msg.bits}-bit range [{lo}, {hi}]{one_bit}",
            "out_of_range",
        )
    return codes.reshape(msg.num_samples, channels)


def adc_physical(msg: AdcFrame) -> np.ndarray:
    """Physical values (n, channels) = codes * lsb + offset of a validated AdcFrame.

    Raises:
        FrameError: inconsistent sizes, non-positive or non-finite rate/lsb
            (``malformed``), codes outside the declared bit range (``out_of_range``), or
            values whose conversion overflows (``non_finite``).
    """
    codes = adc_codes(msg)
    channels = codes.shape[1]
    lsb = np.asarray(msg.lsb, dtype=float)
    offset = np.asarray(msg.offset, dtype=float) if len(msg.offset) else np.zeros(channels)
    with np.errstate(over="ignore", invalid="ignore"):
        values = codes * lsb + offset
    if not np.all(np.isfinite(values)):
        raise FrameError(
            f"AdcFrame at {msg.first_sample_index}: conversion code * lsb + offset overflows",
            "non_finite",
        )
    return values


def signal_data(msg: SignalFrame) -> np.ndarray:
    """Samples (n, channels) of a validated SignalFrame.

    Raises:
        FrameError: inconsistent sizes (``malformed``) or non-finite samples
            (``non_finite``).
    """
    channels = _check_common(msg, len(msg.data), "SignalFrame")
    data = (
        np.frombuffer(msg.data, dtype=np.float64)
        if isinstance(msg.data, array.array)
        else np.asarray(msg.data, dtype=float)
    )
    if not np.all(np.isfinite(data)):
        raise FrameError("SignalFrame: non-finite samples", "non_finite")
    return data.reshape(msg.num_samples, channels)


def estimate_states(msg: StateEstimate) -> np.ndarray:
    """States (n, states) of a validated StateEstimate.

    Raises:
        FrameError: no states, sizes inconsistent (``malformed``) or non-finite states
            (``non_finite``).
    """
    k = len(msg.state_names)
    if k == 0 or len(msg.state_units) != k:
        raise FrameError(f"StateEstimate at {msg.first_sample_index}: state names/units")
    if not np.isfinite(msg.sample_rate_hz) or msg.sample_rate_hz <= 0:
        raise FrameError(f"StateEstimate: sample_rate_hz = {msg.sample_rate_hz} must be > 0")
    if len(msg.states) != msg.num_samples * k:
        raise FrameError(
            f"StateEstimate at {msg.first_sample_index}: {len(msg.states)} values for "
            f"num_samples = {msg.num_samples} x {k} states"
        )
    states = (
        np.frombuffer(msg.states, dtype=np.float64)
        if isinstance(msg.states, array.array)
        else np.asarray(msg.states, dtype=float)
    )
    if not np.all(np.isfinite(states)):
        raise FrameError(
            f"StateEstimate at {msg.first_sample_index}: non-finite values", "non_finite"
        )
    return states.reshape(msg.num_samples, k)


def frame_format(msg) -> tuple:
    """What a stream's frames share (sample rate, channel or state names and units and, for
    an AdcFrame, bits, lsb, offset and full scale): frames of one stream have equal formats."""
    if isinstance(msg, AdcFrame):
        return (
            float(msg.sample_rate_hz),
            tuple(msg.channel_names),
            tuple(msg.channel_units),
            int(msg.bits),
            tuple(msg.lsb),
            tuple(msg.offset),
            tuple(msg.full_scale),
        )
    if isinstance(msg, StateEstimate):
        return (
            float(msg.sample_rate_hz),
            msg.estimator,
            tuple(msg.state_names),
            tuple(msg.state_units),
        )
    return float(msg.sample_rate_hz), tuple(msg.channel_names), tuple(msg.channel_units)

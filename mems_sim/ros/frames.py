"""Conversion between numpy sample blocks and the frame messages of mems_msgs.

Frames carry consecutive samples: ``header.stamp`` is the
time of the first sample, derived from its index and the sample rate, never
from the wall clock, so that recordings are bit-identical across runs.
"""

from __future__ import annotations

import array
from collections.abc import Sequence
from fractions import Fraction

import numpy as np
from builtin_interfaces.msg import Time

from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.bag.writer import FrameGapCounter as IndexTracker  # noqa: F401 (re-export)


class FrameError(ValueError):
    """A malformed or non-finite frame (rejected and counted, never used)."""


def index_to_ns(index: int, sample_rate_hz: float, t0_ns: int = 0) -> int:
    """Time of sample ``index`` [ns] = t0 + index / fs, exact in integer arithmetic.

    Args:
        index: sample index (>= 0).
        sample_rate_hz: sample rate [Hz] (> 0).
        t0_ns: time of sample 0 [ns].
    """
    rate = Fraction(repr(float(sample_rate_hz)))
    return t0_ns + (int(index) * 10**9 * rate.denominator) // rate.numerator


def ns_to_time(ns: int) -> Time:
    """builtin_interfaces/Time from integer nanoseconds."""
    return Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9))


def time_to_ns(stamp: Time) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return int(stamp.sec) * 10**9 + int(stamp.nanosec)


def _int32_array(values: np.ndarray) -> array.array:
    out = array.array("i")
    out.frombytes(np.ascontiguousarray(values, dtype=np.int32).tobytes())
    return out


def _float64_array(values: np.ndarray) -> array.array:
    out = array.array("d")
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


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
    if codes.ndim != 2 or codes.shape[1] != len(channel_names):
        raise FrameError(f"codes shape {codes.shape} does not match {len(channel_names)} channels")
    msg = _fill_frame(AdcFrame(), first_index, sample_rate_hz, codes.shape[0], frame_id, t0_ns)
    msg.bits = int(bits)
    msg.channel_names = list(channel_names)
    msg.channel_units = list(channel_units)
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
    if data.ndim != 2 or data.shape[1] != len(channel_names):
        raise FrameError(f"data shape {data.shape} does not match {len(channel_names)} channels")
    msg = _fill_frame(SignalFrame(), first_index, sample_rate_hz, data.shape[0], frame_id, t0_ns)
    msg.channel_names = list(channel_names)
    msg.channel_units = list(channel_units)
    msg.data = _float64_array(data)
    return msg


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


def adc_physical(msg: AdcFrame) -> np.ndarray:
    """Physical values (n, channels) = codes * lsb + offset of a validated AdcFrame.

    Raises:
        FrameError: inconsistent sizes, non-positive or non-finite rate/lsb.
    """
    channels = _check_common(msg, len(msg.codes), "AdcFrame")
    lsb = np.asarray(msg.lsb, dtype=float)
    offset = np.asarray(msg.offset, dtype=float) if len(msg.offset) else np.zeros(channels)
    if lsb.shape != (channels,) or offset.shape != (channels,):
        raise FrameError(f"AdcFrame: lsb/offset need {channels} entries")
    if not (np.all(np.isfinite(lsb)) and np.all(lsb > 0) and np.all(np.isfinite(offset))):
        raise FrameError("AdcFrame: lsb must be finite and > 0, offset finite")
    codes = (
        np.frombuffer(msg.codes, dtype=np.int32)
        if isinstance(msg.codes, array.array)
        else np.asarray(msg.codes, dtype=np.int32)
    )
    return codes.reshape(msg.num_samples, channels) * lsb + offset


def signal_data(msg: SignalFrame) -> np.ndarray:
    """Samples (n, channels) of a validated SignalFrame.

    Raises:
        FrameError: inconsistent sizes or non-finite samples.
    """
    channels = _check_common(msg, len(msg.data), "SignalFrame")
    data = (
        np.frombuffer(msg.data, dtype=np.float64)
        if isinstance(msg.data, array.array)
        else np.asarray(msg.data, dtype=float)
    )
    if not np.all(np.isfinite(data)):
        raise FrameError("SignalFrame: non-finite samples")
    return data.reshape(msg.num_samples, channels)

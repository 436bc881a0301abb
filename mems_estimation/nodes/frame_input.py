"""Input side shared by the estimator nodes: pairing of a device's ADC and drive frames,
rate check, and rejection of bad frames counted on /diagnostics."""

from __future__ import annotations

from mems_sim.ros.frames import FrameError


class FramePairer:
    """Pairs the frames of two streams (e.g. ADC and drive) that share a
    ``first_sample_index``, in index order (ROS-free)."""

    def __init__(self, kinds: tuple[str, str] = ("adc", "drive")) -> None:
        self.kinds = kinds
        self.frames: dict[str, dict[int, object]] = {k: {} for k in kinds}

    def add(self, kind: str, first: int, values) -> list[tuple[int, object, object]]:
        """Store one frame of stream ``kind``; return the pairs now complete, ordered by index
        as ``(first_sample_index, values of kinds[0], values of kinds[1])``."""
        self.frames[kind][first] = values
        a, b = (self.frames[k] for k in self.kinds)
        return [(k, a.pop(k), b.pop(k)) for k in sorted(set(a) & set(b))]


class FrameInputMixin:
    """``_reject`` and ``_check_rate`` of an estimator node (needs ``self.diag``, ``self.fs``)."""

    def _reject(self, text: str) -> None:
        """Count a rejected frame and warn on /diagnostics (the node keeps running)."""
        self.diag.count("rejected_frames")
        self.diag.warn(f"rejected frame: {text}")

    def _check_rate(self, msg) -> None:
        """FrameError unless the frame's sample rate is the model's ``self.fs`` [Hz]."""
        if msg.sample_rate_hz != self.fs:
            raise FrameError(
                f"frame at {msg.first_sample_index}: sample_rate_hz "
                f"{msg.sample_rate_hz} differs from the model's {self.fs} Hz"
            )

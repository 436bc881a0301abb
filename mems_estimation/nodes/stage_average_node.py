"""ROS 2 node: synchronous averaging of the stage's capacitive channels over drive periods
(Chen 2018 sec. 3.5.2: 12.5 MHz acquired, 1024 drive periods averaged, saved at 625 kHz).

Subscribes the stage's ``adc`` (capacitive channels 1A, 1B, 2A, 2B, AdcFrame) and
``drive`` (SignalFrame with v_bias [V], f_drive [Hz], trial [-]) -- the node's namespace,
default ``/stage``, or ``device_namespace`` --, pairs them by ``first_sample_index``,
cancels the feedthrough with the bias on/off periods (sec. 3.5.4; ``cancel_feedthrough``)
and averages each cancelled sample with the nearest samples at the same drive phase in the
previous ``n_periods - 1`` periods of the same kind (``period_step`` 2: every other
period carries the sensor signal), restarting at each drive segment (trial or drive
frequency) and leaving out its first ``skip_periods`` periods (:class:`SynchronousAverager`).

Output ``adc_averaged`` (SignalFrame, one frame per input pair, same
``first_sample_index``, sample rate and header stamp as the ADC frame): channels 1A, 1B,
2A, 2B [V], the averages, and ``n_avg`` [-], the number of drive periods averaged in that
sample. Where a sample has no value (a bias-off period, the first period after a start,
the skipped periods of a segment) ``n_avg`` is 0 and the four values are 0: frame
validation refuses non-finite samples in a SignalFrame, so "no value" is carried by the
count, never by NaN. White readout noise is reduced by exactly 1/sqrt(n_avg); a
periodic signal of harmonic h passes attenuated by (2 pi h f_drive/fs)^2/24 (1.2e-5 of
the fundamental at 1700 Hz, 625 kHz), once the average holds only steady periods.

A gap, a stream reset or a change of the input format starts the average again (the
phase-locked taps need every sample since the start) and the feedthrough cancellation
from no history; the periods after it count up again from n_avg = 1. A drive whose
average would keep more than ``max_history_samples`` samples is rejected (counted) and the
average starts again at the next frame. Malformed or non-finite frames are rejected and
counted on /diagnostics (input path: :class:`EstimatorNode`).
"""

from __future__ import annotations

import numpy as np

from mems_estimation.filters.stage_ekf import FeedthroughCanceller
from mems_estimation.filters.synchronous_average import SynchronousAverager, tap_plan
from mems_estimation.nodes.frame_input import (
    DEVICE_NAMESPACE,
    EstimatorNode,
    drive_channels,
    input_specs,
    output_frame,
)
from mems_msgs.msg import AdcFrame, SignalFrame
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import FrameError, adc_physical, make_signal_frame, signal_data
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import FRAME_QOS

#: The stage's capacitive channels, averaged in this order.
CHANNELS = ("1A", "1B", "2A", "2B")
#: Channels of the averaged frames: the four averages [V] and the periods averaged [-].
OUTPUT_CHANNELS = (*CHANNELS, "n_avg")
OUTPUT_UNITS = ("V", "V", "V", "V", "-")

AVERAGE_SPECS: tuple[ParamSpec, ...] = (
    DEVICE_NAMESPACE,
    ParamSpec(
        "n_periods",
        1024,
        "periods",
        "drive periods of the same kind averaged (N)",
        "Chen 2018 sec. 3.5.2: 1024-period averaging",
        min=1,
        max=65536,
    ),
    ParamSpec(
        "period_step",
        2,
        "periods",
        "drive periods between two averaged periods (2: the bias on/off alternation of "
        "the feedthrough cancellation; 1: every period)",
        "Chen 2018 sec. 3.5.2 and 3.5.4 (bias on every other period)",
        min=1,
        max=1000,
    ),
    ParamSpec(
        "skip_periods",
        0,
        "periods",
        "drive periods left out at the start of each drive segment (the settling "
        "transient: 1/(zeta wn) = 18.6 ms = 32 periods at 1700 Hz)",
        "Chen 2018 sec. 3.5.2 (no number given: 0, every period)",
        min=0,
        max=10**7,
    ),
    ParamSpec(
        "cancel_feedthrough",
        True,
        "-",
        "bias on/off feedthrough cancellation before averaging (false: the raw bias-on "
        "samples are averaged)",
        "Chen 2018 sec. 3.5.4",
    ),
    ParamSpec(
        "max_history_samples",
        2**22,
        "samples",
        "largest span of input samples the average keeps (40 bytes per sample for four "
        "channels); a drive that needs more is rejected",
        "chosen: 1024 periods x 2 at 1700 Hz, 625 kHz need 0.76 M samples",
        min=1,
        max=2**31 - 1,
    ),
)


def drive_columns(msg: SignalFrame) -> tuple[np.ndarray, ...]:
    """(v_bias [V], f_drive [Hz], trial [-], sample rate [Hz] per sample) of a drive frame;
    FrameError when a channel is absent or a value non-finite."""
    cols = drive_channels(msg, ("v_bias", "f_drive", "trial"))
    return (*cols, np.full(cols[0].shape[0], float(msg.sample_rate_hz)))


def decode_adc(msg: AdcFrame) -> tuple[np.ndarray, np.ndarray]:
    """(channels 1A, 1B, 2A, 2B (n, 4) [V], sample rate [Hz] per sample) of an ADC frame;
    FrameError when a channel is absent."""
    y = adc_physical(msg)
    names = list(msg.channel_names)
    missing = [c for c in CHANNELS if c not in names]
    if missing:
        raise FrameError(
            f"adc frame at {msg.first_sample_index}: channels {missing} absent", "foreign"
        )
    y = np.ascontiguousarray(y[:, [names.index(c) for c in CHANNELS]])
    return y, np.full(y.shape[0], float(msg.sample_rate_hz))


class StageAverageNode(EstimatorNode):
    """Synchronous average of the feedthrough-cancelled channels (see module doc)."""

    GAP_NOTE = "synchronous average and cancellation history start again"

    NODE_NAME = "stage_average"
    DEFAULT_NAMESPACE = "stage"
    SPECS = AVERAGE_SPECS + input_specs()
    DIAGNOSTICS_TITLE = "stage synchronous average"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        #: sample rate of the running average [Hz] (the frames'; None before the first)
        self.rate: float | None = None
        self._history: dict[float, int] = {}
        # load the compiled (numba) kernels before subscribing, not at the first frame
        # (~1 s late otherwise); throwaway canceller and averager, same argument types
        nch = len(CHANNELS)
        yc = FeedthroughCanceller(nch, 625e3).step(np.zeros((2, nch)), np.ones(2), np.ones(2))
        SynchronousAverager(nch, 625e3, 2, 1).step(yc, np.full(2, 1e3), np.zeros(2))
        self.pub = self.create_publisher(SignalFrame, self.device_topic("adc_averaged"), FRAME_QOS)
        self.subscribe_pair(("adc", AdcFrame, decode_adc), ("drive", SignalFrame, drive_columns))

    def _start(self, fs: float) -> None:
        """New canceller and averager at sample rate ``fs`` [Hz]."""
        p = self.p
        self.rate = fs
        self._history = {}
        self.canceller = FeedthroughCanceller(len(CHANNELS), fs, enabled=p["cancel_feedthrough"])
        self.averager = SynchronousAverager(
            len(CHANNELS), fs, p["n_periods"], p["period_step"], p["skip_periods"]
        )

    def history_samples(self, f_drive: float) -> int:
        """Input samples the average keeps at drive frequency ``f_drive`` [Hz]: the span
        of its taps, N periods of the same kind, rounded up to whole repetitions of the
        sampling pattern (:func:`tap_plan`)."""
        if f_drive not in self._history:
            d = self.p["period_step"] * self.rate / f_drive
            if self.p["n_periods"] * d > 2 * self.p["max_history_samples"]:
                self._history[f_drive] = 2**62  # far too long: no plan needed
            else:
                _, L, _, m_hi = tap_plan(d, self.p["n_periods"])
                self._history[f_drive] = m_hi * L + 1
        return self._history[f_drive]

    def on_gap(self, gap: int) -> None:
        """A gap breaks the phase lock: the average and the cancellation start again."""
        self.reset_estimator()

    def on_format_change(self, kind: str) -> None:
        """A new input format (e.g. sample rate): the average starts again."""
        self.reset_estimator()

    def reset_estimator(self) -> None:
        """The average starts again from no period, the cancellation from no history."""
        if self.rate is not None:
            self.averager.reset()
            self.canceller.reset()

    def process_pair(self, first: int, stamp_ns: int, adc, drive) -> None:
        """Cancel the feedthrough, average one frame and publish it (module doc)."""
        y, rate = adc
        vb, fd, trial, drate = drive
        fs = float(rate[0])
        if float(drate[0]) != fs:
            raise FrameError(
                f"drive at {drate[0]} Hz, adc at {fs} Hz: not one device's frames", "foreign"
            )
        if fs != self.rate:
            self._start(fs)
        for f in np.unique(fd[fd > 0]).tolist():
            need = self.history_samples(f)
            if need > self.p["max_history_samples"]:
                self.reset_estimator()
                raise FrameError(
                    f"averaging {self.p['n_periods']} periods at f_drive = {f} Hz keeps "
                    f"{need} samples, more than max_history_samples = "
                    f"{self.p['max_history_samples']}",
                    "oversized",
                )
        yc = self.canceller.step(y, vb, fd)
        xa, count = self.averager.step(yc, fd, trial)
        ok = np.isfinite(xa).all(axis=1)
        data = np.zeros((y.shape[0], len(OUTPUT_CHANNELS)))
        data[ok, : len(CHANNELS)] = xa[ok]
        data[ok, len(CHANNELS)] = count[ok]
        msg = output_frame(
            make_signal_frame,
            data,
            first=first,
            fs=fs,
            stamp_ns=stamp_ns,
            channel_names=OUTPUT_CHANNELS,
            channel_units=OUTPUT_UNITS,
            frame_id="stage",
        )
        self.pub.publish(msg)


def averaged_channels(msg: SignalFrame) -> tuple[np.ndarray, np.ndarray]:
    """(averages (n, 4) [V] with NaN where no value, n_avg (n,)) of an ``adc_averaged``
    frame."""
    data = signal_data(msg)
    names = list(msg.channel_names)
    x = data[:, [names.index(c) for c in CHANNELS]].copy()
    n = data[:, names.index("n_avg")].copy()
    x[n <= 0] = np.nan
    return x, n


def main(argv: list[str] | None = None) -> int:
    """Entry point ``stage_average_node``."""
    return run_node(StageAverageNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

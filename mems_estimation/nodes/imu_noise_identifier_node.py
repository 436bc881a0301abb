"""ROS 2 node: Allan-variance noise identification on a stream of AdcFrames.

Subscribes to ``input_topic`` (mems_msgs/AdcFrame, default ``adc`` in the node's
namespace, default ``/imu``), accumulates the overlapping Allan sums of every channel
online (bounded memory: :class:`NoiseAccumulator`), and
publishes the identified noise model (mems_msgs/NoiseModel: N, B, K, T, Q per axis with
confidence intervals, the discrete model and the Allan deviation) on ``output_topic``
(default ``noise_model``, beside the input) every ``publish_period_s`` of *data* (so replaying a bag
gives exactly the live output) and once more, ``final = true``, at shutdown.
Malformed frames are rejected and counted on /diagnostics; gaps in
``first_sample_index`` are counted and reported, not bridged silently (input path:
:class:`EstimatorNode`: codes outside the bit range, frames of another format, repeated
and out-of-order frames never reach the data). The samples on either side of a gap or
stream reset are concatenated; a new stream format (adopted after consecutive frames of
it) starts the accumulation again. An identification that fails is counted
(``identification_failures``) and the node keeps running.
"""

from __future__ import annotations

import numpy as np

from mems_estimation.identification.allan_stream import StreamingAllan
from mems_estimation.identification.imu_noise_fit import identify_axes, identify_stream
from mems_estimation.nodes.frame_input import EstimatorNode, input_specs
from mems_estimation.nodes.imu_noise_messages import noise_model_msg
from mems_msgs.msg import AdcFrame, NoiseModel
from mems_sim.params import ParamSpec
from mems_sim.ros.frames import (
    FrameError,
    adc_physical,
    index_to_ns,
    ns_to_time,
    time_to_ns,
)
from mems_sim.ros.node_main import run_node
from mems_sim.ros.qos import RESULT_QOS
from mems_sim.stream_index import StreamIndex

IDENTIFIER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "input_topic",
        "adc",
        "-",
        "AdcFrame topic of the sensor at rest (relative: in the node's namespace)",
        "",
    ),
    ParamSpec(
        "output_topic",
        "noise_model",
        "-",
        "NoiseModel topic (relative: in the node's namespace)",
        "",
    ),
    ParamSpec(
        "tau_grid",
        "octave",
        "-",
        "Allan averaging-time grid",
        "allantools tau names",
        choices=("octave", "decade", "all"),
    ),
    ParamSpec(
        "publish_period_s",
        3600.0,
        "s",
        "data time between periodic results; 0 publishes only at shutdown",
        "",
        min=0.0,
        max=1.0e9,
    ),
    ParamSpec(
        "min_duration_s",
        60.0,
        "s",
        "least data before a model is identified",
        "",
        min=1.0,
        max=1.0e9,
    ),
)


class NoiseAccumulator:
    """ROS-free accumulation of one stream of AdcFrames (validated, gap-aware).

    For the "octave" and "decade" grids the samples are not kept: a
    :class:`~mems_estimation.identification.allan_stream.StreamingAllan` keeps the overlapping
    Allan sums and the channel means online, so memory does not grow with the record
    (about 48 MB for six channels). The "all" grid (every m up to L/2, O(L^2) work) keeps
    the samples (``chunks``) and computes in one batch.
    """

    def __init__(self, grid: str = "octave") -> None:
        self.grid = grid
        self.chunks: list[np.ndarray] = []
        self.stream: StreamingAllan | None = None
        self.num_samples = 0
        self.first_index: int | None = None
        self.fs: float | None = None
        self.channels: tuple[str, ...] = ()
        self.units: tuple[str, ...] = ()
        self.tracker = StreamIndex.recording(start=0)
        self.last_stamp_ns = 0

    def start(self, fs: float, first_index: int, channels, units) -> None:
        """Fix the stream's rate, first sample index, channel names and units."""
        self.fs, self.first_index = float(fs), int(first_index)
        self.channels, self.units = tuple(channels), tuple(units)
        if self.grid != "all":
            self.stream = StreamingAllan(len(self.channels), self.fs, self.grid)

    def extend(self, values: np.ndarray) -> None:
        """Accumulate samples (n, channels) in physical units (after :meth:`start`)."""
        values = np.asarray(values, dtype=float)
        if self.stream is not None:
            self.stream.add(values)
        else:
            self.chunks.append(values)
        self.num_samples += values.shape[0]

    def add(self, msg: AdcFrame) -> int:
        """Append a frame; return samples missing before it. Raises FrameError if malformed."""
        return self.append(msg, adc_physical(msg))

    def append(self, msg: AdcFrame, values: np.ndarray) -> int:
        """Append a frame whose physical values (n, channels) are ``values``; return samples
        missing before it. Raises FrameError if its rate or channels differ."""
        if self.fs is None:
            self.start(
                msg.sample_rate_hz, msg.first_sample_index, msg.channel_names, msg.channel_units
            )
        elif msg.sample_rate_hz != self.fs or tuple(msg.channel_names) != self.channels:
            raise FrameError(
                f"frame at {msg.first_sample_index}: sample rate or channels changed "
                f"({msg.sample_rate_hz} Hz, {list(msg.channel_names)})",
                "foreign",
            )
        _, missing = self.tracker.update(int(msg.first_sample_index), int(msg.num_samples))
        self.extend(values)
        self.last_stamp_ns = index_to_ns(values.shape[0] - 1, self.fs, time_to_ns(msg.header.stamp))
        return missing

    def data(self) -> np.ndarray:
        """All samples so far, shape (n, channels) (the "all" grid only; a streaming
        accumulator keeps no samples)."""
        if self.stream is not None:
            raise ValueError(f"a streaming ({self.grid}) accumulator keeps no samples")
        if len(self.chunks) > 1:
            self.chunks = [np.concatenate(self.chunks)]
        return self.chunks[0] if self.chunks else np.zeros((0, len(self.channels)))

    def duration_s(self) -> float:
        """Data accumulated [s]."""
        return self.num_samples / self.fs if self.fs else 0.0

    def results(self):
        """(fit, AllanResult) per channel and the channel means."""
        if self.stream is not None:
            return identify_stream(self.stream), self.stream.mean()
        data = self.data()
        return identify_axes(data, self.fs, self.grid), data.mean(axis=0)


def identify_message(
    acc: NoiseAccumulator, grid: str, final: bool, frame_id: str = ""
) -> NoiseModel:
    """Identify every channel of ``acc`` and build the NoiseModel message (``grid`` must be
    the accumulator's, or "all" with its samples kept)."""
    if grid != acc.grid:
        raise ValueError(f"tau grid {grid!r} differs from the accumulator's {acc.grid!r}")
    results, means = acc.results()
    return noise_model_msg(
        results,
        acc.channels,
        acc.units,
        means,
        fs=acc.fs,
        first_index=acc.first_index,
        num_samples=acc.num_samples,
        grid=grid,
        final=final,
        stamp=ns_to_time(acc.last_stamp_ns),
        frame_id=frame_id,
    )


class ImuNoiseIdentifierNode(EstimatorNode):
    """Accumulates AdcFrames and publishes identified noise models."""

    NODE_NAME = "imu_noise_identifier"
    DEFAULT_NAMESPACE = "imu"
    SPECS = IDENTIFIER_SPECS + input_specs(paired=False, max_frame_samples=100_000)
    DIAGNOSTICS_TITLE = "noise identification"

    def __init__(self, **node_kwargs) -> None:
        super().__init__(**node_kwargs)
        self.acc = NoiseAccumulator(self.p["tau_grid"])
        self.results: list[NoiseModel] = []
        self._next_publish_s = self.p["publish_period_s"]
        self._finalised = False
        self._final: NoiseModel | None = None
        self.pub = self.create_publisher(NoiseModel, self.p["output_topic"], RESULT_QOS)
        self.sub = self.subscribe_single(
            ("input", AdcFrame, adc_physical), check_rate=False, topic=self.p["input_topic"]
        )

    def process_frame(self, first: int, stamp_ns: int, values, msg: AdcFrame) -> None:
        """Accumulate a good frame; publish a periodic result when due."""
        self.acc.append(msg, values)
        period = self.p["publish_period_s"]
        if period > 0 and self.acc.duration_s() >= self._next_publish_s:
            self._next_publish_s += period
            self.publish_result(final=False)

    def on_format_change(self, kind: str) -> None:
        """A new stream format: the accumulation (and the periodic schedule) starts again."""
        self.acc = NoiseAccumulator(self.p["tau_grid"])
        self._next_publish_s = self.p["publish_period_s"]
        self.diag.warn("input format changed: noise identification starts again")

    def publish_result(self, final: bool) -> NoiseModel | None:
        """Identify on all data so far and publish; None if too little data."""
        if self.acc.duration_s() < self.p["min_duration_s"]:
            if final:
                self.diag.warn(
                    f"only {self.acc.duration_s():.1f} s of data, less than "
                    f"min_duration_s = {self.p['min_duration_s']} s: no model"
                )
            return None
        try:
            msg = identify_message(self.acc, self.p["tau_grid"], final)
        except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
            self.diag.count("identification_failures")
            self.diag.warn(f"noise identification failed: {exc}")
            return None
        self.results.append(msg)
        self.pub.publish(msg)
        return msg

    def finish(self) -> NoiseModel | None:
        """End of input: publish the final model (once; the first call's model is returned
        again) and return it; None if there was too little data."""
        if not self._finalised:
            self._finalised = True
            self._final = self.publish_result(final=True)
        return self._final

    def close(self) -> None:
        """Publish the final model (once)."""
        self.finish()


def main(argv: list[str] | None = None) -> int:
    """Entry point ``imu_noise_identifier_node``."""
    return run_node(ImuNoiseIdentifierNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

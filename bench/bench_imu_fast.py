"""Real-time factor of the imu_noise graph in fast mode, with and without the recorder.

The scenario's graph in one process (emulator stepped by the runner, Allan identifier,
optionally the MCAP recorder), run as fast as its consumers take the frames: simulated
seconds per wall second from the first frame to the last frame delivered (set-up and the
final identification excluded). Ratios measured in one run on this machine.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
from mems_scenarios.base import Graph, parameters
from mems_scenarios.delivery import consumed, drive_fast, finish_delivery
from mems_sim.bag.recorder import RecorderNode
from mems_sim.nodes.imu_node import ImuNode

DURATION_S = 2000.0
FRAME = 100  # samples per frame at 100 Hz, as the scenario's fast runs


def rtf(record: bool, tmp: Path, split: dict | None = None) -> float:
    """Simulated s / wall s of DURATION_S of the imu_noise graph (with or without recorder;
    ``split``: the recorder's max_bag_size / max_bag_duration, a split bag directory)."""
    graph = Graph()
    try:
        emu = graph.add_device(
            ImuNode,
            {"seed": 1, "duration_s": DURATION_S, "frame_size": FRAME, "publish_imu": False},
            realtime=False,
        )
        ident = graph.add(
            ImuNoiseIdentifierNode(
                context=graph.context, namespace="imu", parameter_overrides=parameters({})
            )
        )
        if record:
            topics = ["/imu/adc", "/imu/truth", "/imu/noise_model"]
            out = tmp / ("split.mcap" if split else "bench.mcap")
            graph.add(RecorderNode(str(out), topics=topics, context=graph.context, **(split or {})))
        graph.spin_until(
            lambda: emu.pub_adc.get_subscription_count() >= (2 if record else 1),
            30.0,
            "subscribers",
        )
        t0 = time.perf_counter()
        drive_fast(graph, [emu], consumed(ident), None, 50)
        finish_delivery(graph, [emu], consumed(ident))
        wall = time.perf_counter() - t0
    finally:
        graph.close()
    return DURATION_S / wall


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        without = rtf(False, Path(d))
        with_rec = rtf(True, Path(d))
        # 2000 s of 6-axis frames are ~1 MB of MCAP: split every 100 s of data (20 files)
        split = rtf(True, Path(d), dict(max_bag_duration=100.0))
        files = len(list((Path(d) / "split").glob("*.mcap")))
    print(
        f"imu_noise fast mode, {DURATION_S:.0f} s at 100 Hz in frames of {FRAME}: "
        f"real-time factor {without:.0f}x without the recorder, {with_rec:.0f}x with it "
        f"(ratio {with_rec / without:.2f}), {split:.0f}x with it splitting every 100 s of "
        f"data into {files} files (ratio to one file {split / with_rec:.2f})"
    )


if __name__ == "__main__":
    main()

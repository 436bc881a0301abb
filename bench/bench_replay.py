"""Replay on the data's timeline: lossless fast replay into another process, and pacing.

1. Records the ``imu_noise`` scenario as fast as possible (``--duration``, default 600 s of
   data): the identifier's final model in that run is the *live* model.
2. Replays the recording's ``/imu/adc`` as fast as possible into
   ``imu_noise_identifier_node`` started as a separate process (``-r __ns:=/imu``), with
   ``mcap_play --wait-for-consumer /imu/imu_noise_identifier`` (application-level flow
   control), and compares the node's final model with the live one field by field. The
   same replay without flow control is shown for contrast (frames the node missed, as
   its final model's sample count and its gap count on /diagnostics say).
3. Plays the recording at ``--rate 1`` and ``--rate 10`` and measures, in this process,
   the wall time between the first and the last frame received: wall duration / (recorded
   duration / rate) should be 1 within 2 %.

Usage: ``python bench/bench_replay.py [--duration S] [--rates 1 10] [--domain N]``
(``--duration 600`` takes about 11 minutes, most of it the replay at rate 1).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from mems_msgs.msg import AdcFrame, NoiseModel
from mems_scenarios import imu_noise
from mems_scenarios.base import ScenarioOptions
from mems_sim.bag.info import bag_info
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS

BIN = Path(sys.executable).parent
IDENTIFIER = "/imu/imu_noise_identifier"


def differences(a, b, path: str = "") -> list[str]:
    """Fields of two messages that differ (NaN equals NaN)."""
    if hasattr(a, "get_fields_and_field_types"):
        out = []
        for name in a.get_fields_and_field_types():
            out += differences(getattr(a, name), getattr(b, name), f"{path}.{name}")
        return out
    if isinstance(a, float):
        return [] if a == b or (math.isnan(a) and math.isnan(b)) else [path]
    if isinstance(a, (str, int, bool, bytes)):
        return [] if a == b else [path]
    if len(a) != len(b):
        return [path]
    if len(a) and hasattr(a[0], "get_fields_and_field_types"):
        return [d for k, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{k}]")]
    x, y = np.asarray(a), np.asarray(b)
    return [] if np.array_equal(x, y, equal_nan=x.dtype.kind == "f") else [path]


def count_fields(msg) -> int:
    """Leaf fields of a message (arrays count once)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return sum(count_fields(getattr(msg, n)) for n in msg.get_fields_and_field_types())
    if isinstance(msg, (list, tuple)) and msg and hasattr(msg[0], "get_fields_and_field_types"):
        return sum(count_fields(m) for m in msg)
    return 1


class Probe:
    """A node in this process: final models, the identifier's gaps, frame arrival times."""

    def __init__(self, domain: int):
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("bench_replay_probe", context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.models: list[NoiseModel] = []
        self.gaps = None
        self.arrivals: list[tuple[float, int]] = []
        self.node.create_subscription(
            NoiseModel, "/imu/noise_model", self.models.append, RESULT_QOS
        )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 50)
        self.node.create_subscription(AdcFrame, "/imu/adc", self._frame, FRAME_QOS)

    def _diag(self, msg) -> None:
        for s in msg.status:
            if s.name.startswith("imu_noise_identifier:"):
                self.gaps = int({kv.key: kv.value for kv in s.values}.get("gaps", 0))

    def _frame(self, msg) -> None:
        self.arrivals.append((time.monotonic(), msg.first_sample_index))

    def spin_until(self, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate() and time.monotonic() < deadline:
            self.ex.spin_once(timeout_sec=0.02)
        return predicate()

    def run(self, args, env, timeout: float) -> subprocess.CompletedProcess:
        """Run a console script while spinning; its exit code and output."""
        proc = subprocess.Popen(
            args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        try:
            self.spin_until(lambda: proc.poll() is not None, timeout)
            out, err = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        return subprocess.CompletedProcess(args, proc.returncode, out, err)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def replay_into_identifier(probe: Probe, bag: Path, env, flow: bool, data_s: float):
    """Start the identifier process, replay /imu/adc as fast as possible, stop it; return
    (final model or None, player output, wall time of the replay [s], identifier gaps)."""
    probe.models.clear()
    probe.gaps = None
    ident = subprocess.Popen(
        [str(BIN / "imu_noise_identifier_node"), "--ros-args", "-r", "__ns:=/imu"]
        + ["-p", "publish_period_s:=0.0"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        probe.spin_until(
            lambda: ("imu_noise_identifier", "/imu") in probe.node.get_node_names_and_namespaces(),
            60,
        )
        args = [str(BIN / "mcap_play"), str(bag), "--topics", "/imu/adc", "--as-fast-as-possible"]
        if flow:
            args += ["--wait-for-consumer", IDENTIFIER, "--wait-timeout", "60"]
        else:
            args += ["--wait-for-subscribers", "2", "--wait-timeout", "60"]
        t0 = time.monotonic()
        res = probe.run(args, env, timeout=max(120.0, data_s))
        wall = time.monotonic() - t0
        probe.spin_until(lambda: False, 2.0)  # the identifier's last diagnostics
        ident.send_signal(signal.SIGINT)
        probe.spin_until(lambda: any(m.final for m in probe.models), 120)
        ident.wait(timeout=30)
    finally:
        if ident.poll() is None:
            ident.kill()
            ident.wait()
    finals = [m for m in probe.models if m.final]
    return (finals[-1] if finals else None), res, wall, probe.gaps


def pacing(probe: Probe, bag: Path, env, rate: float, data_s: float) -> tuple[float, float, str]:
    """Play /imu/adc at ``rate``; (wall span of the frames received here, recorded span [s],
    the player's own line)."""
    probe.arrivals.clear()
    res = probe.run(
        [str(BIN / "mcap_play"), str(bag), "--topics", "/imu/adc", "--rate", str(rate)]
        + ["--wait-for-subscribers", "1"],
        env,
        timeout=data_s / rate + 120,
    )
    probe.spin_until(lambda: False, 0.5)
    firsts = [i for _, i in probe.arrivals]
    wall = probe.arrivals[-1][0] - probe.arrivals[0][0]
    fs = 100.0
    recorded = (firsts[-1] - firsts[0]) / fs
    line = res.stdout.strip().splitlines()[0] if res.stdout.strip() else res.stderr.strip()
    return wall, recorded, line


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=600.0, help="data recorded [s]")
    parser.add_argument("--rates", type=float, nargs="*", default=[1.0, 10.0])
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", 62)))
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain))
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "imu_noise.mcap"
        t0 = time.monotonic()
        live = imu_noise.run(
            ScenarioOptions(
                duration_s=args.duration,
                seed=args.seed,
                out=bag,
                domain_id=args.domain,
                progress=False,
                plots=False,
            )
        )["model"]
        info = bag_info(str(bag))
        print(
            f"recorded: imu_noise {args.duration:g} s of data as fast as possible in "
            f"{time.monotonic() - t0:.1f} s; mcap_info: start {info['start_ns'] / 1e9:.3f} s, "
            f"duration {info['duration_s']:.3f} s, {info['topics']['/imu/adc']['count']} frames"
        )
        probe = Probe(args.domain)
        try:
            fields = count_fields(live)
            for flow in (True, False):
                model, res, wall, gaps = replay_into_identifier(
                    probe, bag, env, flow, args.duration
                )
                what = "with --wait-for-consumer" if flow else "without flow control"
                print(f"fast replay into imu_noise_identifier_node (own process), {what}:")
                print(f"  player exit {res.returncode}, replay {wall:.2f} s wall")
                for line in res.stdout.strip().splitlines():
                    print(f"  | {line}")
                if model is None:
                    print("  no final model")
                    continue
                diff = differences(model, live)
                print(
                    f"  final model: {model.num_samples} samples (live {live.num_samples}), "
                    f"identifier gaps {gaps}; fields equal to the live model: "
                    f"{fields - len(diff)} of {fields}"
                    + ("" if not diff else f" (differ: {', '.join(diff[:4])} ...)")
                )
            for rate in args.rates:
                wall, recorded, line = pacing(probe, bag, env, rate, args.duration)
                ratio = wall / (recorded / rate)
                print(
                    f"pacing --rate {rate:g}: {recorded:.2f} s recorded in {wall:.2f} s wall, "
                    f"ratio {ratio:.4f} ({100 * (ratio - 1):+.2f} %)"
                )
                print(f"  | {line}")
        finally:
            probe.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

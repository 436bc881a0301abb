"""``make bags``: regenerate the reference recordings of ``bags/`` from fixed seeds.

One short, seeded excerpt per device family, each a rosbag2-compatible MCAP file (zstd,
at most 5 MB, 25 MB in all) holding the device topics its estimator subscribes to
(``adc``, and ``drive`` except for the IMU), the device's ``truth`` and the estimator's
outputs as they were published live:

=============  ==================================  =======================================
bag            device -> estimator                 estimator parameters (besides defaults)
=============  ==================================  =======================================
imu            imu_node, 600 s at rest             publish_period_s = 120 (a model per
               -> imu_noise_identifier_node        2 min of data, then the final one)
accelerometer  accelerometer_node, PI loop, 1 g,   -
               40 ms -> accelerometer_ekf_node
stage          stage_node, 1.0 V at 1700 Hz,       params_yaml = bags/stage_params.yaml
               80 ms -> stage_ekf_node             (identified here: seeded short plan)
scanner        scanner_node, 50 ms sweep into      -
               parametric resonance, 20 ms hold,
               30 ms ring-down
               -> scanner_threshold_ekf_node
scanner_amdm   scanner_amdm_node, first 30 ms of   -
               the scenario's sweep
               -> scanner_amdm_estimator_node
resonator      resonator_node, observer loop,      output_noise_std = 0.5
               output noise 0.5 V, 30 ms
               -> resonator_observer_node
=============  ==================================  =======================================

Every estimator runs in its device's namespace (``/imu``, ``/stage``, ...). The graph is
one process, run as the scenarios run (:class:`mems_scenarios.base.Graph`,
:func:`mems_scenarios.delivery.drive_fast`): the script steps the emulators and waits for the
recorder and the estimator to take every frame, so the recordings are lossless and their
messages and their log times (sensor time: the stamps, from epoch 0) identical from run to
run (``publish_time``, the wall-clock time of publication, is the only thing that
differs). ``/diagnostics`` is left out: it is published on a wall-clock timer, so what it
holds would differ on every regeneration.

Rerun ``make bags`` whenever the recording format (messages, recorder) or a device or
estimator changes its output; ``test/bags`` checks that regeneration reproduces the
committed bags message for message and that replaying them into the estimators gives the
stored estimates.

Usage: ``python tools/make_bags.py [--out DIR] [--only NAME ...] [--replay]``
(``--replay`` prints, for each bag, a shell line that replays it into its estimator
executable and records what that publishes.)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
from mems_estimation.nodes.resonator_observer_node import ResonatorObserverNode
from mems_estimation.nodes.scanner_amdm_estimator_node import ScannerAmdmEstimatorNode
from mems_estimation.nodes.scanner_threshold_ekf_node import ScannerThresholdEkfNode
from mems_estimation.nodes.stage_ekf_node import StageEkfNode
from mems_scenarios.base import Graph, default_domain_id, parameters
from mems_scenarios.delivery import drive_fast
from mems_sim.bag.recorder import RecorderNode
from mems_sim.devices.scanner_amdm import SWEEP_STUDY
from mems_sim.nodes.accelerometer_node import AccelerometerNode
from mems_sim.nodes.imu_node import ImuNode
from mems_sim.nodes.resonator_node import ResonatorNode
from mems_sim.nodes.scanner_amdm_node import ScannerAmdmNode
from mems_sim.nodes.scanner_node import ScannerNode
from mems_sim.nodes.stage_node import StageNode

REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO / "bags"
#: Name of the identified stage parameter file written next to ``stage.mcap``.
STAGE_YAML = "stage_params.yaml"
#: Seed of the stage identification runs (short plan) behind ``stage_params.yaml``.
STAGE_ID_SEED = 7
MAX_BYTES = 5_000_000


def _frames_done(est) -> int:
    """Input frames the estimator has processed (most estimator nodes)."""
    return est.frames_done


def finish(est) -> None:
    """End of the stream: what ``run_node`` does at shutdown, ``close()`` where the node has
    one (the IMU identifier publishes its final model, the scanner node its last ``lag``
    estimates)."""
    close = getattr(est, "close", None)
    if close is not None:
        close()


@dataclass(frozen=True)
class Family:
    """One reference bag: a device node, its estimator node and what is recorded.

    Attributes:
        name: bag name (``<name>.mcap``).
        namespace: namespace of the device and of the estimator.
        device: emulator node class (``drive_externally`` is set here).
        device_params: its parameters (seed, duration, frame size, ...).
        estimator: estimator node class.
        estimator_params: its parameters besides the defaults (the replay needs them too).
        inputs: device topics the estimator subscribes to (relative to ``namespace``).
        outputs: estimator output topics (relative to ``namespace``).
        executable: console script of the estimator (for the replay line).
        consumed: input frames the estimator has taken so far.
        published: messages the estimator has published so far, per output topic.
        prepare: ``(out_dir) -> extra estimator parameters``, run before the graph
            (the stage writes its identified parameter YAML there).
        extra_recorded: device topics recorded besides the inputs (the truth).
        window: frames the device may run ahead of its slowest consumer.
    """

    name: str
    namespace: str
    device: type
    device_params: dict
    estimator: type
    estimator_params: dict
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    executable: str
    consumed: Callable[[object], int] = _frames_done
    published: Callable[[object], dict[str, int]] | None = None
    prepare: Callable[[Path], dict] | None = None
    extra_recorded: tuple[str, ...] = ("truth",)
    window: int = 20

    def topic(self, relative: str) -> str:
        """Absolute name of a topic of this family's namespace."""
        return f"/{self.namespace}/{relative}"

    def recorded(self) -> list[str]:
        """Every recorded topic: estimator inputs, truth, estimator outputs."""
        return [self.topic(t) for t in self.inputs + self.extra_recorded + self.outputs]

    def replay_params(self, bag_dir: Path) -> dict:
        """Estimator parameters that replay the bag in ``bag_dir`` (with its stage YAML)."""
        params = dict(self.estimator_params)
        if self.prepare is not None:
            params["params_yaml"] = str(bag_dir / STAGE_YAML)
        return params

    def expected(self, est) -> dict[str, int]:
        """Messages published by the estimator per absolute output topic."""
        if self.published is not None:
            counts = self.published(est)
        else:
            counts = {t: est.frames_done for t in self.outputs}
        return {self.topic(t): n for t, n in counts.items()}


# ------------------------------------------------------------------ family specifics


def _scanner_published(est) -> dict[str, int]:
    """One estimate message per frame plus the flushed tail; detections per frame."""
    n = est.frames_done + (1 if getattr(est, "flushed", False) else 0)
    return {"estimate": n, "estimate_plain": n, "threshold_detections": est.frames_done}


def _amdm_published(est) -> dict[str, int]:
    """Estimates per frame; one phase/amplitude message per frame with extrema."""
    out = {f"{k}/estimate": est.frames_done for k in ("ekf", "ukf")}
    out.update({f"{k}/phase_amplitude": est.event_msgs[k] for k in ("ekf", "ukf")})
    return out


def _stage_identify(out_dir: Path) -> dict:
    """Identify the stage (seeded short plan, ROS-free cores) and write its YAML."""
    from mems_estimation.filters.stage_ekf import save_model
    from mems_estimation.identification.stage_gyro_calibration import Plan, identify_stage

    model, _ = identify_stage(
        seed=STAGE_ID_SEED, plan=Plan.short(), stage_params={"idealised": True}
    )
    path = out_dir / STAGE_YAML
    save_model(model, str(path))
    return {"params_yaml": str(path)}


FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        Family(
            name="imu",
            namespace="imu",
            device=ImuNode,
            device_params=dict(seed=11, duration_s=600.0, frame_size=100, publish_imu=False),
            estimator=ImuNoiseIdentifierNode,
            estimator_params=dict(publish_period_s=120.0),
            inputs=("adc",),
            outputs=("noise_model",),
            executable="imu_noise_identifier_node",
            consumed=lambda est: est.frames_received,
            published=lambda est: {"noise_model": len(est.results)},
            window=50,
        ),
        Family(
            name="accelerometer",
            namespace="accelerometer",
            device=AccelerometerNode,
            device_params=dict(seed=12, mode="pi_rebalance", duration_s=0.04, frame_size=5000),
            estimator=AccelerometerEkfNode,
            estimator_params={},
            inputs=("adc", "drive"),
            outputs=("estimate",),
            executable="accelerometer_ekf_node",
        ),
        Family(
            name="stage",
            namespace="stage",
            device=StageNode,
            # the drift-free stage of Table 3.3 (nominal damping and registration)
            device_params=dict(
                seed=13, duration_s=0.08, frame_size=10000, gyro_enabled=False, idealised=True
            ),
            estimator=StageEkfNode,
            estimator_params={},
            inputs=("adc", "drive"),
            outputs=("estimate",),
            executable="stage_ekf_node",
            prepare=_stage_identify,
        ),
        Family(
            name="scanner",
            namespace="scanner",
            device=ScannerNode,
            device_params=dict(
                seed=14,
                sweep_time_s=0.05,
                hold_time_s=0.02,
                ringdown_time_s=0.03,
                duration_s=0.1,
                frame_size=5000,
            ),
            estimator=ScannerThresholdEkfNode,
            estimator_params={},
            inputs=("adc", "drive"),
            outputs=("estimate", "estimate_plain", "threshold_detections"),
            executable="scanner_threshold_ekf_node",
            published=_scanner_published,
        ),
        Family(
            name="scanner_amdm",
            namespace="scanner_amdm",
            device=ScannerAmdmNode,
            device_params=dict(SWEEP_STUDY, seed=15, duration_s=0.03, frame_size=1000),
            estimator=ScannerAmdmEstimatorNode,
            estimator_params={},
            inputs=("adc", "drive"),
            outputs=("ekf/estimate", "ukf/estimate", "ekf/phase_amplitude", "ukf/phase_amplitude"),
            executable="scanner_amdm_estimator_node",
            published=_amdm_published,
        ),
        Family(
            name="resonator",
            namespace="resonator",
            device=ResonatorNode,
            device_params=dict(
                seed=16, mode="observer", output_noise_std=0.5, duration_s=0.03, frame_size=1000
            ),
            estimator=ResonatorObserverNode,
            estimator_params=dict(output_noise_std=0.5),
            inputs=("adc", "drive"),
            outputs=("estimate",),
            executable="resonator_observer_node",
        ),
    )
}


# ------------------------------------------------------------------ graph


def build(graph: Graph, family: Family, out: Path, estimator_params: dict):
    """Add the device, the estimator (both in the family's namespace) and the recorder."""
    dev = graph.add_device(
        family.device, family.device_params, realtime=False, namespace=family.namespace
    )
    est = graph.add(
        family.estimator(
            context=graph.context,
            namespace=family.namespace,
            parameter_overrides=parameters(estimator_params),
        )
    )
    rec = graph.add(RecorderNode(str(out), topics=family.recorded(), context=graph.context))
    return dev, est, rec


def wait_matched(graph: Graph, family: Family, rec: RecorderNode) -> None:
    """Spin until the recorder records every topic and every publisher of a recorded topic
    has its subscribers (estimator inputs two: estimator and recorder; the rest one)."""
    inputs = {family.topic(t) for t in family.inputs}
    pubs = {}
    for node in graph.nodes:
        for pub in node.publishers:
            if pub.topic_name in family.recorded():
                pubs[pub.topic_name] = pub

    def matched() -> bool:
        return len(rec.recorded_topics()) == len(family.recorded()) and all(
            pub.get_subscription_count() >= (2 if topic in inputs else 1)
            for topic, pub in pubs.items()
        )

    graph.spin_until(matched, 30.0, "the recorder and the estimator to subscribe")


def run_family(graph: Graph, family: Family, dev, est, rec: RecorderNode) -> None:
    """Step the device as fast as the recorder and estimator take its frames, finish the
    estimator and wait until the recorder holds everything it published."""
    device_topics = [family.topic(t) for t in family.inputs + family.extra_recorded]

    def delivered(_dev) -> int:
        """Samples taken by the slowest of the recorder and the estimator (frames of
        ``frame_size`` samples each)."""
        frames = min([rec.received(t) for t in device_topics] + [family.consumed(est)])
        return frames * dev.p["frame_size"]

    drive_fast(graph, [dev], delivered, window=family.window)
    graph.spin_until(lambda: delivered(dev) >= dev.next_index, 60.0, "the last frames")
    finish(est)
    expected = family.expected(est)
    graph.spin_until(
        lambda: all(rec.received(t) >= n for t, n in expected.items()),
        60.0,
        "the recorder to receive the last estimates",
    )


def generate(family: Family, out_dir: Path, domain_id: int | None = None) -> dict:
    """Write ``<out_dir>/<name>.mcap`` (and the stage's YAML); return its path, size [bytes],
    message counts per topic and the wall time [s]."""
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / f"{family.name}.mcap"
    t0 = time.monotonic()
    params = dict(family.estimator_params)
    if family.prepare is not None:
        params.update(family.prepare(out_dir))
    graph = Graph(default_domain_id() if domain_id is None else domain_id)
    rec = None
    try:
        dev, est, rec = build(graph, family, out, params)
        wait_matched(graph, family, rec)
        run_family(graph, family, dev, est, rec)
    finally:
        if rec is not None:
            rec.close()
        graph.close()
    counts = rec.counts()
    return dict(path=out, size=out.stat().st_size, counts=counts, wall_s=time.monotonic() - t0)


def report(result: dict) -> str:
    """One block per bag: path, size, messages per topic."""
    lines = [
        f"{result['path']}: {result['size'] / 1e6:.3f} MB, "
        f"{sum(result['counts'].values())} messages ({result['wall_s']:.1f} s)"
    ]
    lines += [f"  {t}: {n}" for t, n in sorted(result["counts"].items())]
    if result["size"] > MAX_BYTES:
        lines.append(f"  WARNING: larger than {MAX_BYTES / 1e6:g} MB")
    return "\n".join(lines)


def replay_line(family: Family, bag_dir: Path = Path("bags")) -> str:
    """A shell line that replays ``<bag_dir>/<name>.mcap`` into the family's estimator
    executable (started in the device's namespace with the bag's parameters) as fast as it
    takes the frames (``--wait-for-consumer``: flow control on its progress), records what
    it publishes to ``/tmp/<name>_replay.mcap`` and summarises that file. The estimator is
    stopped first (the IMU identifier and the scanner publish their last output then)."""
    bag_dir = Path(os.path.relpath(bag_dir))
    params = family.replay_params(bag_dir)
    bin_ = ".venv/bin"
    out = f"/tmp/{family.name}_replay.mcap"
    estimator = f"{bin_}/{family.executable} --ros-args -r __ns:=/{family.namespace}" + "".join(
        f" -p {k}:={v}" for k, v in params.items()
    )
    outputs = " ".join(family.topic(t) for t in family.outputs)
    inputs = " ".join(family.topic(t) for t in family.inputs)
    return (
        f"{estimator} & {bin_}/mcap_record --overwrite -o {out} {outputs} & "
        f"{bin_}/mcap_play {bag_dir}/{family.name}.mcap --topics {inputs} --wait-timeout 60 "
        f"--wait-for-consumer /{family.namespace}/{family.estimator.NODE_NAME} "
        "--as-fast-as-possible; "
        f"sleep 2; kill %1; sleep 1; kill %2; wait; {bin_}/mcap_info {out}"
    )


def main(argv: list[str] | None = None) -> int:
    """Regenerate the selected bags; exit code 1 if one is over the size limit."""
    parser = argparse.ArgumentParser(prog="make_bags", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output directory")
    parser.add_argument(
        "--only", nargs="+", choices=sorted(FAMILIES), default=None, help="these bags only"
    )
    parser.add_argument(
        "--replay",
        action="store_true",
        help="print a shell line per bag that replays it into its estimator, and exit",
    )
    args = parser.parse_args(argv)
    names = args.only or list(FAMILIES)
    if args.replay:
        for name in names:
            print(replay_line(FAMILIES[name], args.out))
        return 0
    total, too_big = 0, False
    for name in names:
        result = generate(FAMILIES[name], args.out)
        print(report(result), flush=True)
        total += result["size"]
        too_big |= result["size"] > MAX_BYTES
    print(f"total {total / 1e6:.3f} MB in {len(names)} bags")
    return 1 if too_big else 0


if __name__ == "__main__":
    sys.exit(main())

"""Fast mode, one device per graph: each device family's real-time factor first frame to last.

Run:  .venv/bin/python bench/bench_single_device_fast.py [FAMILY ...] [--repeat N] [--scale K]

For each family (imu, accelerometer, resonator, scanner, scanner_amdm, stage) one graph in
this process, built with the scenario skeleton (:mod:`mems_scenarios.base`): ONE emulator
node, its estimator node(s) and the MCAP recorder with zstd (the default), driven in fast
mode (``publish_all(..., realtime=False)``: the runner steps the device as fast as its
slowest consumer takes the frames, lossless). The figure is the one ``run_scenario``
prints (``THROUGHPUT``): simulated seconds per wall second from the moment every consumer
took the first frame (numba kernels loaded, start-up excluded) to the last frame delivered.

The graphs (device parameters as the scenarios set them, shorter durations):

- imu: ``ImuNode`` (100 Hz) + Allan noise identifier.
- accelerometer: ``AccelerometerNode`` (1 MHz, PI rebalance loop at 1 g, 10,000-sample
  frames) + the downstream hybrid EKF node.
- resonator: ``ResonatorNode`` (1 MHz, observer-mode loop, noisy) + one observer set
  (exact model, 5 % f0 error, adaptive), 10,000-sample frames (the node's default).
- scanner: ``ScannerNode`` (500 kHz, drifted sensing comb, the whole drive programme)
  + threshold detector / hybrid EKF node, 5000-sample frames.
- scanner_amdm: ``ScannerAmdmNode`` (1 MHz out, 10 MHz internal, driven into parametric
  resonance) + EKF/UKF estimator node, 10,000-sample frames.
- stage: ``StageNode`` (625 kHz, calibration sweep of 3 trials) + stage EKF (model of
  the nominal device) + gyro calibration node, 20,000-sample frames.

Prints one summary line per family (with the load average) and a table; ~15 s with
``--repeat 2`` on the 2-core VM (start-up included: discovery, imports, the numba cache).
``--scale K`` multiplies every graph's simulated duration (the defaults are short: 19
frames of the accelerometer, 40 of the resonator; K = 5 gives steadier figures).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from process_tools import (
    RESONATOR_NOISE,
    RESONATOR_OBSERVERS,
    RESONATOR_STATE_NOISE,
    check_families,
    family_parser,
    resonator_device_parameters,
)

from mems_scenarios.base import NOT_RECORDED, ScenarioOptions, format_table, graph_for
from mems_scenarios.delivery import THROUGHPUT, publish_all

FAMILIES = ("imu", "accelerometer", "resonator", "scanner", "scanner_amdm", "stage")


def _imu(graph, duration):
    from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
    from mems_sim.nodes.imu_node import ImuNode

    dev = graph.add_device(
        ImuNode,
        dict(seed=1, duration_s=duration, frame_size=100, publish_imu=False),
        realtime=False,
    )
    est = graph.node(ImuNoiseIdentifierNode, {}, namespace="imu")
    return dev, [est], lambda: est.frames_received, r"^/imu/"


def _accelerometer(graph, duration):
    from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
    from mems_sim.devices.accelerometer import G0
    from mems_sim.nodes.accelerometer_node import AccelerometerNode

    ns = "acc_pi_1g"
    case = dict(mode="pi_rebalance", accel_amplitude=1.0 * G0)
    dev = graph.add_device(
        AccelerometerNode,
        dict(case, seed=1, duration_s=duration, frame_size=10000),
        realtime=False,
        namespace=ns,
    )
    est = graph.node(
        AccelerometerEkfNode,
        dict(case, device_namespace=f"/{ns}", output_topic=f"/{ns}/hybrid_ekf/estimate"),
        namespace=ns,
    )
    return dev, [est], lambda: est.frames_done, rf"^/{ns}/"


def _resonator(graph, duration):
    from mems_estimation.nodes.resonator_observer_node import ResonatorObserverNode
    from mems_sim.nodes.resonator_node import ResonatorNode

    ns = "sd_noisy"
    dev = graph.add_device(
        ResonatorNode,
        resonator_device_parameters(duration_s=duration, frame_size=10000),
        realtime=False,
        namespace=ns,
    )
    base = dict(
        output_noise_std=RESONATOR_NOISE,
        state_noise_std=RESONATOR_STATE_NOISE,
        device_namespace=f"/{ns}",
    )
    observers = []
    for name, extra in RESONATOR_OBSERVERS:
        observers.append(
            graph.node(
                ResonatorObserverNode,
                dict(base, output_topic=f"/{ns}/{name}/estimate", **extra),
                namespace=f"{ns}/{name}",
            )
        )
    return dev, observers, lambda: min(o.frames_done for o in observers), rf"^/{ns}/"


def _scanner(graph, duration):
    from mems_estimation.nodes.scanner_threshold_ekf_node import ScannerThresholdEkfNode
    from mems_estimation.studies.scanner_threshold import DRIFTED_SENSOR
    from mems_sim.nodes.scanner_node import ScannerNode

    ns = "scanner"
    dev = graph.add_device(
        ScannerNode,
        dict(
            DRIFTED_SENSOR,
            ringdown_time_s=round(duration - 0.25 - 0.05, 9),
            seed=1,
            duration_s=duration,
            frame_size=5000,
        ),
        realtime=False,
        namespace=ns,
    )
    est = graph.node(
        ScannerThresholdEkfNode,
        dict(device_namespace=f"/{ns}", dog_sigma=45.0),
        namespace=f"{ns}/threshold",
    )
    return dev, [est], lambda: est.frames_done, rf"^/{ns}/"


def _scanner_amdm(graph, duration):
    from mems_estimation.filters import scanner_amdm_model as sam
    from mems_estimation.nodes.scanner_amdm_estimator_node import ScannerAmdmEstimatorNode
    from mems_sim.devices import scanner_amdm as sa
    from mems_sim.nodes.scanner_amdm_node import ScannerAmdmNode

    ns = "scanner_amdm"
    p = sa.resolve_amdm()
    qa = next(s.default for s in sam.ESTIMATOR_SPECS if s.name == "accel_noise_var")
    dev = graph.add_device(
        ScannerAmdmNode,
        dict(
            sa.SWEEP_STUDY,
            torque_noise_std=p["inertia"] * math.sqrt(qa * p["output_decimation"]),
            seed=1,
            duration_s=duration,
            frame_size=10000,
        ),
        realtime=False,
        namespace=ns,
    )
    est = graph.node(
        ScannerAmdmEstimatorNode,
        dict(device_namespace=f"/{ns}", chain_delay_s=dev.device.delay),
        namespace=f"{ns}/estimator",
    )
    return dev, [est], lambda: est.frames_done, rf"^/{ns}/"


def _stage(graph, duration, tmp: Path):

    from mems_estimation.filters.stage_ekf import oracle_model, save_model
    from mems_estimation.nodes.stage_ekf_node import StageEkfNode
    from mems_estimation.nodes.stage_gyro_calibration_node import StageGyroCalibrationNode
    from mems_sim.devices.stage import MicroStage
    from mems_sim.nodes.stage_node import StageNode

    ns, n_trials = "stage_t1", 3
    periods = max(2, 2 * round(duration * 1700.0 / n_trials / 2))  # even, at 1.7 kHz
    s = MicroStage(dict(idealised=True))
    model = oracle_model(s, float(s.noise_std) ** 2)  # white read-out noise per channel
    yaml_path = tmp / "stage_model.yaml"
    save_model(model, str(yaml_path))
    dev = graph.add_device(
        StageNode,
        dict(
            seed=150,
            idealised=True,
            n_trials=n_trials,
            periods_per_trial=periods,
            frame_size=20000,
            frame_id=ns,
            publish_imu=False,
        ),
        realtime=False,
        namespace=ns,
    )
    ekf = graph.node(
        StageEkfNode, dict(device_namespace=f"/{ns}", params_yaml=str(yaml_path)), namespace=ns
    )
    cal = graph.node(
        StageGyroCalibrationNode, dict(device_namespace=f"/{ns}", n_trials=n_trials), namespace=ns
    )
    return dev, [ekf, cal], lambda: ekf.frames_done, rf"^/{ns}/"


#: family -> (builder, simulated seconds)
BUILDERS = {
    "imu": (_imu, 300.0),
    "accelerometer": (_accelerometer, 0.2),
    "resonator": (_resonator, 0.4),
    "scanner": (_scanner, 0.4),
    "scanner_amdm": (_scanner_amdm, 0.06),
    "stage": (_stage, 0.5),
}


def _matched(graph, dev, estimators, rec) -> bool:
    """Every data topic of the device has its recorder and estimator subscriptions, and
    the recorder subscribes to every estimator output it records."""
    for pub in dev.publishers:
        topic = pub.topic_name
        if topic not in dev.streams:
            continue
        want = int(rec.wants(topic)) + sum(
            any(s.topic_name == topic for s in e.subscriptions) for e in estimators
        )
        if pub.get_subscription_count() < want:
            return False
    return all(
        pub.get_subscription_count() >= 1
        for e in estimators
        for pub in e.publishers
        if rec.wants(pub.topic_name)
    )


def run_family(family: str, tmp: Path, domain_id: int | None, scale: float = 1.0) -> dict:
    """One graph of ``family`` (its simulated duration x ``scale``); returns the summary
    line and the figures."""
    build, duration = BUILDERS[family]
    duration *= scale
    THROUGHPUT.reset()
    t0 = time.monotonic()
    graph = graph_for(ScenarioOptions(domain_id=domain_id, progress=False, plots=False))
    rec = None
    try:
        args = (graph, duration, tmp) if family == "stage" else (graph, duration)
        dev, estimators, taken, regex = build(*args)
        rec = graph.recorder(str(tmp / f"{family}.mcap"), regex=regex, exclude=NOT_RECORDED)
        graph.spin_until(
            lambda: _matched(graph, dev, estimators, rec), 30.0, "the consumers to subscribe"
        )
        publish_all(
            graph,
            [dev],
            lambda d: taken() * d.p["frame_size"],  # frames -> samples
            None,
            realtime=False,
            realtime_timeout_s=0.0,
            drain_timeout_s=120.0,
        )
    finally:
        if rec is not None:
            rec.close()
        graph.close()
    run = THROUGHPUT.runs[-1]
    wall = run["t_last"] - run["t_first"]
    sim = run["samples"] / run["rates"][0]
    return dict(
        family=family,
        line=THROUGHPUT.summary(),
        fs=run["rates"][0],
        sim=sim,
        wall=wall,
        rtf=sim / wall,
        total=time.monotonic() - t0,
    )


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The options of the module docstring (``--help`` prints them)."""
    ap = family_parser(
        "bench_single_device_fast.py",
        "Fast mode, one device per graph: each device family's real-time factor "
        "from its first frame to its last (details in the module docstring).",
        FAMILIES,
    )
    ap.add_argument("--repeat", type=int, default=1, help="graphs per family (default 1)")
    ap.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="simulated duration of each graph x SCALE (default 1: 0.06-0.5 s, imu 300 s)",
    )
    args = ap.parse_args(argv)
    check_families(ap, args, FAMILIES)
    if args.repeat < 1:
        ap.error(f"--repeat ({args.repeat}) must be >= 1")
    if not 0.1 <= args.scale <= 100.0:
        ap.error(f"--scale ({args.scale}) must be in [0.1, 100]")
    return args


def main() -> None:
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    args = parse_args(sys.argv[1:])
    repeat, families = args.repeat, args.families or list(FAMILIES)
    env = os.environ.get("ROS_DOMAIN_ID")
    domain_id = int(env) if env else None
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for family in families:
            results = []
            for _ in range(repeat):
                r = run_family(family, Path(d), domain_id, args.scale)
                print(
                    f"{family:14s} {r['line']} (graph with start-up {r['total']:.1f} s; "
                    f"load {os.getloadavg()[0]:.2f})",
                    flush=True,
                )
                results.append(r)
            rtfs = [r["rtf"] for r in results]
            rows.append(
                [
                    family,
                    f"{results[0]['fs'] / 1e3:g} kHz",
                    f"{results[0]['sim']:.4g} s",
                    f"{min(r['wall'] for r in results):.3g} s",
                    " / ".join(f"{x:.3g}" for x in rtfs),
                    "yes" if min(rtfs) >= 1.0 else "no",
                ]
            )
    load = os.getloadavg()
    print()
    print(
        format_table(
            ["family", "rate", "simulated", "wall (best)", "x real time", ">= 1x"],
            rows,
        )
    )
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (1, 5, 15 min)")


if __name__ == "__main__":
    main()

"""Each device family's graph as separate processes, paced by the device's wall-clock timer.

Run:  .venv/bin/python bench/bench_device_processes.py [FAMILY ...] [--pace 1.5]
                                                         [--seconds S] [--frame-size FAMILY=N]
                                                         [--keep-bags DIR]
                                                         [--storage-preset-profile PRESET]
                                                         [--compose]

For each family (imu, accelerometer, resonator, scanner, scanner_amdm, stage; default all)
the graph the way ROS users run it, one process per node, localhost discovery in
ROS_DOMAIN_ID (77 if unset): the emulator node (its executable, ``realtime_factor`` =
``--pace`` (default 1.5), stamps from the wall clock, ``start_when_matched``: its timer
started once every subscriber of the graph is matched, ``exit_when_acknowledged``: the
process ending at the end of its data; its numba kernels loaded before the first frame;
its timing read back from the recording), its
estimator node(s) and the calibration node where the family has one (``python -m
mems_estimation.nodes.*_node``), and ``python -m mems_sim.bag.record_cli -o OUT
--compression zstd TOPICS`` recording every topic the graph publishes (the end-of-stream
record, the estimates, the calibration result) and /diagnostics (zstd level 1 with chunk
CRCs, or ``--storage-preset-profile PRESET``, e.g. ``zstd_fast``). The graphs (estimators as
the scenarios and bench_single_device_fast.py attach them), frames of the node
executable's default size unless ``--frame-size FAMILY=N``; with ``--compose`` a family's
two or more estimator and calibration nodes run in one ``component_container`` process
(ROS 2 composition: the resonator's three observers, the stage's EKF and calibration, the
IMU's identifier and calibration):

- imu: ``imu_node`` (ADIS16350 preset, 100 Hz, 10-sample frames, sensor_msgs/Imu on
  ``data``) on a short multi-position / rate-table profile (12 segments of >= 5.5 s: the
  calibration needs 5 s per segment after settling), the Allan noise identifier (a model
  every 5 s of data; on this moving profile a load, not a noise figure) and
  ``imu_calibration_node`` (the profile's calibration at its end, ``calibration``);
- accelerometer: ``accelerometer_node`` (1 MHz, PI rebalance at 1 g) + hybrid EKF;
- resonator: ``resonator_node`` (1 MHz sigma-delta loop, observer mode, noisy) + three
  ``resonator_observer_node`` (exact, 5 % f0 error, adaptive);
- scanner: ``scanner_node`` (500 kHz, drifted sensing comb, the drive's hold stretched to
  fill the run) + threshold detector / hybrid EKF node;
- scanner_amdm: ``scanner_amdm_node`` (published at its decimated 1 MHz, 10 MHz inside)
  + EKF/UKF estimator;
- stage: ``stage_node`` (625 kHz, idealised, calibration sweep of 7 trials stretched to
  fill the run) + stage EKF (the nominal model) + ``stage_gyro_calibration_node``
  (``gyro_scale_factor``).

The device publishes ``--seconds`` (default 7) wall seconds of data at the pace (imu: at
least 66 s of data). Measured per family: the device's throughput as x real time from
its first to its last frame publication and over the steady state (from 2 s after the
first frame); kept up = the steady-state figure >= 0.99 x the pace and nothing lost (at
the start the estimators load their numba kernels, which takes CPU from the device on 2
cores; it then catches up); frames published
(the device's count per topic) vs recorded, frame-index and sequence gaps and missing tails
(against the device's end-of-stream record) per topic; estimator outputs: samples recorded
against the device's; topics of the graph not recorded; worst frame delay: each recorded
frame's publication (the MCAP's publish time, the DDS source time of the publisher: the
device's, or the estimator's for its outputs) after its first sample was due on the wall
clock (its stamp, the MCAP's log time, mapped through the pacing), beyond the median of
its topic, over the whole run and over the steady state, and the device's worst
publication lateness behind the end of the frame; the consumers' drain (how long they kept
working after the device's last frame); CPU cores per process while the device published
and the other jobs' cores on the machine (load).
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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from process_tools import (
    RESONATOR_NOISE,
    RESONATOR_OBSERVERS,
    RESONATOR_STATE_NOISE,
    check_families,
    cpu_ticks,
    device_parameters,
    device_timing,
    family_parser,
    graph_topics,
    machine_ticks,
    process_env,
    reap,
    recorder_command,
    resonator_device_parameters,
    wait_quiet,
)

from mems_sim.table import format_table

FAMILIES = ("imu", "accelerometer", "resonator", "scanner", "scanner_amdm", "stage")
#: Wall seconds after the device's first frame outside the steady state (the estimator
#: nodes load their numba kernels at their first frame: their outputs lag up to ~1.5 s
#: behind at the start, then catch up).
WARMUP_S = 2.0
#: A frame published this much beyond its topic's median delay counts as delayed.
DELAYED_S = 0.2


@dataclass
class Proc:
    """One node process: label, ``python -m`` module (the node's executable), namespace,
    parameters, topics it subscribes and publishes."""

    name: str
    module: str
    namespace: str
    params: dict
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()

    @property
    def fqn(self) -> str:
        """Fully qualified node name of a consumer (its executable's default node name)."""
        return f"{self.namespace.rstrip('/')}/{self.module.rsplit('.', 1)[1].removesuffix('_node')}"


@dataclass
class Graph:
    """One family's graph: the device, its estimators and calibration, a note on the run."""

    family: str
    device: Proc
    consumers: list[Proc]
    note: str = ""

    @property
    def topics(self) -> list[str]:
        """Every topic recorded: the device's and the consumers' outputs (their
        ``~/progress`` included), /diagnostics."""
        out = list(self.device.outputs)
        for c in self.consumers:
            out += [t for t in (*c.outputs, f"{c.fqn}/progress") if t not in out]
        return out + ["/diagnostics"]

    def wait_subs(self) -> dict[str, int]:
        """Subscriptions each topic must have before the device starts: the recorder's and
        the consumers' that read it."""
        want = {}
        for t in self.topics:
            if t == "/diagnostics":
                continue
            want[t] = 1 + sum(t in c.inputs for c in self.consumers)
        return want


def _ros_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


# ------------------------------------------------------------------ the graphs


def _imu(pace: float, seconds: float, frame: int | None, tmp: Path) -> Graph:
    import yaml

    ns = "/imu"
    # the calibration uses segments with >= 5 s of data after settling
    seg = max(5.5, pace * seconds / 12.0)
    six = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    segments = [dict(duration_s=seg, up_body=u) for u in six]
    for axis in six[::2]:
        segments += [dict(duration_s=seg, up_body=axis, rate_deg_s=r) for r in (100.0, -100.0)]
    profile = tmp / "imu_profile.yaml"
    profile.write_text(
        yaml.safe_dump(dict(name="bench_multi_position", settle_s=0.2, segments=segments))
    )
    dev = Proc(
        "imu",
        "mems_sim.nodes.imu_node",
        ns,
        dict(
            seed=1,
            preset="adis16350",
            motion="profile",
            motion_profile=str(profile),
            **({"frame_size": frame} if frame else {}),
        ),
        outputs=tuple(
            f"{ns}/{t}"
            for t in (
                "adc",
                "truth",
                "temperature_sensor",
                "truth_calibration",
                "data",
                "end_of_stream",
            )
        ),
    )
    ident = Proc(
        "noise_identifier",
        "mems_estimation.nodes.imu_noise_identifier_node",
        ns,
        dict(min_duration_s=5.0, publish_period_s=5.0),
        inputs=(f"{ns}/adc",),
        outputs=(f"{ns}/noise_model",),
    )
    cal = Proc(
        "calibration",
        "mems_estimation.nodes.imu_calibration_node",
        ns,
        dict(
            profile=str(profile),
            noise_model="adis16350",
            temperature_source="sensor",
            output_yaml=str(tmp / "imu_calibration.yaml"),
        ),
        inputs=(f"{ns}/adc", f"{ns}/temperature_sensor"),
        outputs=(f"{ns}/calibration",),
    )
    return Graph("imu", dev, [ident, cal], note=f"12 segments of {seg:.2f} s")


def _accelerometer(pace: float, seconds: float, frame: int | None, tmp: Path) -> Graph:
    from mems_sim.devices.accelerometer import G0

    ns = "/accelerometer"
    case = dict(mode="pi_rebalance", accel_amplitude=1.0 * G0)
    dev = Proc(
        "accelerometer",
        "mems_sim.nodes.accelerometer_node",
        ns,
        dict(case, seed=1, duration_s=pace * seconds, **({"frame_size": frame} if frame else {})),
        outputs=tuple(f"{ns}/{t}" for t in ("adc", "drive", "truth", "end_of_stream")),
    )
    ekf = Proc(
        "ekf",
        "mems_estimation.nodes.accelerometer_ekf_node",
        ns,
        dict(case, device_namespace=ns),
        inputs=(f"{ns}/adc", f"{ns}/drive"),
        outputs=(f"{ns}/estimate",),
    )
    return Graph("accelerometer", dev, [ekf])


def _resonator(pace: float, seconds: float, frame: int | None, tmp: Path) -> Graph:
    ns = "/resonator"
    dev = Proc(
        "resonator",
        "mems_sim.nodes.resonator_node",
        ns,
        resonator_device_parameters(
            duration_s=pace * seconds, **({"frame_size": frame} if frame else {})
        ),
        outputs=tuple(
            f"{ns}/{t}" for t in ("adc", "drive", "truth", "loop_estimate", "end_of_stream")
        ),
    )
    base = dict(
        output_noise_std=RESONATOR_NOISE, state_noise_std=RESONATOR_STATE_NOISE, device_namespace=ns
    )
    observers = [
        Proc(
            name,
            "mems_estimation.nodes.resonator_observer_node",
            f"{ns}/{name}",
            dict(base, output_topic=f"{ns}/{name}/estimate", **extra),
            inputs=(f"{ns}/adc", f"{ns}/drive"),
            outputs=(f"{ns}/{name}/estimate",),
        )
        for name, extra in RESONATOR_OBSERVERS
    ]
    return Graph("resonator", dev, observers)


def _scanner(pace: float, seconds: float, frame: int | None, tmp: Path) -> Graph:
    from mems_estimation.studies.scanner_threshold import DRIFTED_SENSOR

    ns = "/scanner"
    sim = pace * seconds
    sweep, ring = 0.25, 0.1
    dev = Proc(
        "scanner",
        "mems_sim.nodes.scanner_node",
        ns,
        dict(
            DRIFTED_SENSOR,
            sweep_time_s=sweep,
            hold_time_s=round(sim - sweep - ring, 9),
            ringdown_time_s=ring,
            seed=1,
            duration_s=sim,
            **({"frame_size": frame} if frame else {}),
        ),
        outputs=tuple(f"{ns}/{t}" for t in ("adc", "drive", "truth", "psd", "end_of_stream")),
    )
    est = Proc(
        "threshold_ekf",
        "mems_estimation.nodes.scanner_threshold_ekf_node",
        f"{ns}/threshold",
        dict(device_namespace=ns, dog_sigma=45.0),
        inputs=(f"{ns}/adc", f"{ns}/drive"),
        outputs=tuple(f"{ns}/{t}" for t in ("estimate", "estimate_plain", "threshold_detections")),
    )
    return Graph("scanner", dev, [est], note=f"sweep {sweep} s, hold {sim - sweep - ring:.2f} s")


def _scanner_amdm(pace: float, seconds: float, frame: int | None, tmp: Path) -> Graph:
    from mems_estimation.filters import scanner_amdm_model as sam
    from mems_sim.devices import scanner_amdm as sa

    ns = "/scanner_amdm"
    overrides = dict(sa.SWEEP_STUDY)
    p = sa.resolve_amdm(overrides)
    qa = next(s.default for s in sam.ESTIMATOR_SPECS if s.name == "accel_noise_var")
    overrides["torque_noise_std"] = float(p["inertia"] * math.sqrt(qa * p["output_decimation"]))
    delay = sa.chain_delay(sa.resolve_amdm(overrides))
    dev = Proc(
        "scanner_amdm",
        "mems_sim.nodes.scanner_amdm_node",
        ns,
        dict(
            overrides, seed=1, duration_s=pace * seconds, **({"frame_size": frame} if frame else {})
        ),
        outputs=tuple(f"{ns}/{t}" for t in ("adc", "drive", "truth", "end_of_stream")),
    )
    est = Proc(
        "estimator",
        "mems_estimation.nodes.scanner_amdm_estimator_node",
        f"{ns}/estimator",
        dict(device_namespace=ns, chain_delay_s=float(delay)),
        inputs=(f"{ns}/adc", f"{ns}/drive"),
        outputs=tuple(
            f"{ns}/{k}/{t}" for k in ("ekf", "ukf") for t in ("estimate", "phase_amplitude")
        ),
    )
    return Graph("scanner_amdm", dev, [est])


def _stage(pace: float, seconds: float, frame: int | None, tmp: Path) -> Graph:
    from mems_estimation.filters.stage_ekf import oracle_model, save_model
    from mems_sim.devices.stage import MicroStage

    ns, n_trials, f_drive = "/stage", 7, 1700.0
    periods = max(2, 2 * round(pace * seconds * f_drive / n_trials / 2))  # even
    s = MicroStage(dict(idealised=True))
    model = oracle_model(s, float(s.noise_std) ** 2)  # white read-out noise per channel
    yaml_path = tmp / "stage_model.yaml"
    save_model(model, str(yaml_path))
    dev = Proc(
        "stage",
        "mems_sim.nodes.stage_node",
        ns,
        dict(
            seed=150,
            idealised=True,
            n_trials=n_trials,
            periods_per_trial=periods,
            drive_freq_hz=f_drive,
            **({"frame_size": frame} if frame else {}),
        ),
        outputs=tuple(
            f"{ns}/{t}"
            for t in (
                "adc",
                "drive",
                "truth",
                "ldv",
                "temperature",
                "gyro/adc",
                "gyro/imu",
                "end_of_stream",
            )
        ),
    )
    ekf = Proc(
        "ekf",
        "mems_estimation.nodes.stage_ekf_node",
        ns,
        dict(device_namespace=ns, params_yaml=str(yaml_path)),
        inputs=(f"{ns}/adc", f"{ns}/drive"),
        outputs=(f"{ns}/estimate",),
    )
    cal = Proc(
        "calibration",
        "mems_estimation.nodes.stage_gyro_calibration_node",
        ns,
        dict(device_namespace=ns, n_trials=n_trials),
        inputs=(f"{ns}/estimate", f"{ns}/drive", f"{ns}/gyro/adc"),
        outputs=(f"{ns}/gyro_scale_factor",),
    )
    return Graph("stage", dev, [ekf, cal], note=f"{n_trials} trials of {periods} periods")


BUILDERS = {
    "imu": _imu,
    "accelerometer": _accelerometer,
    "resonator": _resonator,
    "scanner": _scanner,
    "scanner_amdm": _scanner_amdm,
    "stage": _stage,
}


# ------------------------------------------------------------------ running a graph


#: Process name of a family's estimator nodes composed in one container (``--compose``).
COMPOSED = "estimators"


def consumer_processes(g: Graph, compose: bool) -> dict[str, list[Proc]]:
    """Process name -> the consumer nodes it runs: one process per consumer, or with
    ``compose`` one ``component_container`` for a family's two or more consumers."""
    if compose and len(g.consumers) > 1:
        return {COMPOSED: list(g.consumers)}
    return {c.name: [c] for c in g.consumers}


def _ros_section(namespace: str, params: dict) -> list[str]:
    """A node's own ROS arguments: namespace and parameters."""
    args = ["-r", f"__ns:={namespace}"]
    for k, v in params.items():
        args += ["-p", f"{k}:={_ros_value(v)}"]
    return args


def _commands(
    g: Graph,
    out: Path,
    pace: float,
    preset: str | None = None,
    compose: bool = False,
) -> dict[str, list[str]]:
    py = sys.executable
    cmds = {
        "recorder": recorder_command(
            out,
            ["--compression", "zstd", *(["--storage-preset-profile", preset] if preset else [])],
            g.topics,
        )
    }
    for name, nodes in consumer_processes(g, compose).items():
        if name == COMPOSED:
            cmds[name] = [
                py,
                "-m",
                "mems_scenarios.component_container",
                "--ros-args",
                "--log-level",
                "warn",
            ]
            for c in nodes:
                plugin = c.module.rsplit(".", 1)[1]  # the node's executable
                cmds[name] += ["--node", plugin, "--ros-args", *_ros_section(c.namespace, c.params)]
        else:
            cmds[name] = [py, "-m", nodes[0].module, "--ros-args", "--log-level", "warn"]
            cmds[name] += _ros_section(nodes[0].namespace, nodes[0].params)
    d = g.device
    cmds[d.name] = [py, "-m", d.module, "--ros-args", "--log-level", "warn"]
    # sensor time on the wall clock: stamps and publication times are on one timeline
    params = dict(
        d.params,
        stamp_origin="wall",
        realtime_factor=float(pace),
        **device_parameters(g.wait_subs()),
    )
    cmds[d.name] += _ros_section(d.namespace, params)
    return cmds


class _EarlyExit(Exception):
    """A process of the graph ended before the device's data did."""


def run_graph(
    g: Graph,
    pace: float,
    domain_id: int,
    tmp: Path,
    keep: str | None = None,
    preset: str | None = None,
    compose: bool = False,
) -> dict:
    """Run ``g``'s processes; the figures of the module docstring."""
    from mems_sim.bag.info import bag_info

    env = process_env(domain_id)
    out = tmp / f"{g.family}.mcap"
    sim = g.device.params.get("duration_s")
    max_wall = 60.0 + 20.0 * (sim or 30.0) / pace
    cmds = _commands(g, out, pace, preset, compose)
    consumers = list(consumer_processes(g, compose))
    dev = g.device.name
    procs, logs, cpu = {}, {}, {}
    early: list[str] = []
    stopped = False  # the device was stopped after max_wall (its data not finished)
    graph: dict = {}
    samples = []  # (monotonic, CPU ticks per process and of the machine) while it runs
    t_start = time.monotonic()
    try:
        for name, cmd in cmds.items():
            logs[name] = open(tmp / f"{g.family}_{name}.log", "w+")
            procs[name] = subprocess.Popen(
                cmd, env=env, stdout=logs[name], stderr=subprocess.STDOUT, cwd=str(tmp)
            )
        deadline = time.monotonic() + max_wall + 120.0
        while cpu.get(dev) is None:
            samples.append(
                (
                    time.monotonic(),
                    dict({n: cpu_ticks(p.pid) for n, p in procs.items()}, **machine_ticks()),
                )
            )
            cpu[dev] = reap(procs[dev], 0.05)
            if not stopped and time.monotonic() > t_start + max_wall:
                procs[dev].send_signal(signal.SIGINT)
                stopped = True
            if time.monotonic() > deadline:
                raise RuntimeError(f"the {dev} process did not finish in time")
            early = [n for n, p in procs.items() if n != dev and p.poll() is not None]
            if early:
                break
        if early:
            raise _EarlyExit(early[0])
        rest = [procs[n] for n in consumers] + [procs["recorder"]]
        drain_s = wait_quiet(rest, 120.0)
        graph = graph_topics(domain_id)  # also one more /diagnostics with final counters
        stop_ns = time.time_ns()  # what the consumers publish from now on: at shutdown
        for n in consumers:
            procs[n].send_signal(signal.SIGINT)
        for n in consumers:
            cpu[n] = reap(procs[n], 30.0)
        time.sleep(0.5)
        procs["recorder"].send_signal(signal.SIGINT)
        cpu["recorder"] = reap(procs["recorder"], 60.0)
    except _EarlyExit:
        pass
    finally:
        for p in procs.values():
            if p.returncode is None and p.poll() is None:
                p.kill()
                p.wait()
        texts = {}
        for name, f in logs.items():
            f.flush()
            f.seek(0)
            texts[name] = f.read()
            f.close()
    if early:
        name = early[0]
        raise RuntimeError(
            f"{name} exited early ({procs[name].returncode}):\n" + texts[name][-3000:]
        )
    total_s = time.monotonic() - t_start
    if procs[dev].returncode:
        raise RuntimeError(f"{dev} process failed:\n" + texts[dev][-3000:])
    if procs["recorder"].returncode or not out.exists():
        raise RuntimeError("recorder failed:\n" + texts["recorder"][-3000:])
    st = device_timing(out, g.device.namespace, pace)
    # the device's topics are gone from the graph when it has exited: its record has them
    graph.update({t: [1, 0] for t in st["topics"] if t not in graph})
    st.update(graph_topics=graph, finished=not stopped)
    failed = {n: procs[n].returncode for n in procs if procs[n].returncode not in (0, None)}
    info = bag_info(str(out))
    delays, diag = _read_bag(out, info, st, stop_ns)
    if keep:
        import shutil

        os.makedirs(keep, exist_ok=True)
        shutil.copyfile(out, Path(keep) / f"{g.family}_{pace:g}x.mcap")
    # CPU cores of each process while the device published (first frame's start to last)
    hz = os.sysconf("SC_CLK_TCK")
    w0 = st["t_first"] - st["frame_size"] / st["fs"] / pace
    w1 = st["t_last"]
    inside = [s_ for s_ in samples if w0 <= s_[0] <= w1]
    run_cpu = {}
    if len(inside) >= 2:
        span = inside[-1][0] - inside[0][0]
        run_cpu = {
            n: (inside[-1][1][n] - inside[0][1][n]) / hz / span
            for n in inside[0][1]
            if n != dev or inside[-1][1][n]
        }
        machine = run_cpu.pop("machine")
        run_cpu["others"] = max(machine - sum(v for k, v in run_cpu.items() if k in procs), 0.0)
    return dict(
        family=g.family,
        namespace=g.device.namespace,
        note=g.note,
        pace=pace,
        preset=preset,
        compose=compose and COMPOSED in consumers,
        st=st,
        info=info,
        topics=g.topics,
        consumers=[c.name for c in g.consumers],
        consumer_nodes={c.name: c for c in g.consumers},
        device_outputs=g.device.outputs,
        delays=delays,
        diag=diag,
        drain_s=drain_s,
        cpu_s=cpu,
        run_cpu=run_cpu,
        failed=failed,
        total_s=total_s,
        logs={n: t[-1500:] for n, t in texts.items() if "Traceback" in t or n in failed},
    )


def _read_bag(out: Path, info: dict, st: dict, stop_ns: int) -> tuple[dict, dict]:
    """Per stamped topic (frames, sensor_msgs/Imu): delays of the publications beyond the
    topic's median, over the run and over the steady state, and the messages published
    at the consumers' shutdown (after ``stop_ns``: e.g. the threshold EKF's last ``lag``
    samples, held until then; left out of the delays); the last /diagnostics status of
    each node (hardware_id: its values)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    stamped = [
        t
        for t, e in info["topics"].items()
        if e.get("total_samples") or e["type"] == "sensor_msgs/msg/Imu"
    ]
    pace = st["pace"]
    times: dict[str, list] = {}
    diag: dict[str, dict] = {}
    with open(out, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(topics=stamped + ["/diagnostics"]):
            if ch.topic == "/diagnostics":
                msg = deserialize_message(m.data, DiagnosticArray)
                for s in msg.status:
                    diag[s.hardware_id or s.name] = {kv.key: kv.value for kv in s.values}
                continue
            times.setdefault(ch.topic, []).append((m.log_time, m.publish_time))
    steady_ns = st["t_first_ns"] + int(WARMUP_S * 1e9)
    delays = {}
    for t, tp in times.items():
        lt, pt = np.asarray(tp, dtype=np.int64).T
        live = pt < stop_ns
        at_stop = int(np.sum(~live))
        lt, pt = lt[live], pt[live]
        if not lt.size:
            continue
        due = st["wall_start_ns"] + (lt - st["t0_ns"]) / pace
        lat = (pt - due) / 1e9
        d = lat - np.median(lat)
        steady = due >= steady_ns
        delays[t] = dict(
            worst=float(d.max()),
            delayed=int(np.sum(d > DELAYED_S)),
            worst_steady=float(d[steady].max()) if steady.any() else math.nan,
            median=float(np.median(lat)),
            at_stop=at_stop,
        )
    return delays, diag


# ------------------------------------------------------------------ report


def summarise(r: dict) -> dict:
    """Losses, completeness and the verdict of one run."""
    st, info = r["st"], r["info"]
    tp = info["topics"]
    rows = []
    lost_dev = lost_out = 0
    for t in r["topics"]:
        e = tp.get(t, {})
        pub = st["topics"].get(t, {}).get("messages")
        gaps = e.get("gaps", 0) or 0
        seq = e.get("sequence_gaps") or 0
        tail = e.get("tail") or {}
        missing = (e.get("missing_samples") or 0) + (tail.get("samples") or 0)
        if pub is not None:  # the device's topics: every message it published
            lost_dev += max(pub - e.get("count", 0), 0)
        else:  # the consumers' outputs: samples missing in frame gaps, messages in others
            lost_out += missing + (e.get("missing_messages") or 0)
        rows.append(
            dict(
                topic=t,
                published=pub,
                recorded=e.get("count", 0),
                samples=e.get("total_samples"),
                gaps=gaps + seq,
                missing=missing,
                tail=tail.get("messages") or 0,
            )
        )
    graph = {t for t, (npub, _) in st["graph_topics"].items() if npub > 0}
    not_recorded = sorted(graph - set(r["topics"]) - {"/clock"})
    # throughput over the steady state (the whole run when it is shorter than the warm-up)
    rtf = st["rtf_steady"] if st["rtf_steady"] is not None else st["rtf"]
    kept = rtf >= 0.99 * r["pace"] and lost_dev + lost_out == 0 and st["finished"]
    dl = r["delays"]
    worst = max(dl.items(), key=lambda kv: kv[1]["worst"], default=(None, None))
    worst_s = max(
        dl.items(),
        key=lambda kv: np.nan_to_num(kv[1]["worst_steady"], nan=-1),
        default=(None, None),
    )
    return dict(
        rows=rows,
        lost_dev=lost_dev,
        lost_out=lost_out,
        not_recorded=not_recorded,
        kept=kept,
        worst=worst,
        worst_steady=worst_s,
    )


def print_run(r: dict, s: dict) -> None:
    st = r["st"]
    print(
        f"{r['family']}: {st['node']} at {st['fs'] / 1e3:g} kHz, frames of {st['frame_size']}, "
        f"paced at {r['pace']:g} x ({r['note'] + ', ' if r['note'] else ''}"
        f"{st['samples'] / st['fs']:.2f} s of data, executor {st['executor']}"
        f"{', recorder preset ' + r['preset'] if r['preset'] else ''}"
        f"{', estimators in one component_container' if r['compose'] else ''}): "
        f"{st['rtf']:.3f} x real time first to last frame "
        f"({st['sim_span_s']:.2f} sim s in {st['wall_span_s']:.2f} wall s), "
        + (f"{st['rtf_steady']:.3f} x steady" if st["rtf_steady"] else "no steady state")
        + f" -> {'keeps up' if s['kept'] else 'DOES NOT KEEP UP'}"
        + ("" if st["finished"] else " (stopped before the end of its data)")
    )
    print(
        format_table(
            [
                "topic",
                "published",
                "recorded",
                "samples",
                "gaps",
                "missing samples",
                "tail",
                "worst delay [ms] (steady)",
                "> 0.2 s",
                "at stop",
            ],
            [
                [
                    x["topic"],
                    "-" if x["published"] is None else str(x["published"]),
                    str(x["recorded"]),
                    "-" if x["samples"] is None else str(x["samples"]),
                    str(x["gaps"]),
                    str(x["missing"]),
                    str(x["tail"]),
                    (
                        f"{r['delays'][x['topic']]['worst'] * 1e3:.0f} "
                        f"({r['delays'][x['topic']]['worst_steady'] * 1e3:.0f})"
                        if x["topic"] in r["delays"]
                        else "-"
                    ),
                    str(r["delays"][x["topic"]]["delayed"]) if x["topic"] in r["delays"] else "-",
                    str(r["delays"][x["topic"]]["at_stop"]) if x["topic"] in r["delays"] else "-",
                ]
                for x in s["rows"]
            ],
        )
    )
    if s["not_recorded"]:
        print(f"    topics of the graph NOT recorded: {', '.join(s['not_recorded'])}")
    for name, c in r["consumer_nodes"].items():
        fq = c.fqn
        d = next((v for k, v in r["diag"].items() if k == fq), None)
        if d is None:
            print(f"    {name}: no /diagnostics recorded ({fq})")
            continue
        keys = [
            k
            for k in d
            if k == "frames"
            or any(
                w in k
                for w in (
                    "reject",
                    "gap",
                    "missing",
                    "drop",
                    "diverg",
                    "overflow",
                    "fail",
                    "stale",
                    "reset",
                )
            )
        ]
        print(f"    {name} ({fq}) last /diagnostics: " + ", ".join(f"{k} {d[k]}" for k in keys))
    run = ", ".join(f"{k} {v:.2f}" for k, v in r["run_cpu"].items())
    ours = {k: v for k, v in r["run_cpu"].items() if k not in ("others", "irq", "steal")}
    need = sum(ours.values())
    rtf = min(x for x in (st["rtf"], st["rtf_steady"]) if x)
    per1x = ", ".join(f"{k} {v / rtf:.2f}" for k, v in ours.items())
    print(
        f"    device worst publication {st['max_late_s'] * 1e3:.0f} ms behind its due time; "
        f"consumers busy {r['drain_s']:.1f} s after the last frame; CPU [cores] while the "
        f"device published: {run} (of {os.cpu_count()}; the graph {need:.2f}); per 1x real "
        f"time (cores / the device's x real time): {per1x}, the graph {need / rtf:.2f}; "
        f"bag {r['info']['file_size'] / 1e6:.0f} MB; run {r['total_s']:.0f} s"
    )
    if r["failed"]:
        print(f"    processes with a non-zero exit status: {r['failed']}")
    for n, t in r["logs"].items():
        print(f"    --- {n} log (tail):\n" + "\n".join("    " + x for x in t.splitlines()[-12:]))


def table_row(r: dict, s: dict) -> list[str]:
    st = r["st"]
    rc = r["run_cpu"]
    cpu = " ".join(f"{k[:6]} {v:.2f}" for k, v in rc.items() if k not in ("others", "irq", "steal"))
    w, ws = s["worst"], s["worst_steady"]
    procs = [k for k in rc if k not in ("others", "irq", "steal")]
    busiest = max(procs, key=lambda k: rc[k]) if procs else "-"
    return [
        r["family"],
        f"{st['fs'] / 1e3:g} kHz",
        str(st["frame_size"]),
        f"{r['pace']:g}",
        f"{st['samples'] / st['fs']:.2f} / {st['wall_span_s']:.2f}",
        f"{st['rtf']:.3f} / " + (f"{st['rtf_steady']:.3f}" if st["rtf_steady"] else "-"),
        "yes" if s["kept"] else "NO",
        str(st["frames"]),
        f"{s['lost_dev']} / {s['lost_out']}"
        + (f" +{len(s['not_recorded'])} topics unrecorded" if s["not_recorded"] else ""),
        (
            f"{w[1]['worst'] * 1e3:.0f} / {ws[1]['worst_steady'] * 1e3:.0f} "
            f"({ws[0].removeprefix(r['namespace'] + '/')})"
            if w[0]
            else "-"
        ),
        f"{st['max_late_s'] * 1e3:.0f}",
        f"{r['drain_s']:.1f}",
        cpu + f" (max {busiest})",
        f"{rc.get('others', math.nan):.2f}",
    ]


HEADER = [
    "family",
    "rate",
    "frame",
    "pace",
    "data s / wall s",
    "x real time (all / steady)",
    "kept up",
    "frames",
    "lost (dev frames / out samples)",
    "worst delay ms (all / steady, topic)",
    "dev late ms",
    "drain s",
    "CPU cores per process",
    "others",
]


def _frame_size(text: str) -> tuple[str, int]:
    fam, sep, n = text.partition("=")
    if not sep or fam not in FAMILIES or not n.isdigit() or int(n) < 1:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected FAMILY=N with FAMILY one of {', '.join(FAMILIES)} and N >= 1"
        )
    return fam, int(n)


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The options of the module docstring (``--help`` prints them)."""
    ap = family_parser(
        "bench_device_processes.py",
        "Each device family's graph as separate processes, paced by the "
        "device's wall-clock timer (details in the module docstring).",
        FAMILIES,
    )
    ap.add_argument("--pace", type=float, default=1.5, help="x real time (default 1.5)")
    ap.add_argument(
        "--seconds",
        type=float,
        default=7.0,
        help="wall seconds of data at the pace (default 7; imu at least 66 s of data)",
    )
    ap.add_argument(
        "--frame-size",
        type=_frame_size,
        action="append",
        default=[],
        metavar="FAMILY=N",
        help="frame size of a family (repeatable)",
    )
    ap.add_argument("--keep-bags", metavar="DIR", help="keep the recordings in DIR")
    ap.add_argument(
        "--compose",
        action="store_true",
        help="run a family's estimator and calibration nodes (two or more) in one "
        "component_container process instead of one process each",
    )
    ap.add_argument(
        "--storage-preset-profile",
        metavar="PRESET",
        help="the recorder's preset (mcap_record's option; default none: zstd level 1 "
        "with chunk CRCs)",
    )
    args = ap.parse_args(argv)
    from mems_sim.bag.compression import STORAGE_PRESETS

    if args.storage_preset_profile not in (None, *STORAGE_PRESETS):
        ap.error(
            f"--storage-preset-profile {args.storage_preset_profile!r}: known "
            f"{', '.join(STORAGE_PRESETS)}"
        )
    check_families(ap, args, FAMILIES)
    if not args.pace > 0 or not args.seconds > 0:
        ap.error(f"--pace ({args.pace}) and --seconds ({args.seconds}) must be > 0")
    args.frame_size = dict(args.frame_size)
    return args


def main() -> None:
    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    args = parse_args(sys.argv[1:])
    pace, seconds, keep, frames, families = (
        args.pace,
        args.seconds,
        args.keep_bags,
        args.frame_size,
        args.families or list(FAMILIES),
    )
    domain = int(os.environ.get("ROS_DOMAIN_ID") or 77)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for family in families:
            tmp = Path(d)
            g = BUILDERS[family](pace, seconds, frames.get(family), tmp)
            try:
                r = run_graph(g, pace, domain, tmp, keep, args.storage_preset_profile, args.compose)
            except RuntimeError as exc:
                print(f"{family}: FAILED: {exc}", flush=True)
                rows.append([family] + ["-"] * (len(HEADER) - 2) + ["failed"])
                continue
            s = summarise(r)
            print_run(r, s)
            print(f"    load average {os.getloadavg()[0]:.2f}", flush=True)
            print(flush=True)
            rows.append(table_row(r, s))
            for f in tmp.glob("*.mcap"):
                f.unlink()
    load = os.getloadavg()
    print(format_table(HEADER, rows))
    print(
        f"x real time: the device's simulated s per wall s, first to last frame / from "
        f"{WARMUP_S:g} s after the first frame; kept up: the latter >= 0.99 x the pace, nothing "
        "lost (frames of the device not recorded / samples or messages missing in the "
        "estimators' outputs); worst delay: publication after the frame's first sample was due, beyond its "
        "topic's median; others: other jobs' cores on the machine while the device "
        f"published; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (1, 5, 15 min)"
    )


if __name__ == "__main__":
    main()

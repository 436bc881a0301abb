"""Helpers of the benches that run a graph as processes (bench_device_processes.py,
bench_stage_ekf.py --graph-processes): the processes' environment and CPU, and the
emulator's timing read back from the recording; the recorder benches' KEEP_ALL publisher.

The emulator is its executable with ``start_when_matched`` and ``exit_when_acknowledged``
(:func:`device_parameters`); what the benches measure of it comes from the MCAP
(:func:`device_timing`): its frames' stamps (log time) and DDS source times of publication
(publish time) and its end-of-stream record. Importing this module loads no ROS code.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

#: Topics of every node, not data of a graph.
IGNORED_TOPICS = ("/rosout", "/parameter_events")
#: Wall seconds after the first frame excluded from ``rtf_steady``.
WARMUP_S = 2.0


#: Resonator graph of the device benches (one process and separate processes): natural
#: frequency [Hz], output and thermomechanical noise std [V] of the emulator and observers.
RESONATOR_F0, RESONATOR_NOISE, RESONATOR_STATE_NOISE = 5.0e4, 0.25, 5e-4
#: Its three observers: (name, parameters besides the noise): the exact model, a 5 % f0
#: error, and the adaptive observer from that error.
RESONATOR_OBSERVERS = (
    ("exact", dict(f0_hz=RESONATOR_F0)),
    ("f0_error", dict(f0_hz=RESONATOR_F0 * 1.05)),
    ("adaptive", dict(f0_hz=RESONATOR_F0 * 1.05, adaptive=True)),
)


def resonator_device_parameters(**extra) -> dict:
    """Parameters of the resonator emulator of the device benches (observer loop, full
    Kalman gain, seed 1) plus ``extra`` (duration, frame size)."""
    from mems_sim.devices.resonator import default_pulse_amplitude

    return dict(
        mode="observer",
        output_noise_std=RESONATOR_NOISE,
        state_noise_std=RESONATOR_STATE_NOISE,
        observer_state_noise_std=RESONATOR_STATE_NOISE,
        fast=False,
        pulse_amplitude=float(default_pulse_amplitude(0.25)),
        seed=1,
        **extra,
    )


def recorder_command(out, storage: list[str], topics) -> list[str]:
    """Command line of the recorder process (``mems_sim.bag.record_cli``) writing the MCAP
    ``out`` with the storage options ``storage`` (compression, preset) from ``topics``,
    logging warnings only."""
    return [
        sys.executable,
        "-m",
        "mems_sim.bag.record_cli",
        "-o",
        str(out),
        *storage,
        *topics,
        "--ros-args",
        "--log-level",
        "warn",
    ]


def cpu_ticks(pid: int) -> int:
    """utime + stime of a running process [clock ticks] (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return int(fields[11]) + int(fields[12])
    except (OSError, IndexError, ValueError):
        return 0


def machine_ticks() -> dict:
    """CPU ticks of the whole machine since boot (all cores): processes (user, nice,
    system), interrupts (irq + softirq: e.g. the loopback network stack) and steal (the
    hypervisor's other guests)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:9]]
    return {"machine": v[0] + v[1] + v[2], "irq": v[5] + v[6], "steal": v[7]}


def reap(proc, timeout_s: float) -> float | None:
    """Wait for a child with os.wait4; its CPU seconds (None after a timeout)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return ru.ru_utime + ru.ru_stime
        time.sleep(0.02)
    return None


def process_env(domain_id: int) -> dict:
    """Environment of a graph's process: this one's, with localhost discovery in
    ``domain_id``, unbuffered output and the repository on ``PYTHONPATH``."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(
        os.environ,
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_DOMAIN_ID=str(domain_id),
        PYTHONUNBUFFERED="1",
        PYTHONPATH=os.pathsep.join([root] + [x for x in [os.environ.get("PYTHONPATH")] if x]),
    )
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def wait_quiet(procs: list, limit_s: float) -> float:
    """Wait until ``procs`` stop using CPU (0.5 s without a tick beyond noise); the time
    it took (``limit_s`` at most)."""
    hz = os.sysconf("SC_CLK_TCK")
    t0 = time.monotonic()
    prev, quiet_since = None, None
    while time.monotonic() - t0 < limit_s:
        ticks = sum(cpu_ticks(p.pid) for p in procs)
        now = time.monotonic()
        if prev is not None and ticks - prev <= 0.05 * hz * 0.1 * len(procs) + 1:
            quiet_since = quiet_since or now
            if now - quiet_since >= 0.5:
                break
        else:
            quiet_since = None
        prev = ticks
        time.sleep(0.1)
    return (quiet_since or time.monotonic()) - t0


def device_parameters(wait_subs: dict[str, int]) -> dict:
    """Parameters of an emulator executable in a bench graph: it starts once every topic
    of ``wait_subs`` has its subscriptions (the recorder's and the consumers'; for its own
    topics the matched ones) and exits once its data is published and acknowledged."""
    return dict(
        start_when_matched=True,
        min_subscribers=0,
        wait_for_subscribers=",".join(f"{t}:{n}" for t, n in wait_subs.items()),
        exit_when_acknowledged=True,
    )


def graph_topics(domain_id: int, settle_s: float = 1.5) -> dict[str, list[int]]:
    """Every topic of the ROS graph in ``domain_id`` (but :data:`IGNORED_TOPICS`) with its
    publisher and subscriber counts, seen by a probe node after ``settle_s`` of discovery."""
    import rclpy
    from rclpy.context import Context

    from mems_sim.ros.env import apply_defaults

    apply_defaults()
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    node = rclpy.create_node("bench_graph_probe", context=ctx)
    try:
        time.sleep(settle_s)
        return {
            name: [node.count_publishers(name), node.count_subscribers(name)]
            for name, _ in node.get_topic_names_and_types()
            if name not in IGNORED_TOPICS
        }
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def _end_of_stream(path, namespace: str) -> tuple[dict, str]:
    """The device's end-of-stream record in the recording (per topic: messages, samples,
    end_sample_index; {} without one) and the node that sent it ("" without one)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    from mems_sim.ros.end_of_stream import END_OF_STREAM, parse_end_of_stream

    topic = f"{namespace.rstrip('/')}/{END_OF_STREAM}"
    record: dict = {}
    node = ""
    with open(path, "rb") as f:
        for _, _, m in make_reader(f).iter_messages(topics=[topic]):
            msg = deserialize_message(m.data, DiagnosticArray)
            record = parse_end_of_stream(msg)
            node = next((st.hardware_id for st in msg.status), node)
    return record, node


def device_timing(path, namespace: str, pace: float, topic: str = "adc") -> dict:
    """The timing of the emulator in ``namespace``, from the recording ``path`` of its
    frame topic ``topic`` (relative) paced at ``pace`` x real time (``stamp_origin``
    'wall': the epoch t0 is the wall time at which the pacing started, sample k was due
    at t0 + k / fs / pace).

    Keys: node (its name), executor (``MEMS_EXECUTOR``), frames (published, by the
    end-of-stream record), samples, fs, frame_size, pace,
    t_first/t_last (publication of the first and last recorded frame, time.monotonic and
    as t_first_ns/t_last_ns the wall clock), sim_span_s, wall_span_s, rtf = simulated
    span / wall span between them, rtf_steady = the same from the first frame published
    :data:`WARMUP_S` after the first one, max_late_s = worst lateness of a publication
    behind the end of the frame's last sample on the wall clock, t0_ns and wall_start_ns
    (the epoch), topics (messages and samples published per data topic)."""
    import numpy as np
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    from mems_sim.bag.schema import message_class

    topic = f"{namespace.rstrip('/')}/{topic}"
    rows = []  # (publish time, first sample index, samples)
    fs, t0_ns = None, None
    with open(path, "rb") as f:
        for schema, _, m in make_reader(f).iter_messages(topics=[topic]):
            msg = deserialize_message(m.data, message_class(schema.name))
            if t0_ns is None:
                if msg.first_sample_index != 0:
                    raise RuntimeError(f"{path}: {topic} does not start at sample 0")
                t0_ns = int(msg.header.stamp.sec) * 1_000_000_000 + msg.header.stamp.nanosec
            fs = float(msg.sample_rate_hz)
            rows.append((m.publish_time, int(msg.first_sample_index), int(msg.num_samples)))
    if not rows:
        raise RuntimeError(f"{path}: no frame on {topic}")
    record, node = _end_of_stream(path, namespace)
    pt = np.array([r[0] for r in rows], dtype=np.int64)
    end = np.array([r[1] + r[2] for r in rows], dtype=np.int64)
    due = t0_ns + end / fs / pace * 1e9
    span_wall = (pt[-1] - pt[0]) / 1e9
    span_sim = (end[-1] - end[0]) / fs
    steady = np.flatnonzero(pt >= pt[0] + WARMUP_S * 1e9)
    rtf_steady = None
    if steady.size and pt[-1] > pt[steady[0]]:
        k = steady[0]
        rtf_steady = (end[-1] - end[k]) / fs / ((pt[-1] - pt[k]) / 1e9)
    to_monotonic = time.monotonic() - time.time()
    return dict(
        node=node,
        executor=os.environ.get("MEMS_EXECUTOR", "events"),  # the node executables' choice
        frames=record.get(topic, {}).get("messages", len(rows)),
        samples=int(end[-1]),
        fs=fs,
        frame_size=rows[0][2],
        pace=float(pace),
        t_first=pt[0] / 1e9 + to_monotonic,
        t_last=pt[-1] / 1e9 + to_monotonic,
        t_first_ns=int(pt[0]),
        t_last_ns=int(pt[-1]),
        sim_span_s=span_sim,
        wall_span_s=span_wall,
        rtf=span_sim / span_wall if span_wall > 0 else None,
        rtf_steady=rtf_steady,
        max_late_s=float(np.max(pt - due)) / 1e9,
        t0_ns=t0_ns,
        wall_start_ns=t0_ns,
        topics={
            t: {k: v for k, v in e.items() if k in ("messages", "samples")}
            for t, e in record.items()
        },
    )


def keep_all_publisher(node, msg_type, topic: str, timeout_s: float = 30.0):
    """A RELIABLE, KEEP_ALL publisher of ``topic`` (FRAME_QOS's depth), returned once a
    subscriber matched it or ``timeout_s`` passed. KEEP_ALL: a lagging recorder pushes back on
    the publisher instead of losing frames, so the achieved rate is the recorder's sustained
    rate and any loss is the recorder's."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from mems_sim.ros.qos import FRAME_QOS

    qos = QoSProfile(
        reliability=ReliabilityPolicy.RELIABLE,
        history=HistoryPolicy.KEEP_ALL,
        depth=FRAME_QOS.depth,
    )
    pub = node.create_publisher(msg_type, topic, qos)
    deadline = time.monotonic() + timeout_s
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    return pub


def family_parser(prog: str, description: str, families) -> argparse.ArgumentParser:
    """A bench's option parser whose positional arguments name device families (default
    all of ``families``); :func:`check_families` refuses unknown ones after parsing."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument(
        "families",
        nargs="*",
        metavar="FAMILY",
        help=f"families to run (default all: {', '.join(families)})",
    )
    return ap


def check_families(ap: argparse.ArgumentParser, args: argparse.Namespace, families) -> None:
    """``ap.error`` (exit 2) on the names of ``args.families`` that ``families`` lacks."""
    unknown = sorted(set(args.families) - set(families))
    if unknown:
        ap.error(f"unknown families {unknown}; known: {', '.join(families)}")

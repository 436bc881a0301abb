"""Device process of the multi-process benches: any emulator node (``EmulatorNode``
subclass) in a process of its own, paced by its own wall-clock timer
(``PacedEmulator.start``), with per-frame publish times.

Run:  python bench/paced_device.py --node=MODULE:CLASS [--wait-subs=TOPIC:N,...]
                                   [--timeout=S] [--max-wall=S] [--no-warm]
                                   --ros-args -r __ns:=/NS -p ...

e.g. ``--node=mems_sim.nodes.stage_node:MicroStageNode`` (bench/paced_stage.py is this
with the stage), used by ``bench_device_processes.py`` and ``bench_stage_ekf.py
--graph-processes``.

The node is the executable's class (same parameters, same publishers, same timer), spun
by the executor ``run_node`` would give it (``mems_sim.ros.node_base.make_executor`` when
the module has it, else rclpy's ``SingleThreadedExecutor``). What differs from the node
executable (``mems_sim/nodes/*_node.py``), none of which the node itself offers:

* the timer starts once the subscribers of the graph are matched (``--wait-subs``: the
  topic has at least N subscriptions; for the node's own publishers the matched readers,
  for other topics, e.g. an estimator's output, the graph's count): the recorder
  subscribes only after it has seen the publishers, so frames published earlier would be
  missing from the bag;
* the process exits once the node's duration (``duration_s``) or schedule is published
  and acknowledged by every subscriber (the executable spins on until SIGINT); a node
  without an end (no ``duration_s``, no schedule) is refused; ``--max-wall=S`` stops it
  after S wall seconds of publishing (then ``finished`` is false);
* before the timer starts, one frame of a copy of the node's device is computed (unless
  ``--no-warm``; the node's ``warm_kernels``, which a self-started node runs before its
  timer), so that numba kernels are loaded before the first frame is due;
* it prints one JSON line with the timing:

    frames, samples, fs, frame_size, pace (``realtime_factor``), t_first/t_last
    (time.monotonic and time.time_ns of the first and the last frame's publication),
    rtf = simulated span / wall span between the first and the last frame, rtf_steady =
    the same from the first frame published 2 s after the first one, max_late_s = worst
    lateness of a frame's publication behind its due time (end of its last sample on the
    wall clock), t0_ns (the epoch: stamp of sample 0), wall_start_ns (time.time_ns when
    sample 0 was due), topics (messages published per data topic, and samples for
    frame topics), graph_topics (every topic of the ROS graph at the end, with its
    publisher and subscriber counts), cpu_s of this process while it published,
    executor, acked (every data subscriber acknowledged every message).

A subscriber that does not match within ``--timeout`` (default 60 s) gives
``{"error": ..., "subs": ...}`` and exit status 3.

The benches that start this process import its CPU helpers (:func:`cpu_ticks`,
:func:`machine_ticks`, :func:`reap`); importing the module loads no ROS code.
"""

from __future__ import annotations

import importlib
import json
import os
import resource
import sys
import time

#: Topics of every node, not data of a graph.
IGNORED_TOPICS = ("/rosout", "/parameter_events")
#: Wall seconds after the first frame excluded from ``rtf_steady``.
WARMUP_S = 2.0


# ------------------------------------------------------------------ the benches' side:
# CPU of the graph's processes, read by the process-graph benches


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
    import os

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return ru.ru_utime + ru.ru_stime
        time.sleep(0.02)
    return None


# ------------------------------------------------------------------ the device process


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


def node_class(spec: str):
    """The class named ``MODULE:CLASS``."""
    module, _, name = spec.partition(":")
    if not name:
        raise SystemExit(f"--node={spec!r}: give MODULE:CLASS")
    return getattr(importlib.import_module(module), name)


def _executor(node):
    """The executor ``run_node`` spins a node with."""
    from mems_sim.ros import node_base

    make = getattr(node_base, "make_executor", None)
    if make is not None:
        return make(node)
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def _warm(dev) -> bool:
    """Load the device's compiled kernels before the first frame: the node's
    ``warm_kernels()`` (one short frame of a copy of its device), or for the IMU
    ``model.generate(n, ...)`` at rest on a copy. False when the node has neither or the
    copy fails."""
    import copy

    import numpy as np

    if dev.warm_kernels():
        return True
    n = int(dev.p["frame_size"])
    model = getattr(dev, "model", None)
    try:
        if model is not None and hasattr(model, "generate"):
            copy.deepcopy(model).generate(n, np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, 25.0))
        else:
            return False
    except Exception:  # a warm-up only
        return False
    return True


def main(argv: list[str] | None = None, node: str | None = None) -> int:
    """Run the node class ``node`` (or ``--node=``) paced; print the JSON line."""
    import rclpy
    from rclpy.duration import Duration
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    from mems_sim.ros.env import apply_defaults

    argv = list(sys.argv if argv is None else argv)
    args = remove_ros_args(argv)[1:]
    wait: dict[str, int] = {}
    timeout_s, max_wall, warm = 60.0, None, True
    for a in args:
        if a.startswith("--wait-subs="):
            for item in filter(None, a.split("=", 1)[1].split(",")):
                topic, count = item.rsplit(":", 1)
                wait[topic] = int(count)
        elif a.startswith("--timeout="):
            timeout_s = float(a.split("=", 1)[1])
        elif a.startswith("--max-wall="):
            max_wall = float(a.split("=", 1)[1])
        elif a == "--no-warm":
            warm = False
        elif a.startswith("--node="):
            node = a.split("=", 1)[1]
        else:
            raise SystemExit(f"unknown argument {a!r}")
    if not node:
        raise SystemExit("give --node=MODULE:CLASS")
    base = node_class(node)

    class Timed(base):
        def __init__(self, **kw):
            self.pub_times: list[tuple[float, int, int]] = []  # (monotonic, epoch ns, end index)
            super().__init__(**kw)

        def step(self) -> int:
            n = super().step()
            if n:
                self.pub_times.append((time.monotonic(), time.time_ns(), self.next_index))
            return n

    Timed.__name__ = Timed.__qualname__ = base.__name__

    apply_defaults()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    dev = None
    out: dict = {}
    try:
        dev = Timed(autostart=False)
        if dev.total_samples is None:
            print(json.dumps({"error": "the node has no end: set duration_s"}), flush=True)
            return 3
        ex = _executor(dev)
        ex.add_node(dev)
        own = {p.topic_name: p for p in dev.publishers}

        def subs(topic: str) -> int:
            p = own.get(topic)
            return p.get_subscription_count() if p is not None else dev.count_subscribers(topic)

        t_wait = time.monotonic()
        deadline = t_wait + timeout_s
        while not all(subs(t) >= c for t, c in wait.items()):
            if time.monotonic() > deadline:
                print(
                    json.dumps(
                        {
                            "error": "subscribers not matched",
                            "subs": {t: subs(t) for t in wait},
                            "want": wait,
                        }
                    ),
                    flush=True,
                )
                return 3
            ex.spin_once(timeout_sec=0.02)
        waited = time.monotonic() - t_wait
        warmed = warm and _warm(dev)
        cpu0 = resource.getrusage(resource.RUSAGE_SELF)
        dev.start()
        t_start = time.monotonic()
        while not dev.finished:
            ex.spin_once(timeout_sec=0.1)
            if max_wall is not None and time.monotonic() - t_start > max_wall:
                break
        cpu1 = resource.getrusage(resource.RUSAGE_SELF)
        finished = bool(dev.finished)
        dev.close()  # the end-of-stream record when stopped early
        pubs = [a.publisher for a in dev.streams.values()] + [dev.pub_end_of_stream]
        acked = all(p.wait_for_all_acked(Duration(seconds=30.0)) for p in pubs)
        graph = {
            name: [dev.count_publishers(name), dev.count_subscribers(name)]
            for name, _ in dev.get_topic_names_and_types()
            if name not in IGNORED_TOPICS
        }
        t = dev.pub_times
        if not t:
            print(json.dumps({"error": "no frame published"}), flush=True)
            return 3
        fs = dev.fs
        pace = float(dev.p["realtime_factor"])
        frame = int(dev.p["frame_size"])
        start = dev._wall_start
        span_sim = (t[-1][2] - t[0][2]) / fs
        span_wall = t[-1][0] - t[0][0]
        late = max(tm - (start + idx / fs / pace) for tm, _, idx in t)
        steady = next((x for x in t if x[0] >= t[0][0] + WARMUP_S), None)
        rtf_steady = None
        if steady is not None and t[-1][0] > steady[0]:
            rtf_steady = (t[-1][2] - steady[2]) / fs / (t[-1][0] - steady[0])
        # epoch clock of the monotonic start: the offset between the two clocks at the
        # first frame's publication
        wall_start_ns = int(t[0][1] - (t[0][0] - start) * 1e9)
        out = dict(
            node=dev.get_fully_qualified_name(),
            frames=dev.frames_published,
            samples=dev.next_index,
            total_samples=dev.total_samples,
            finished=finished,
            fs=fs,
            frame_size=frame,
            pace=pace,
            t_first=t[0][0],
            t_last=t[-1][0],
            t_first_ns=t[0][1],
            t_last_ns=t[-1][1],
            sim_span_s=span_sim,
            wall_span_s=span_wall,
            rtf=span_sim / span_wall if span_wall > 0 else None,
            rtf_steady=rtf_steady,
            max_late_s=late,
            t0_ns=int(dev.t0_ns),
            wall_start_ns=wall_start_ns,
            topics={
                topic: {"messages": a.messages, **({"samples": a.samples} if a.frames else {})}
                for topic, a in dev.streams.items()
            },
            graph_topics=graph,
            waited_s=waited,
            warmed=warmed,
            acked=acked,
            executor=type(ex).__name__,
            cpu_s=(cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime),
        )
    finally:
        if dev is not None:
            dev.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

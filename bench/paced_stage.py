"""Stage process of ``bench_stage_ekf.py --graph-processes``: ``stage_node`` in a
process of its own, paced by its own wall-clock timer (``PacedEmulator.start``), with
per-frame publish times.

Run:  python bench/paced_stage.py --ros-args -r __ns:=/stage_t1 -p frame_size:=20000 ...

The node is the executable's :class:`MicroStageNode` (same parameters, same publishers,
same timer, spun by ``rclpy.spin``-like single-threaded executor); the only differences
from ``stage_node`` are that the timer starts once the subscribers of the graph are
matched (``--wait-subs=TOPIC:N,...``; the recorder subscribes only after it has
seen the publishers, so frames published earlier would be missing from the bag), that the
process exits once the schedule is published and acknowledged by every subscriber, and
that it prints one JSON line with the timing:

    frames, samples, fs, t_first/t_last (time.monotonic and time.time_ns of the first and
    the last frame's publication), rtf = simulated span / wall span between the first and
    the last frame, max_late_s = worst lateness of a frame's publication behind its due
    time (end of its last sample on the wall clock), cpu_s of this process.
"""

from __future__ import annotations

import json
import resource
import sys
import time


def main() -> int:
    import rclpy
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    from mems_sim.nodes.stage_node import MicroStageNode
    from mems_sim.ros.env import apply_defaults

    args = remove_ros_args(sys.argv)[1:]
    wait = {}
    timeout_s = 60.0
    for a in args:
        if a.startswith("--wait-subs="):
            for item in a.split("=", 1)[1].split(","):
                topic, count = item.rsplit(":", 1)
                wait[topic] = int(count)
        elif a.startswith("--timeout="):
            timeout_s = float(a.split("=", 1)[1])

    class TimedStage(MicroStageNode):
        def __init__(self, **kw):
            self.pub_times: list[tuple[float, int, int]] = []  # (monotonic, epoch ns, end index)
            super().__init__(**kw)

        def step(self) -> int:
            n = super().step()
            if n:
                self.pub_times.append((time.monotonic(), time.time_ns(), self.next_index))
            return n

    apply_defaults()
    rclpy.init(args=sys.argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    out: dict = {}
    try:
        node = TimedStage(autostart=False)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        deadline = time.monotonic() + timeout_s
        while not all(node.count_subscribers(t) >= c for t, c in wait.items()):
            if time.monotonic() > deadline:
                print(
                    json.dumps(
                        {
                            "error": "subscribers not matched",
                            "subs": {t: node.count_subscribers(t) for t in wait},
                        }
                    ),
                    flush=True,
                )
                return 3
            ex.spin_once(timeout_sec=0.02)
        cpu0 = resource.getrusage(resource.RUSAGE_SELF)
        node.start()
        while not node.finished:
            ex.spin_once(timeout_sec=0.1)
        cpu1 = resource.getrusage(resource.RUSAGE_SELF)
        acked = all(
            p.wait_for_all_acked(Duration(seconds=30.0))
            for p in (node.pub_adc, node.pub_drive, node.pub_truth, node.pub_gyro)
        )
        t = node.pub_times
        fs = node.fs
        frame = node.p["frame_size"]
        span_sim = (t[-1][2] - t[0][2]) / fs
        span_wall = t[-1][0] - t[0][0]
        start = node._wall_start
        late = max(tm - (start + idx / fs / node.p["realtime_factor"]) for tm, _, idx in t)
        out = dict(
            frames=node.frames_published,
            samples=node.next_index,
            fs=fs,
            frame_size=frame,
            t_first=t[0][0],
            t_last=t[-1][0],
            t_first_ns=t[0][1],
            t_last_ns=t[-1][1],
            sim_span_s=span_sim,
            wall_span_s=span_wall,
            rtf=span_sim / span_wall if span_wall > 0 else None,
            max_late_s=late,
            acked=acked,
            cpu_s=(cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime),
        )
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Device process of the two-host test of test_two_hosts: an emulator node class in a
process of its own, paced by its own wall-clock timer, started once its subscribers are
matched (frames published before would be lost to discovery), ended once its schedule is
published and acknowledged by every subscriber; prints one JSON line.

Run:  python test/nodes/paced_device.py MODULE:CLASS TOPIC:N[,TOPIC:N...] --ros-args ...
"""

from __future__ import annotations

import importlib
import json
import sys
import time


def main() -> int:
    import rclpy
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    from mems_sim.ros.env import apply_defaults

    args = remove_ros_args(sys.argv)[1:]
    module, _, cls = args[0].partition(":")
    wait = {t: int(n) for t, n in (item.rsplit(":", 1) for item in args[1].split(","))}
    apply_defaults()
    rclpy.init(args=sys.argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    out: dict = {}
    try:
        node = getattr(importlib.import_module(module), cls)(autostart=False)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        deadline = time.monotonic() + 60.0
        while not all(node.count_subscribers(t) >= n for t, n in wait.items()):
            if time.monotonic() > deadline:
                subs = {t: node.count_subscribers(t) for t in wait}
                print(json.dumps({"error": f"subscribers not matched: {subs}"}), flush=True)
                return 3
            ex.spin_once(timeout_sec=0.05)
        node.start()
        while not node.finished:
            ex.spin_once(timeout_sec=0.1)
        acked = all(p.wait_for_all_acked(Duration(seconds=30.0)) for p in node.publishers)
        out = dict(frames=node.frames_published, samples=node.next_index, acked=acked)
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

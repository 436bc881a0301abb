"""``scenario_run_record``: publishes a scenario's run record in a graph of processes.

The node publishes the file its ``record_file`` parameter names (the JSON run record that
``run_scenario NAME --write-launch`` wrote beside the launch file,
:func:`mems_scenarios.contract.run_info`; at most 16 MiB) once on
:data:`~mems_scenarios.contract.RUN_INFO_TOPIC`, reliable and transient-local, and exits with
status 0 once a subscriber (the recorder) acknowledged it, so that ``run_graph`` ends when
the emulators have. The contract: docs/scenarios.md.
"""

from __future__ import annotations

import sys
import time

#: Seconds the node waits for a subscriber to acknowledge the record before it gives up.
ACK_TIMEOUT_S = 120.0


def main(argv: list[str] | None = None) -> int:
    """Entry point ``scenario_run_record``: 0 once the record is acknowledged, 1 if no
    subscriber took it within :data:`ACK_TIMEOUT_S`, 130 on SIGINT."""
    import argparse

    import rclpy
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from mems_scenarios.contract import RUN_INFO_TOPIC
    from mems_sim.bounded_yaml import YamlLimitError, read_text

    args = sys.argv[1:] if argv is None else list(argv)
    ours = args[: args.index("--ros-args")] if "--ros-args" in args else args
    argparse.ArgumentParser(
        prog="scenario_run_record",
        description=__doc__.splitlines()[0],
        epilog="parameters: record_file (path of the JSON run record); --ros-args as any node",
    ).parse_args(ours)
    rclpy.init(args=["scenario_run_record", *args])
    node = rclpy.create_node("run_record")
    try:
        path = node.declare_parameter("record_file", "").value
        try:
            text = read_text(path)
        except (OSError, YamlLimitError) as exc:
            print(f"scenario_run_record: error: record_file: {exc}", file=sys.stderr)
            return 2
        qos = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        pub = node.create_publisher(String, RUN_INFO_TOPIC, qos)
        pub.publish(String(data=text))
        deadline = time.monotonic() + ACK_TIMEOUT_S
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
            if pub.get_subscription_count() > 0 and pub.wait_for_all_acked(Duration(seconds=1)):
                return 0
        print("scenario_run_record: error: no subscriber took the run record", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    raise SystemExit(main())

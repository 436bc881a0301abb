"""/diagnostics of many nodes in one executor, recorded by an in-process recorder: every
status lands in the MCAP file (through real topics, one rclpy context, localhost).

An executor takes one message per subscription per wait, so a topic that many publishers
feed (every node's status on /diagnostics) queues up in the recorder's reader while the
graph is busy; closing the recorder must still write what was delivered (the scenario
``gyro_calibration`` recorded 119 of its 302 statuses before the fix, without a gap in
any publisher's sequence numbers: the missing tail was invisible).
"""

import time

import rclpy
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor

from mems_sim.bag.recorder import RecorderNode
from mems_sim.ros.diagnostics import DiagnosticsReporter

REPORTERS = 6
BURST = 40  # per reporter, beyond the reporter's history depth (10)


def _spin_until(executor, predicate, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return predicate()


def test_burst_of_statuses_from_several_reporters_all_recorded(ros_context, tmp_path):
    out = tmp_path / "diag.mcap"
    ex = SingleThreadedExecutor(context=ros_context)
    nodes, reporters = [], []
    rec = None
    try:
        for k in range(REPORTERS):
            node = rclpy.create_node("reporter", namespace=f"/dev{k}", context=ros_context)
            reporters.append(
                DiagnosticsReporter(
                    node,
                    "reporter: burst",
                    hardware_id=node.get_fully_qualified_name(),
                    period_s=0,
                )
            )
            nodes.append(node)
            ex.add_node(node)
        rec = RecorderNode(str(out), topics=["/diagnostics"], context=ros_context)
        ex.add_node(rec)
        assert _spin_until(
            ex,
            lambda: (
                rec.matched("/diagnostics")
                and rec._topic_subs["/diagnostics"].get_publisher_count() >= REPORTERS
            ),
            10.0,
        )
        assert rec.received("/diagnostics") == 0
        # a busy graph: every reporter publishes its burst while the executor only gets
        # round to a few waits (as between the stage EKF's frames)
        for i in range(BURST):
            for r in reporters:
                r.count("burst")
                r.publish()
            if i % 10 == 0:
                ex.spin_once(timeout_sec=0)
        rec.close()
        counts = rec.counts()
        seq = rec.sequence_details()["/diagnostics"]
        assert counts["/diagnostics"] == REPORTERS * BURST, rec.summary()
        assert (seq["publishers"], seq["gaps"], seq["missing_messages"]) == (REPORTERS, 0, 0)
        assert rec.losses() == []
    finally:
        if rec is not None:
            rec.destroy_node()
        for node in nodes:
            node.destroy_node()
        ex.shutdown()

    # in the file: each reporter's statuses 1..BURST in order, told apart by hardware_id
    seen: dict[str, list[int]] = {}
    with open(out, "rb") as f:
        for _, channel, message, msg in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            assert channel.topic == "/diagnostics"
            (status,) = msg.status
            value = int({kv.key: kv.value for kv in status.values}["burst"])
            seen.setdefault(status.hardware_id, []).append(value)
            assert message.sequence == value  # the publisher's sequence number
    assert sorted(seen) == [f"/dev{k}/reporter" for k in range(REPORTERS)]
    for values in seen.values():
        assert values == list(range(1, BURST + 1))


def test_estimator_status_names_its_node(ros_context):
    """Estimators of two devices publish the same status name; the hardware_id is the
    node's fully qualified name, so their statuses are told apart in a recording."""
    from mems_estimation.nodes.stage_gyro_calibration_node import StageGyroCalibrationNode

    nodes = [
        StageGyroCalibrationNode(context=ros_context, namespace=ns)
        for ns in ("/stage_d1", "/stage_d2")
    ]
    try:
        statuses = [n.diag.status() for n in nodes]
        assert statuses[0].name == statuses[1].name
        assert [s.hardware_id for s in statuses] == [n.get_fully_qualified_name() for n in nodes]
        assert statuses[0].hardware_id != statuses[1].hardware_id
    finally:
        for n in nodes:
            n.destroy_node()

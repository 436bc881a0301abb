"""An emulator that left without its end-of-stream record reaching the recorder, through
real topics in one rclpy context: the recording cannot show whether the streams' tails
arrived, so it is a loss naming the end-of-stream topic; an emulator still running (the
recorder stopped first) is none, and neither is one whose record came."""

import rclpy
from conftest import spin_until
from diagnostic_msgs.msg import DiagnosticArray
from node_helpers import one_channel_adc

from mems_msgs.msg import AdcFrame
from mems_sim.bag.recorder import RecorderNode
from mems_sim.ros.end_of_stream import END_OF_STREAM_QOS, StreamAccount, end_of_stream_message
from mems_sim.ros.qos import FRAME_QOS

NUM = 4  # samples per frame
FRAMES = 5


def frame(first: int) -> AdcFrame:
    """A one-channel frame of ``NUM`` zero codes from sample index ``first`` at 200 Hz."""
    return one_channel_adc(first, [0] * NUM, 200.0, bits=16, name="a", lsb=1e-3, full_scale=32.767)


def emulator(ctx, name: str):
    """A node with a frame publisher and an end-of-stream publisher under ``/name``; the
    frame account of the record."""
    node = rclpy.create_node(name, namespace=f"/{name}", context=ctx)
    adc = StreamAccount(node.create_publisher(AdcFrame, "adc", FRAME_QOS)).wrap()
    eos = node.create_publisher(DiagnosticArray, "end_of_stream", END_OF_STREAM_QOS)
    return node, adc, eos


def test_an_emulator_gone_without_its_record_is_a_loss(graph, tmp_path):
    ctx, ex, _ = graph
    names = ("silent", "running", "ended")
    nodes = {n: emulator(ctx, n) for n in names}
    for node, _, _ in nodes.values():
        ex.add_node(node)
    topics = [f"/{n}/{t}" for n in names for t in ("adc", "end_of_stream")]
    rec = RecorderNode(str(tmp_path / "silent.mcap"), topics=topics, context=ctx)
    ex.add_node(rec)
    try:
        assert spin_until(ex, lambda: all(rec.matched(t) for t in topics))
        for n in names:
            for k in range(FRAMES):
                nodes[n][1].publish(frame(k * NUM))
        stamp = nodes["ended"][0].get_clock().now().to_msg()
        record = end_of_stream_message({"/ended/adc": nodes["ended"][1]}, stamp, "/ended")
        nodes["ended"][2].publish(record)
        assert spin_until(ex, lambda: all(rec.received(f"/{n}/adc") == FRAMES for n in names))
        assert spin_until(ex, lambda: rec.received("/ended/end_of_stream") == 1)
        assert rec.losses() == []  # every emulator still there
        for n in ("silent", "ended"):  # these two exit; "running" goes on
            ex.remove_node(nodes[n][0])
            nodes[n][0].destroy_node()
        assert spin_until(ex, lambda: not rec.matched("/silent/end_of_stream"))
        rec.stop_taking()
        assert rec.silent_ends() == {"/silent/end_of_stream"}
        losses = rec.losses()
        assert losses == [
            "/silent/end_of_stream: the emulator left without its end-of-stream record "
            "reaching the recorder (its streams' tails are unverified)"
        ], losses
        assert "lost: /silent/end_of_stream" in rec.summary()
    finally:
        ex.remove_node(rec)
        rec.destroy_node()
        ex.remove_node(nodes["running"][0])
        nodes["running"][0].destroy_node()


class _RefusingPublisher:
    """A publisher whose middleware refuses every message after the first ``keep``."""

    topic_name = "/refusing/adc"
    qos_profile = FRAME_QOS

    def __init__(self, keep: int):
        self.keep, self.delivered = keep, []

    def publish(self, msg) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        if len(self.delivered) >= self.keep:
            raise _rclpy.RCLError("Failed to publish: cannot publish data")
        self.delivered.append(msg)


def test_a_refused_publish_is_lost_at_the_source_not_a_crash():
    pub = _RefusingPublisher(keep=2)
    account = StreamAccount(pub).wrap()
    warned = []
    account.on_refused = warned.append
    for k in range(5):
        pub.publish(frame(k * NUM))
    assert len(pub.delivered) == 2
    assert (account.messages, account.sent, account.refused) == (5, 2, 3)
    # the record counts what the device produced: a recorder sees the refused ones missing
    assert account.end_sample_index == 5 * NUM and account.samples == 5 * NUM
    assert warned == ["/refusing/adc"]  # one warning, at the first refusal

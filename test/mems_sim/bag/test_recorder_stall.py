"""Stalls seen by the recorder (``stall_timeout_s``), through real topics in one rclpy
context: a publisher that sent steadily and then nothing for longer than the timeout is
``stalled: TOPIC (N s without data)``; the same silence over a gap its device declared (a
scheduled device gap) is neither a stall nor transport loss."""

from conftest import spin_until

from mems_msgs.msg import AdcFrame
from mems_sim.bag.recorder import RecorderNode
from mems_sim.ros.qos import FRAME_QOS

NUM = 4  # samples per frame
STEADY = 20  # frames before the silence, 20 ms apart
SILENCE_S = 1.5
TIMEOUT_S = 0.5


def frame(first: int) -> AdcFrame:
    msg = AdcFrame()
    msg.sample_rate_hz = 200.0
    msg.num_samples = NUM
    msg.bits = 16
    msg.channel_names, msg.channel_units = ["a"], ["V"]
    msg.lsb, msg.offset, msg.full_scale = [1e-3], [0.0], [32.767]
    msg.first_sample_index = first
    msg.codes = [0] * NUM
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(first * 5_000_000, 1_000_000_000)
    return msg


def test_a_silent_publisher_is_stalled_unless_its_device_declared_the_gap(graph, tmp_path):
    ctx, ex, probe = graph
    topics = ("/stall/stalled/adc", "/stall/declared/adc")
    pubs = {t: probe.create_publisher(AdcFrame, t, FRAME_QOS) for t in topics}
    rec = RecorderNode(
        str(tmp_path / "stall.mcap"), topics=topics, stall_timeout_s=TIMEOUT_S, context=ctx
    )
    ex.add_node(rec)
    try:
        assert spin_until(ex, lambda: all(rec.matched(t) for t in topics))

        def send(first_frame: int, frames: int) -> None:
            for k in range(first_frame, first_frame + frames):
                for pub in pubs.values():
                    pub.publish(frame(k * NUM))
                spin_until(ex, lambda: False, timeout=0.02)

        send(0, STEADY)
        assert spin_until(ex, lambda: all(rec.received(t) == STEADY for t in topics))
        # the declared device's samples of the silence will not come; the other's do
        rec.declare_device_gap(topics[1], STEADY * NUM, 10 * NUM)
        spin_until(ex, lambda: False, timeout=SILENCE_S)
        for k in range(STEADY, STEADY + 5):
            pubs[topics[0]].publish(frame(k * NUM))
            pubs[topics[1]].publish(frame((k + 10) * NUM))
            spin_until(ex, lambda: False, timeout=0.02)
        assert spin_until(ex, lambda: all(rec.received(t) == STEADY + 5 for t in topics))
        stalls = rec.stalls()
        assert len(stalls) == 1 and stalls[0].startswith(f"stalled: {topics[0]} ("), stalls
        silence = float(stalls[0].split("(")[1].split(" s without data)")[0])
        assert SILENCE_S - 0.1 <= silence < SILENCE_S + 2.0, stalls
        assert rec.losses() == []  # the declared gap is no transport loss
        assert rec.gap_details()[topics[1]]["gaps"] == 0
        assert stalls[0] in rec.summary()
    finally:
        ex.remove_node(rec)
        rec.destroy_node()

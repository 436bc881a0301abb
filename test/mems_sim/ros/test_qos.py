"""Tests of the QoS profiles (mems_sim.ros.qos): the depth of a per-sample stream."""

from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS, SAMPLE_HISTORY_S, sample_stream_qos


def test_a_per_sample_stream_holds_seconds_of_samples():
    """sensor_msgs/Imu at 1 kHz in frames of 100: a frame plus 5 s of messages, so that a
    recorder 1 s behind (a loaded machine) loses none; a slow stream keeps FRAME_DEPTH."""
    qos = sample_stream_qos(1000.0, 100)
    assert qos.depth == 100 + 1000 * SAMPLE_HISTORY_S == 5100
    assert (qos.reliability, qos.durability, qos.history) == (
        FRAME_QOS.reliability,
        FRAME_QOS.durability,
        FRAME_QOS.history,
    )
    assert sample_stream_qos(10.0, 10).depth == FRAME_DEPTH

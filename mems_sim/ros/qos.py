"""Quality-of-service profiles used by every frame topic.

Frames carry 10^1..10^4 samples each, so message rates are modest, but a
lost frame is a gap in the sample stream. Publishers and the recorder use
RELIABLE delivery with a deep KEEP_LAST history so that a subscriber that
falls behind for a moment catches up instead of losing frames.
"""

import math

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Depth of the history of frame publishers and subscribers [messages].
FRAME_DEPTH = 1000

#: Frames of sampled data: reliable, volatile, deep history.
FRAME_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=FRAME_DEPTH,
)

#: Latched results (identified models, calibration): late joiners get the last one.
RESULT_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
)

#: Progress of a lossless consumer (``~/progress``, std_msgs/UInt64): one past the last
#: sample index of its primary input that it has finished with (reliable, transient local,
#: depth 1). Estimator nodes and a recorder asked to report progress publish it; the
#: player's ``--wait-for-consumer`` flow control reads it.
PROGRESS_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
)


#: Time [s] a per-sample stream's history holds on top of a frame: a reader of a topic with
#: one message per sample (sensor_msgs/Imu at 1 kHz and more) that falls this far behind (a
#: loaded machine, a recorder writing a chunk) loses none. FRAME_DEPTH frames of such a
#: stream would be minutes of messages; a few seconds bounds the history's memory.
SAMPLE_HISTORY_S = 5.0


def sample_stream_qos(fs: float, frame_size: int) -> QoSProfile:
    """FRAME_QOS with the depth of a stream of one message per sample, published a frame at a
    time: a whole frame plus :data:`SAMPLE_HISTORY_S` of samples, and never less than the
    frames' FRAME_DEPTH. ``fs``: sample rate [Hz]; ``frame_size``: samples per frame."""
    depth = max(FRAME_DEPTH, int(frame_size) + math.ceil(SAMPLE_HISTORY_S * float(fs)))
    return QoSProfile(
        reliability=FRAME_QOS.reliability,
        durability=FRAME_QOS.durability,
        history=FRAME_QOS.history,
        depth=depth,
    )


#: Health verdicts of an estimator (``<device>/health``, diagnostic_msgs/DiagnosticStatus,
#: one per completed window of its consistency monitor): reliable, volatile, depth 10.
HEALTH_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
)

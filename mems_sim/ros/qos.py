"""Quality-of-service profiles used by every frame topic.

Frames carry 10^1..10^4 samples each, so message rates are modest, but a
lost frame is a gap in the sample stream. Publishers and the recorder use
RELIABLE delivery with a deep KEEP_LAST history so that a subscriber that
falls behind for a moment catches up instead of losing frames.
"""

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

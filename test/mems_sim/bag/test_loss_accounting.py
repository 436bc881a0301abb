"""Loss accounting of recordings without a graph: publisher sequence numbers and the
end-of-stream record, as the writer counts them and as ``mcap_info`` reads them back."""

from __future__ import annotations

from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from std_msgs.msg import String

from mems_msgs.msg import SignalFrame
from mems_sim.bag import info as info_mod
from mems_sim.bag.schema import schema_text
from mems_sim.bag.writer import McapBagWriter
from mems_sim.ros.end_of_stream import (
    END_OF_STREAM_TYPE,
    StreamAccount,
    end_of_stream_message,
    parse_end_of_stream,
)
from mems_sim.ros.qos import FRAME_QOS
from mems_sim.ros.qos_yaml import profiles_yaml as qos_profiles_yaml


class _Account:
    """What the end-of-stream record needs of a stream account."""

    def __init__(self, messages, end=None, samples=0):
        self.messages, self.end_sample_index, self.samples = messages, end, samples
        self.frames = end is not None

    status_values = StreamAccount.status_values


def _writer(path, *topics):
    w = McapBagWriter(str(path))
    for topic, type_name in topics:
        w.add_topic(topic, type_name, schema_text(type_name), qos_profiles_yaml([FRAME_QOS]))
    return w


def _frame(first, n=10):
    return serialize_message(
        SignalFrame(first_sample_index=first, num_samples=n, data=[0.0] * n, sample_rate_hz=1.0)
    )


def test_sequence_gaps_of_a_topic_that_is_not_frames(tmp_path):
    path = tmp_path / "seq.mcap"
    w = _writer(path, ("/r", "std_msgs/msg/String"), ("/two", "std_msgs/msg/String"))
    data = serialize_message(String(data="x"))
    for seq in (1, 2, 5, 6):
        w.write("/r", data, seq, seq, sequence=seq, publisher=b"a")
    for seq, pub in ((1, b"a"), (1, b"b"), (2, b"a"), (2, b"b")):  # two publishers
        # each its own bytes: identical topic, log time and bytes would be a duplicate
        own = serialize_message(String(data=pub.decode()))
        w.write("/two", own, 10, 10, sequence=seq, publisher=pub)
    w.close()
    details = w.sequence_details()
    assert details["/r"] == {
        "publishers": 1,
        "gaps": 1,
        "missing_messages": 2,
        "resets": 0,
        "last": 6,
    }
    assert details["/two"]["publishers"] == 2 and details["/two"]["gaps"] == 0
    info = info_mod.bag_info(str(path))
    assert info["topics"]["/r"]["sequence_gaps"] == 1
    assert info["topics"]["/r"]["missing_messages"] == 2
    # interleaved numbers of two publishers cannot be checked from the file alone
    assert info["topics"]["/two"]["sequence_gaps"] is None
    assert info["topics"]["/two"]["duplicates"] == 0 and info["topics"]["/two"]["count"] == 4
    assert info_mod.losses(info) == ["/r: 1 sequence gaps (2 messages)"]


def test_end_of_stream_record_reveals_a_missing_tail(tmp_path, capsys):
    path = tmp_path / "tail.mcap"
    w = _writer(
        path,
        ("/d/truth", "mems_msgs/msg/SignalFrame"),
        ("/d/adc", "mems_msgs/msg/SignalFrame"),
        ("/d/temperature", "std_msgs/msg/String"),
        ("/d/end_of_stream", END_OF_STREAM_TYPE),
    )
    for k in range(10):
        w.write("/d/adc", _frame(10 * k), k, k, sequence=k + 1, publisher=b"d")
        if k < 7:  # the truth topic lost its last 3 frames
            w.write("/d/truth", _frame(10 * k), k, k, sequence=k + 1, publisher=b"d")
        if k < 9:  # and the temperature its last message
            w.write("/d/temperature", serialize_message(String()), k, k, k + 1, b"d")
    record = end_of_stream_message(
        {
            "/d/adc": _Account(10, 100, 100),
            "/d/truth": _Account(10, 100, 100),
            "/d/temperature": _Account(10),
            "/d/ldv": _Account(10, 100, 100),  # not recorded: nothing to compare
        },
        stamp=Time(),
        hardware_id="/d/dev",
    )
    assert parse_end_of_stream(record)["/d/truth"] == {
        "messages": 10,
        "end_sample_index": 100,
        "samples": 100,
    }
    w.write("/d/end_of_stream", serialize_message(record), 10, 10, sequence=1, publisher=b"e")
    w.close()
    info = info_mod.bag_info(str(path))
    t = info["topics"]
    assert t["/d/truth"]["gaps"] == 0
    assert t["/d/truth"]["tail"] == {"messages": 3, "samples": 30, "from_index": 70}
    assert t["/d/adc"]["tail"] == {"messages": 0, "samples": 0, "from_index": 100}
    assert t["/d/temperature"]["tail"] == {"messages": 1}
    assert "/d/ldv" not in t
    assert info_mod.losses(info) == [
        "/d/temperature: missing tail of 1 of 10 messages",
        "/d/truth: missing tail of 3 of 10 messages (30 samples from sample 70)",
    ]
    assert info_mod.main([str(path)]) == 0
    out = capsys.readouterr()
    assert "missing tail of 3 of 10 messages (30 samples from sample 70)" in out.out
    assert out.err.count("lost data:") == 2


def test_a_frame_topic_recorded_from_after_sample_0_has_a_missing_head(tmp_path, capsys):
    """A recording whose first frame is sample 40,000 (the recorder joined late) lost the
    head: the writer counts it, mcap_info prints it and lists it as loss."""
    path = tmp_path / "head.mcap"
    w = _writer(
        path, ("/d/adc", "mems_msgs/msg/SignalFrame"), ("/d/truth", "mems_msgs/msg/SignalFrame")
    )
    for first in (40_000, 40_010):
        w.write("/d/adc", _frame(first), first, first)
    for first in (0, 10):
        w.write("/d/truth", _frame(first), first, first)
    w.close()
    details = w.gap_details()
    assert details["/d/adc"]["missing_head"] == 40_000 and details["/d/adc"]["gaps"] == 0
    assert details["/d/truth"]["missing_head"] == 0
    info = info_mod.bag_info(str(path))
    assert info["topics"]["/d/adc"]["missing_head"] == 40_000
    phrase = "missing head (40000 samples before the first frame)"
    assert info_mod.losses(info) == [f"/d/adc: {phrase}"]
    assert phrase in info_mod.format_info(info)
    assert info_mod.main([str(path)]) == 0
    assert f"lost data: /d/adc: {phrase}" in capsys.readouterr().err

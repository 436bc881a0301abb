"""``mcap_record`` with rosbag2's record options: split bags, ``--duration``, QoS overrides.

* ``-b/--max-bag-size`` and ``-d/--max-bag-duration`` write a rosbag2 bag directory: it
  opens with rosbags as one bag whose per-topic counts equal a single-file recording of the
  same publisher (recorded at the same time), every split file is a complete MCAP file on
  its own, and ``metadata.yaml`` lists them in order;
* ``--duration`` ends on time (wall clock) with a finalised file;
* ``--qos-profile-overrides-path`` sets the subscription's QoS (seen in the ROS graph);
* bad values: one line, exit status 2; an existing bag directory needs ``--overwrite``.

Each test has its own rclpy context and ROS domain id (conftest); discovery stays local.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import Imu

from mems_msgs.msg import AdcFrame
from mems_sim.bag.writer import BagWriteError, McapBagWriter, bag_directory_problem
from mems_sim.ros.qos import FRAME_QOS

BIN = Path(sys.executable).parent
FRAMES = 240  # 100-sample frames at 1 kHz: 24 s of sensor time
IMUS = 120


def _frame(k: int, num: int = 100) -> AdcFrame:
    msg = AdcFrame()
    first = k * num
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(first * 1_000_000, 1_000_000_000)
    msg.first_sample_index = first
    msg.sample_rate_hz = 1000.0
    msg.num_samples = num
    msg.bits = 16
    msg.channel_names = ["x", "y", "z"]
    msg.channel_units = ["rad/s"] * 3
    msg.lsb, msg.offset, msg.full_scale = [1e-3] * 3, [0.0] * 3, [32.767] * 3
    msg.codes = [((first + i) * 7919) % 30000 - 15000 for i in range(num * 3)]
    return msg


def _imu(k: int) -> Imu:
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 200_000_000, 1_000_000_000)
    msg.angular_velocity.x = 0.01 * k
    return msg


def _recorder(env, *args) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "mcap_record"), *[str(a) for a in args]],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _stop(proc: subprocess.Popen, timeout: float = 15.0) -> tuple[str, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"mcap_record did not stop: {err[-2000:]}") from None
    return out, err


def _wait_matched(pubs, count: int, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(p.get_subscription_count() >= count for p in pubs):
            return
        time.sleep(0.05)
    raise AssertionError(
        f"recorders did not subscribe: {[p.get_subscription_count() for p in pubs]}"
    )


def _file_counts(path: Path) -> dict[str, int]:
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics is not None, path
    topics = {cid: ch.topic for cid, ch in summary.channels.items()}
    return {topics[c]: n for c, n in summary.statistics.channel_message_counts.items() if n}


def _rosbags_counts(directory: Path) -> tuple[dict[str, int], int]:
    from rosbags.rosbag2 import Reader

    counts: dict[str, int] = {}
    with Reader(directory) as reader:
        for connection, _, _ in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
        assert reader.message_count == sum(counts.values())
        return counts, len(reader.connections)


def test_split_by_size_and_duration_match_single_file(ros_context, subprocess_env, tmp_path):
    """One publisher, three recorders at once: one file, split by size, split by log time."""
    import rclpy

    node = rclpy.create_node("split_pub", context=ros_context)
    frames = node.create_publisher(AdcFrame, "/split/adc", FRAME_QOS)
    imus = node.create_publisher(Imu, "/split/imu", FRAME_QOS)
    topics = ["/split/adc", "/split/imu"]
    single = tmp_path / "single.mcap"
    by_size, by_time = tmp_path / "by_size", tmp_path / "by_time.mcap"  # .mcap is dropped
    procs = [
        _recorder(subprocess_env, "-o", single, *topics),
        _recorder(subprocess_env, "-o", by_size, "-b", "40000", "--topics", *topics),
        _recorder(subprocess_env, "-o", by_time, "--max-bag-duration", "5", *topics),
    ]
    try:
        _wait_matched([frames, imus], 3)
        for k in range(FRAMES):
            frames.publish(_frame(k))
            if k % 2 == 0:
                imus.publish(_imu(k // 2))
            time.sleep(0.001)
        time.sleep(1.0)  # reliable delivery of the tail before the stop request
        outputs = [_stop(p) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        node.destroy_node()
    for p, (out, err) in zip(procs, outputs, strict=True):
        assert p.returncode == 0, err[-2000:]
        assert "frame-index gaps: 0 (0 samples missing)" in out and "lost:" not in out, out

    expected = {"/split/adc": FRAMES, "/split/imu": IMUS}
    assert _file_counts(single) == expected
    for directory, min_files in ((by_size, 3), (tmp_path / "by_time", 4)):
        assert directory.is_dir()
        meta = yaml.safe_load((directory / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        assert info["version"] == 9 and info["storage_identifier"] == "mcap"
        names = info["relative_file_paths"]
        assert names == [f"{directory.name}_{i}.mcap" for i in range(len(names))]
        assert len(names) >= min_files, names
        assert sorted(p.name for p in directory.iterdir()) == sorted(names + ["metadata.yaml"])
        assert [f["path"] for f in info["files"]] == names
        total: dict[str, int] = {}
        for entry in info["files"]:
            alone = _file_counts(directory / entry["path"])  # each file is complete on its own
            assert sum(alone.values()) == entry["message_count"] > 0
            for topic, n in alone.items():
                total[topic] = total.get(topic, 0) + n
        assert total == expected
        assert info["message_count"] == FRAMES + IMUS
        meta_counts = {
            t["topic_metadata"]["name"]: t["message_count"]
            for t in info["topics_with_message_count"]
        }
        assert meta_counts == expected
        qos = info["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"]
        assert qos[0]["reliability"] == "reliable"  # as offered (the graph gives no depth)
        counts, connections = _rosbags_counts(directory)  # one bag, the single file's counts
        assert counts == expected and connections == 2
    # by log time, as the writer documents it: a file ends before the message at which the
    # highest log time seen is 5 s past the highest one at the file's first message. (A
    # file's own span can pass 5 s: a message of the other topic taken late, with an older
    # log time, lands in the next file.)
    info = yaml.safe_load((tmp_path / "by_time" / "metadata.yaml").read_text())
    high, start = None, None
    for name in info["rosbag2_bagfile_information"]["relative_file_paths"]:
        for i, t in enumerate(_log_times_as_written(tmp_path / "by_time" / name)):
            high = t if high is None else max(high, t)
            if i == 0:
                assert start is None or high - start >= 5_000_000_000  # not split early
                start = high
            assert high - start < 5_000_000_000  # nor late
    assert start is not None
    info = info["rosbag2_bagfile_information"]
    assert info["duration"]["nanoseconds"] == (FRAMES - 1) * 100_000_000


def _log_times_as_written(path: Path) -> list[int]:
    """Log times of an MCAP file's messages in the order they were written."""
    with open(path, "rb") as f:
        return [r.log_time for r in StreamReader(f).records if isinstance(r, Message)]


def test_duration_ends_on_time(ros_context, subprocess_env, tmp_path):
    """``--duration 6`` with a busy publisher: the file is finalised within 0.5 s of the
    6 s (wall clock from the start of recording) and the process exits. (Discovery and
    matching take up to ~2.5 s of it here, more on a loaded machine.)"""
    import rclpy

    node = rclpy.create_node("duration_pub", context=ros_context)
    pub = node.create_publisher(AdcFrame, "/dur/adc", FRAME_QOS)
    out_path = tmp_path / "dur.mcap"
    t0 = time.monotonic()
    proc = _recorder(subprocess_env, "-o", out_path, "/dur/adc", "--duration", "6")
    try:
        k = 0
        while proc.poll() is None and time.monotonic() - t0 < 30:
            pub.publish(_frame(k, num=1000))  # ~12 kB frames at ~500 Hz
            k += 1
            time.sleep(0.002)
        out, err = _stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        node.destroy_node()
    wall = time.monotonic() - t0
    assert proc.returncode == 0, err[-2000:]
    match = re.search(r"--duration 6 s: file finalised ([0-9.]+) s after it \(([0-9.]+) s", out)
    assert match, out
    late, recorded = float(match.group(1)), float(match.group(2))
    assert late < 0.5 and 6.0 <= recorded < 6.5, out
    assert wall < 18.0, wall  # process start-up included
    counts = _file_counts(out_path)
    assert 0 < counts.get("/dur/adc", 0) <= k, (out, err)


def test_qos_profile_overrides(ros_context, subprocess_env, tmp_path):
    """An overridden topic is subscribed with the file's QoS; the others keep the adapted
    (reliable) QoS. Read back from the ROS graph and from the recorder's log."""
    import rclpy

    overrides = tmp_path / "qos.yaml"
    overrides.write_text(
        "/qos/adc:\n  history: keep_last\n  depth: 7\n  reliability: best_effort\n"
        "  durability: volatile\n"
    )
    node = rclpy.create_node("qos_pub", context=ros_context)
    pubs = [node.create_publisher(AdcFrame, t, FRAME_QOS) for t in ("/qos/adc", "/qos/other")]
    out_path = tmp_path / "qos.mcap"
    proc = _recorder(
        subprocess_env,
        "-o",
        out_path,
        "/qos/adc",
        "/qos/other",
        "--qos-profile-overrides-path",
        overrides,
    )
    try:
        _wait_matched(pubs, 1)
        seen = {}
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and len(seen) < 2:
            for topic in ("/qos/adc", "/qos/other"):
                for info in node.get_subscriptions_info_by_topic(topic):
                    if info.node_name == "mcap_recorder":
                        seen[topic] = info.qos_profile
            time.sleep(0.05)
        for k in range(20):
            for p in pubs:
                p.publish(_frame(k))
        time.sleep(0.5)
        out, err = _stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        node.destroy_node()
    assert proc.returncode == 0, err[-2000:]
    assert seen["/qos/adc"].reliability == ReliabilityPolicy.BEST_EFFORT
    assert seen["/qos/other"].reliability == ReliabilityPolicy.RELIABLE
    assert "recording /qos/adc [mems_msgs/msg/AdcFrame] (best_effort, volatile, depth 7)" in err
    assert "recording /qos/other [mems_msgs/msg/AdcFrame] (reliable, volatile" in err
    assert _file_counts(out_path)["/qos/other"] == 20


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["-s", "sqlite3"], "only 'mcap'"),
        (["-b", "ten"], "--max-bag-size"),
        (["--duration", "0"], "--duration"),
        (["--qos-profile-overrides-path", "QOS"], "reliability 'sometimes'"),
    ],
)
def test_bad_values_one_line(args, words, subprocess_env, tmp_path):
    qos = tmp_path / "qos.yaml"
    qos.write_text("/t:\n  reliability: sometimes\n")
    args = [qos if a == "QOS" else a for a in args]
    proc = _recorder(subprocess_env, "-o", tmp_path / "x.mcap", "/t", *args)
    out, err = proc.communicate(timeout=30)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 2 and len(lines) == 1, err
    assert lines[0].startswith("mcap_record: error: ") and words in lines[0], lines[0]
    assert "Traceback" not in err and not (tmp_path / "x.mcap").exists()


def test_bag_directory_refused_unless_overwrite(tmp_path):
    """An existing bag directory needs ``overwrite`` (then only its bag is replaced); a
    directory holding anything else is never emptied."""
    bag = tmp_path / "bag"
    McapBagWriter(str(bag), max_bag_size=10_000).close()
    assert sorted(os.listdir(bag)) == ["bag_0.mcap", "metadata.yaml"]
    assert "exists (give --overwrite" in bag_directory_problem(str(bag))
    with pytest.raises(BagWriteError, match="exists"):
        McapBagWriter(str(bag), max_bag_size=10_000, overwrite=False)
    assert bag_directory_problem(str(bag), overwrite=True) is None
    McapBagWriter(str(bag) + ".mcap", max_bag_duration=1.0, overwrite=True).close()
    (bag / "notes.txt").write_text("keep me")
    problem = bag_directory_problem(str(bag), overwrite=True)
    assert "not part of a bag (notes.txt)" in problem
    with pytest.raises(BagWriteError, match="notes.txt"):
        McapBagWriter(str(bag), max_bag_size=10_000, overwrite=True)
    assert (bag / "notes.txt").read_text() == "keep me"
    assert (
        not (tmp_path / "fresh").exists() and bag_directory_problem(str(tmp_path / "fresh")) is None
    )
    assert not (tmp_path / "fresh").exists()  # the probe leaves nothing behind

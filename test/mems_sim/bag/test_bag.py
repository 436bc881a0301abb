"""Tests of the MCAP recorder, writer, player and info tool (mems_sim.bag).

Each test has its own rclpy context and ROS domain id; discovery stays on localhost.
"""

import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mems_sim.ros import env as ros_env

ros_env.apply_defaults()

import rclpy
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu

from mems_msgs.msg import AdcFrame, NoiseModel
from mems_sim.bag import info as bag_info_mod
from mems_sim.bag.player import Player, read_messages
from mems_sim.bag.recorder import RecorderNode
from mems_sim.bag.schema import (
    SEPARATOR,
    peek_frame_index,
    peek_header_stamp_ns,
    schema_text,
    split_schema,
)
from mems_sim.bag.writer import McapBagWriter
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS
from mems_sim.ros.qos_yaml import profiles_from_yaml as qos_profiles_from_yaml
from mems_sim.ros.qos_yaml import profiles_yaml as qos_profiles_yaml

BIN = Path(sys.executable).parent


@pytest.fixture
def ctx(domain_id):
    """A fresh rclpy context on a domain of its own per test."""
    context = rclpy.context.Context()
    domain = domain_id
    rclpy.init(context=context, domain_id=domain)
    context.test_domain_id = domain
    yield context
    rclpy.shutdown(context=context)


def make_frame(index: int, num: int = 100, channels: int = 3, frame_id: str = "imu0") -> AdcFrame:
    """AdcFrame number ``index`` of a contiguous stream of ``num``-sample frames."""
    msg = AdcFrame()
    first = index * num
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(first * 1_000_000, 1_000_000_000)
    msg.header.frame_id = frame_id
    msg.first_sample_index = first
    msg.sample_rate_hz = 1000.0
    msg.num_samples = num
    msg.bits = 16
    msg.channel_names = [f"ch{c}" for c in range(channels)]
    msg.channel_units = ["rad/s"] * channels
    msg.lsb = [1e-3] * channels
    msg.offset = [0.0] * channels
    msg.full_scale = [32.767] * channels
    msg.codes = [(first + i) % 30000 - 15000 for i in range(num * channels)]
    msg.saturated_count = index % 3
    return msg


def write_adc_bag(path: str, topic: str, n: int, step_ns: int) -> list[bytes]:
    """A bag at ``path`` of ``n`` :func:`make_frame` frames on ``topic``, ``step_ns`` apart
    from now (log and publish time); their serialized payloads."""
    writer = McapBagWriter(path)
    writer.add_topic(
        topic,
        "mems_msgs/msg/AdcFrame",
        schema_text("mems_msgs/msg/AdcFrame"),
        qos_profiles_yaml([FRAME_QOS]),
    )
    payloads = [serialize_message(make_frame(k)) for k in range(n)]
    t0 = time.time_ns()
    for k, data in enumerate(payloads):
        writer.write(topic, data, t0 + k * step_ns, t0 + k * step_ns)
    writer.close()
    return payloads


def make_imu(i: int) -> Imu:
    msg = Imu()
    msg.header.stamp.sec = 100 + i
    msg.header.frame_id = "imu_link"
    msg.angular_velocity.x = 0.01 * i
    msg.linear_acceleration.z = 9.81
    msg.orientation_covariance[0] = -1.0
    return msg


def spin_until(executor, predicate, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        executor.spin_once(timeout_sec=0.02)
    return predicate()


def run_cli(args, domain: int, timeout: float = 30.0):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain))
    return subprocess.run(
        [str(BIN / args[0])] + list(args[1:]),
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# ---------------------------------------------------------------- pure helpers


def test_schema_text_format():
    text = schema_text("sensor_msgs/msg/Imu")
    lines = text.splitlines()
    seps = [i for i, line in enumerate(lines) if line.startswith("=")]
    assert seps and all(lines[i] == "=" * 80 and len(SEPARATOR) == 80 for i in seps)
    msg_lines = [lines[i + 1] for i in seps]
    assert all(m.startswith("MSG: ") for m in msg_lines)
    names = [m[5:] for m in msg_lines]
    assert names.count("std_msgs/msg/Header") == 1
    assert len(names) == len(set(names))
    assert set(names) == {
        "std_msgs/msg/Header",
        "builtin_interfaces/msg/Time",
        "geometry_msgs/msg/Quaternion",
        "geometry_msgs/msg/Vector3",
    }
    assert text.startswith(open(os.path.join(sys.prefix, "share/sensor_msgs/msg/Imu.msg")).read())
    parts = split_schema(schema_text("mems_msgs/msg/NoiseModel"))
    assert {
        "mems_msgs/msg/AxisNoiseModel",
        "mems_msgs/msg/NoiseTerm",
        "std_msgs/msg/Header",
        "builtin_interfaces/msg/Time",
    } == set(parts) - {""}


def test_peek_matches_rclpy_serialization():
    for frame_id in ("", "a", "abc", "abcd", "abcdefgh", "x" * 13):
        msg = make_frame(7, num=33, frame_id=frame_id)
        msg.first_sample_index = 2**40 + 5
        data = serialize_message(msg)
        assert peek_frame_index(data) == (2**40 + 5, 33)
        assert peek_header_stamp_ns(data) == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        nm = NoiseModel()
        nm.header.frame_id = frame_id
        nm.first_sample_index, nm.num_samples = 11, 2**33
        assert peek_frame_index(serialize_message(nm), "noise_model") == (11, 2**33)
    assert peek_frame_index(b"\x00\x01\x00\x00") is None


def test_qos_yaml_round_trip():
    text = qos_profiles_yaml([FRAME_QOS, RESULT_QOS])
    assert text.startswith("- history: keep_last\n  depth: 1000\n  reliability: reliable\n")
    assert "deadline:\n    sec: 0\n    nsec: 0" in text
    back = qos_profiles_from_yaml(text)
    assert [(q.reliability, q.durability, q.depth) for q in back] == [
        (FRAME_QOS.reliability, FRAME_QOS.durability, 1000),
        (RESULT_QOS.reliability, RESULT_QOS.durability, 10),
    ]


def test_writer_close_idempotent(tmp_path):
    path = str(tmp_path / "w.mcap")
    writer = McapBagWriter(path)
    writer.add_topic(
        "/f",
        "mems_msgs/msg/AdcFrame",
        schema_text("mems_msgs/msg/AdcFrame"),
        qos_profiles_yaml([FRAME_QOS]),
    )
    for k in (0, 1, 3):
        writer.write("/f", serialize_message(make_frame(k)), 10 + k, 10 + k)
    writer.close()
    writer.close()
    assert writer.counts() == {"/f": 3} and writer.gaps() == {"/f": 1}
    info = bag_info_mod.bag_info(path)
    assert info["topics"]["/f"]["gaps"] == 1 and info["topics"]["/f"]["missing_samples"] == 100


def test_writer_thread_order_and_error(tmp_path):
    """Messages queued faster than a small queue drains arrive complete and in order; a
    failure inside the writer thread is not lost: the next write and close() raise it,
    and the file is closed."""
    from mcap.reader import make_reader

    path = str(tmp_path / "q.mcap")
    writer = McapBagWriter(path, queue_size=2, chunk_size=4096)
    writer.add_topic(
        "/f",
        "mems_msgs/msg/AdcFrame",
        schema_text("mems_msgs/msg/AdcFrame"),
        qos_profiles_yaml([FRAME_QOS]),
    )
    for k in range(300):
        writer.write("/f", serialize_message(make_frame(k)), 10 + k, 10 + k)
    writer.close()
    with open(path, "rb") as fh:
        seq = [m.sequence for _, _, m in make_reader(fh).iter_messages(log_time_order=False)]
    assert seq == list(range(300))

    bad = McapBagWriter(str(tmp_path / "bad.mcap"))
    bad.add_topic(
        "/f",
        "mems_msgs/msg/AdcFrame",
        schema_text("mems_msgs/msg/AdcFrame"),
        qos_profiles_yaml([FRAME_QOS]),
    )

    def fail(**_):
        raise OSError("disk full")

    bad._writer.add_message = fail
    bad.write("/f", serialize_message(make_frame(0)), 1, 1)
    deadline = time.monotonic() + 5.0
    while bad._error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(OSError, match="disk full"):
        bad.write("/f", serialize_message(make_frame(1)), 2, 2)
    with pytest.raises(OSError, match="disk full"):
        bad.close()
    assert bad.closed


# ---------------------------------------------------------------- recording


def test_record_and_read_back(ctx, tmp_path):
    n_frames, n_imu = 200, 50
    frames = [make_frame(k) for k in range(n_frames)]
    imus = [make_imu(i) for i in range(n_imu)]

    # create the publishers before recording so that discovery sees them
    out = str(tmp_path / "rec.mcap")
    pub_node = rclpy.create_node("test_pub", context=ctx)
    pf = pub_node.create_publisher(AdcFrame, "/dev/adc", FRAME_QOS)
    pi = pub_node.create_publisher(Imu, "/dev/imu", 100)
    recorder = RecorderNode(out, topics=["/dev/adc", "/dev/imu"], context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(pub_node)
    executor.add_node(recorder)
    assert spin_until(
        executor,
        lambda: pf.get_subscription_count() >= 1 and pi.get_subscription_count() >= 1,
        10.0,
    )
    for k, f in enumerate(frames):
        pf.publish(f)
        if k < n_imu:
            pi.publish(imus[k])
        if k % 20 == 0:
            executor.spin_once(timeout_sec=0)
    assert spin_until(
        executor,
        lambda: (
            recorder.received("/dev/adc") == n_frames and recorder.received("/dev/imu") == n_imu
        ),
        20.0,
    ), recorder.counts()
    recorder.close()
    assert recorder.counts() == {"/dev/adc": n_frames, "/dev/imu": n_imu}
    assert recorder.gaps() == {"/dev/adc": 0}
    executor.shutdown()
    recorder.destroy_node()
    pub_node.destroy_node()

    # mcap: header profile, channels, Statistics
    with open(out, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        stats = summary.statistics
        by_topic = {c.topic: c for c in summary.channels.values()}
        assert stats.channel_message_counts[by_topic["/dev/adc"].id] == n_frames
        assert stats.channel_message_counts[by_topic["/dev/imu"].id] == n_imu
        for ch in by_topic.values():
            assert ch.message_encoding == "cdr"
            assert "reliability: reliable" in ch.metadata["offered_qos_profiles"]
            assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
            assert summary.schemas[ch.schema_id].encoding == "ros2msg"
        decoded = {"/dev/adc": [], "/dev/imu": []}
        for schema, channel, message, ros_msg in reader.iter_decoded_messages():
            decoded[channel.topic].append((message, ros_msg))
    assert [m.first_sample_index for _, m in decoded["/dev/adc"]] == [
        f.first_sample_index for f in frames
    ]
    assert [list(m.codes) for _, m in decoded["/dev/adc"]] == [list(f.codes) for f in frames]
    assert [m.angular_velocity.x for _, m in decoded["/dev/imu"]] == [
        i.angular_velocity.x for i in imus
    ]
    # log_time is the header stamp (sensor time); publish_time is when it was published
    assert decoded["/dev/imu"][3][0].log_time == 103 * 10**9
    assert abs(decoded["/dev/imu"][3][0].publish_time - time.time_ns()) < 60 * 10**9

    # the real classes: exact equality
    got = {"/dev/adc": [], "/dev/imu": []}
    for topic, type_name, log_time, msg in read_messages(out):
        got[topic].append(msg)
    assert got["/dev/adc"] == frames and got["/dev/imu"] == imus

    # rosbags (independent reader; registers the types from the schema in the file)
    from rosbags.highlevel import AnyReader

    with AnyReader([Path(out)]) as rb:
        counts = {}
        for conn, timestamp, raw in rb.messages():
            msg = rb.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == "/dev/adc":
                ref = frames[counts[conn.topic] - 1]
                assert msg.first_sample_index == ref.first_sample_index
                assert list(msg.codes) == list(ref.codes)
                assert msg.header.frame_id == "imu0"
        assert counts == {"/dev/adc": n_frames, "/dev/imu": n_imu}

    info = bag_info_mod.bag_info(out)
    adc = info["topics"]["/dev/adc"]
    assert (adc["count"], adc["gaps"], adc["total_samples"], adc["sample_rate_hz"]) == (
        n_frames,
        0,
        n_frames * 100,
        1000.0,
    )
    assert info["compression"] == ["zstd"] and info["has_summary"]
    res = run_cli(["mcap_info", out], ctx.test_domain_id)
    assert res.returncode == 0 and "/dev/adc" in res.stdout and "0 gaps" in res.stdout


def test_gap_detected(ctx, tmp_path):
    out = str(tmp_path / "gap.mcap")
    pub_node = rclpy.create_node("test_pub", context=ctx)
    pf = pub_node.create_publisher(AdcFrame, "/gap/adc", FRAME_QOS)
    recorder = RecorderNode(out, regex=r"^/gap/", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(pub_node)
    executor.add_node(recorder)
    assert spin_until(executor, lambda: pf.get_subscription_count() >= 1, 10.0)
    indices = [0, 1, 2, 4, 5, 6]  # frame 3 skipped
    for k in indices:
        pf.publish(make_frame(k))
    assert spin_until(executor, lambda: recorder.received("/gap/adc") == len(indices), 10.0)
    recorder.close()
    assert recorder.gaps() == {"/gap/adc": 1}
    assert recorder.gap_details()["/gap/adc"]["missing_samples"] == 100
    assert bag_info_mod.bag_info(out)["topics"]["/gap/adc"]["gaps"] == 1
    executor.shutdown()
    recorder.destroy_node()
    pub_node.destroy_node()


def test_transient_local_and_best_effort(ctx, tmp_path):
    """Latched results recorded although published before the recorder started; best-effort topic matched."""
    from rclpy.qos import qos_profile_sensor_data

    out = str(tmp_path / "qos.mcap")
    pub_node = rclpy.create_node("test_pub", context=ctx)
    latched = pub_node.create_publisher(NoiseModel, "/q/noise_model", RESULT_QOS)
    sensor = pub_node.create_publisher(Imu, "/q/imu", qos_profile_sensor_data)
    nm = NoiseModel()
    nm.tau_grid = "octave"
    latched.publish(nm)
    recorder = RecorderNode(out, all_topics=True, exclude=r"^/(?!q/)", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(pub_node)
    executor.add_node(recorder)
    assert spin_until(executor, lambda: sensor.get_subscription_count() >= 1, 10.0)
    assert spin_until(executor, lambda: recorder.received("/q/noise_model") == 1, 10.0)
    for i in range(5):
        sensor.publish(make_imu(i))
    spin_until(executor, lambda: recorder.received("/q/imu") == 5, 5.0)
    recorder.close()
    assert set(recorder.counts()) == {"/q/noise_model", "/q/imu"}
    assert recorder.received("/q/imu") >= 1
    info = bag_info_mod.bag_info(out)
    assert "durability: transient_local" in info["topics"]["/q/noise_model"]["offered_qos_profiles"]
    assert "reliability: best_effort" in info["topics"]["/q/imu"]["offered_qos_profiles"]
    executor.shutdown()
    recorder.destroy_node()
    pub_node.destroy_node()


def test_player_round_trip(ctx, tmp_path):
    """Write a bag, play it (in-process Player), record the replay; bytes identical."""
    src = str(tmp_path / "src.mcap")
    payloads = write_adc_bag(src, "/p/adc", 50, 2_000_000)

    out = str(tmp_path / "replay.mcap")
    node = rclpy.create_node("player", context=ctx)
    player = Player(node, src, remap={"/p/adc": "/p/replayed"})
    recorder = RecorderNode(out, topics=["/p/replayed"], context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(recorder)
    assert spin_until(executor, lambda: "/p/replayed" in recorder.recorded_topics(), 10.0)
    assert player.wait_for_subscribers(1, 10.0)
    start = time.monotonic()
    assert player.play(rate=2.0) == 50
    assert time.monotonic() - start >= 0.049 - 0.01  # 98 ms of bag time at rate 2
    assert spin_until(executor, lambda: recorder.received("/p/replayed") == 50, 10.0)
    recorder.close()
    replayed = [
        m.data for m in __import__("mems_sim.bag.player", fromlist=["x"]).iter_messages(out)
    ]
    assert replayed == payloads
    executor.shutdown()
    recorder.destroy_node()
    node.destroy_node()


# ---------------------------------------------------------------- CLI


def test_cli_bad_input(tmp_path, domain_id):
    bad = tmp_path / "bad.mcap"
    bad.write_text("this is not an mcap file\n")
    missing = tmp_path / "missing.mcap"
    for tool in ("mcap_info", "mcap_play"):
        for path, words in ((bad, "not an MCAP file"), (missing, "no such file")):
            res = run_cli([tool, str(path)], domain_id)
            assert res.returncode != 0
            err = res.stderr.strip()
            assert len(err.splitlines()) == 1 and words in err and str(path) in err, (tool, err)


def _start_recorder(out: str, domain: int, *topics):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain))
    return subprocess.Popen(
        [str(BIN / "mcap_record"), "-o", out, *topics],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _publish_until_matched(ctx, topic, timeout=15.0):
    node = rclpy.create_node("test_pub", context=ctx)
    pub = node.create_publisher(AdcFrame, topic, FRAME_QOS)
    deadline = time.monotonic() + timeout
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert pub.get_subscription_count() >= 1, "mcap_record did not subscribe"
    return node, pub


def test_sigkill_leaves_complete_chunks(ctx, tmp_path):
    out = str(tmp_path / "killed.mcap")
    proc = _start_recorder(out, ctx.test_domain_id, "/k/adc")
    try:
        node, pub = _publish_until_matched(ctx, "/k/adc")
        # 10000 samples x 3 channels x int32 = 120 kB per frame: ~9 frames per 1 MiB chunk
        n = 60
        for k in range(n):
            pub.publish(make_frame(k, num=10000))
            time.sleep(0.01)
        time.sleep(1.5)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    node.destroy_node()
    chunks = 0
    with open(out, "rb") as handle:
        try:
            for record in StreamReader(handle, emit_chunks=True).records:
                chunks += isinstance(record, Chunk)
        except Exception:  # torn tail
            pass
    assert chunks >= 3  # several complete chunks on disk despite the kill

    indices, truncated = [], False
    with open(out, "rb") as handle:
        try:
            for record in StreamReader(handle).records:
                if isinstance(record, Message):
                    indices.append(peek_frame_index(record.data)[0])
        except Exception:  # torn tail
            truncated = True
    assert len(indices) > 0
    assert indices == [k * 10000 for k in range(len(indices))]
    assert len(indices) < n or not truncated
    info = bag_info_mod.bag_info(out)
    assert not info["has_summary"] and info["topics"]["/k/adc"]["gaps"] == 0
    assert [m.first_sample_index for _, _, _, m in read_messages(out)] == indices


def test_sigint_finalises(ctx, tmp_path):
    out = str(tmp_path / "int.mcap")
    proc = _start_recorder(out, ctx.test_domain_id, "/i/adc")
    try:
        node, pub = _publish_until_matched(ctx, "/i/adc")
        n = 100
        for k in range(n):
            pub.publish(make_frame(k))
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    node.destroy_node()
    assert proc.returncode == 0, stderr
    assert "/i/adc" in stdout and "100 messages" in stdout and "0 gaps" in stdout, stdout
    with open(out, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics.message_count == n
    assert bag_info_mod.bag_info(out)["topics"]["/i/adc"]["count"] == n


def test_cli_play_round_trip(ctx, tmp_path):
    """mcap_play (subprocess, --as-fast-as-possible, --clock) -> RecorderNode: no loss, same
    bytes. The replay is flow-controlled by the recorder's progress (``--wait-for-consumer``):
    unpaced, a recorder behind by more than the 1000-frame history on a loaded machine
    loses frames, and a lossless path in a test uses the project's flow control."""
    src = str(tmp_path / "src.mcap")
    payloads = write_adc_bag(src, "/c/adc", 2000, 1_000_000)
    out = str(tmp_path / "replay.mcap")
    recorder = RecorderNode(out, topics=["/c/adc", "/clock"], progress_topic="/c/adc", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(recorder)
    env = dict(
        os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(ctx.test_domain_id)
    )
    proc = subprocess.Popen(
        [
            str(BIN / "mcap_play"),
            src,
            "--as-fast-as-possible",
            "--wait-for-consumer",
            "/mcap_recorder:/c/adc",
            "--clock",
            "100",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert spin_until(executor, lambda: recorder.received("/c/adc") == 2000, 120.0), (
            recorder.counts()
        )
        stdout, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    recorder.close()
    assert proc.returncode == 0 and "published 2000 messages" in stdout, stderr
    assert recorder.gaps() == {"/c/adc": 0}
    from mems_sim.bag.player import iter_messages

    assert [m.data for m in iter_messages(out, ["/c/adc"])] == payloads
    executor.shutdown()
    recorder.destroy_node()

"""mcap_play / mcap_info on split bags, topic remapping, pause / play-next control, closed pipes.

A split bag is a rosbag2 bag directory: ``<dir>/<dir>_0.mcap, <dir>_1.mcap`` and a
``metadata.yaml`` (``rosbag2_bagfile_information`` with ``relative_file_paths``), each
file a complete MCAP file. The tests build one from two files of consecutive data whose
log times overlap at the split (a frame topic and a sequence-numbered topic), play it
through real topics with ``mcap_play`` in a subprocess and read it back with a probe.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu

from mems_msgs.msg import AdcFrame
from mems_sim.bag.info import bag_info, losses
from mems_sim.bag.play_cli import split_ros_args
from mems_sim.bag.player import iter_messages, read_messages, recorded_topics
from mems_sim.bag.reader import BagReadError, bag_files
from mems_sim.bag.schema import schema_text
from mems_sim.bag.writer import McapBagWriter
from mems_sim.ros.qos import FRAME_QOS
from mems_sim.ros.qos_yaml import profiles_yaml as qos_profiles_yaml

BIN = Path(sys.executable).parent
FRAMES = 60  # /s/adc: 100 samples at 1 kHz each, log time k * 0.1 s
SPLIT = 30  # frames 0..29 in file 0, 30..59 in file 1
REPO = Path(__file__).resolve().parents[3]


def _frame(k: int) -> AdcFrame:
    msg = AdcFrame()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 100_000_000, 1_000_000_000)
    msg.header.frame_id = "s"
    msg.first_sample_index = k * 100
    msg.sample_rate_hz = 1000.0
    msg.num_samples = 100
    msg.bits = 16
    msg.channel_names = ["x"]
    msg.channel_units = ["V"]
    msg.lsb = [1e-3]
    msg.offset = [0.0]
    msg.full_scale = [32.767]
    msg.codes = [k] * 100
    return msg


def _imu(i: int) -> Imu:
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(i * 100_000_000 + 50_000_000, 10**9)
    msg.angular_velocity.x = float(i)
    return msg


def _end_of_stream(adc_messages: int) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp.sec = 6
    values = {"messages": adc_messages, "end_sample_index": 100 * adc_messages}
    msg.status = [
        DiagnosticStatus(
            name="/s/adc",
            message="end of stream",
            hardware_id="/s/emulator",
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
        )
    ]
    return msg


def write_split_bag(
    directory: Path,
    drop_frames=(),
    drop_imu=(),
    metadata: bool = True,
    names=None,
    end_of_stream: bool = False,
) -> list[bytes]:
    """Write the split bag; return the CDR bytes of the /s/adc frames written, in order.

    File 0 has frames 0..29 (log time up to 2.9 s) and IMU messages 0..30 (up to 3.05 s);
    file 1 starts with frame 30 at 3.0 s: the files overlap in log time at the split.
    """
    directory.mkdir(parents=True, exist_ok=True)
    names = names or [f"{directory.name}_0.mcap", f"{directory.name}_1.mcap"]
    written = []
    for part, name in enumerate(names):
        writer = McapBagWriter(str(directory / name))
        writer.add_topic(
            "/s/adc",
            "mems_msgs/msg/AdcFrame",
            schema_text("mems_msgs/msg/AdcFrame"),
            qos_profiles_yaml([FRAME_QOS]),
        )
        writer.add_topic(
            "/s/imu",
            "sensor_msgs/msg/Imu",
            schema_text("sensor_msgs/msg/Imu"),
            qos_profiles_yaml([FRAME_QOS]),
        )
        items = []
        for k in range(FRAMES):
            if (k >= SPLIT) == bool(part) and k not in drop_frames:
                items.append((k * 100_000_000, "/s/adc", serialize_message(_frame(k)), k + 1))
        for i in range(FRAMES):
            if (i > SPLIT) == bool(part) and i not in drop_imu:
                items.append(
                    (i * 100_000_000 + 50_000_000, "/s/imu", serialize_message(_imu(i)), i + 1)
                )
        # write order = receive order: each file's messages in time order
        for t, topic, data, seq in sorted(items, key=lambda x: x[0]):
            writer.write(topic, data, t, t, sequence=seq)
            if topic == "/s/adc":
                written.append(data)
        if end_of_stream and part == len(names) - 1:
            writer.add_topic(
                "/s/end_of_stream",
                "diagnostic_msgs/msg/DiagnosticArray",
                schema_text("diagnostic_msgs/msg/DiagnosticArray"),
                qos_profiles_yaml([FRAME_QOS]),
            )
            writer.write(
                "/s/end_of_stream",
                serialize_message(_end_of_stream(FRAMES)),
                6 * 10**9,
                6 * 10**9,
                1,
            )
        writer.close()
    if metadata:
        lines = ["rosbag2_bagfile_information:", "  version: 9", "  storage_identifier: mcap"]
        lines += ["  relative_file_paths:"] + [f"  - {n}" for n in names]
        (directory / "metadata.yaml").write_text("\n".join(lines) + "\n")
    return written


# ---------------------------------------------------------------- reading (no graph)


def test_split_bag_reads_as_one_timeline(tmp_path):
    bag = tmp_path / "run"
    payloads = write_split_bag(bag)
    assert [Path(f).name for f in bag_files(str(bag))] == ["run_0.mcap", "run_1.mcap"]
    items = list(iter_messages(str(bag)))
    times = [m.log_time_ns for m in items]
    assert len(items) == 2 * FRAMES and times == sorted(times)  # merged across the overlap
    assert [m.data for m in items if m.topic == "/s/adc"] == payloads
    assert set(recorded_topics(str(bag))) == {"/s/adc", "/s/imu"}
    later = [m.log_time_ns for m in iter_messages(str(bag), ["/s/adc"], start_offset_s=3.0)]
    assert later[0] == 3 * 10**9 and len(later) == FRAMES - SPLIT
    decoded = [msg for _, _, _, msg in read_messages(str(bag), ["/s/adc"])]
    assert [m.first_sample_index for m in decoded] == [100 * k for k in range(FRAMES)]

    info = bag_info(str(bag))
    adc, imu = info["topics"]["/s/adc"], info["topics"]["/s/imu"]
    assert info["message_count"] == 2 * FRAMES and len(info["files"]) == 2
    assert (adc["count"], adc["frames"], adc["gaps"], adc["total_samples"]) == (60, 60, 0, 6000)
    assert (imu["count"], imu["sequence_gaps"]) == (60, 0)
    assert info["start_ns"] == 0 and info["duration_s"] == pytest.approx(6.0)
    assert losses(info) == []
    # a single file of the bag still reads exactly as a file
    assert bag_info(str(bag / "run_1.mcap"))["topics"]["/s/adc"]["count"] == FRAMES - SPLIT


def test_split_bag_loss_is_counted_across_files(tmp_path):
    # the first frame and the first IMU message of file 1 are lost: gaps at the split
    bag = tmp_path / "lossy"
    write_split_bag(bag, drop_frames=(SPLIT,), drop_imu=(SPLIT + 1,))
    info = bag_info(str(bag))
    adc, imu = info["topics"]["/s/adc"], info["topics"]["/s/imu"]
    assert (adc["gaps"], adc["missing_samples"]) == (1, 100)
    assert (imu["sequence_gaps"], imu["missing_messages"]) == (1, 1)
    # the end-of-stream record in the last file is compared with the whole bag
    whole = tmp_path / "whole"
    write_split_bag(whole, end_of_stream=True)
    assert bag_info(str(whole))["topics"]["/s/adc"]["tail"]["messages"] == 0
    assert losses(bag_info(str(whole))) == []
    cut = tmp_path / "cut"
    write_split_bag(cut, drop_frames=(58, 59), end_of_stream=True)
    tail = bag_info(str(cut))["topics"]["/s/adc"]["tail"]
    assert (tail["messages"], tail["samples"], tail["from_index"]) == (2, 200, 5800)


def test_bag_directory_fallbacks_and_errors(tmp_path, subprocess_env):
    # no metadata.yaml: the *.mcap files sorted naturally (x_2 before x_10)
    bag = tmp_path / "nat"
    payloads = write_split_bag(bag, metadata=False, names=["nat_2.mcap", "nat_10.mcap"])
    assert [Path(f).name for f in bag_files(str(bag))] == ["nat_2.mcap", "nat_10.mcap"]
    assert [m.data for m in iter_messages(str(bag), ["/s/adc"])] == payloads
    # metadata.yaml's order wins over names
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  relative_file_paths: [nat_10.mcap, nat_2.mcap]\n"
    )
    assert [Path(f).name for f in bag_files(str(bag))] == ["nat_10.mcap", "nat_2.mcap"]
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  relative_file_paths: [../../etc/passwd]\n"
    )
    with pytest.raises(BagReadError, match="outside the bag directory"):
        bag_files(str(bag))
    # a directory without bag files: one line, exit status 2, for both tools
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("x")
    for tool in ("mcap_info", "mcap_play"):
        res = subprocess.run(
            [str(BIN / tool), str(empty)],
            env=subprocess_env,
            capture_output=True,
            text=True,
            timeout=30,
        )
        err = res.stderr.strip()
        assert res.returncode == 2 and len(err.splitlines()) == 1, (tool, err)
        assert "without bag files" in err and str(empty) in err


def test_split_ros_args():
    own, ros = split_ros_args(["b", "--remap", "/a:=/b", "--ros-args", "-r", "/c:=/d", "--", "-l"])
    assert own == ["b", "--remap", "/a:=/b", "-l"]
    assert ros == ["--ros-args", "-r", "/c:=/d"]


# ---------------------------------------------------------------- closed pipe


def test_info_closed_pipe_exits_quietly(tmp_path, subprocess_env):
    bag = str(REPO / "bags" / "imu.mcap")
    # a reader that is gone before anything is written: EPIPE on the first write
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        res = subprocess.run(
            [str(BIN / "mcap_info"), bag],
            env=subprocess_env,
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
        )
    finally:
        os.close(write_end)
    assert res.returncode == 128 + signal.SIGPIPE and res.stderr == "", res.stderr
    # the shell pipeline users write: the first line, no traceback
    res = subprocess.run(
        ["bash", "-c", 'set -o pipefail; "$0" "$1" | head -1', str(BIN / "mcap_info"), bag],
        env=subprocess_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.stdout.startswith("File:") and len(res.stdout.splitlines()) == 1
    assert res.returncode in (0, 128 + signal.SIGPIPE) and "Traceback" not in res.stderr


# ---------------------------------------------------------------- through real topics


def _play(bag: Path, env: dict, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / "mcap_play"), str(bag), "--wait-for-subscribers", "1", *extra],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(proc: subprocess.Popen, timeout: float = 20.0) -> tuple[str, str]:
    try:
        return proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def _spin_until(executor, predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return predicate()


@pytest.mark.parametrize("how", ["--remap", "--ros-args"])
def test_remap_through_real_topics(how, tmp_path, graph, subprocess_env):
    """``--remap FROM:=TO`` (paced), and ROS's ``--ros-args -r FROM:=TO`` with lossless
    flow control into a consumer of the remapped topic (``--wait-for-consumer``)."""
    import rclpy
    from std_msgs.msg import UInt64

    ctx, executor, probe = graph
    bag = tmp_path / "rm"
    write_split_bag(bag)
    got: list[int] = []
    imu: list[float] = []
    if how == "--remap":
        probe.create_subscription(
            AdcFrame, "/r/adc", lambda m: got.append(m.first_sample_index), FRAME_QOS
        )
        probe.create_subscription(Imu, "/r/imu", lambda m: imu.append(m.angular_velocity.x), 100)
        # the bag after the remaps (argparse would take it as one more remap)
        args = ["--remap", "/s/adc:=/r/adc", "/s/imu:=/r/imu"]
        proc = subprocess.Popen(
            [str(BIN / "mcap_play"), *args, str(bag), "--wait-for-subscribers", "1", "-r", "20"],
            env=subprocess_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
    else:
        # a consumer that reports its progress (one past the last sample it processed)
        consumer = rclpy.create_node("consumer", namespace="/c", context=ctx)
        progress = consumer.create_publisher(UInt64, "~/progress", FRAME_QOS)
        diagnostics = consumer.create_publisher(DiagnosticArray, "/diagnostics", 10)

        def on_frame(msg):
            got.append(msg.first_sample_index)
            progress.publish(UInt64(data=msg.first_sample_index + msg.num_samples))

        def on_timer():  # its own gap count, as the estimators report it
            status = DiagnosticStatus(name="consumer", hardware_id="/c/consumer")
            status.values = [KeyValue(key="gaps", value="0")]
            diagnostics.publish(DiagnosticArray(status=[status]))

        consumer.create_subscription(AdcFrame, "/r/adc", on_frame, FRAME_QOS)
        consumer.create_timer(0.2, on_timer)
        executor.add_node(consumer)
        proc = subprocess.Popen(
            [str(BIN / "mcap_play"), str(bag), "--topics", "/s/adc", "--as-fast-as-possible"]
            + ["--wait-for-consumer", "/c/consumer", "--credit", "3f"]
            + ["--ros-args", "-r", "/s/adc:=/r/adc"],  # ROS's remapping rules
            env=subprocess_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
    try:
        want_imu = FRAMES if how == "--remap" else 0
        assert _spin_until(executor, lambda: len(got) == FRAMES and len(imu) == want_imu, 30.0), (
            len(got),
            len(imu),
        )
        stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "deprecated" not in stderr, stderr  # rcl never saw a bare FROM:=TO
    assert got == [100 * k for k in range(FRAMES)]  # one timeline across both files
    if how == "--remap":
        assert imu == [float(i) for i in range(FRAMES)]
    else:
        assert f"/s/adc: published {FRAMES}, acknowledged {FRAMES}" in stdout, stdout
        assert "loss: none" in stdout, stdout


def test_start_paused_play_next_resume(tmp_path, graph, subprocess_env):
    from std_srvs.srv import Trigger

    ctx, executor, probe = graph
    bag = tmp_path / "pz"
    write_split_bag(bag)
    got: list[int] = []
    clocks: list[int] = []
    probe.create_subscription(
        AdcFrame, "/s/adc", lambda m: got.append(m.first_sample_index), FRAME_QOS
    )
    probe.create_subscription(
        Clock, "/clock", lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), 10
    )
    proc = _play(
        bag, subprocess_env, "--topics", "/s/adc", "--start-paused", "--clock", "50", "-r", "10"
    )

    # one client per service for the whole test: a reply is lost when it is sent before
    # the client's reply reader is matched (wait_for_service sees the request side only),
    # so every client is made before the first call and the first call, an idempotent
    # query, is repeated until a reply arrives
    clients = {
        name: probe.create_client(Trigger, f"/mcap_player/{name}")
        for name in ("is_paused", "play_next", "resume")
    }

    def call(name: str, attempts: int = 1):
        client = clients[name]
        assert client.wait_for_service(timeout_sec=15.0), name
        for _ in range(attempts):
            future = client.call_async(Trigger.Request())
            if _spin_until(executor, future.done, 10.0 / attempts):
                return future.result()
            client.remove_pending_request(future)
        raise AssertionError(f"no reply from {name} in 10 s")

    try:
        assert call("is_paused", attempts=4).success
        assert _spin_until(executor, lambda: len(clocks) >= 5, 10.0)
        _spin_until(executor, lambda: False, 1.0)
        assert got == []  # paused: nothing published
        assert len(set(clocks)) == 1 and clocks[0] == 0  # the clock holds at the bag's start
        reply = call("play_next")
        assert reply.success, reply.message
        _spin_until(executor, lambda: False, 1.0)
        assert got == [0]  # exactly the next message
        assert call("is_paused").success
        assert call("resume").success and not call("is_paused").success
        assert not call("play_next").success  # only while paused
        assert _spin_until(executor, lambda: len(got) == FRAMES, 30.0), len(got)
        stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert got == [100 * k for k in range(FRAMES)]
    assert f"published {FRAMES} messages" in stdout
    last = (FRAMES - 1) * 100_000_000  # the last message's log time, published at the end
    assert _spin_until(executor, lambda: clocks[-1] >= last, 5.0), clocks[-5:]
    assert clocks == sorted(clocks)  # /clock never goes back

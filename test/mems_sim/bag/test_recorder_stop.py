"""``mcap_record`` stopped the way ``ros2 launch`` and ``docker stop`` stop processes.

A separate publisher process sends AdcFrames continuously (500 Hz) while the
recorder is stopped by SIGINT, by SIGTERM, or by the escalation "SIGINT, SIGTERM
after 5 s, SIGKILL after 10 s" (and by two SIGINTs 50 ms apart). In every case the recorder must exit by itself,
with status 0, within 2 s of the first signal (so the later signals are never
sent), and leave a finalised file (Summary with Statistics, footer) that
rosbags' AnyReader and mcap + mcap-ros2-support read back completely.
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest
from bagtool_helpers import BIN, Collector, start_publisher, stop_process

TOPIC = "/live/adc"

SEQUENCES = {
    "sigint": [(0.0, signal.SIGINT)],
    "sigterm": [(0.0, signal.SIGTERM)],
    "sigint_sigterm_sigkill": [(0.0, signal.SIGINT), (5.0, signal.SIGTERM), (10.0, signal.SIGKILL)],
    # an impatient user: the second signal cuts the grace window and the drain short
    "sigint_twice": [(0.0, signal.SIGINT), (0.05, signal.SIGINT)],
}


def _stop(proc, sequence) -> tuple[float, list[str]]:
    """Send the signals of ``sequence`` (offsets from the first) while the process lives;
    return (seconds from the first signal to exit, names of the signals sent)."""
    sent = []
    t0 = time.monotonic()
    pending = list(sequence)
    while True:
        now = time.monotonic() - t0
        while pending and pending[0][0] <= now:
            _, sig = pending.pop(0)
            if proc.poll() is None:
                proc.send_signal(sig)
                sent.append(sig.name)
        if proc.poll() is not None:
            return time.monotonic() - t0, sent
        if now > 20.0:
            proc.kill()
            proc.wait()
            return time.monotonic() - t0, sent
        time.sleep(0.002)


def _read_back(out: Path) -> tuple[int, list[int]]:
    """Message count from the Summary's Statistics; first_sample_index of every message,
    read by mcap + mcap-ros2-support and checked against rosbags' AnyReader."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    with open(out, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "no Summary"
        assert summary.chunk_indexes, "no chunk indexes in the Summary"
        indices = [
            msg.first_sample_index
            for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=False)
            if channel.topic == TOPIC
        ]
        count = summary.statistics.message_count
    with AnyReader([out]) as rb:
        rb_indices = [
            rb.deserialize(raw, conn.msgtype).first_sample_index
            for conn, _, raw in rb.messages()
            if conn.topic == TOPIC
        ]
    assert rb_indices == indices
    return count, indices


@pytest.mark.parametrize("name", list(SEQUENCES))
def test_recorder_finalises_on_stop_signals(name, tmp_path, subprocess_env, capsys):
    out = tmp_path / f"{name}.mcap"
    publisher = start_publisher(subprocess_env, TOPIC, period_s=0.002)
    recorder = subprocess.Popen(
        [str(BIN / "mcap_record"), "-o", str(out), TOPIC, "--chunk-size", "65536"],
        env=subprocess_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    stdout, stderr = Collector(recorder.stdout), Collector(recorder.stderr)
    try:
        assert stderr.wait_for(f"recording {TOPIC}", 20.0), stderr.text(0.1)
        time.sleep(1.0)  # data flowing: several chunks written, the writer queue busy
        assert recorder.poll() is None, stderr.text(0.1)
        elapsed, sent = _stop(recorder, SEQUENCES[name])
    finally:
        stop_process(publisher)
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    text_out, text_err = stdout.text(), stderr.text()
    with capsys.disabled():
        print(
            f"\n[{name}] signals sent: {', '.join(sent)}; first signal to exit: "
            f"{elapsed:.3f} s; recorder says: "
            + " ".join(line for line in text_out.splitlines() if "finalised" in line)
        )
    assert recorder.returncode == 0, (recorder.returncode, text_err)
    if name == "sigint_twice":
        assert sent == ["SIGINT", "SIGINT"] and elapsed < 1.0, (sent, elapsed)
    else:
        assert sent == [SEQUENCES[name][0][1].name], sent  # exited before any later signal
    assert elapsed < 2.0, elapsed
    assert "Traceback" not in text_err, text_err

    count, indices = _read_back(out)
    assert count == len(indices) > 100, (count, len(indices))
    assert f"{TOPIC} [mems_msgs/msg/AdcFrame]: {count} messages" in text_out, text_out
    # what arrived was kept in order: a contiguous stream of frame indices
    # (the publisher started before the recorder subscribed, so the stream starts later)
    assert indices == list(range(indices[0], indices[0] + 100 * count, 100))


def test_writer_close_deadline_drops_and_counts(tmp_path):
    """A writer thread that lags behind: close(timeout_s) returns in bounded time with a
    finalised file; what was still queued is dropped and counted, never lost silently."""
    from mcap.reader import make_reader

    from mems_sim.bag.schema import schema_text
    from mems_sim.bag.writer import McapBagWriter
    from mems_sim.ros.qos_yaml import profiles_yaml as qos_profiles_yaml

    path = tmp_path / "slow.mcap"
    writer = McapBagWriter(str(path), queue_size=1000)
    writer.add_topic(
        "/slow", "std_msgs/msg/String", schema_text("std_msgs/msg/String"), qos_profiles_yaml([])
    )
    real_add = writer._writer.add_message

    def slow_add(**kw):
        time.sleep(0.02)
        real_add(**kw)

    writer._writer.add_message = slow_add
    payload = b"\x00\x01\x00\x00\x06\x00\x00\x00hello\x00"
    for k in range(200):  # about 4 s of work for the writer thread
        writer.write("/slow", payload, 1000 + k, 1000 + k)
    t0 = time.monotonic()
    writer.close(timeout_s=0.3)
    elapsed = time.monotonic() - t0
    written, dropped = writer.counts()["/slow"], writer.dropped().get("/slow", 0)
    assert elapsed < 0.6, elapsed
    assert written + dropped == 200 and 0 < written < 200 and dropped > 0, (written, dropped)
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary.statistics.message_count == written

    # a second stop request (abort) ends the drain at once, whatever the timeout
    writer = McapBagWriter(str(tmp_path / "abort.mcap"), queue_size=1000)
    writer.add_topic(
        "/slow", "std_msgs/msg/String", schema_text("std_msgs/msg/String"), qos_profiles_yaml([])
    )
    real_add = writer._writer.add_message
    writer._writer.add_message = slow_add
    for k in range(200):
        writer.write("/slow", payload, 1000 + k, 1000 + k)
    t0 = time.monotonic()
    writer.close(timeout_s=60.0, abort=lambda: time.monotonic() - t0 > 0.1)
    assert time.monotonic() - t0 < 0.5
    assert writer.counts()["/slow"] + writer.dropped()["/slow"] == 200

"""Recorder throughput: sustained msg/s and MB/s with zero loss.

A publisher in this process sends SignalFrames (1000 float64 samples, ~8 kB)
at a fixed rate for a few seconds per stage to ``mcap_record`` running as a
separate process (as in a real graph); after each stage the recorder is
stopped with SIGINT and the file's Statistics are compared with the number
sent. Reported: per stage the offered rate, msg/s and MB/s written, and lost.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import numpy as np
import rclpy
from mcap.reader import make_reader
from process_tools import keep_all_publisher
from rclpy.context import Context
from rclpy.duration import Duration

from mems_msgs.msg import SignalFrame
from mems_sim.ros.frames import make_signal_frame

TOPIC = "/bench/frames"
SAMPLES = 1000


def stage(rate_hz: float, seconds: float, out: Path, domain: int) -> dict:
    """Publish at ``rate_hz`` for ``seconds`` to a recorder process; return counts."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    topic = f"{TOPIC}_{os.getpid()}_{int(rate_hz)}"  # no cross-talk with any other recorder
    rec = subprocess.Popen(
        [str(Path(sys.executable).parent / "mcap_record"), "-o", str(out), topic],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        return _publish(rec, topic, rate_hz, seconds, out, domain)
    finally:
        if rec.poll() is None:
            rec.kill()


def _publish(rec, topic: str, rate_hz: float, seconds: float, out: Path, domain: int) -> dict:
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("bench_pub", context=ctx)
    pub = keep_all_publisher(node, SignalFrame, topic)
    data = np.random.default_rng(0).normal(size=(SAMPLES, 1))
    sent, refused, t0 = 0, 0, time.monotonic()
    while time.monotonic() - t0 < seconds:
        due = int((time.monotonic() - t0) * rate_hz)
        while sent < due:
            try:
                pub.publish(
                    make_signal_frame(
                        data, sent * SAMPLES, 1e6, channel_names=["x"], channel_units=["V"]
                    )
                )
            except Exception:
                refused += 1
                time.sleep(0.001)
                continue
            sent += 1
            if time.monotonic() - t0 >= seconds:
                break
        time.sleep(0.0005)
    # reliable delivery: wait until the recorder acknowledged every frame, then stop it
    acked = pub.wait_for_all_acked(Duration(seconds=60))
    elapsed = time.monotonic() - t0
    rec.send_signal(signal.SIGINT)
    rec.wait(timeout=60)
    node.destroy_node()
    rclpy.shutdown(context=ctx)
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    got = sum(summary.statistics.channel_message_counts.values())
    size = 8 * SAMPLES + 100
    return dict(
        offered=rate_hz,
        acked=acked,
        sent=sent,
        recorded=got,
        lost=sent - got,
        refused=refused,
        msg_s=got / elapsed,
        mb_s=got * size / elapsed / 1e6,
    )
    # msg/s and MB/s: recorded messages over the time from the first publish to the last ack


def main() -> None:
    """Run the stages and print one line each."""
    domain = int(os.environ.get("ROS_DOMAIN_ID", "62"))
    print(
        f"recorder throughput: {TOPIC} SignalFrame of {SAMPLES} float64 samples, "
        "mcap_record in a separate process, 3 s per stage"
    )
    lossless = None
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (1000, 2000, 4000, 8000, 16000):
            r = stage(rate, 3.0, Path(tmp) / f"rec-{rate}.mcap", domain)
            if r["lost"] == 0:
                lossless = r
            print(
                f"  offered {r['offered']:5.0f} msg/s: recorded {r['msg_s']:7.0f} msg/s, "
                f"{r['mb_s']:6.1f} MB/s, sent {r['sent']}, recorded {r['recorded']}, "
                f"lost {r['lost']}"
                + (
                    f", publisher blocked {r['refused']} times by the recorder's back-pressure"
                    if r["refused"]
                    else ""
                )
            )

    if lossless is None:
        print("  zero-loss limit: below the lowest offered rate (1000 msg/s)")
    else:
        print(
            f"  zero-loss limit: at least {lossless['msg_s']:.0f} msg/s, "
            f"{lossless['mb_s']:.1f} MB/s (the highest stage that lost nothing)"
        )


if __name__ == "__main__":
    main()

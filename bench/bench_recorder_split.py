"""Cost of splitting a recording: ``mcap_record`` throughput split vs one file, in one run.

A publisher in this process sends SignalFrames (1000 float64 samples, ~8 kB) with a
KEEP_ALL reliable QoS (a lagging recorder pushes back instead of losing frames) to
``mcap_record`` in a separate process, at a fixed offered rate for a few seconds per
stage; the same stages run with one output file, split by size (``-b``) and split by log
time (``-d``). The frames cycle through 256 distinct random blocks (2 MB, more than a
chunk), so compression cannot shrink them to nothing. After the last frame is
acknowledged the recorder is stopped only once its output stopped growing for 1 s, so
the figure is the whole pipeline's rate (middleware, executor, writer thread, disk), and
"lost" compares the files' Statistics with what was sent. Reported per stage: msg/s
recorded, files written and messages lost, and
per configuration the ratio of its recorded msg/s to the one-file recording's at the same
offered rate (1.00: splitting costs nothing).
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
import yaml
from mcap.reader import make_reader
from process_tools import keep_all_publisher
from rclpy.context import Context
from rclpy.duration import Duration

from mems_msgs.msg import SignalFrame
from mems_sim.ros.frames import make_signal_frame

SAMPLES = 1000
SECONDS = 1.5
RATES = (3000, 12000)
BLOCKS = 256
# frames of 1000 samples at 1 MHz: 1 ms of log (sensor) time each
CONFIGS = {
    "one file": [],
    "split -b 4M": ["-b", "4000000"],
    "split -d 1": ["-d", "1"],
}


def _count(out: Path) -> tuple[int, int]:
    """(messages, files) of a recording: one MCAP file or a bag directory."""
    if out.is_dir():
        info = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        files = [out / name for name in info["relative_file_paths"]]
    else:
        files = [out]
    total = 0
    for path in files:
        with open(path, "rb") as handle:
            total += make_reader(handle).get_summary().statistics.message_count
    return total, len(files)


def _size(out: Path) -> int:
    """Bytes written so far (chunks go to the OS as they complete)."""
    try:
        if out.is_dir():
            return sum(p.stat().st_size for p in out.iterdir())
        return out.stat().st_size
    except OSError:
        return 0


def stage(rate_hz: float, extra: list[str], out: Path, domain: int, tag: str) -> dict:
    """Publish at ``rate_hz`` for SECONDS to a recorder process; return its figures."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    topic = f"/bench/split_{os.getpid()}_{tag}"
    rec = subprocess.Popen(
        [str(Path(sys.executable).parent / "mcap_record"), "-o", str(out), topic, *extra],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = rclpy.create_node("bench_split_pub", context=ctx)
        pub = keep_all_publisher(node, SignalFrame, topic)
        blocks = np.random.default_rng(0).normal(size=(BLOCKS, SAMPLES, 1))
        sent, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < SECONDS:
            due = min(int((time.monotonic() - t0) * rate_hz), int(SECONDS * rate_hz))
            while sent < due:
                try:
                    pub.publish(
                        make_signal_frame(
                            blocks[sent % BLOCKS],
                            sent * SAMPLES,
                            1e6,
                            channel_names=["x"],
                            channel_units=["V"],
                        )
                    )
                except Exception:  # the recorder's back-pressure: try again
                    time.sleep(0.001)
                    continue
                sent += 1
            time.sleep(0.0005)
        pub.wait_for_all_acked(Duration(seconds=60))
        # the recorder's reader history may still hold frames: wait until the output stops
        # growing (1 s), then stop it; the rate counts up to the last growth
        size, changed = _size(out), time.monotonic()
        while time.monotonic() - changed < 1.0 and time.monotonic() - t0 < 60:
            time.sleep(0.05)
            now_size = _size(out)
            if now_size != size:
                size, changed = now_size, time.monotonic()
        elapsed = changed - t0
        rec.send_signal(signal.SIGINT)
        rec.wait(timeout=60)
        node.destroy_node()
    finally:
        if rec.poll() is None:
            rec.kill()
        rclpy.shutdown(context=ctx)
    got, files = _count(out)
    return dict(sent=sent, recorded=got, lost=sent - got, files=files, msg_s=got / elapsed)


def main() -> None:
    """Run every configuration at every offered rate; print one line per stage and the ratios."""
    domain = int(os.environ.get("ROS_DOMAIN_ID", "62"))
    print(
        f"recorder split overhead: SignalFrame of {SAMPLES} float64 samples, mcap_record in a "
        f"separate process, {SECONDS:g} s per stage"
    )
    results: dict[tuple[str, int], dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rate in RATES:
            for i, (name, extra) in enumerate(CONFIGS.items()):
                out = Path(tmp) / f"rec_{rate}_{i}" if extra else Path(tmp) / f"rec_{rate}.mcap"
                r = stage(rate, extra, out, domain, f"{rate}_{i}")
                results[name, rate] = r
                print(
                    f"  offered {rate:5d} msg/s, {name:12s}: recorded {r['msg_s']:7.0f} msg/s, "
                    f"{r['files']:3d} files, sent {r['sent']}, lost {r['lost']}"
                )
    for name in list(CONFIGS)[1:]:
        ratios = ", ".join(
            f"{results[name, rate]['msg_s'] / results['one file', rate]['msg_s']:.2f} at {rate}"
            for rate in RATES
        )
        lost = sum(results[name, rate]["lost"] for rate in RATES)
        print(f"  {name}: throughput ratio to one file {ratios} msg/s offered; lost {lost}")


if __name__ == "__main__":
    main()

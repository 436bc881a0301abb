"""``identify_noise`` on duplicated and corrupt bags (generated here, in-process runs).

* an MCAP whose chunks are all stored twice (bags/imu.mcap rewritten): the same JSON as
  the bag stored once, and the duplicates reported (600 frames, head line and JSON);
* ROS 1 and sqlite3 bags of sensor_msgs/Imu written twice by rosbags: the same model as
  the bags written once (num_samples and every interval), duplicates reported;
* 36 corrupt ROS 1 / sqlite3 bags (fixed seeds): exit 0, or exit 2 with one line on
  stderr; no exception leaves ``main``.
"""

from __future__ import annotations

import json
from pathlib import Path

from bag_builders import fuzz_ros1, fuzz_sqlite, imu_bag, rechunked_mcap
from identify_noise_helpers import IMU_BAG, run_identify_noise

BAG = IMU_BAG


_run = run_identify_noise


def _model(path: Path) -> tuple[dict, str]:
    """The JSON model and the head line of a successful ``identify_noise --json`` run."""
    code, out, err = _run([path, "--json"])
    assert code == 0, err
    return json.loads(out), err.splitlines()[0]


def test_mcap_with_every_chunk_stored_twice(tmp_path):
    """Same chunks, stored once and twice: identical models (every value and interval), the
    600 duplicated /imu/adc frames reported in the head line and the JSON."""
    once, once_head = _model(rechunked_mcap(BAG, tmp_path / "once.mcap"))
    twice, twice_head = _model(rechunked_mcap(BAG, tmp_path / "twice.mcap", copies=2))
    assert once.pop("duplicates") == 0 and twice.pop("duplicates") == 600
    assert once == twice
    assert twice_head.endswith(", 600 duplicate messages (used once)"), twice_head
    assert "duplicate" not in once_head


def test_third_party_bags_with_duplicated_messages(tmp_path):
    """sensor_msgs/Imu in a ROS 1 bag and a sqlite3 bag, every message written twice by
    rosbags: the model of the bag written once (400 samples, same intervals), 400
    duplicates reported."""
    for kind in ("ros1", "sqlite3"):
        suffix = ".bag" if kind == "ros1" else ""
        once, _ = _model(imu_bag(tmp_path / f"once_{kind}{suffix}", kind))
        twice, head = _model(imu_bag(tmp_path / f"twice_{kind}{suffix}", kind, repeat=2))
        assert twice.pop("duplicates") == 400 and once.pop("duplicates") == 0, kind
        assert once == twice and twice["num_samples"] == 400, kind
        assert "400 duplicate messages (used once)" in head, head


def test_corrupt_bags_exit_0_or_one_line(tmp_path):
    """36 fuzzed bags (6 per format and compression, seeds 100..105): exit 0 with a model,
    or exit 2 with one line ``identify_noise: error: ...``; nothing raises."""
    sources = {
        f"{kind}_{c}": imu_bag(
            tmp_path / (f"{kind}_{c}" + (".bag" if kind == "ros1" else "")),
            kind,
            n=200,
            compression=None if c == "plain" else c,
        )
        for kind, c in (
            ("ros1", "plain"),
            ("ros1", "bz2"),
            ("ros1", "lz4"),
            ("sqlite3", "plain"),
            ("sqlite3", "message"),
            ("sqlite3", "file"),
        )
    }
    codes = []
    for name, src in sources.items():
        for seed in range(100, 106):
            fuzz = fuzz_ros1 if name.startswith("ros1") else fuzz_sqlite
            path = fuzz(src, tmp_path / f"{seed}_{src.name}", seed)
            code, out, err = _run([path])
            lines = err.splitlines()
            if code == 2:
                assert len(lines) == 1 and lines[0].startswith("identify_noise: error: "), err
            else:
                assert code == 0 and "samples" in out, (name, seed, code, err)
            codes.append(code)
    assert codes.count(2) >= 12

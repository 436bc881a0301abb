"""Duplicated messages (identical topic, log time and bytes) in ``mcap_info``, and the bounded
window of :class:`mems_sim.stream_index.DuplicateFilter` that finds them.

bags/imu.mcap is rewritten by mcap's Writer in chunks of 50 messages, once and with every
chunk stored twice (Statistics and chunk indexes count both copies): ``bag_info`` of the
second is that of the first (counts, samples, gaps, times) plus the duplicates per topic,
shown on the topic lines and in one warning line; exit status 0.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from bag_builders import rechunked_mcap

from mems_sim.bag.info import bag_info, format_info, main
from mems_sim.stream_index import DuplicateFilter

BAG = Path(__file__).resolve().parents[3] / "bags" / "imu.mcap"
EXPECTED = {"/imu/adc": 600, "/imu/noise_model": 6, "/imu/truth": 600}


def _comparable(info: dict) -> dict:
    out = {k: v for k, v in info.items() if k not in ("path", "files", "file_size")}
    out["topics"] = {
        t: {k: v for k, v in e.items() if k != "duplicates"} for t, e in info["topics"].items()
    }
    return out


def test_mcap_info_of_a_bag_with_every_chunk_stored_twice(tmp_path):
    once = rechunked_mcap(BAG, tmp_path / "once.mcap")
    twice = rechunked_mcap(BAG, tmp_path / "twice.mcap", copies=2)
    a, b = bag_info(str(once)), bag_info(str(twice))
    assert b["file_size"] > 1.8 * a["file_size"]  # every chunk really is there twice
    assert _comparable(a) == _comparable(b)
    assert b["message_count"] == 1206 and b["topics"]["/imu/adc"]["gaps"] == 0
    assert {t: e["duplicates"] for t, e in a["topics"].items()} == dict.fromkeys(EXPECTED, 0)
    assert {t: e["duplicates"] for t, e in b["topics"].items()} == EXPECTED
    assert "600 msgs, 60000 samples @ 100 Hz, 0 gaps (0 samples missing), 600 duplicates" in (
        format_info(b)
    )
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        assert main([str(twice)]) == 0
    assert err.getvalue().splitlines() == [
        f"mcap_info: warning: {twice}: duplicated messages (identical topic, log time and "
        "bytes; counted once): /imu/adc 600, /imu/noise_model 6, /imu/truth 600"
    ]


def test_duplicate_filter_window():
    """A repeat within the window is a duplicate (counted per topic), other topics, times,
    bytes or sequence numbers are not; past the window a repeat is no longer seen, and the keys kept never
    exceed the window."""
    dups = DuplicateFilter(window=3)
    assert not dups.seen("/a", 1, b"x")
    assert dups.seen("/a", 1, b"x")
    assert not any(dups.seen(*m) for m in (("/b", 1, b"x"), ("/a", 2, b"x"), ("/a", 1, b"y")))
    assert dups.counts == {"/a": 1} and dups.total == 1
    assert not dups.seen("/a", 1, b"x")  # three other keys since: out of the window
    assert len(dups._keys) == len(dups._order) == 3
    assert not dups.seen("/a", 2, b"x", sequence=7)  # numbered apart: another publication
    assert dups.seen("/a", 2, b"x", sequence=7)

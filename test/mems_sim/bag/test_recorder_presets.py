"""rosbag2's MCAP storage presets in the recorder (``mcap_record --storage-preset-profile``).

* every preset writes a file that mcap (+ mcap-ros2-support) and rosbags read back, with
  the messages written, byte for byte and decoded field for field;
* the preset's chunk compression, CRCs and chunk size are those in the file, and its
  zstd level is the one used (the fastest level compresses less than the default);
* ``mcap_record`` accepts a preset, explicit ``--compression-format``/``--chunk-size``
  override it, and an unknown one is refused with one line naming the allowed values.
"""

from __future__ import annotations

import pytest
from bagtool_helpers import reference_frames, run_measured

from mems_sim.bag.compression import STORAGE_PRESETS, storage_preset
from mems_sim.bag.record_cli import _parse_args
from mems_sim.bag.writer import McapBagWriter

TOPIC = "/imu/adc"
TYPE = "mems_msgs/msg/AdcFrame"


def _write(path, options, frames, qos, schema):
    bag = McapBagWriter(str(path), **options)
    bag.add_topic(TOPIC, TYPE, schema, qos)
    for i, data in enumerate(frames):
        bag.write(TOPIC, data, 1_000_000 * i, 1_000_000 * i, sequence=i + 1)
    bag.close()


def _chunks(path):
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as handle:
        return [r for r in StreamReader(handle, emit_chunks=True).records if isinstance(r, Chunk)]


@pytest.fixture(scope="module")
def frames():
    schema, qos, data = reference_frames(40)
    return schema, qos, data


@pytest.mark.parametrize("preset", list(STORAGE_PRESETS))
def test_preset_file_reads_back_equal(preset, frames, tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    schema, qos, data = frames
    data = data * 12  # 1.4 MB: more than one default chunk, one zstd_small chunk
    out = tmp_path / f"{preset}.mcap"
    options = storage_preset(preset)
    _write(out, options, data, qos, schema)

    with open(out, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        assert reader.get_summary().statistics.message_count == len(data)
        raw, decoded = [], []
        for _, _, message, msg in reader.iter_decoded_messages(log_time_order=True):
            raw.append(bytes(message.data))
            decoded.append(msg)
    assert raw == data
    with AnyReader([out]) as rb:
        rb_msgs = [rb.deserialize(r, c.msgtype) for c, _, r in rb.messages()]
    assert len(rb_msgs) == len(data)
    for a, b in zip(decoded, rb_msgs, strict=True):
        assert a.first_sample_index == b.first_sample_index
        assert list(a.codes) == b.codes.tolist()
        assert list(a.lsb) == b.lsb.tolist() and a.bits == b.bits

    chunks = _chunks(out)
    assert chunks, "chunked, as rosbags needs"
    compression = {c.compression for c in chunks}
    crcs = {c.uncompressed_crc != 0 for c in chunks}
    if preset in ("none", "zstd_fast", "zstd_small"):
        assert compression == {"zstd"}
    else:
        assert compression == {""}
    assert crcs == {options.get("crcs", True)}
    if preset == "zstd_small":
        assert len(chunks) == 1 and chunks[0].uncompressed_size > 1 << 20
    else:
        assert len(chunks) == 2


def test_zstd_level_is_used(frames, tmp_path):
    schema, qos, data = frames
    sizes = {}
    for level in (None, -5, 19):
        out = tmp_path / f"l{level}.mcap"
        _write(out, {"compression": "zstd", "compression_level": level}, data, qos, schema)
        sizes[level] = sum(len(c.data) for c in _chunks(out))
    assert sizes[-5] > sizes[None] > sizes[19], sizes
    with pytest.raises(ValueError, match="zstd"):
        McapBagWriter(str(tmp_path / "x.mcap"), compression="lz4", compression_level=1)


def test_cli_preset_and_overrides():
    args = _parse_args(["-o", "x.mcap", "/a", "--storage-preset-profile", "zstd_fast"])
    assert args.writer_options == {"compression": "zstd", "compression_level": -5, "crcs": False}
    args = _parse_args(["-o", "x.mcap", "/a", "--storage-preset-profile", "zstd_small"])
    assert args.chunk_size == 4 << 20 and args.writer_options["compression_level"] == 19
    # explicit options override the preset's
    args = _parse_args(
        ["-o", "x.mcap", "/a", "--storage-preset-profile", "zstd_fast", "--compression", "lz4"]
    )
    assert args.compression == "lz4" and "compression_level" not in args.writer_options
    args = _parse_args(
        ["-o", "x.mcap", "/a", "--storage-preset-profile", "zstd_small"] + ["--chunk-size", "65536"]
    )
    assert args.chunk_size == 65536
    # no preset: the defaults as before
    args = _parse_args(["-o", "x.mcap", "/a"])
    assert (args.compression, args.chunk_size, args.writer_options) == ("zstd", 1 << 20, {})
    with pytest.raises(ValueError, match="allowed: none, fastwrite, zstd_fast, zstd_small"):
        storage_preset("fast")


def test_cli_refuses_unknown_preset_and_records_with_one(tmp_path, subprocess_env):
    run = run_measured(
        ["mcap_record", "-o", tmp_path / "x.mcap", "/x", "--storage-preset-profile", "zstd"],
        subprocess_env,
    )
    assert run.returncode == 2
    assert len(run.err_lines) == 1 and "Traceback" not in run.stderr, run.stderr
    line = run.err_lines[0]
    assert "--storage-preset-profile" in line
    for name in STORAGE_PRESETS:
        assert name in line, line
    out = tmp_path / "fast.mcap"
    run = run_measured(
        ["mcap_record", "-o", out, "/x", "--duration", "0.3", "--storage-preset-profile"]
        + ["zstd_fast"],
        subprocess_env,
    )
    assert run.returncode == 0, run.stderr
    from mcap.reader import make_reader

    with open(out, "rb") as handle:
        assert make_reader(handle).get_summary() is not None

"""Output paths of ``mcap_record`` and ``run_scenario --out``: refusals and a full disk.

* an existing file is refused without ``--overwrite`` (and replaced with it);
* a symbolic link is refused (with or without ``--overwrite``), its target untouched;
* a directory as output gets one line;
* ``/dev/full`` and a full tmpfs: one line naming the path, non-zero exit, and the
  complete chunks of the partial file read back with a streaming reader;
* ``run_scenario --out`` on an unwritable path: one line, exit 2, no traceback.
"""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest
from bagtool_helpers import BIN, Collector, run_measured, start_publisher, stop_process

from mems_sim.bag.writer import BagWriteError, McapBagWriter, output_problem

PRECIOUS = b"precious data, must survive\n"


def _one_error_line(run, path) -> str:
    lines = run.err_lines
    assert len(lines) == 1, run.stderr
    assert "Traceback" not in run.stderr
    assert str(path) in lines[0], lines[0]
    return lines[0]


def test_existing_file_needs_overwrite(tmp_path, subprocess_env):
    out = tmp_path / "exists.mcap"
    out.write_bytes(PRECIOUS)
    run = run_measured(["mcap_record", "-o", out, "/x", "--duration", "0.3"], subprocess_env)
    assert run.returncode == 2
    assert "exists" in _one_error_line(run, out) and "--overwrite" in run.stderr
    assert out.read_bytes() == PRECIOUS

    run = run_measured(
        ["mcap_record", "-o", out, "/x", "--duration", "0.3", "--overwrite"], subprocess_env
    )
    assert run.returncode == 0, run.stderr
    from mcap.reader import make_reader

    with open(out, "rb") as handle:
        assert make_reader(handle).get_summary() is not None


def test_symlink_target_never_truncated(tmp_path, subprocess_env):
    target = tmp_path / "target.mcap"
    target.write_bytes(PRECIOUS)
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    dangling = tmp_path / "dangling.mcap"
    dangling.symlink_to(tmp_path / "nowhere.mcap")
    for extra in ([], ["--overwrite"]):
        for path in (link, dangling):
            run = run_measured(
                ["mcap_record", "-o", path, "/x", "--duration", "0.3", *extra], subprocess_env
            )
            assert run.returncode != 0
            assert "symbolic link" in _one_error_line(run, path)
    assert target.read_bytes() == PRECIOUS
    assert not (tmp_path / "nowhere.mcap").exists()
    # the library refuses too (the scenario runner's recorder overwrites by default)
    with pytest.raises(BagWriteError, match="symbolic link"):
        McapBagWriter(str(link))
    assert target.read_bytes() == PRECIOUS


def test_directory_as_output(tmp_path, subprocess_env):
    run = run_measured(["mcap_record", "-o", tmp_path, "/x", "--duration", "0.3"], subprocess_env)
    assert run.returncode != 0
    assert "is a directory" in _one_error_line(run, tmp_path)
    missing = tmp_path / "no" / "such" / "dir.mcap"
    run = run_measured(["mcap_record", "-o", missing, "/x", "--duration", "0.3"], subprocess_env)
    assert run.returncode != 0
    assert "does not exist" in _one_error_line(run, missing)
    assert output_problem(str(tmp_path / "fresh.mcap")) is None
    assert not (tmp_path / "fresh.mcap").exists()  # the probe leaves nothing behind


def test_dev_full(subprocess_env):
    run = run_measured(["mcap_record", "-o", "/dev/full", "/x", "--duration", "1"], subprocess_env)
    assert run.returncode != 0
    assert "no space left" in _one_error_line(run, "/dev/full")


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 256 KiB tmpfs (we are root); skipped when mounting is not permitted here."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    res = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
        capture_output=True,
        text=True,
    )
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip() or res.returncode}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_disk_full_keeps_complete_chunks(small_tmpfs, subprocess_env):
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader

    from mems_sim.bag.schema import peek_frame_index

    out = small_tmpfs / "full.mcap"
    publisher = start_publisher(subprocess_env, "/full/adc", period_s=0.002)
    try:
        recorder = subprocess.Popen(
            [
                str(BIN / "mcap_record"),
                "-o",
                str(out),
                "/full/adc",
                "--chunk-size",
                "16384",
                "--ros-args",
                "--log-level",
                "warn",
            ],
            env=subprocess_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        stdout, stderr = Collector(recorder.stdout), Collector(recorder.stderr)
        try:
            recorder.wait(timeout=30)  # must stop by itself once the disk is full
        finally:
            if recorder.poll() is None:
                recorder.kill()
                recorder.wait()
    finally:
        stop_process(publisher)
    err = stderr.text()
    lines = [line for line in err.splitlines() if line.strip()]
    assert recorder.returncode == 1, (recorder.returncode, err, stdout.text())
    assert len(lines) == 1 and str(out) in lines[0] and "no space left" in lines[0], err
    assert "Traceback" not in err

    chunks, indices = 0, []
    with open(out, "rb") as handle:
        try:
            for record in StreamReader(handle, emit_chunks=True).records:
                chunks += isinstance(record, Chunk)
        except Exception:  # the torn tail
            pass
    with open(out, "rb") as handle:
        try:
            for record in StreamReader(handle).records:
                if isinstance(record, Message):
                    indices.append(peek_frame_index(record.data)[0])
        except Exception:  # the torn tail
            pass
    assert chunks >= 3, chunks
    assert len(indices) > 50 and indices == list(
        range(indices[0], indices[0] + 100 * len(indices), 100)
    )
    # the project's tools read it as a truncated file: warning line, exit 0
    run = run_measured(["mcap_info", out], subprocess_env)
    # (and, the publisher having started before the recorder, the missing head as loss)
    head = [line for line in run.err_lines if "lost data: /full/adc: missing head (" in line]
    assert run.returncode == 0 and "truncated" in run.err_lines[0], run.stderr
    assert len(run.err_lines) == 1 + len(head) and len(head) <= 1, run.stderr
    assert f"/full/adc [mems_msgs/msg/AdcFrame] {len(indices)} msgs" in run.stdout, run.stdout


def test_run_scenario_unwritable_out(tmp_path, subprocess_env):
    for out in ("/proc/forbidden.mcap", "/sys/forbidden.mcap", str(tmp_path)):
        path = out if out.endswith(".mcap") else out + "/dir.mcap"
        if not out.endswith(".mcap"):
            os.mkdir(path)  # a directory named like the output
        t0 = time.monotonic()
        run = run_measured(
            ["run_scenario", "imu_noise", "--duration", "60", "--out", path, "--no-progress"],
            subprocess_env,
        )
        assert run.returncode == 2, (run.returncode, run.stderr)
        line = _one_error_line(run, path)
        assert line.startswith("run_scenario: error:"), line
        assert time.monotonic() - t0 < 30
    assert not Path("/proc/forbidden.mcap").exists()

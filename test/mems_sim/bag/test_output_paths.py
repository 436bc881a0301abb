"""``write_output``: the one writer of a file a user names (YAML results, figures, reports).

A symbolic link is refused (its target untouched, with or without ``overwrite``), an
existing file needs ``overwrite``, a failed write leaves the old file as it was and no
temporary file behind, a character device is written in place, and the file appears whole.
"""

from __future__ import annotations

import os

import pytest

from mems_sim.bag.output_paths import BagWriteError, write_output

PRECIOUS = "precious, must survive\n"


def _write_text(text: str):
    def write(name: str) -> None:
        with open(name, "w", encoding="utf-8") as handle:
            handle.write(text)

    return write


def test_new_file_written_and_no_temporary_left(tmp_path):
    out = tmp_path / "result.yaml"
    write_output(out, _write_text("a: 1\n"))
    assert out.read_text() == "a: 1\n"
    assert sorted(os.listdir(tmp_path)) == ["result.yaml"]


def test_existing_file_needs_overwrite(tmp_path):
    out = tmp_path / "result.yaml"
    out.write_text(PRECIOUS)
    with pytest.raises(BagWriteError, match="exists .give --overwrite"):
        write_output(out, _write_text("new\n"))
    assert out.read_text() == PRECIOUS
    write_output(out, _write_text("new\n"), overwrite=True)
    assert out.read_text() == "new\n"
    assert sorted(os.listdir(tmp_path)) == ["result.yaml"]


@pytest.mark.parametrize("overwrite", [False, True])
def test_symlink_refused_target_untouched(tmp_path, overwrite):
    target = tmp_path / "target.yaml"
    target.write_text(PRECIOUS)
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    dangling = tmp_path / "dangling.png"
    dangling.symlink_to(tmp_path / "nowhere.png")
    for path in (link, dangling):
        with pytest.raises(BagWriteError, match="symbolic link"):
            write_output(path, _write_text("evil\n"), overwrite=overwrite)
    assert target.read_text() == PRECIOUS
    assert link.is_symlink() and not (tmp_path / "nowhere.png").exists()


def test_failed_write_leaves_old_file(tmp_path):
    out = tmp_path / "figure.png"
    out.write_text(PRECIOUS)

    def half_then_fail(name: str) -> None:
        assert name.endswith(".png") and name != str(out)  # the format's suffix is kept
        with open(name, "w") as handle:
            handle.write("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(BagWriteError) as err:
        write_output(out, half_then_fail, overwrite=True)
    assert str(err.value) == f"{out}: no space left on device"
    assert out.read_text() == PRECIOUS
    assert sorted(os.listdir(tmp_path)) == ["figure.png"]


def test_directory_and_missing_parent(tmp_path):
    with pytest.raises(BagWriteError, match="is a directory"):
        write_output(tmp_path, _write_text("x"), overwrite=True)
    with pytest.raises(BagWriteError, match="does not exist"):
        write_output(tmp_path / "no" / "x.yaml", _write_text("x"))


def test_character_device_written_in_place():
    write_output("/dev/null", _write_text("discarded\n"))
    assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")

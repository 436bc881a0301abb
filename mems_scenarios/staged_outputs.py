"""Default outputs of a run (``runs/``) replaced only after the run succeeded.

A run that names no output writes its MCAP file, figures and YAML results into a staging
directory inside ``runs/`` (``runs/.partial-<random>/``: the same file system, so every move
is a rename). When the run succeeded, each file is renamed into ``runs/`` over the previous
run's file of that name (``os.replace``: atomic per file, a reader sees the old file or the
new one, and a symbolic link there is replaced itself, its target never written). When the
run recorded but failed (lost data, a stop signal), its files go to ``runs/incomplete/``
instead, so the previous outputs stay as they were and the failed run's recording can still
be read; a run that failed before recording leaves nothing. Docs: docs/scenarios.md.
"""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from pathlib import Path

#: Where the files of a run that recorded but failed are kept, inside the outputs directory.
INCOMPLETE = "incomplete"


class StagedOutputs:
    """A staging directory inside ``final_dir`` for one run's outputs (module doc)."""

    def __init__(self, final_dir: Path | str) -> None:
        self.final_dir = Path(final_dir)
        self.final_dir.mkdir(parents=True, exist_ok=True)
        self.staging = Path(tempfile.mkdtemp(prefix=".partial-", dir=self.final_dir))
        self._done = False

    def path(self, name: str) -> Path:
        """Where the run writes its output ``name`` (a file name, no directory)."""
        return self.staging / name

    def destination(self, succeeded: bool) -> Path:
        """The directory the outputs move to: ``final_dir`` or its ``incomplete/``."""
        return self.final_dir if succeeded else self.final_dir / INCOMPLETE

    def publish(self, succeeded: bool) -> dict[Path, Path]:
        """Move every staged output to :meth:`destination` (module doc); returns staged
        path -> final path. Raises OSError naming the staging directory, which is then kept
        with what it still holds."""
        dest = self.destination(succeeded)
        moved = {}
        try:
            dest.mkdir(exist_ok=True)
            if dest.is_symlink() or not dest.is_dir():
                raise NotADirectoryError(f"{dest}: not a directory")
            for name in sorted(os.listdir(self.staging)):
                moved[self.staging / name] = _replace_entry(self.staging / name, dest / name)
        except OSError as exc:
            self._done = True  # keep what was not moved
            text = " ".join(str(exc).split())
            raise OSError(f"{text}; the outputs not moved are in {self.staging}") from None
        self.discard()
        return moved

    def discard(self) -> None:
        """Remove the staging directory and what is left in it. Idempotent."""
        if not self._done:
            self._done = True
            shutil.rmtree(self.staging, ignore_errors=True)


def _replace_entry(source: Path, target: Path) -> Path:
    """Rename ``source`` to ``target``; a directory (a split recording's bag directory)
    replaces an existing directory of that name, which is removed after the rename."""
    try:
        info = os.lstat(target)
    except FileNotFoundError:
        info = None
    if source.is_dir() and info is not None and stat.S_ISDIR(info.st_mode):
        old = source.with_name(source.name + ".old")
        os.rename(target, old)  # removed with the staging directory
        os.rename(source, target)
    else:
        os.replace(source, target)
    return target

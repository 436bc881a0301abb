"""Where an output may be written: checks of an output file (:func:`output_problem`) and of a
bag directory of a split recording (:func:`bag_directory_problem`), its layout (rosbag2's
``NAME/NAME_<n>.mcap`` and ``metadata.yaml``), the one-line :class:`BagWriteError`, and
:func:`write_output`, the one way every tool writes a file a user names (a YAML result, a
figure, a report): refused like a bag output, written to a temporary sibling and moved
into place whole. Symbolic links are never followed; nothing but a bag written here is ever
replaced. Docs: docs/recording.md.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from collections.abc import Callable


class BagWriteError(OSError):
    """The output cannot be written (message is one line and names the path)."""


def describe_error(path: str, exc: OSError) -> str:
    """One line for an OSError of opening or writing ``path``."""
    reason = {
        errno.EEXIST: "exists (give --overwrite to replace it)",
        errno.ELOOP: "is a symbolic link; refusing to write through it",
        errno.EISDIR: "is a directory",
        errno.ENOENT: "cannot create it (no such file or directory)",
        errno.ENOTDIR: "a part of the path is not a directory",
        errno.ENOSPC: "no space left on device",
        errno.EDQUOT: "disk quota exceeded",
        errno.EROFS: "read-only file system",
    }.get(exc.errno)
    if reason is None:
        reason = exc.strerror or str(exc)
    return f"{path}: {reason}"


def _lstat_output(path: str) -> tuple[os.stat_result | None, str | None]:
    """``(lstat of path or None if absent, problem)``: a symbolic link (never followed) or
    an unreadable path is a problem (one line naming the path)."""
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        return None, describe_error(path, exc)
    if stat.S_ISLNK(info.st_mode):
        return info, f"{path}: is a symbolic link; refusing to write through it"
    return info, None


def output_problem(path: str, overwrite: bool = False, probe: bool = True) -> str | None:
    """Why ``path`` cannot be used as a bag output, or None (one line naming the path).

    Refused: a symbolic link (never followed), a directory, an existing regular file
    unless ``overwrite``, special files other than character devices, a path whose
    directory is missing or not writable. With ``probe``, a file that does not exist
    yet is created and removed again (the only reliable test for root, to whom
    ``access()`` grants everything, e.g. in ``/proc``); nothing else is modified.
    """
    path = str(path)
    info, problem = _lstat_output(path)
    if problem is not None:
        return problem
    if info is not None:
        if stat.S_ISDIR(info.st_mode):
            return f"{path}: is a directory"
        if stat.S_ISCHR(info.st_mode):
            return None
        if not stat.S_ISREG(info.st_mode):
            return f"{path}: not a regular file"
        if not overwrite:
            return f"{path}: exists (give --overwrite to replace it)"
        if not os.access(path, os.W_OK):
            return f"{path}: not writable"
        return None
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        return f"{path}: directory {parent} does not exist"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{path}: directory {parent} is not writable"
    if probe:
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
        except FileExistsError:
            return None  # appeared meanwhile: the real open decides
        except OSError as exc:
            return describe_error(path, exc)
        os.close(fd)
        try:
            os.unlink(path)
        except OSError:
            pass
    return None


#: rosbag2 metadata file of a bag directory.
METADATA_FILE = "metadata.yaml"


def bag_directory_path(path: str) -> str:
    """The bag directory a split recording of ``path`` is written to: ``path`` without a
    trailing separator and without a ``.mcap`` suffix (``run.mcap`` -> ``run``)."""
    path = str(path)
    stripped = path.rstrip(os.sep) or path
    return stripped[: -len(".mcap")] if stripped.endswith(".mcap") else stripped


def bag_file_name(directory: str, index: int) -> str:
    """File name of split ``index`` in bag ``directory`` (rosbag2's ``<name>_<index>``)."""
    return f"{os.path.basename(directory)}_{index}.mcap"


def _foreign_entries(directory: str) -> list[str]:
    """Entries of ``directory`` that are not parts of a bag written here (split files
    ``<name>_<n>.mcap`` and ``metadata.yaml``)."""
    own = re.compile(rf"^{re.escape(os.path.basename(directory))}_\d+\.mcap$")
    names = sorted(os.listdir(directory))
    return [n for n in names if n != METADATA_FILE and not own.match(n)]


def bag_directory_problem(path: str, overwrite: bool = False, probe: bool = True) -> str | None:
    """Why ``path`` cannot be used as a bag directory, or None (one line naming the path).

    Refused: a symbolic link, an existing file that is not a directory, an existing directory
    unless ``overwrite`` (rosbag2 refuses one always), and even with ``overwrite`` a directory
    holding anything but a bag written here (nothing else is ever deleted); a parent directory
    that is missing or not writable. With ``probe`` a new directory is created and removed.
    """
    path = str(path)
    info, problem = _lstat_output(path)
    if problem is not None:
        return problem
    if info is not None:
        if not stat.S_ISDIR(info.st_mode):
            return f"{path}: exists and is not a directory (a split recording is a directory)"
        if not overwrite:
            return f"{path}: exists (give --overwrite to replace it)"
        try:
            foreign = _foreign_entries(path)
        except OSError as exc:
            return describe_error(path, exc)
        if foreign:
            shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
            return f"{path}: holds files that are not part of a bag ({shown}); not replacing it"
        if not os.access(path, os.W_OK | os.X_OK):
            return f"{path}: not writable"
        return None
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        return f"{path}: directory {parent} does not exist"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{path}: directory {parent} is not writable"
    if probe:
        try:
            os.mkdir(path, 0o755)
        except FileExistsError:
            return None  # appeared meanwhile: the real creation decides
        except OSError as exc:
            return describe_error(path, exc)
        try:
            os.rmdir(path)
        except OSError:
            pass
    return None


def prepare_directory(path: str, overwrite: bool) -> None:
    """Create the bag directory, or with ``overwrite`` empty an existing bag directory of
    its split files and metadata (anything else in it: refused). Raises BagWriteError."""
    problem = bag_directory_problem(path, overwrite=overwrite, probe=False)
    if problem is not None:
        raise BagWriteError(problem)
    try:
        if os.path.isdir(path):
            for name in os.listdir(path):
                os.unlink(os.path.join(path, name))
        else:
            os.mkdir(path, 0o755)
    except OSError as exc:
        raise BagWriteError(describe_error(path, exc)) from None


def _temporary_sibling(path: str) -> str:
    """A new empty file beside ``path`` (same file system, so a rename is atomic), named
    ``.<name>.<pid>.<n>.tmp<suffix>`` so that tools choosing a format by the suffix (e.g.
    matplotlib's ``savefig``) see the final one; created with ``O_EXCL | O_NOFOLLOW``."""
    head, name = os.path.split(path)
    suffix = os.path.splitext(name)[1]
    for n in range(100):
        tmp = os.path.join(head, f".{name}.{os.getpid()}.{n}.tmp{suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary name", path)


def _move_into_place(tmp: str, path: str, overwrite: bool) -> None:
    """Rename ``tmp`` to ``path``; without ``overwrite`` never over a file that appeared
    meanwhile (a hard link fails with EEXIST; where links are not supported, a rename)."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path, follow_symlinks=False)
    except FileExistsError:
        raise
    except OSError:  # no hard links on this file system
        if os.path.lexists(path):
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), path) from None
        os.replace(tmp, path)
        return
    os.unlink(tmp)


def _is_character_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.lstat(path).st_mode)
    except FileNotFoundError:
        return False


def write_output(path, write: Callable[[str], object], overwrite: bool = False) -> None:
    """Write the file ``path`` a user named: ``write(name)`` writes the content to the file
    ``name`` (a temporary sibling), which is then moved to ``path`` whole, so a reader never
    sees half a file and a failed write leaves ``path`` as it was.

    Refused as :func:`output_problem` refuses (a symbolic link, never followed, even with
    ``overwrite``; an existing file unless ``overwrite``; a directory); a character device
    (``/dev/null``) is written in place. Raises :class:`BagWriteError` (one line naming the
    path) for a refusal and for any OSError of writing (e.g. the disk is full).
    """
    path = str(path)
    problem = output_problem(path, overwrite=overwrite, probe=False)
    if problem is not None:
        raise BagWriteError(problem)
    tmp = None
    try:
        if _is_character_device(path):
            write(path)
            return
        tmp = _temporary_sibling(path)
        write(tmp)
        _move_into_place(tmp, path, overwrite)
    except OSError as exc:
        raise BagWriteError(describe_error(path, exc)) from None
    finally:
        if tmp is not None and os.path.lexists(tmp):
            os.unlink(tmp)

"""One bounded reader for every YAML file a user hands over (parameter files, launch files,
QoS overrides, motion profiles, identified-parameter and calibration files, bag metadata).

A small YAML file can ask for unbounded work: nested aliases that expand exponentially when
a consumer walks the data (a 921-byte parameter file took 7.3 GB), nesting deep enough for
a RecursionError, a path that names a FIFO or ``/dev/zero``. The reader refuses each with a
:class:`YamlLimitError` (a ``yaml.YAMLError``, so every consumer's one-line YAML error path
reports it):

* only regular files (opened without blocking, so a FIFO cannot hang the read), at most
  :data:`MAX_BYTES`, UTF-8;
* no aliases (``*name``): parameter and launch files have no need of them;
* at most :data:`MAX_DEPTH` levels of nesting and :data:`MAX_NODES` nodes.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import yaml

#: Largest YAML file read [bytes].
MAX_BYTES = 16 * 1024 * 1024
#: Deepest nesting of collections, -.
MAX_DEPTH = 64
#: Most nodes (scalars and collections) in one document, -.
MAX_NODES = 2_000_000


class YamlLimitError(yaml.YAMLError):
    """A YAML input refused by a bound of this module (one line)."""


def read_text(path: str | os.PathLike, max_bytes: int = MAX_BYTES) -> str:
    """The text of a regular file of at most ``max_bytes`` bytes, decoded as UTF-8.

    Raises:
        YamlLimitError: not a regular file, too large or not UTF-8.
        OSError: the file cannot be opened or read.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO opens at once, then is refused
    with os.fdopen(fd, "rb") as handle:
        mode = os.fstat(handle.fileno()).st_mode
        if not stat.S_ISREG(mode):
            raise YamlLimitError(f"{path}: not a regular file")
        data = handle.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise YamlLimitError(f"{path}: larger than {max_bytes} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise YamlLimitError(f"{path}: not UTF-8 text (byte {exc.start})") from None


def bounded_loader(
    base: type = yaml.SafeLoader, max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES
) -> type:
    """A loader class derived from ``base`` (a safe loader) that refuses aliases and
    documents nested deeper than ``max_depth`` or larger than ``max_nodes``."""

    class Bounded(base):
        def compose_document(self):
            self._depth, self._nodes = 0, 0
            return super().compose_document()

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                event = self.peek_event()
                raise YamlLimitError(f"{_at(event)}YAML aliases (*{event.anchor}) are not accepted")
            self._nodes += 1
            if self._nodes > max_nodes:
                raise YamlLimitError(f"{_at(self.peek_event())}more than {max_nodes} YAML nodes")
            if self.check_event(yaml.MappingStartEvent, yaml.SequenceStartEvent):
                self._depth += 1
                if self._depth > max_depth:
                    event = self.peek_event()
                    raise YamlLimitError(f"{_at(event)}nested deeper than {max_depth} levels")
                try:
                    return super().compose_node(parent, index)
                finally:
                    self._depth -= 1
            return super().compose_node(parent, index)

    Bounded.__name__ = f"Bounded{base.__name__}"
    return Bounded


def _at(event) -> str:
    """``line L, column C: `` of an event's start, or ''."""
    mark = getattr(event, "start_mark", None)
    return f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""


def problem(exc: BaseException) -> str:
    """A YAML error in one line: ``line L, column C: problem`` where PyYAML marks it."""
    mark = getattr(exc, "problem_mark", None)
    text = getattr(exc, "problem", None) or str(exc)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    return where + " ".join(str(text).split())


#: The bounded safe loader.
BoundedSafeLoader = bounded_loader()


def load(text: str, loader: type = BoundedSafeLoader):
    """One YAML document from ``text`` with a bounded loader (``bounded_loader(...)``)."""
    return yaml.load(text, Loader=loader)  # a bounded SafeLoader


def load_file(
    path: str | os.PathLike, loader: type = BoundedSafeLoader, max_bytes: int = MAX_BYTES
):
    """One YAML document from the file ``path``, every bound applied."""
    return load(read_text(Path(path), max_bytes), loader)


def load_mapping(path: str | os.PathLike, what: str) -> dict:
    """The mapping a parameter file ``path`` holds (``what``: its kind, for the messages,
    e.g. ``"scanner parameter YAML"``), every bound applied. Raises FileNotFoundError when
    there is no such file and ValueError for YAML that does not parse or is not a mapping."""
    if not path or not os.path.isfile(path):
        raise FileNotFoundError(f"{what} not found: {str(path)!r} (run the identification first)")
    try:
        data = load_file(path)
    except yaml.YAMLError as exc:
        raise ValueError(f"{what} {str(path)!r}: {problem(exc)}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{what} {str(path)!r} is not a mapping")
    return data

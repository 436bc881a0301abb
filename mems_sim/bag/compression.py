"""zstd levels and rosbag2 storage presets of :class:`~mems_sim.bag.writer.McapBagWriter`.

mcap's Python Writer compresses zstd chunks at zstandard's default level and takes no
level; :class:`_LeveledZstd` stands in for its ``zstandard`` module so the level set by
:class:`_zstd_level` reaches it. :data:`STORAGE_PRESETS` maps rosbag2's MCAP storage
preset profiles onto writer options (docs/recording.md).
"""

from __future__ import annotations

import threading

import mcap.writer as _mcap_writer
from mcap.writer import CompressionType

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
    "": CompressionType.NONE,
    None: CompressionType.NONE,
}

#: zstd level of mcap's Python Writer (it calls ``zstandard.compress``, whose default is 3).
MCAP_PY_ZSTD_LEVEL = 3

#: zstd level this writer compresses at when none is given: mcap's C++ writer's
#: ``CompressionLevel::Default``, which rosbag2's MCAP storage writes with when no preset
#: is given (zstd chunks at level 1 with chunk CRCs). On frame data it takes ~0.6 x the CPU
#: of level 3 for a 5-10 % larger file.
DEFAULT_ZSTD_LEVEL = 1

#: rosbag2's MCAP storage preset profiles (``ros2 bag record --storage-preset-profile``)
#: as options of :class:`McapBagWriter`. ``none`` is no preset: the writer's own defaults
#: (zstd level 1, 1 MiB chunks, chunk CRCs) or the options given apply. The zstd levels
#: are those mcap's C++ writer (which rosbag2 uses) gives its ``Fastest`` and ``Slowest``
#: compression levels. ``fastwrite`` is unchunked in rosbag2; here it keeps chunks
#: (uncompressed, no CRCs): rosbags does not read an unchunked MCAP file, and the crash
#: safety of this writer is per chunk.
STORAGE_PRESETS: dict[str, dict] = {
    "none": {},
    "fastwrite": {"compression": "none", "crcs": False},
    "zstd_fast": {"compression": "zstd", "compression_level": -5, "crcs": False},
    "zstd_small": {
        "compression": "zstd",
        "compression_level": 19,
        "chunk_size": 4 << 20,
        "crcs": True,
    },
}


def storage_preset(name: str | None) -> dict:
    """The :class:`McapBagWriter` options of a rosbag2 storage preset profile (``None``
    or ``''``: none); ValueError naming the allowed values for an unknown one."""
    if not name:
        return {}
    try:
        return dict(STORAGE_PRESETS[name])
    except (KeyError, TypeError):
        allowed = ", ".join(STORAGE_PRESETS)
        raise ValueError(f"unknown storage preset profile {name!r} (allowed: {allowed})") from None


class _LeveledZstd:
    """Stands in for the ``zstandard`` module inside :mod:`mcap.writer`, whose Writer
    compresses every chunk with ``zstandard.compress(data)`` at zstandard's default level
    and takes no level. :func:`_zstd_level` sets the level for the calling thread while a
    :class:`McapBagWriter` calls into its Writer; any other caller gets the plain
    ``zstandard.compress``. One compressor per thread and level (zstandard's compressors
    are not shared between threads); they release the GIL while compressing."""

    def __init__(self, module):
        self._module = module
        self._local = threading.local()

    def __getattr__(self, name):
        return getattr(self._module, name)

    def compress(self, data, *args, **kwargs):
        level = getattr(self._local, "level", None)
        if level is None or args or kwargs:
            return self._module.compress(data, *args, **kwargs)
        cache = self._local.__dict__.setdefault("compressors", {})
        compressor = cache.get(level)
        if compressor is None:
            compressor = cache[level] = self._module.ZstdCompressor(level=level)
        return compressor.compress(data)


_ZSTD = None
if getattr(_mcap_writer, "zstandard", None) is not None:
    if isinstance(_mcap_writer.zstandard, _LeveledZstd):  # module reloaded
        _ZSTD = _mcap_writer.zstandard
    else:
        _ZSTD = _mcap_writer.zstandard = _LeveledZstd(_mcap_writer.zstandard)


class _zstd_level:
    """Context: mcap's Writer compresses at ``level`` in this thread (None: its default)."""

    __slots__ = ("_level", "_saved")

    def __init__(self, level: int | None):
        self._level = level

    def __enter__(self):
        if _ZSTD is not None:
            self._saved = getattr(_ZSTD._local, "level", None)
            _ZSTD._local.level = self._level

    def __exit__(self, *exc):
        if _ZSTD is not None:
            _ZSTD._local.level = self._saved

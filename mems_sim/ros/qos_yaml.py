"""rosbag2's QoS YAML, both ways, in one place.

One entry is a mapping of policies (``history``, ``depth``, ``reliability``, ``durability``,
``liveliness``, ``avoid_ros_namespace_conventions``; ``deadline``, ``lifespan`` and
``liveliness_lease_duration`` as ``{sec, nsec}``). It appears as a channel's
``offered_qos_profiles`` metadata (a list, written by :func:`profiles_yaml`, read back by
:func:`profiles_from_yaml`) and in a ``--qos-profile-overrides-path`` file (topic -> entry,
:func:`load_overrides`). An override file is checked strictly (one-line ``ValueError``);
recorded metadata is read leniently (older rosbag2 versions write policies as integers).
Files are read through :mod:`mems_sim.bounded_yaml`; rclpy is imported when a profile is built.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

from mems_sim import bounded_yaml

DURATION_KEYS = ("deadline", "lifespan", "liveliness_lease_duration")
POLICY_KEYS = ("history", "reliability", "durability", "liveliness")
VALUE_KEYS = ("depth", "avoid_ros_namespace_conventions")

#: Depth of an entry that names none [messages] (rosbag2's and rclpy's default).
DEFAULT_DEPTH = 10
#: RMW_DURATION_INFINITE [ns]: rosbag2 writes it as ``{sec: 9223372036, nsec: 854775807}``.
INFINITE_NS = 0x7FFFFFFFFFFFFFFF
_NS = 1_000_000_000


def _policy_enums() -> dict:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, ReliabilityPolicy

    return {
        "history": HistoryPolicy,
        "reliability": ReliabilityPolicy,
        "durability": DurabilityPolicy,
        "liveliness": LivelinessPolicy,
    }


def _policy(enum, key: str, value, where: str, recorded: bool):
    """The ``enum`` member named ``value`` (its rmw short name; an integer in recorded metadata)."""
    if recorded and isinstance(value, int):
        return enum(value)
    try:
        return enum[str(value).upper()]
    except KeyError:
        if recorded:
            raise
        names = ", ".join(p.name.lower() for p in enum)
        raise ValueError(f"{where}: {key} {value!r} is not one of {names}") from None


def _duration_ns(key: str, value, where: str, recorded: bool) -> int:
    """Nanoseconds of a ``{sec, nsec}`` mapping, at most :data:`INFINITE_NS`."""
    if recorded:
        value = value or {}
    elif not (isinstance(value, dict) and set(value) <= {"sec", "nsec"}):
        raise ValueError(f"{where}: {key} must be {{sec: S, nsec: N}}, got {value!r}")
    try:
        sec, nsec = int(value.get("sec", 0)), int(value.get("nsec", 0))
    except (TypeError, ValueError):
        if recorded:
            raise
        raise ValueError(f"{where}: {key} must be whole numbers, got {value!r}") from None
    if not recorded and (sec < 0 or nsec < 0):
        raise ValueError(f"{where}: {key} must not be negative")
    return min(sec * _NS + nsec, INFINITE_NS)


def _depth(value, where: str, recorded: bool) -> int:
    if recorded:
        return int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{where}: depth must be a whole number >= 0, got {value!r}")
    return value


def profile_from_dict(entry: dict, where: str = "", recorded: bool = False):
    """An rclpy ``QoSProfile`` from one entry.

    An override entry (``recorded`` False) raises ValueError with one line naming ``where``
    and the bad key or value; a recorded one ignores unknown keys and accepts integer policies.
    """
    from rclpy.duration import Duration
    from rclpy.qos import HistoryPolicy, QoSProfile

    if not isinstance(entry, dict):
        raise ValueError(f"{where}: expected a mapping of QoS policies, got {entry!r}")
    enums = _policy_enums()
    kwargs = {}
    for key, value in entry.items():
        if key in POLICY_KEYS:
            kwargs[key] = _policy(enums[key], key, value, where, recorded)
        elif key in DURATION_KEYS:
            kwargs[key] = Duration(nanoseconds=_duration_ns(key, value, where, recorded))
        elif key == "depth":
            kwargs[key] = _depth(value, where, recorded)
        elif key == "avoid_ros_namespace_conventions":
            kwargs[key] = bool(value)
        elif not recorded:
            allowed = ", ".join(POLICY_KEYS + VALUE_KEYS + DURATION_KEYS)
            raise ValueError(f"{where}: unknown QoS key {key!r} (allowed: {allowed})")
    kwargs.setdefault("depth", DEFAULT_DEPTH)
    if not recorded and kwargs.get("history") == HistoryPolicy.KEEP_LAST and kwargs["depth"] == 0:
        raise ValueError(f"{where}: history keep_last needs a depth > 0")
    return QoSProfile(**kwargs)


def load_overrides(path: str | os.PathLike) -> dict:
    """Topic -> QoSProfile from a rosbag2 QoS override file (YAML: ``/topic: {history:
    keep_last, depth: 10, reliability: best_effort, ...}``). Raises ValueError (one line)."""
    import yaml

    try:
        data = bounded_yaml.load_file(path)
    except OSError as exc:
        raise ValueError(f"{path}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of topic names to QoS profiles")
    return {str(t): profile_from_dict(e, f"{path}: {t}") for t, e in data.items()}


def profiles_from_yaml(text: str) -> list:
    """rclpy ``QoSProfile``s of an ``offered_qos_profiles`` value (version-9 strings or older
    integers); empty text is no profiles."""
    entries = bounded_yaml.load(text) if text else []
    return [profile_from_dict(entry, recorded=True) for entry in entries or []]


def playback_profile(text: str):
    """Publisher QoS for replaying a topic recorded with ``offered_qos_profiles`` ``text``
    (rosbag2's adaptation): the first profile's reliability and durability, KEEP_LAST at
    least :data:`~mems_sim.ros.qos.FRAME_DEPTH` deep; FRAME_QOS if none can be read."""
    from rclpy.qos import HistoryPolicy, QoSProfile

    from mems_sim.ros.qos import FRAME_DEPTH, FRAME_QOS

    try:
        profiles = profiles_from_yaml(text)
    except Exception:
        profiles = []
    if not profiles:
        return FRAME_QOS
    first = profiles[0]
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=max(FRAME_DEPTH, int(first.depth)),
        reliability=first.reliability,
        durability=first.durability,
    )


def _nanoseconds(duration) -> int:
    """Nanoseconds of an rclpy Duration (or an int/None)."""
    if duration is None:
        return 0
    if isinstance(duration, int):
        return duration
    return int(duration.nanoseconds)


def _policy_name(policy) -> str:
    """rmw short name of a QoS policy enum value ('keep_last', 'reliable', ...)."""
    return getattr(policy, "name", str(policy)).lower()


def profile_dict(qos) -> dict:
    """rosbag2's dict form of one rclpy ``QoSProfile`` (durations as ``{sec, nsec}``)."""

    def time(duration) -> dict:
        ns = _nanoseconds(duration)
        return {"sec": ns // _NS, "nsec": ns % _NS}

    return {
        "history": _policy_name(qos.history),
        "depth": int(qos.depth),
        "reliability": _policy_name(qos.reliability),
        "durability": _policy_name(qos.durability),
        "deadline": time(qos.deadline),
        "lifespan": time(qos.lifespan),
        "liveliness": _policy_name(qos.liveliness),
        "liveliness_lease_duration": time(qos.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }


def profiles_yaml(profiles: Iterable) -> str:
    """The ``offered_qos_profiles`` YAML string (a list, one entry per publisher) of rclpy
    QoS profiles, laid out as rosbag2 writes it."""
    lines = []
    for qos in profiles:
        for n, (key, value) in enumerate(profile_dict(qos).items()):
            prefix = "  " if n else "- "
            if isinstance(value, dict):
                lines += [
                    f"{prefix}{key}:",
                    f"    sec: {value['sec']}",
                    f"    nsec: {value['nsec']}",
                ]
            elif isinstance(value, bool):
                lines.append(f"{prefix}{key}: {'true' if value else 'false'}")
            else:
                lines.append(f"{prefix}{key}: {value}")
    return "\n".join(lines) if lines else "[]"

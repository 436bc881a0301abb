"""Message definitions, QoS metadata and a CDR peek for rosbag2-compatible MCAP.

Everything here is what a ``ros2`` profile MCAP file needs besides the message
bytes themselves:

* :func:`schema_text` -- the ``ros2msg`` schema of a type ``pkg/msg/Type``:
  the top-level ``.msg`` text, then every dependency once (depth first),
  each preceded by a line of exactly 80 ``=`` and a line ``MSG: pkg/msg/Type``
  (rosbag2's ``LocalMessageDefinitionSource`` layout).
* the ``offered_qos_profiles`` channel metadata is written and read by
  :mod:`mems_sim.ros.qos_yaml`.
* :func:`type_hash` -- the ``RIHS01_...`` type hash that rosbag2 stores as
  ``topic_type_hash``, read from the ``Type.json`` that rosidl installs next to
  the ``.msg`` file.
* :func:`peek_frame_index` / :func:`peek_header_stamp_ns` -- read a few leading
  fields of a serialised (CDR) message without deserialising it.

Only the standard library and ``ament_index_python`` are needed at import
time; rclpy is imported lazily by the QoS helpers.
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import re
import struct
import sys

#: Line that separates definitions in a ``ros2msg`` schema (exactly 80 '=').
SEPARATOR = "=" * 80

#: Builtin (primitive) field types of the ``.msg`` format.
PRIMITIVE_TYPES = frozenset(
    {
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    }
)

#: Frame types and the layout of their leading fields (see :func:`peek_frame_index`).
#: ``frame``: header, uint64 first_sample_index, float64 sample_rate_hz, uint32 num_samples.
#: ``noise_model``: header, uint64 first_sample_index, uint64 num_samples, float64 sample_rate_hz.
FRAME_LAYOUTS: dict[str, str] = {
    "mems_msgs/msg/AdcFrame": "frame",
    "mems_msgs/msg/SignalFrame": "frame",
    "mems_msgs/msg/StateEstimate": "frame",
    "mems_msgs/msg/NoiseModel": "noise_model",
}

#: Types whose frames form a contiguous sample stream, so that a jump of
#: ``first_sample_index`` is a drop. NoiseModel is not one of them: each
#: result describes a (possibly growing, overlapping) window of data.
GAP_CHECKED_TYPES = frozenset(name for name, layout in FRAME_LAYOUTS.items() if layout == "frame")

# A field or constant line: type (with optional array suffix), whitespace, name.
_FIELD_RE = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_/]*)(\[[^\]]*\])?\s+[A-Za-z]")
_STRING_BOUND_RE = re.compile(r"^(w?string)<=\d+$")


class SchemaError(LookupError):
    """A message definition could not be found or understood."""


# --------------------------------------------------------------------------
# type names


def normalize_type_name(type_name: str) -> str:
    """Return the full form ``pkg/msg/Type`` of ``pkg/Type`` or ``pkg/msg/Type``.

    Raises :class:`SchemaError` for anything else.
    """
    parts = type_name.strip().split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    if len(parts) == 3 and all(parts):
        return type_name.strip()
    raise SchemaError(f"type name not understood: {type_name!r} (expected pkg/msg/Type)")


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """Split a type name into ``(package, namespace, Type)``, e.g. ``('std_msgs', 'msg', 'Header')``."""
    pkg, ns, name = normalize_type_name(type_name).split("/")
    return pkg, ns, name


#: ROS interface type names: a package name (lowercase letters, digits, ``_``, starting
#: with a letter), the interface kind, and a CamelCase type name (``_`` only in the
#: generated service/action parts such as ``AddTwoInts_Request``).
_INTERFACE_TYPE_RE = re.compile(
    r"[a-z][a-z0-9_]*/(msg|srv|action)/[A-Z][A-Za-z0-9]*(_[A-Za-z0-9]+)*"
)


def _ament_interfaces(package: str) -> frozenset[str]:
    """Interface files (``msg/Imu.msg``, ``srv/X.idl``, ...) that ``package`` registers
    in the ament index (resource type ``rosidl_interfaces``); empty if none.

    The prefixes are those of ``AMENT_PREFIX_PATH``, or the interpreter prefix when it
    is unset (where the PyPI ROS 2 wheels install their index, as
    :func:`mems_sim.ros.env.apply_defaults` assumes). ``package`` must already match
    the package-name grammar (no path separators).
    """
    prefixes = os.environ.get("AMENT_PREFIX_PATH", "") or sys.prefix
    return _ament_interfaces_cached(package, prefixes)


@functools.cache
def _ament_interfaces_cached(package: str, prefixes: str) -> frozenset[str]:
    for prefix in prefixes.split(os.pathsep):
        if not prefix:
            continue
        path = os.path.join(
            prefix, "share", "ament_index", "resource_index", "rosidl_interfaces", package
        )
        if os.path.isfile(path):
            try:
                with open(path, encoding="utf-8") as handle:
                    content = handle.read(1 << 20)
            except (OSError, ValueError):
                return frozenset()
            return frozenset(line.strip() for line in content.splitlines() if line.strip())
    return frozenset()


def interface_problem(type_name: str) -> str | None:
    """Why ``type_name`` may not be imported, or None when it is an installed interface type.

    Only names of the ROS type grammar (``pkg/msg/Type``, also ``pkg/Type``) whose
    package registers that interface in the ament index qualify; for service and
    action types (``pkg/srv/X_Request``) the interface file ``X`` must be registered.
    """
    try:
        pkg, ns, name = split_type_name(type_name)
    except SchemaError:
        return f"unknown type {type_name[:80]!r}: not a ROS type name (pkg/msg/Type)"
    full = f"{pkg}/{ns}/{name}"
    if _INTERFACE_TYPE_RE.fullmatch(full) is None:
        return f"unknown type {full[:80]!r}: not a ROS type name (pkg/msg/Type)"
    base = name.split("_", 1)[0]
    wanted = {f"{ns}/{base}.idl", f"{ns}/{base}.{ns}"}
    if not wanted & _ament_interfaces(pkg):
        return f"unknown type {full!r}: not an interface of the ament index"
    return None


def message_class(type_name: str):
    """Import and return the Python class of a message type (``pkg/msg/Type``).

    Nothing is imported unless :func:`interface_problem` accepts the name, so a type
    name read from a file can never make this import an arbitrary module. Raises
    :class:`SchemaError` for an unknown or non-importable type.
    """
    problem = interface_problem(type_name)
    if problem is not None:
        raise SchemaError(problem)
    pkg, ns, name = split_type_name(type_name)
    try:
        module = importlib.import_module(f"{pkg}.{ns}")
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        raise SchemaError(f"message type {type_name} is not importable: {exc}") from exc


def type_name_of(msg_class) -> str:
    """Return ``pkg/msg/Type`` of a generated message class."""
    module = msg_class.__module__.split(".")
    return f"{module[0]}/{module[1]}/{msg_class.__name__}"


# --------------------------------------------------------------------------
# .msg files and the ros2msg schema


def _share_directory(package: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return get_package_share_directory(package)
    except (PackageNotFoundError, LookupError, ValueError) as exc:
        raise SchemaError(
            f"package {package!r} not found in the ament index "
            f"(AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH', '')!r})"
        ) from exc


@functools.cache
def msg_file_text(type_name: str) -> str:
    """Return the text of ``<share of pkg>/msg/Type.msg`` of a type, as installed."""
    pkg, ns, name = split_type_name(type_name)
    path = os.path.join(_share_directory(pkg), ns, name + ".msg")
    try:
        with open(path, encoding="utf-8") as handle:
            return handle.read()
    except OSError as exc:
        raise SchemaError(f"no .msg definition for {type_name} at {path}") from exc


def _strip_comment(line: str) -> str:
    """Remove a ``#`` comment unless the ``#`` sits inside a quoted default value."""
    quote = None
    for i, char in enumerate(line):
        if quote:
            if char == quote:
                quote = None
        elif char in "\"'":
            quote = char
        elif char == "#":
            return line[:i]
    return line


def resolve_field_type(base_type: str, package: str) -> str | None:
    """Resolve a field's base type (array suffix removed) to ``pkg/msg/Type``.

    Returns None for builtin types (including bounded strings ``string<=N``).
    Rules: ``pkg/Type`` and ``pkg/msg/Type`` are absolute; a bare ``Header``
    means ``std_msgs/msg/Header`` unless the package defines its own
    ``Header.msg``; any other bare ``Type`` belongs to the same package.
    """
    if base_type in PRIMITIVE_TYPES or _STRING_BOUND_RE.match(base_type):
        return None
    if "/" in base_type:
        return normalize_type_name(base_type)
    if base_type == "Header" and not _package_has_msg(package, "Header"):
        return "std_msgs/msg/Header"
    return f"{package}/msg/{base_type}"


def _package_has_msg(package: str, name: str) -> bool:
    try:
        return os.path.exists(os.path.join(_share_directory(package), "msg", name + ".msg"))
    except SchemaError:
        return False


def parse_fields(text: str, package: str) -> list[tuple[str, str | None, str]]:
    """Parse ``.msg`` text into ``(field_type, resolved_complex_type_or_None, name)``.

    Constants (``TYPE NAME=value``) are skipped. ``field_type`` keeps any array suffix.
    """
    fields = []
    for raw in text.splitlines():
        line = _strip_comment(raw).strip()
        if not line:
            continue
        parts = line.split(None, 2)
        if len(parts) < 2:
            raise SchemaError(f"cannot parse .msg line {raw!r}")
        field_type, rest = parts[0], line[len(parts[0]) :].strip()
        if "=" in rest.split(None, 1)[0] or re.match(r"^[A-Za-z0-9_]+\s*=", rest):
            continue  # constant
        name = rest.split()[0]
        base = re.sub(r"\[[^\]]*\]$", "", field_type)
        fields.append((field_type, resolve_field_type(base, package), name))
    return fields


def dependencies(type_name: str) -> list[str]:
    """Direct complex dependencies of a type, in full form, sorted, without duplicates."""
    pkg, _, _ = split_type_name(type_name)
    deps = {resolved for _, resolved, _ in parse_fields(msg_file_text(type_name), pkg) if resolved}
    return sorted(deps)


@functools.cache
def schema_text(type_name: str) -> str:
    """Return the ``ros2msg`` schema text of ``pkg/msg/Type`` (rosbag2's layout).

    The top-level ``.msg`` text comes first; then each dependency appears once,
    depth first, as ``"\\n" + 80*"=" + "\\nMSG: pkg/msg/Type\\n" + text``.
    Raises :class:`SchemaError` when a definition is missing.
    """
    root = normalize_type_name(type_name)
    seen = {root}

    def append(name: str, depth: int) -> str:
        if depth > 50:
            raise SchemaError(f"recursion too deep resolving {root}")
        out = msg_file_text(name)
        for dep in dependencies(name):
            if dep not in seen:
                seen.add(dep)
                out += f"\n{SEPARATOR}\nMSG: {dep}\n" + append(dep, depth + 1)
        return out

    return append(root, 0)


def split_schema(text: str) -> dict[str, str]:
    """Split a ``ros2msg`` schema into ``{type_name: msg_text}``; the root is under ``''``."""
    parts = re.split(r"\n?^={80}\n", text, flags=re.MULTILINE)
    out = {"": parts[0]}
    for part in parts[1:]:
        first, _, body = part.partition("\n")
        if not first.startswith("MSG: "):
            raise SchemaError(f"schema section without 'MSG:' line: {first!r}")
        out[first[5:].strip()] = body
    return out


@functools.cache
def has_header(type_name: str) -> bool:
    """True when the first field of the type is a ``std_msgs/Header`` (so the CDR starts with a stamp)."""
    pkg, _, _ = split_type_name(type_name)
    fields = parse_fields(msg_file_text(type_name), pkg)
    return bool(fields) and fields[0][1] == "std_msgs/msg/Header" and fields[0][0].find("[") < 0


@functools.cache
def type_hash(type_name: str) -> str | None:
    """Return the ``RIHS01_<hex>`` type hash of a type, or None when not available.

    Read from ``<share>/<pkg>/msg/Type.json`` (``type_hashes``), which rosidl
    generates with the same hash that rclpy/rmw advertise in discovery.
    """
    pkg, ns, name = split_type_name(type_name)
    try:
        path = os.path.join(_share_directory(pkg), ns, name + ".json")
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except (SchemaError, OSError, ValueError):
        return None
    full = f"{pkg}/{ns}/{name}"
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == full:
            return entry.get("hash_string")
    return None


# --------------------------------------------------------------------------
# CDR peek

_U32 = {True: struct.Struct("<I"), False: struct.Struct(">I")}
_I32U32 = {True: struct.Struct("<iI"), False: struct.Struct(">iI")}
_FRAME = {True: struct.Struct("<QdI"), False: struct.Struct(">QdI")}
_NOISE = {True: struct.Struct("<QQd"), False: struct.Struct(">QQd")}


def _encapsulation(serialized: bytes) -> tuple[bool, int]:
    """(little_endian, max_alignment) from the 4-byte CDR encapsulation header.

    Representation ids 0/1 are XCDR1 (CDR_BE/CDR_LE, 8-byte alignment of 64-bit
    values); 6..11 are XCDR2 flavours, where alignment is capped at 4.
    """
    rep_id = serialized[1]
    return bool(rep_id & 1), (4 if rep_id >= 6 else 8)


def peek_header_stamp_ns(serialized: bytes) -> int | None:
    """``header.stamp`` in ns of a CDR message that starts with ``std_msgs/Header``; None if too short."""
    if len(serialized) < 12:
        return None
    little, _ = _encapsulation(serialized)
    sec, nsec = _I32U32[little].unpack_from(serialized, 4)
    return sec * 1_000_000_000 + nsec


def peek_frame_index(serialized: bytes, layout: str = "frame") -> tuple[int, int] | None:
    """Return ``(first_sample_index, num_samples)`` of a serialised frame message, or None.

    Reads only the leading fields of the CDR bytes:
    4 bytes encapsulation header; ``header.stamp`` (int32 sec, uint32 nanosec);
    ``header.frame_id`` (uint32 length including the NUL, then the bytes);
    padding to 8 (4 in XCDR2) relative to the end of the encapsulation header;
    then for ``layout='frame'`` (AdcFrame, SignalFrame, StateEstimate)
    uint64 first_sample_index, float64 sample_rate_hz, uint32 num_samples;
    for ``layout='noise_model'`` uint64 first_sample_index, uint64 num_samples.
    Returns None when the bytes are too short.
    """
    parsed = peek_frame_fields(serialized, layout)
    if parsed is None:
        return None
    return parsed[0], parsed[1]


def peek_frame_fields(serialized: bytes, layout: str = "frame") -> tuple[int, int, float] | None:
    """Like :func:`peek_frame_index`, plus ``sample_rate_hz`` [Hz]: ``(first, num_samples, rate)``."""
    if len(serialized) < 16:
        return None
    little, max_align = _encapsulation(serialized)
    (length,) = _U32[little].unpack_from(serialized, 12)
    pos = 16 + length - 4  # offsets relative to the end of the encapsulation header
    pos = (pos + max_align - 1) // max_align * max_align
    offset = 4 + pos
    if layout == "frame":
        if len(serialized) < offset + 20:
            return None
        first, rate, num = _FRAME[little].unpack_from(serialized, offset)
        return first, num, rate
    if layout == "noise_model":
        if len(serialized) < offset + 24:
            return None
        first, num, rate = _NOISE[little].unpack_from(serialized, offset)
        return first, num, rate
    raise ValueError(f"unknown frame layout {layout!r}")

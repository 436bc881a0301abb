"""rosbag2's ``metadata.yaml`` of a split recording: its content and its atomic write.

The content is ``rosbag2_bagfile_information`` version :data:`METADATA_VERSION`, as
rosbag2_storage encodes bag metadata: per-topic message counts with their offered QoS
profiles and type hashes, and per-file start, duration and message count.
``compression_format``/``compression_mode`` are empty because the MCAP chunk compression
is internal to each file (rosbag2's fields describe its own file or message compression).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

from mems_sim.bag.output_paths import METADATA_FILE, BagWriteError, describe_error

#: rosbag2 metadata version written (rosbag2_storage).
METADATA_VERSION = 9


def _topic_entries(topic_defs: Sequence[tuple], totals: dict[int, int]) -> list[dict]:
    """``topics_with_message_count``: one entry per ``(topic, type, _, metadata)`` of
    ``topic_defs``, numbered from 1 as the files' channel ids, with its message total."""
    import yaml  # only bag directories need it

    topics = []
    for bag_id, (topic, type_name, _, metadata) in enumerate(topic_defs, 1):
        qos = yaml.safe_load(metadata.get("offered_qos_profiles") or "[]") or []
        topics.append(
            {
                "topic_metadata": {
                    "name": topic,
                    "type": type_name,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": qos,
                    "type_description_hash": metadata.get("topic_type_hash", ""),
                },
                "message_count": totals.get(bag_id, 0),
            }
        )
    return topics


def _file_entry(f: dict) -> dict:
    """One ``files`` entry; times in nanoseconds of log time."""
    duration = (f["last"] - f["first"]) if f["first"] is not None else 0
    return {
        "path": f["path"],
        "starting_time": {"nanoseconds_since_epoch": f["first"] or 0},
        "duration": {"nanoseconds": duration},
        "message_count": sum(f["counts"].values()),
    }


def rosbag2_metadata(files: Sequence[dict], topic_defs: Sequence[tuple]) -> dict:
    """The ``metadata.yaml`` content of a bag made of ``files``.

    Args:
        files: per file ``{"path", "first", "last", "counts"}``: its name in the bag
            directory, first and last log time (ns, ``None`` when empty) and messages per
            channel id.
        topic_defs: ``(topic, type name, schema, channel metadata)`` in channel-id order.
    """
    totals: dict[int, int] = {}
    for f in files:
        for cid, n in f["counts"].items():
            totals[cid] = totals.get(cid, 0) + n
    firsts = [f["first"] for f in files if f["first"] is not None]
    lasts = [f["last"] for f in files if f["last"] is not None]
    start = min(firsts) if firsts else 0
    return {
        "rosbag2_bagfile_information": {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": (max(lasts) - start) if lasts else 0},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(totals.values()),
            "topics_with_message_count": _topic_entries(topic_defs, totals),
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [f["path"] for f in files],
            "files": [_file_entry(f) for f in files],
            "custom_data": None,
            "ros_distro": os.environ.get("ROS_DISTRO", ""),
        }
    }


def message_count(metadata: dict) -> int:
    """Messages a ``metadata.yaml`` content (:func:`rosbag2_metadata`) lists."""
    return int(metadata["rosbag2_bagfile_information"]["message_count"])


def write_metadata(directory: str, metadata: dict) -> None:
    """Write ``metadata`` as ``directory/metadata.yaml`` atomically (a temporary file,
    fsync'ed, renamed over it). Raises :class:`BagWriteError` (one line) on failure,
    leaving no temporary file behind."""
    import yaml

    text = yaml.safe_dump(metadata, sort_keys=False, default_flow_style=False)
    final = os.path.join(directory, METADATA_FILE)
    tmp = final + ".tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, final)
    except OSError as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise BagWriteError(describe_error(final, exc)) from None

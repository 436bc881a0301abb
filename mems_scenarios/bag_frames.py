"""A recording's frame topics as arrays, for a scenario's analysis (one pass over the file)."""

from __future__ import annotations

from mems_scenarios.base import IncompleteStream, ScenarioError


def topics_frames(path, topics, missing_ok: bool = False) -> dict[str, dict]:
    """Concatenate the frames of several topics of an MCAP file into arrays, in one pass
    over the file (its chunks hold every topic, so reading topic by topic would
    decompress the whole file once per topic).

    Returns:
        dict topic -> dict with ``first_index`` (first sample index), ``names``,
        ``units``, ``data`` (n, channels) — SignalFrame data, StateEstimate states or
        AdcFrame physical values — and, for StateEstimate, ``variances`` (n, channels).
        A topic without frames raises :class:`ScenarioError` (``missing_ok``: it is
        left out of the dict); a topic whose frames jump ahead (a gap) raises
        :class:`IncompleteStream`.
    """
    import numpy as np

    from mems_sim.bag.player import read_messages
    from mems_sim.ros.frames import adc_physical, signal_data

    topics = list(dict.fromkeys(topics))
    acc = {
        t: dict(chunks=[], variances=[], first=None, next=None, names=(), units=()) for t in topics
    }
    for topic, type_name, _, msg in read_messages(str(path), topics):
        a = acc[topic]
        first = int(msg.first_sample_index)
        if a["first"] is None:
            a["first"] = first
        elif first > a["next"]:
            raise IncompleteStream(
                f"{path}: {topic} jumps from sample {a['next']} to {first} (a gap of "
                f"{first - a['next']} samples: dropped samples or loss); the analysis aligns "
                "whole streams sample by sample"
            )
        a["next"] = first + int(msg.num_samples)
        if type_name.endswith("/StateEstimate"):
            k = len(msg.state_names)
            a["names"], a["units"] = tuple(msg.state_names), tuple(msg.state_units)
            a["chunks"].append(np.asarray(msg.states).reshape(-1, k))
            a["variances"].append(np.asarray(msg.variances).reshape(-1, k))
        elif type_name.endswith("/AdcFrame"):
            a["names"], a["units"] = tuple(msg.channel_names), tuple(msg.channel_units)
            a["chunks"].append(adc_physical(msg))
        else:
            a["names"], a["units"] = tuple(msg.channel_names), tuple(msg.channel_units)
            a["chunks"].append(signal_data(msg))
    out = {}
    for t, a in acc.items():
        if not a["chunks"]:
            if missing_ok:
                continue
            raise ScenarioError(f"{path}: no frames on {t}")
        out[t] = dict(
            first_index=a["first"],
            names=a["names"],
            units=a["units"],
            data=np.concatenate(a["chunks"]),
        )
        if a["variances"]:
            out[t]["variances"] = np.concatenate(a["variances"])
    return out


def topic_frames(path, topic: str) -> dict:
    """The frames of one topic of an MCAP file as arrays (:func:`topics_frames` of one
    topic; for several topics of one file call that once)."""
    return topics_frames(path, [topic])[topic]

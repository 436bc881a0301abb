"""The reference recordings of ``bags/`` (made by ``tools/make_bags.py``, ``make bags``).

* Each bag is at most 5 MB (25 MB in all) and holds exactly the topics its family records.
* Regeneration reproduces the committed bags message for message: every family is
  regenerated into a temporary directory (all six take about 8 s here, so none is left
  out) and its messages are compared deserialised, field by field, per topic and in order
  (raw CDR bytes differ in alignment padding), and so are their log times (sensor time,
  from epoch 0; ``publish_time`` is the wall clock and is not compared). The stage's
  identified parameter YAML must be the same text.
* Replay: the device topics of each bag are published through rclpy, as recorded, to a real
  estimator node built with the bag's parameters (those of ``make_bags.FAMILIES``); what it
  publishes must equal the estimates stored in the bag exactly (the pipeline is
  deterministic: same frames in, same floating-point operations).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import params, spin_until

from mems_sim.bag.player import Player, iter_messages, read_messages, recorded_topics
from mems_sim.bag.schema import message_class
from mems_sim.ros.qos import FRAME_QOS

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / "bags"


def _load_make_bags():
    """``tools/make_bags.py`` as a module (tools/ is not a package)."""
    if "make_bags" in sys.modules:
        return sys.modules["make_bags"]
    spec = importlib.util.spec_from_file_location("make_bags", REPO / "tools" / "make_bags.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_bags"] = module
    spec.loader.exec_module(module)
    return module


make_bags = _load_make_bags()
NAMES = list(make_bags.FAMILIES)


def difference(a, b, path: str = "") -> str | None:
    """Where two deserialised messages differ, field by field (None: equal). NaN equals NaN
    (the IMU model reports NaN for a correlation time it cannot identify)."""
    if hasattr(a, "get_fields_and_field_types"):
        if type(a) is not type(b):
            return f"{path}: {type(a).__name__} vs {type(b).__name__}"
        for name in a.get_fields_and_field_types():
            found = difference(getattr(a, name), getattr(b, name), f"{path}.{name}")
            if found:
                return found
        return None
    if isinstance(a, (str, bytes, bool, int, float)):
        same = a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b))
        return None if same else f"{path}: {a!r} vs {b!r}"
    if len(a) != len(b):
        return f"{path}: {len(a)} vs {len(b)} elements"
    if len(a) and hasattr(a[0], "get_fields_and_field_types"):
        for k, (x, y) in enumerate(zip(a, b)):
            found = difference(x, y, f"{path}[{k}]")
            if found:
                return found
        return None
    x, y = np.asarray(a), np.asarray(b)
    numeric = x.dtype.kind in "fc" and y.dtype.kind in "fc"
    same = np.array_equal(x, y, equal_nan=numeric)
    return None if same else f"{path}: arrays differ"


def assert_same_messages(new: list, old: list, what: str) -> None:
    """Same number of messages, each equal field by field."""
    assert len(new) == len(old), f"{what}: {len(new)} messages, {len(old)} stored"
    for k, (a, b) in enumerate(zip(new, old)):
        found = difference(a, b)
        assert found is None, f"{what} message {k}: {found}"


def messages_by_topic(path: Path) -> dict[str, list]:
    """Deserialised messages of a bag, per topic, in recording order."""
    out: dict[str, list] = {}
    for topic, _, _, msg in read_messages(str(path)):
        out.setdefault(topic, []).append(msg)
    return out


def test_sizes_and_topics():
    sizes = {}
    for name, family in make_bags.FAMILIES.items():
        path = BAGS / f"{name}.mcap"
        sizes[name] = path.stat().st_size
        assert sizes[name] <= 5_000_000, (name, sizes[name])
        assert sorted(recorded_topics(str(path))) == sorted(family.recorded()), name
    assert sum(sizes.values()) <= 25_000_000, sizes
    assert (BAGS / make_bags.STAGE_YAML).is_file()


@pytest.mark.parametrize("name", NAMES)
def test_regeneration_reproduces_the_bag(name, tmp_path, domain_id):
    family = make_bags.FAMILIES[name]
    result = make_bags.generate(family, tmp_path, domain_id=domain_id)
    new, old = messages_by_topic(result["path"]), messages_by_topic(BAGS / f"{name}.mcap")
    assert sorted(new) == sorted(old)
    for topic, messages in old.items():
        assert_same_messages(new[topic], messages, f"{name}: {topic}")
    log_times = [{}, {}]  # per topic, in order (across topics equal times may swap)
    for times, path in zip(log_times, (result["path"], BAGS / f"{name}.mcap")):
        for m in iter_messages(str(path)):
            times.setdefault(m.topic, []).append(m.log_time_ns)
    assert log_times[0] == log_times[1], f"{name}: log times"
    if family.prepare is not None:
        assert (tmp_path / make_bags.STAGE_YAML).read_text() == (
            BAGS / make_bags.STAGE_YAML
        ).read_text()


def _collect(probe, bag: Path, topics: list[str]) -> dict[str, list]:
    """Subscribe the probe to ``topics`` (types from the bag); received messages per topic."""
    types = recorded_topics(str(bag))
    got: dict[str, list] = {t: [] for t in topics}
    for topic in topics:
        probe.create_subscription(
            message_class(types[topic][0]), topic, got[topic].append, FRAME_QOS
        )
    return got


def _feed(executor, player: Player, family, est, bag: Path, window: int = 50) -> None:
    """Publish the bag's device topics in recording order, keeping at most ``window`` frames
    ahead of what the estimator has consumed (its subscriptions keep 1000)."""
    sent = {t: 0 for t in player.publishers}
    for item in iter_messages(str(bag), list(player.publishers)):
        player.publishers[item.topic].publish(item.data)
        sent[item.topic] += 1
        assert spin_until(
            executor, lambda: min(sent.values()) - family.consumed(est) < window, timeout=30
        )
    n = min(sent.values())
    assert spin_until(executor, lambda: family.consumed(est) >= n, timeout=30)


@pytest.mark.parametrize("name", NAMES)
def test_replay_reproduces_the_stored_estimates(name, graph):
    ctx, executor, probe = graph
    family = make_bags.FAMILIES[name]
    bag = BAGS / f"{name}.mcap"
    est = family.estimator(
        context=ctx,
        namespace=family.namespace,
        parameter_overrides=params(**family.replay_params(BAGS)),
    )
    executor.add_node(est)
    outputs = [family.topic(t) for t in family.outputs]
    got = _collect(probe, bag, outputs)
    player = Player(probe, str(bag), topics=[family.topic(t) for t in family.inputs])
    assert player.wait_for_subscribers(1, 10.0)
    assert spin_until(
        executor,
        lambda: all(p.get_subscription_count() >= 1 for p in est.publishers if p.topic_name in got),
    )
    _feed(executor, player, family, est, bag)
    make_bags.finish(est)
    stored = messages_by_topic(bag)
    assert spin_until(
        executor, lambda: all(len(got[t]) >= len(stored[t]) for t in outputs), timeout=30
    ), {t: (len(got[t]), len(stored[t])) for t in outputs}
    for topic in outputs:
        assert_same_messages(got[topic], stored[topic], f"{name}: replayed {topic}")
    executor.remove_node(est)
    est.destroy_node()

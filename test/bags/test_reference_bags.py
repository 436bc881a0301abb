"""The reference recordings of ``bags/`` (made by ``tools/make_bags.py``, ``make bags``).

* Each bag is at most 5 MB (25 MB in all) and holds exactly the topics its family records.
* Regeneration reproduces the committed bags message for message: every family is
  regenerated into a temporary directory (all six take about 8 s here, so none is left
  out) and its messages are compared deserialised, field by field, per topic and in order
  (raw CDR bytes differ in alignment padding), by the reference rule of docs/testing.md
  (``reference_rule``: codes, stamps and kernel outputs exact, fitted floats within 1e-9
  relative), and so are their log times (sensor time, from epoch 0; ``publish_time`` is the
  wall clock and is not compared). The stage's identified parameter YAML: the fitted rule.
* Replay: the device topics of each bag are published through rclpy, as recorded, to a real
  estimator node built with the bag's parameters (those of ``make_bags.FAMILIES``); what it
  publishes must equal the estimates stored in the bag exactly (the pipeline is
  deterministic: same frames in, same floating-point operations).
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import params, spin_until
from portable_probe import TARGETS
from reference_rule import data_difference, difference

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


#: Topics whose floats come from a fit or an optimiser (or from a filter built from a fit
#: that regeneration repeats), compared by the fitted rule of ``reference_rule``; every other
#: topic (codes, truth, drive, kernel outputs) exactly. Replay loads the stored stage YAML,
#: so there the stage estimates are exact too.
FITTED_IN_REGENERATION = {"/imu/noise_model", "/stage/estimate"}
FITTED_IN_REPLAY = {"/imu/noise_model"}


def assert_same_messages(new: list, old: list, what: str, fitted: bool = False) -> None:
    """Same number of messages, each equal field by field under the reference rule."""
    assert len(new) == len(old), f"{what}: {len(new)} messages, {len(old)} stored"
    for k, (a, b) in enumerate(zip(new, old)):
        found = difference(a, b, fitted)
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
    assert_regenerated_like_the_bags(name, tmp_path)
    log_times = [{}, {}]  # per topic, in order (across topics equal times may swap)
    for times, path in zip(log_times, (result["path"], BAGS / f"{name}.mcap")):
        for m in iter_messages(str(path)):
            times.setdefault(m.topic, []).append(m.log_time_ns)
    assert log_times[0] == log_times[1], f"{name}: log times"


def assert_regenerated_like_the_bags(name: str, out: Path) -> None:
    """The bag ``out/<name>.mcap`` (and its stage YAML) equals ``bags/`` by the rule."""
    family = make_bags.FAMILIES[name]
    new, old = messages_by_topic(out / f"{name}.mcap"), messages_by_topic(BAGS / f"{name}.mcap")
    assert sorted(new) == sorted(old)
    for topic, messages in old.items():
        fitted = topic in FITTED_IN_REGENERATION
        assert_same_messages(new[topic], messages, f"{name}: {topic}", fitted)
    if family.prepare is not None:
        new_yaml, old_yaml = (
            yaml.safe_load((d / make_bags.STAGE_YAML).read_text()) for d in (out, BAGS)
        )
        assert data_difference(new_yaml, old_yaml) is None, data_difference(new_yaml, old_yaml)


@pytest.mark.slow
@pytest.mark.parametrize("target", list(TARGETS))
@pytest.mark.parametrize("name", NAMES)
def test_regeneration_on_another_cpu_target(name, target, tmp_path, subprocess_env):
    """``make bags`` compiled for another numba target (code generation for another CPU on
    this one) regenerates every reference bag by the reference rule."""
    env = dict(subprocess_env, **TARGETS[target])
    cmd = [sys.executable, str(REPO / "tools" / "make_bags.py"), "--out", str(tmp_path)]
    run = subprocess.run(
        [*cmd, "--only", name], env=env, capture_output=True, text=True, timeout=1800
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert_regenerated_like_the_bags(name, tmp_path)


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
        fitted = topic in FITTED_IN_REPLAY
        assert_same_messages(got[topic], stored[topic], f"{name}: replayed {topic}", fitted)
    executor.remove_node(est)
    est.destroy_node()

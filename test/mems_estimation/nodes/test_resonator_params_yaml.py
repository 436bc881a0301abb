"""The resonator observer node takes f0 and Q from the bench identification's YAML
(``params_yaml``), not from its parameter table: a drawn device (device seed 5) is
identified on the bench, and the node's model equals the YAML."""

import pytest
from conftest import params
from resonator_bench import bench_ringdowns

from mems_estimation.identification.resonator_identification import (
    MODEL_KEYS,
    identify,
    load_identification,
    save_identification,
)
from mems_estimation.nodes.resonator_observer_node import OBSERVER_SPECS, ResonatorObserverNode
from mems_sim.devices.resonator import RESONATOR_SPECS
from mems_sim.params import ParameterError, draw_device, resolve, spec_table


@pytest.mark.parametrize("adaptive", [False, True])
def test_perturbed_device_observer_runs_with_the_identified_model(ros_context, tmp_path, adaptive):
    dp = draw_device(RESONATOR_SPECS, resolve(RESONATOR_SPECS, {}), 5)
    model = identify(bench_ringdowns(dp, 7_000_005), 1.0e6, 5.0e4, 100.0)["model"]
    path = tmp_path / "resonator_params.yaml"
    save_identification(model, str(path))
    table = spec_table(OBSERVER_SPECS)
    node = ResonatorObserverNode(
        context=ros_context,
        parameter_overrides=params(params_yaml=str(path), adaptive=adaptive, f0_hz=51_000.0),
    )
    try:
        yaml_model = load_identification(str(path))
        assert {k: node.p[k] for k in MODEL_KEYS} == yaml_model  # not the given 51 kHz
        for k in MODEL_KEYS:
            assert node.p[k] != table[k].default  # nor the table's nominal value
        m = node.observer.model if not adaptive else None
        if m is not None:
            assert (m.f0, m.Q) == (yaml_model["f0_hz"], yaml_model["quality_factor"])
    finally:
        node.destroy_node()


def test_node_refuses_a_bad_yaml(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="params_yaml"):
        ResonatorObserverNode(
            context=ros_context, parameter_overrides=params(params_yaml=str(tmp_path / "x.yaml"))
        )


def test_f0_error_is_put_on_the_yaml_model(ros_context, tmp_path):
    path = tmp_path / "resonator_params.yaml"
    save_identification(dict(f0_hz=50_100.0, quality_factor=95.0), str(path))
    node = ResonatorObserverNode(
        context=ros_context, parameter_overrides=params(params_yaml=str(path), f0_error=0.05)
    )
    try:
        assert node.p["f0_hz"] == 50_100.0  # reported as loaded; the error is its own value
        assert node.observer.model.f0 == pytest.approx(50_100.0 * 1.05, rel=1e-15)
    finally:
        node.destroy_node()

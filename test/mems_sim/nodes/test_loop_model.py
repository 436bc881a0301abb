"""``loop_params_yaml`` of the emulators with an estimator in their loop: the in-loop
estimator's model comes from an identified model's YAML, the plant stays the device as
given, and a missing or out-of-range file is refused naming the parameter."""

import pytest
from conftest import params

from mems_sim.nodes.resonator_node import ResonatorNode
from mems_sim.params import ParameterError


def test_resonator_loop_observer_runs_with_the_yaml(ros_context, tmp_path):
    path = tmp_path / "resonator_params.yaml"
    path.write_text("f0_hz: 50250.0\nquality_factor: 93.5\nfit: {n: 3}\n")
    node = ResonatorNode(
        context=ros_context,
        parameter_overrides=params(mode="observer", loop_params_yaml=str(path), f0_hz=49_800.0),
    )
    try:
        m = node.device.model
        assert (m.f0, m.Q) == (50_250.0, 93.5)  # the YAML's, not the given 49.8 kHz
        assert node.device.params["f0_hz"] == 49_800.0  # the plant: the device as given
    finally:
        node.destroy_node()


def test_resonator_refuses_a_bad_loop_yaml(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="loop_params_yaml.*not found"):
        ResonatorNode(
            context=ros_context,
            parameter_overrides=params(loop_params_yaml=str(tmp_path / "missing.yaml")),
        )
    bad = tmp_path / "bad.yaml"
    bad.write_text("f0_hz: -5.0\nquality_factor: 100.0\n")
    with pytest.raises(ParameterError, match="loop_params_yaml.*f0_hz"):
        ResonatorNode(context=ros_context, parameter_overrides=params(loop_params_yaml=str(bad)))

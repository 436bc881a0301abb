"""The accelerometer's hybrid EKFs take their model from the bench identification's YAML,
not from the parameter table: a drawn device (device seed 12: spring +8 %, damping -15 %)
is identified on the bench; the downstream node (``params_yaml``) and the device's in-loop
filter (``loop_params_yaml``) then run with the YAML's model, whatever the table says."""

import numpy as np
import pytest
from conftest import params

from mems_estimation.identification.accelerometer_identification import (
    load_identification,
    save_identification,
)
from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
from mems_estimation.studies.accelerometer_bench import bench_identification
from mems_sim.devices import accelerometer
from mems_sim.devices.accelerometer_specs import ACCEL_SPECS
from mems_sim.nodes.accelerometer_node import AccelerometerNode
from mems_sim.params import ParameterError, draw_device, resolve


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    nominal = resolve(ACCEL_SPECS, {})
    device = draw_device(ACCEL_SPECS, nominal, 12)
    path = tmp_path_factory.mktemp("accel") / "accelerometer_params.yaml"
    save_identification(bench_identification(device, nominal, seed=5)["model"], str(path))
    return path


def _expected_model(path, **given):
    """The EKF model vector of the table's values with the YAML's model on top."""
    p = accelerometer.validate_params(
        dict(resolve(ACCEL_SPECS, given), **load_identification(str(path)))
    )
    return accelerometer.plant_vector(p, accelerometer.bias_voltage(p))


def test_downstream_filter_runs_with_the_identified_model(ros_context, identified):
    # a perturbed table: the node is given another spring and gap than the device's
    given = dict(stiffness=2.5, gap=2.1e-6)
    node = AccelerometerEkfNode(
        context=ros_context, parameter_overrides=params(params_yaml=str(identified), **given)
    )
    try:
        model = node.filter.config.model
        assert np.array_equal(model, _expected_model(identified, **given))
        yaml_model = load_identification(str(identified))
        assert (model[0], model[1], model[2], model[5]) == tuple(
            yaml_model[k] for k in ("mass", "stiffness", "damping", "gap")
        )
        assert model[1] != given["stiffness"] and model[5] != given["gap"]
    finally:
        node.destroy_node()


def test_in_loop_filter_runs_with_the_identified_model(ros_context, identified):
    node = AccelerometerNode(
        context=ros_context,
        parameter_overrides=params(
            mode="ekf_rebalance", loop_params_yaml=str(identified), stiffness=2.5
        ),
    )
    try:
        d = node.device
        expected = _expected_model(identified, mode="ekf_rebalance", stiffness=2.5)
        # V_B stays the designer's (the table as given): the electronics' setting
        expected[8] = d.v_b
        assert np.array_equal(d.ekf_config.model, expected)
        assert d.ekf_config.model[1] == load_identification(str(identified))["stiffness"]
        assert d.mv[1] == 2.5  # the plant is the device as given, not the YAML
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    "node_class, name",
    [(AccelerometerEkfNode, "params_yaml"), (AccelerometerNode, "loop_params_yaml")],
)
def test_nodes_refuse_a_bad_yaml(ros_context, tmp_path, node_class, name):
    with pytest.raises(ParameterError, match=name):
        node_class(
            context=ros_context, parameter_overrides=params(**{name: str(tmp_path / "x.yaml")})
        )
    bad = tmp_path / "bad.yaml"
    good = dict(mass=3.8e-9, stiffness=3.0, damping=7.0e-4, gap=2.3e-6, electronic_accel_std=0.2)
    bad.write_text("".join(f"{k}: {v!r}\n" for k, v in dict(good, gap=2.0).items()))
    with pytest.raises(ParameterError, match="gap"):
        node_class(context=ros_context, parameter_overrides=params(**{name: str(bad)}))

"""The shared-electrode EKF/UKF node takes its model from the bench's identification YAML
(``params_yaml``) of a perturbed device (device_seed 5), not from the nominal table, and
refuses a missing or broken one."""

import pytest
from conftest import params

from mems_estimation.identification.scanner_amdm_identification import (
    MODEL_KEYS,
    save_identification,
)
from mems_estimation.nodes.scanner_amdm_estimator_node import ScannerAmdmEstimatorNode
from mems_estimation.studies import scanner_amdm_bench as bench
from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import ParameterError, draw_device


def test_node_runs_with_the_bench_model_of_a_drawn_device(ros_context, tmp_path):
    p = dict(sa.SWEEP_STUDY, torque_noise_std=1.15e-14 * (1.0e11 * 10) ** 0.5)
    device = sa.resolve_amdm(draw_device(sa.AMDM_SPECS, sa.resolve_amdm(p), 5, 0.0))
    model = bench.run_bench(device, 123)["model"]
    path = tmp_path / "scanner_amdm_params.yaml"
    save_identification(model, str(path))
    table = sa.resolve_amdm()
    node = ScannerAmdmEstimatorNode(
        context=ros_context, parameter_overrides=params(params_yaml=str(path))
    )
    try:
        want = {k: model[k] for k in MODEL_KEYS}
        assert {k: node.est_params[k] for k in MODEL_KEYS} == want
        for f in node.filters.values():
            assert {k: f.p[k] for k in MODEL_KEYS} == want
        # the drawn spring is 9 % off the table's: the node must not run the table's
        assert abs(node.est_params["spring_constant"] / table["spring_constant"] - 1) > 0.05
        # identified: w_n = sqrt(k/J) (J the design value, the drawn one 2 % apart)
        est = node.est_params
        assert (est["spring_constant"] / est["inertia"]) ** 0.5 == pytest.approx(
            (device["spring_constant"] / device["inertia"]) ** 0.5, rel=2e-5
        )
    finally:
        node.destroy_node()


def test_node_refuses_a_bad_yaml(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="params_yaml"):
        ScannerAmdmEstimatorNode(
            context=ros_context, parameter_overrides=params(params_yaml=str(tmp_path / "x.yaml"))
        )
    bad = tmp_path / "bad.yaml"
    bad.write_text("inertia: 1.0e-14\n")
    with pytest.raises(ParameterError, match="lacks"):
        ScannerAmdmEstimatorNode(
            context=ros_context, parameter_overrides=params(params_yaml=str(bad))
        )

"""The threshold hybrid-EKF node takes its model from the identification YAML
(``params_yaml``), over the parameters it was given, and refuses a missing or broken one."""

import pytest
from conftest import params

from mems_estimation.identification.scanner_threshold_identification import (
    MODEL_KEYS,
    save_identification,
)
from mems_estimation.nodes.scanner_threshold_ekf_node import ScannerThresholdEkfNode
from mems_estimation.studies.scanner_threshold import identified_parameters
from mems_sim.params import ParameterError

MODEL = dict(
    model_natural_freq_hz=640.5,
    model_damping_ratio=0.0071,
    model_inertia=3.25e-13,
    model_threshold_angle=0.0031,
    model_sense_c0=1.1e-12,
    model_sense_theta0=0.052,
    model_drive_c0=2.9e-12,
    model_drive_theta0=0.049,
    sense_resistance=1.0e7,
    bias_voltage=10.0,
    sample_rate_hz=5.0e5,
    r_cap=0.0019,
)


def test_node_runs_with_the_yaml_model(ros_context, tmp_path):
    path = tmp_path / "scanner_params.yaml"
    save_identification(dict(MODEL, identification={"source": "test"}), str(path))
    node = ScannerThresholdEkfNode(
        context=ros_context,
        parameter_overrides=params(params_yaml=str(path), model_natural_freq_hz=600.0),
    )
    try:
        assert {k: node.p[k] for k in MODEL_KEYS} == MODEL  # the YAML's, not the given 600 Hz
        for f in (node.hybrid, node.plain):  # both filters are built from it
            assert {k: f.p[k] for k in MODEL_KEYS} == MODEL
        expected = identified_parameters(MODEL)
        assert node.detector.p["noise_std"] == pytest.approx(expected["r_cap"] ** 0.5)
    finally:
        node.destroy_node()


def test_node_refuses_a_bad_yaml(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="params_yaml"):
        ScannerThresholdEkfNode(
            context=ros_context, parameter_overrides=params(params_yaml=str(tmp_path / "x.yaml"))
        )
    bad = tmp_path / "bad.yaml"
    bad.write_text("model_natural_freq_hz: 600.0\n")
    with pytest.raises(ParameterError, match="lacks"):
        ScannerThresholdEkfNode(
            context=ros_context, parameter_overrides=params(params_yaml=str(bad))
        )

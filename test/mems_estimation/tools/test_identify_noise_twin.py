"""``identify_noise --twin``: a parameter file imu_node takes, of the recorded IMU's rate,
resolution and mean; refused onto an existing file without --overwrite."""

from __future__ import annotations

import numpy as np
import yaml
from identify_noise_helpers import IMU_BAG, run_identify_noise

from mems_sim.devices.imu import ImuNoiseModel
from mems_sim.nodes.imu_node import ImuNode

BAG = IMU_BAG


_run = run_identify_noise


def test_twin_file_is_an_imu_node_parameter_file(tmp_path):
    twin = tmp_path / "twin.yaml"
    code, out, err = _run([BAG, "--twin", twin])
    assert code == 0, err
    assert f"twin: {twin} (imu_node --params-file;" in out
    params = yaml.safe_load(twin.read_text())["/**"]["ros__parameters"]
    names = {s.name for s in ImuNode.SPECS}
    assert set(params) <= names
    assert params["sample_rate_hz"] == 100.0 and params["bits"] >= 14
    assert params["gyro_lsb"] == ImuNoiseModel().params["gyro_lsb"]  # the frames' own LSB
    model = ImuNoiseModel(params, seed=3)
    f = model.generate(20_000)
    # the twin's mean is the record's (gyro: the axis biases; accel: on top of [0, 0, g])
    from mems_estimation.tools.identify_noise import identify_bag

    _, _, _, acc = identify_bag(BAG, "/imu/adc", "octave")
    means = acc.results()[1]
    axes = ("x", "y", "z")
    assert [params[f"gyro_axis_bias_{a}"] for a in axes] == list(means[:3])
    assert [params[f"accel_axis_bias_{a}"] for a in axes] == list(means[3:] - [0, 0, 9.80665])
    assert np.all(np.isfinite(f.gyro_si)) and f.gyro_codes.shape == (20_000, 3)
    code, _, err = _run([BAG, "--twin", twin])
    assert code == 2 and "--twin" in err and len(err.strip().splitlines()) == 1
    assert _run([BAG, "--twin", twin, "--overwrite"])[0] == 0

"""Bench identification of the force-rebalance accelerometer's model
(mems_estimation.identification.accelerometer_identification): the linear response of a
synthetic record, and the emulated device on the bench (nominal and drawn devices), whose
mass, spring, damping, gap and readout noise the fit finds without the parameter table."""

import numpy as np
import pytest

from mems_estimation.identification.accelerometer_identification import (
    MODEL_KEYS,
    load_identification,
    response_fit,
    save_identification,
    simulate,
    square_wave,
)
from mems_estimation.studies.accelerometer_bench import bench_identification
from mems_sim.devices import accelerometer
from mems_sim.devices.accelerometer_specs import ACCEL_SPECS
from mems_sim.params import draw_device, resolve

FS = 1.0e6
#: Zhang ch. 5 noise (the scenario's): 500 ug Brownian, 0.02 g electronic per sample.
NOISE = dict(
    brownian_accel_std=500e-6 * accelerometer.G0, electronic_accel_std=0.02 * accelerometer.G0
)


def test_synthetic_records_recover_the_linear_model():
    rng = np.random.default_rng(4)
    a = square_wave(50_000, FS, 9.8, 0.5e-3)
    truth = (1.7e5, 2.9e8, 2.0e8, 7.0e5)
    recs = {
        name: (
            a,
            simulate(a, FS, truth[0], w2, truth[3]) + 0.01 + 2e-4 * rng.standard_normal(a.size),
        )
        for name, w2 in (("open", truth[1]), ("bias", truth[2]))
    }
    guess = dict(damping_per_mass=2.0e5, omega2_open=2.5e8, omega2_bias=1.8e8, readout_gain=8e5)
    fit = response_fit(recs, FS, guess)
    got = (fit.damping_per_mass, fit.omega2_open, fit.omega2_bias, fit.readout_gain)
    for g, t, se in zip(got, truth, fit.std_errors, strict=True):
        assert abs(g - t) < 4 * se, (g, t, se)  # unbiased within its standard error
        assert se / t < 0.01
    assert fit.residual_std[0] == pytest.approx(2e-4, rel=0.02)


def test_fit_refuses_a_short_or_missing_record():
    a = np.zeros(100)
    with pytest.raises(ValueError, match="1000"):
        response_fit({"open": (a, a), "bias": (a, a)}, FS, {})
    with pytest.raises(ValueError, match="'bias'"):
        response_fit({"open": (np.zeros(2000), np.zeros(2000))}, FS, {})


@pytest.mark.parametrize("device_seed", [None, 3, 12])
def test_bench_identifies_the_device_as_built(device_seed):
    nominal = resolve(ACCEL_SPECS, NOISE)
    device = nominal if device_seed is None else draw_device(ACCEL_SPECS, nominal, device_seed)
    out = bench_identification(device, nominal, seed=41)
    model = out["model"]
    # measured (noise seeds 41/42, 0.1 s records): every error below 0.25 % on these draws,
    # whose spring and damping differ from the table by up to 8.5 and 14.5 %
    for k in MODEL_KEYS:
        assert model[k] / device[k] - 1 == pytest.approx(0.0, abs=0.01), k
    if device_seed is not None:
        moved = [k for k in ("stiffness", "damping") if abs(device[k] / nominal[k] - 1) > 0.03]
        assert moved, "the draw should move the spring or the damping"
        for k in moved:  # closer to the device than to the table
            assert abs(model[k] / device[k] - 1) < abs(model[k] / nominal[k] - 1)


def test_identification_yaml_round_trip(tmp_path):
    model = dict(mass=3.7e-9, stiffness=2.8, damping=8e-4, gap=2.4e-6, electronic_accel_std=0.19)
    path = tmp_path / "accel.yaml"
    save_identification(model, str(path))
    assert load_identification(str(path)) == model
    path.write_text("mass: 3.7e-9\n")
    with pytest.raises(ValueError, match="lacks stiffness"):
        load_identification(str(path))
    path.write_text(
        path.read_text().replace("3.7e-9", "-1")
        + "stiffness: 1\ndamping: 1\ngap: 1.0e-6\nelectronic_accel_std: 1\n"
    )
    with pytest.raises(ValueError, match="mass"):
        load_identification(str(path))

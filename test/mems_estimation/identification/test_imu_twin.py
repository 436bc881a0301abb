"""The digital twin of a recorded IMU: identified on a record the project did not generate
(allantools' Kasdin & Walter generator: white + flicker + random-walk rate noise at known
levels, quantised, with a mean), emulated by the project's IMU model for the same length,
and its Allan deviation against the record's."""

import math

import numpy as np
import pytest
from kasdin_records import kasdin_rate

from mems_estimation.identification.allan import allan_analysis, local_slope
from mems_estimation.identification.imu_twin import (
    G0,
    twin_parameters,
    twin_yaml,
    value_resolution,
)
from mems_estimation.nodes.imu_noise_identifier_node import NoiseAccumulator
from mems_estimation.tools.noise_choice_report import axis_choices
from mems_sim.devices.imu import ImuNoiseModel

FS = 200.0
N_SAMPLES = 1 << 19
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
UNITS = ("rad/s",) * 3 + ("m/s^2",) * 3
#: Per sensor: N [u sqrt(s)], flicker B [u], K [u/sqrt(s)], LSB [u], means of x, y, z [u].
LEVELS = {
    "gyro": (2e-4, 1.5e-4, 2e-6, 2e-5, (1e-3, -2e-3, 3e-4)),
    "accel": (1.5e-3, 1e-3, 4e-5, 1e-4, (0.01, -0.02, G0 + 0.05)),
}


@pytest.fixture(scope="module")
def record():
    cols = []
    for i, s in enumerate(("gyro", "accel")):
        N, B, K, lsb, means = LEVELS[s]
        for j, m in enumerate(means):
            x = kasdin_rate(N_SAMPLES, FS, N, B, K, seed=100 + 3 * i + j) + m
            cols.append(np.rint(x / lsb) * lsb)
    return np.column_stack(cols)


@pytest.fixture(scope="module")
def twin(record):
    acc = NoiseAccumulator("octave")
    acc.start(FS, 0, CHANNELS, UNITS)
    acc.extend(record)
    steps = [value_resolution(record[:, j]) for j in range(6)]
    params = twin_parameters(
        axis_choices(acc), CHANNELS, FS, acc.duration_s(), list(record.mean(axis=0)), steps
    )
    return params


def test_twin_parameters_see_rate_resolution_mean_and_flicker(record, twin):
    assert twin["_models"] == {"gyro": "flicker", "accel": "flicker"}
    assert twin["sample_rate_hz"] == FS
    for s in ("gyro", "accel"):
        N, B, K, lsb, means = LEVELS[s]
        assert twin[f"{s}_lsb"] == pytest.approx(lsb, rel=1e-9)
        assert twin[f"{s}_bias_instability"] == 0.0
        assert twin[f"{s}_flicker_coefficient"] == pytest.approx(B, rel=0.25)
        assert twin[f"{s}_noise_density"] == pytest.approx(N, rel=0.05)
    m = record.mean(axis=0)
    assert twin["accel_axis_bias_z"] == m[5] - G0 and twin["gyro_axis_bias_x"] == m[0]
    assert value_resolution(np.array([0.25, 0.5, 1.5])) == pytest.approx(0.25)
    assert value_resolution(np.array([0.0, 1.0, math.pi])) is None
    text = twin_yaml(twin, "a record")
    assert text.startswith("# Digital twin of a record") and "_models" not in text


def test_twin_allan_deviation_agrees_with_the_record(record, twin):
    """|ln sigma_twin(tau) - ln sigma_rec(tau)| <= 1.96 sqrt(var_rec + var_twin) at >= 90 %
    of the octave taus pooled over the 6 axes; var(ln sigma) = 1/(2 edf), the edf of each
    point for the record's local slope."""
    params = {k: v for k, v in twin.items() if not k.startswith("_")}
    f = ImuNoiseModel(params, seed=7).generate(N_SAMPLES)
    emulated = np.hstack([f.gyro_si, f.accel_si])
    inside, total = 0, 0
    for j in range(6):
        rec = allan_analysis(record[:, j], FS, "octave")
        slope = local_slope(rec.taus, rec.avar)
        rec = allan_analysis(record[:, j], FS, "octave", slope=slope)
        emu = allan_analysis(emulated[:, j], FS, rec.taus, slope=slope)
        bound = 1.96 * np.sqrt(1.0 / (2 * rec.edf) + 1.0 / (2 * emu.edf))
        ok = np.abs(np.log(emu.adev) - np.log(rec.adev)) <= bound
        inside += int(ok.sum())
        total += ok.size
    assert inside >= 0.9 * total, f"{inside} of {total} octave taus inside"


def test_twin_model_inside_the_record_95_percent_band(record, twin):
    """The twin model's analytic Allan deviation (white N^2/tau, random walk K^2 tau/3, the
    emulator's flicker generator in closed form, quantisation LSB^2/12 as white noise of one
    sample) inside the record's 95 % chi-square band (edf for its local slope) at >= 90 %
    of the octave taus pooled over the 6 axes."""
    from mems_sim.hardware.flicker import FlickerConfig, flicker_avar

    inside, total = 0, 0
    for j, name in enumerate(CHANNELS):
        s = name.split("_")[0]
        rec = allan_analysis(record[:, j], FS, "octave")
        rec = allan_analysis(
            record[:, j], FS, "octave", confidence=0.95, slope=local_slope(rec.taus, rec.avar)
        )
        taus = rec.taus
        config = FlickerConfig(
            twin[f"{s}_flicker_coefficient"],
            twin[f"{s}_flicker_f_low_hz"],
            twin[f"{s}_flicker_f_high_hz"],
            2,
        )
        white = twin[f"{s}_noise_density"] ** 2 + twin[f"{s}_lsb"] ** 2 / 12 / FS
        avar = white / taus + twin[f"{s}_random_walk"] ** 2 * taus / 3
        adev = np.sqrt(avar + flicker_avar(taus, FS, config))
        ok = (adev >= rec.ci_low) & (adev <= rec.ci_high)
        inside += int(ok.sum())
        total += ok.size
    assert inside >= 0.9 * total, f"{inside} of {total} octave taus inside"

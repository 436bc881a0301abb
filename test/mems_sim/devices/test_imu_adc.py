"""The IMU's ADC static errors (``{gyro,accel}_adc_*``): all 0 is the ideal quantiser bit
for bit; an offset moves the codes by exactly that many LSB before rounding; a gain error
scales them; missing codes never appear and their neighbours take their inputs; the DNL
pattern is the part's (``adc_part_seed``, per axis), not the run's; any frame size gives
the same codes; bad values are refused with the parameter's name."""

from __future__ import annotations

import numpy as np
import pytest

from mems_sim.devices.imu import ImuNoiseModel
from mems_sim.hardware.converter import part_seed
from mems_sim.params import ParameterError

#: A quiet IMU whose inputs span many codes: white noise of ~40 LSB per sample.
BASE = {
    "gyro_bias_instability": 0.0,
    "gyro_random_walk": 0.0,
    "accel_bias_instability": 0.0,
    "accel_random_walk": 0.0,
}


def codes(params, n=20_000, seed=4, frame=None):
    m = ImuNoiseModel({**BASE, **params}, seed=seed)
    if frame is None:
        f = m.generate(n)
        return np.hstack([f.gyro_codes, f.accel_codes]), f
    parts = [m.generate(frame) for _ in range(n // frame)]
    return np.vstack([np.hstack([f.gyro_codes, f.accel_codes]) for f in parts]), parts[-1]


def test_all_zero_is_the_ideal_quantiser_and_a_converter_is_built_only_when_asked():
    m = ImuNoiseModel(BASE, seed=4)
    assert m.sensors["gyro"].converters is None and m.sensors["accel"].converters is None
    ideal, _ = codes({})
    # an explicit zero table equals the default, and a converter with every error 0 is the
    # ideal quantiser (mems_sim.hardware.converter), so a tiny INL is needed to differ
    same, _ = codes({"gyro_adc_offset_lsb": 0.0, "adc_part_seed": 99})
    np.testing.assert_array_equal(same, ideal)
    bent, _ = codes({"gyro_adc_inl_lsb": 1e-9})
    assert ImuNoiseModel({**BASE, "gyro_adc_inl_lsb": 1e-9}).sensors["gyro"].converters
    np.testing.assert_array_equal(bent, ideal)  # 1e-9 LSB moves no transition in range


def test_offset_shifts_the_codes_of_that_sensor_only():
    ideal, f0 = codes({})
    shifted, f1 = codes({"gyro_adc_offset_lsb": 3.0})
    np.testing.assert_array_equal(shifted[:, :3], ideal[:, :3] + 3)
    np.testing.assert_array_equal(shifted[:, 3:], ideal[:, 3:])
    # the reported value is the code times the LSB, as a driver converts it
    np.testing.assert_array_equal(
        f1.gyro_si, f1.gyro_codes * f1.gyro_si[0, 0] / f1.gyro_codes[0, 0]
    )


def test_gain_error_scales_the_codes():
    ideal, _ = codes({})
    gained, _ = codes({"accel_adc_gain_error": 0.01})
    d = gained[:, 3:] - ideal[:, 3:]
    big = np.abs(ideal[:, 3:]) > 300
    rel = d[big] / ideal[:, 3:][big]
    assert np.all(np.abs(rel - 0.01) < 1.5 / 300), (rel.min(), rel.max())
    np.testing.assert_array_equal(gained[:, :3], ideal[:, :3])


def test_missing_codes_never_appear_and_the_pattern_is_the_parts():
    ideal, _ = codes({})
    # a quarter of the 14-bit codes missing, so that many fall where the data are
    p = {"gyro_adc_missing_codes": 4000, "gyro_adc_dnl_lsb": 0.2}
    a, _ = codes(p)
    m = ImuNoiseModel({**BASE, **p}, seed=4)
    for j, conv in enumerate(m.sensors["gyro"].converters):
        missing = conv.missing_codes
        assert len(missing) == 4000
        assert not np.isin(a[:, j], missing).any()
        assert conv.params["seed"] == part_seed(0, "imu_adc", j)
    hit = np.isin(ideal[:, 0], m.sensors["gyro"].converters[0].missing_codes)
    assert hit.mean() > 0.1  # the ideal ADC does produce those codes
    # another run seed: the same part (the same pattern); another part: another pattern
    again = ImuNoiseModel({**BASE, **p}, seed=9)
    other = ImuNoiseModel({**BASE, **p, "adc_part_seed": 1}, seed=4)
    g0 = m.sensors["gyro"].converters[0]
    assert again.sensors["gyro"].converters[0].missing_codes == g0.missing_codes
    assert other.sensors["gyro"].converters[0].missing_codes != g0.missing_codes
    axes = [c.missing_codes for c in m.sensors["gyro"].converters]
    assert len(set(axes)) == 3


def test_any_frame_size_gives_the_same_codes():
    p = {"gyro_adc_dnl_lsb": 0.3, "accel_adc_inl_lsb": 2.0, "accel_adc_missing_codes": 5}
    whole, _ = codes(p, n=12_000)
    framed, _ = codes(p, n=12_000, frame=1000)
    np.testing.assert_array_equal(whole, framed)


@pytest.mark.parametrize(
    "params, words",
    [
        ({"gyro_adc_offset_lsb": 1.0, "bits": 24}, "'bits' = 24"),
        ({"accel_adc_missing_codes": 2**14}, "accel_adc_missing_codes"),
        ({"gyro_adc_inl_shape": "wave"}, "gyro_adc_inl_shape"),
        ({"gyro_adc_dnl_lsb": 0.9}, "gyro_adc_dnl_lsb"),
    ],
)
def test_bad_values_name_the_parameter(params, words):
    with pytest.raises(ParameterError, match=words.replace("(", r"\(")):
        ImuNoiseModel({**BASE, **params}, seed=1)

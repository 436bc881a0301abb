"""Static errors of the stage's readout ADCs (offset, gain, INL bow, DNL, missing codes):
off by default (today's codes bit for bit), otherwise each channel's codes are those of
its own converter model, and the configured errors are visible in the codes."""

import hashlib

import numpy as np
import pytest
from scipy.stats import norm

from mems_sim.devices.stage import CHANNELS, DriveSchedule, MicroStage
from mems_sim.devices.stage_readout import ADC_ERRORS, adc_seed, convert_channels
from mems_sim.hardware.converter import Converter
from mems_sim.hardware.fault_schedule import parse_schedule
from mems_sim.hardware.sensor_faults import SensorFaultInjector
from mems_sim.params import ParameterError

SCHEDULE = DriveSchedule([(1700.0, 1.0, 100)])
ERRORS = {
    "adc_offset_lsb": 2.5,
    "adc_gain_error": 2e-3,
    "adc_inl_lsb": 6.0,
    "adc_dnl_lsb": 0.2,
    "adc_missing_codes": 50,
}

#: SHA-256 of the int32 codes (42000, 4) of six 7000-sample frames of MicroStage({},
#: SCHEDULE, seed=9), recorded before the ADC static errors existed.
TODAY_CODES = "7272bb99a7d7ee0121f523d559c1ea824264a670d931f5d2f0033fa58a108995"


def _sha(codes):
    return hashlib.sha256(np.ascontiguousarray(codes, dtype="<i4").tobytes()).hexdigest()


def run(params, n_frames=6, frame=7000, seed=9, schedule=SCHEDULE):
    st = MicroStage(params, schedule, seed=seed)
    out = [st.step(frame) for _ in range(n_frames)]
    y = np.concatenate([f.y for f in out])
    codes = np.concatenate([f.codes for f in out])
    return st, y, codes, sum(f.saturated for f in out)


def test_default_is_todays_adc_bit_for_bit():
    st, _, codes, _ = run({})
    assert st.converters is None
    assert _sha(codes) == TODAY_CODES
    zero = {name: 0 for name in ADC_ERRORS}
    st0, _, codes0, _ = run({**zero, "adc_inl_shape": "cubic"})
    assert st0.converters is None
    np.testing.assert_array_equal(codes0, codes)


def test_codes_are_the_converters_codes_of_the_readout_voltages():
    st, y, codes, sat = run(ERRORS)
    assert st.converters is not None and len(st.converters) == 4
    expected_sat = 0
    for c in range(4):
        conv = Converter(
            {
                "bits": 16,
                "full_scale": 0.02,
                "offset_lsb": 2.5,
                "gain_error": 2e-3,
                "inl_peak_lsb": 6.0,
                "inl_shape": "parabola",
                "dnl_sd_lsb": 0.2,
                "missing_codes": 50,
                "seed": adc_seed(2018, c),
            }
        )
        q, over = conv.quantize(y[:, c])
        np.testing.assert_array_equal(codes[:, c], q)
        expected_sat += int(np.count_nonzero(over))
        assert len(conv.missing_codes) == 50
    assert sat == expected_sat
    # the errors move the codes off the ideal quantiser's by several codes
    ideal = np.rint(y / st.lsb)
    assert np.mean(np.abs(codes - ideal)) > 2.0


def test_each_channel_has_its_own_part_and_each_device_its_own_four():
    a = MicroStage({"adc_dnl_lsb": 0.2}, SCHEDULE).converters
    b = MicroStage({"adc_dnl_lsb": 0.2}, SCHEDULE).converters
    other = MicroStage({"adc_dnl_lsb": 0.2, "device_seed": 7}, SCHEDULE).converters
    for c in range(4):
        np.testing.assert_array_equal(a[c].dnl, b[c].dnl)
        assert not np.array_equal(a[c].dnl, other[c].dnl)
        for d in range(c):
            assert not np.array_equal(a[c].dnl, a[d].dnl)
        assert np.std(a[c].dnl) == pytest.approx(0.2, rel=0.05)


def test_offset_gain_and_inl_bow_visible_in_the_codes():
    """code ~= G u + V_os/Q - INL(k), INL(k) = peak (1 - (k/32767)^2) (parabola), u = y/Q:
    a least-squares fit of code - u = a + b u + c u^2 gives a = V_os/Q - peak, b = G - 1
    and c = peak / 32767^2 (the quantisation error, uniform +-1/2, averages out)."""
    params = {"adc_offset_lsb": 2.5, "adc_gain_error": 2e-3, "adc_inl_lsb": 12.0}
    sched = DriveSchedule([(1700.0, 1.3, 200)])
    st, y, codes, sat = run(params, n_frames=10, frame=10000, schedule=sched)
    assert sat == 0
    u = (y / st.lsb).reshape(-1)
    r = codes.reshape(-1) - u
    assert np.abs(u).max() > 5000  # enough span to see the bow
    basis = np.column_stack([np.ones_like(u), u, u * u])
    (a, b, c), *_ = np.linalg.lstsq(basis, r, rcond=None)
    assert a == pytest.approx(2.5 - 12.0, abs=0.003)
    assert b == pytest.approx(2e-3, abs=1e-7)
    assert c == pytest.approx(12.0 / 32767.0**2, rel=0.03)
    # the ideal quantiser's codes give none of it
    (a0, b0, c0), *_ = np.linalg.lstsq(basis, np.rint(u) - u, rcond=None)
    assert abs(a0) < 0.003 and abs(b0) < 1e-6 and abs(c0) < 0.03 * 12.0 / 32767.0**2


def test_code_density_of_the_noise_recovers_each_channels_dnl():
    """Zero drive: each channel's input is Gaussian readout noise of ~200 LSB RMS, so the
    expected count of code k is N (Phi((k + 1/2 - mu)/sd) - Phi((k - 1/2 - mu)/sd)) and
    count/expected - 1 estimates DNL[k] (IEEE Std 1241-2010 histogram test) within the
    Poisson error sqrt(1/expected) over the codes within one sd of the mean."""
    zero_drive = DriveSchedule([(1700.0, 0.0, 1000)])
    st, y, codes, _ = run({"adc_dnl_lsb": 0.3}, n_frames=1, frame=300000, schedule=zero_drive)
    u = y / st.lsb
    for c in range(4):
        conv = st.converters[c]
        mu, sd = float(np.mean(u[:, c])), float(np.std(u[:, c]))
        ks = np.arange(int(mu - sd), int(mu + sd) + 1)
        counts = np.bincount(codes[:, c] - conv.code_min, minlength=2**16)[ks - conv.code_min]
        expected = u.shape[0] * (norm.cdf((ks + 0.5 - mu) / sd) - norm.cdf((ks - 0.5 - mu) / sd))
        dnl_hat = counts / expected - 1.0
        dnl = conv.dnl[ks - conv.code_min - 1]
        poisson = np.sqrt(np.mean(1.0 / expected))
        assert np.corrcoef(dnl_hat, dnl)[0, 1] > 0.97
        assert np.sqrt(np.mean((dnl_hat - dnl) ** 2)) < 1.2 * poisson
        # the same check on the ideal quantiser's codes sees Poisson scatter only
        ideal = np.rint(u[:, c]).astype(np.int64)
        counts0 = np.bincount(ideal - conv.code_min, minlength=2**16)[ks - conv.code_min]
        assert np.sqrt(np.mean((counts0 / expected - 1.0) ** 2)) < 1.2 * poisson < 0.2


def test_fault_schedule_with_adc_errors_requantises_through_the_converters():
    entries = [
        {
            "kind": "bias_step",
            "channel": "2A",
            "start_sample": 1500,
            "duration_samples": 2000,
            "magnitude": 40.0 * 0.02 / 32768,
        }
    ]

    def frames(with_faults, frame):
        st = MicroStage(ERRORS, SCHEDULE, seed=9)
        if with_faults:
            sched = parse_schedule({"faults": entries}, CHANNELS, ("V",) * 4, st.fs)
            st.faults = SensorFaultInjector(sched, st.fs, 9, (st.noise_std,) * 4)
        out = [st.step(frame) for _ in range(6000 // frame)]
        return st, np.concatenate([f.y for f in out]), np.concatenate([f.codes for f in out])

    st, y0, c0 = frames(False, 1000)
    st1, y1, c1 = frames(True, 750)
    np.testing.assert_allclose(y1[1500:3500, 2] - y0[1500:3500, 2], 40.0 * st.lsb, rtol=1e-9)
    again, _ = convert_channels(st1.converters, y1)
    np.testing.assert_array_equal(c1, again)
    assert np.all(np.abs(c1[1500:3500, 2] - c0[1500:3500, 2] - 40.0 * 1.002) <= 2)
    mask = np.ones(c0.shape, bool)
    mask[1500:3500, 2] = False
    np.testing.assert_array_equal(c1[mask], c0[mask])


def test_too_many_missing_codes_and_too_many_bits_refused():
    with pytest.raises(ParameterError, match="adc_missing_codes"):
        MicroStage({"adc_bits": 8, "adc_missing_codes": 255}, SCHEDULE)
    MicroStage({"adc_bits": 8, "adc_missing_codes": 254}, SCHEDULE)
    with pytest.raises(ParameterError, match="adc_bits.*at most 20"):
        MicroStage({"adc_bits": 21, "adc_dnl_lsb": 0.1}, SCHEDULE)
    assert MicroStage({"adc_bits": 24}, SCHEDULE).converters is None  # ideal: any width

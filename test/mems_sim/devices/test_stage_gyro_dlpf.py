"""The on-stage gyro's digital low-pass (MPU-6500 DLPF_CFG): off by default (today's gyro
bit for bit); on, a first-order bilinear Butterworth at the table's bandwidth plus whole
samples of delay, against its closed-form response, frame-size independent, and the
apparent scale factor at 1.7 kHz it makes."""

import hashlib
import math

import numpy as np
import pytest
import scipy.signal

from mems_sim.devices.stage import DriveSchedule, MicroStage, record
from mems_sim.devices.stage_gyro import DLPF_TABLE, Dlpf, MemsGyro
from mems_sim.params import ParameterError

#: SHA-256 of the int32 gyro codes (538,) of MemsGyro(seed=9) on six 7000-sample frames of
#: MicroStage({}, [(1700 Hz, 1 V, 100 periods)], seed=9), recorded before the DLPF existed.
TODAY_GYRO = "4fda3ccf6428da30c4f8d7afa69e37b88983845a03cb2b57444f59fc5ca45188"


def closed_form(f, fc, fs, d):
    """First-order Butterworth by the prewarped bilinear transform, then z^-d:
    H = exp(-j 2 pi f d / fs) / (1 + j Omega), Omega = tan(pi f / fs) / tan(pi fc / fs)."""
    omega = np.tan(np.pi * f / fs) / np.tan(np.pi * fc / fs)
    return np.exp(-2j * np.pi * f * d / fs) / (1.0 + 1j * omega)


def test_default_gyro_is_todays_gyro_bit_for_bit():
    st = MicroStage({}, DriveSchedule([(1700.0, 1.0, 100)]), seed=9)
    g = MemsGyro(seed=9)
    assert g.dlpf is None
    codes = []
    for _ in range(6):
        k0 = st.next_index
        f = st.step(7000)
        codes.append(
            g.step(
                k0, st.fs, f.theta[:, 0], f.omega[:, 0], st.last_applied, st.wn, st.zeta, st.b_c
            ).codes
        )
    c = np.ascontiguousarray(np.concatenate(codes), dtype="<i4")
    assert hashlib.sha256(c.tobytes()).hexdigest() == TODAY_GYRO
    np.testing.assert_array_equal(g.dlpf_response([10.0, 1700.0]), [1.0, 1.0])


@pytest.mark.parametrize("cfg", [0, 3, 7])
def test_gain_and_phase_of_the_filter_against_its_closed_form(cfg):
    """Sinusoids through the stateful filter; after the transient, a least-squares fit of
    sin/cos at the input frequency gives H exactly (the steady state is a pure sinusoid)."""
    fc, tau, fs = DLPF_TABLE[cfg]
    filt = Dlpf(fc, tau, fs)
    d = filt.delay_samples
    n = 8000
    t = np.arange(n) / fs
    for f in (0.02 * fc, 0.5 * fc, fc, 2.0 * fc, min(6.0 * fc, 0.45 * fs)):
        filt._zi = None
        x = np.sin(2 * np.pi * f * t)
        y = filt(x)
        tail = slice(n // 2, n)
        basis = np.column_stack([np.sin(2 * np.pi * f * t[tail]), np.cos(2 * np.pi * f * t[tail])])
        (s, c), *_ = np.linalg.lstsq(basis, y[tail], rcond=None)
        h = complex(s, c)  # y = Re(H e^{j w t}) / sin -> s + j c
        want = closed_form(f, fc, fs, d)
        assert abs(h - want) < 1e-9 * abs(want) + 1e-12, (cfg, f, h, want)
        assert filt.response(f)[0] == pytest.approx(want, rel=1e-9)
    # -3 dB at the table's bandwidth (prewarped), unit gain at DC
    assert abs(filt.response(fc)[0]) == pytest.approx(1 / math.sqrt(2), rel=1e-12)
    assert abs(filt.response(0.0)[0]) == pytest.approx(1.0, rel=1e-12)


def test_group_delay_is_the_tables_delay_within_half_a_sample():
    for cfg, (fc, tau, fs) in DLPF_TABLE.items():
        filt = Dlpf(fc, tau, fs)
        # the closed-form DC group delay against the phase slope of the response near DC
        df = 1e-5 * fc
        h1, h2 = filt.response([df, 2 * df])
        gd = -np.angle(h2 / h1) / (2 * np.pi * df)
        assert filt.group_delay_s == pytest.approx(gd, rel=1e-6)
        assert abs(filt.group_delay_s - tau) <= 0.5 / fs, cfg
    # the pure delay is exact: a unit step from rest stays 0 for d samples
    filt = Dlpf(*DLPF_TABLE[4])
    assert filt.delay_samples == 2
    filt._zi = filt.steady_state(0.0)
    y = filt(np.ones(400))
    np.testing.assert_array_equal(y[:2], 0.0)
    assert y[2] > 0 and y[-1] == pytest.approx(1.0, rel=1e-9)


def test_steady_state_is_scipys():
    filt = Dlpf(*DLPF_TABLE[0])
    np.testing.assert_allclose(
        filt.steady_state(2.5), scipy.signal.sosfilt_zi(filt.sos) * 2.5, rtol=1e-12, atol=1e-15
    )
    y = filt(np.full(50, 2.5))
    np.testing.assert_allclose(y, 2.5, rtol=1e-14)


def _run(cfg, frame, periods=400, noise=None):
    st = MicroStage({}, DriveSchedule([(1700.0, 1.0, periods)]), seed=3)
    params = {"gyro_dlpf_cfg": cfg}
    if noise is not None:
        params["gyro_noise_rms"] = noise
    g = MemsGyro(params, seed=3)
    return record(st, g, frame=frame), g


@pytest.mark.parametrize("cfg", [0, 7])
def test_same_samples_at_any_frame_size(cfg):
    a, _ = _run(cfg, 65536, periods=60)
    b, _ = _run(cfg, 777, periods=60)
    c, _ = _run(cfg, 5000, periods=60)
    np.testing.assert_array_equal(a["gyro_value"], b["gyro_value"])
    np.testing.assert_array_equal(a["gyro_value"], c["gyro_value"])
    off, _ = _run(-1, 5000, periods=60)
    assert not np.array_equal(a["gyro_value"], off["gyro_value"])


@pytest.mark.parametrize("cfg", [0, 7])
def test_apparent_scale_factor_at_1700_hz_is_k_times_the_filters_gain(cfg):
    """The decoded gyro output against the gyro's true input rate, both fitted at 1.7 kHz
    (with a DC term) over the last half of 400 periods (the stage's start-up transient down
    to ~2e-3): amplitude ratio = k_I |H(j 2 pi 1.7 kHz)|, phase = arg H."""
    rec, g = _run(cfg, 20000, noise=0.0)
    t = rec["gyro_t"]
    tail = t > t[-1] / 2
    w = 2 * np.pi * 1700.0
    basis = np.column_stack([np.sin(w * t[tail]), np.cos(w * t[tail]), np.ones(tail.sum())])
    out, *_ = np.linalg.lstsq(basis, rec["gyro_value"][tail], rcond=None)
    inp, *_ = np.linalg.lstsq(basis, rec["gyro_true"][tail], rcond=None)
    ratio = complex(out[0], out[1]) / complex(inp[0], inp[1])
    fc, _, _ = DLPF_TABLE[cfg]
    h = closed_form(1700.0, fc, g.rate, g.dlpf.delay_samples)
    k = g.scale_factor()
    assert abs(ratio) == pytest.approx(k * abs(h), rel=5e-5)
    assert np.angle(ratio / h) == pytest.approx(0.0, abs=5e-5)
    assert abs(g.dlpf_response(1700.0)[0]) == pytest.approx(abs(h), rel=1e-9)
    if cfg == 0:  # 250 Hz: the scale factor at 1.7 kHz is a fraction of k_I
        assert abs(ratio) < 0.2
    assert abs(abs(ratio) - k) > 1e-4


def test_rate_must_be_the_rows_internal_rate():
    with pytest.raises(ParameterError, match="gyro_nominal_rate_hz"):
        MemsGyro({"gyro_dlpf_cfg": 3})
    assert MemsGyro({"gyro_dlpf_cfg": 3, "gyro_nominal_rate_hz": 1000.0}).dlpf is not None
    with pytest.raises(ParameterError, match="gyro_dlpf_cfg"):
        MemsGyro({"gyro_dlpf_cfg": 8})

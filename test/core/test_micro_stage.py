"""Core tests of the micro-stage emulator and the gyro (Chen 2018 ch. 3)."""

import math

import numpy as np
import pytest

from mems_estimation.identification.stage_identification import cancelled
from mems_sim.devices.stage import (
    K_BOLTZMANN,
    DriveSchedule,
    MicroStage,
    off_axis_rejection,
    readout_noise_std,
    record,
    steady_amplitude,
)
from mems_sim.devices.stage_capacitance import (
    EPS0,
    channel_limits,
    dual_axis_capacitance,
    dual_axis_gradient,
    single_axis_dcdtheta,
)
from mems_sim.devices.stage_gyro import DPS, MemsGyro
from mems_sim.params import ParameterError

P = MicroStage().params
LIM = channel_limits(P)


def test_parallel_plate_at_rest():
    """Eq. (40) at zero tilt is eq. (35): eps0 A / D_n for each stator."""
    c = dual_axis_capacitance(0.0, 0.0, 19.2e-6, LIM)[0]
    area = (LIM[:, 1] - LIM[:, 0]) * (LIM[:, 3] - LIM[:, 2])
    assert np.all(area > 0)  # Table A.1 2A misprint corrected
    np.testing.assert_allclose(c, EPS0 * area / 19.2e-6, rtol=1e-12)


def test_gradient_matches_finite_difference_and_closed_form():
    """dC/dtheta (quadrature) vs central differences of C and vs the closed form of eq. (46)."""
    th, h = 2e-3, 1e-7
    g = dual_axis_gradient(5e-4, th, 19.2e-6, LIM)[0]
    dy = (
        dual_axis_capacitance(5e-4, th + h, 19.2e-6, LIM)
        - dual_axis_capacitance(5e-4, th - h, 19.2e-6, LIM)
    )[0] / (2 * h)
    dx = (
        dual_axis_capacitance(5e-4 + h, th, 19.2e-6, LIM)
        - dual_axis_capacitance(5e-4 - h, th, 19.2e-6, LIM)
    )[0] / (2 * h)
    np.testing.assert_allclose(g[:, 1], dy, rtol=1e-6)
    np.testing.assert_allclose(g[:, 0], dx, rtol=1e-5, atol=1e-18)
    for c in range(4):
        w1, w2, w3, w4 = LIM[c]
        t = math.tan(th)

        # eq. (46) with the sign corrected, differentiated numerically
        def cap(x):
            tt = math.tan(x)
            return EPS0 * (w4 - w3) / tt * math.log((19.2e-6 - w1 * tt) / (19.2e-6 - w2 * tt))

        num = (cap(th + 1e-6) - cap(th - 1e-6)) / 2e-6
        assert single_axis_dcdtheta(th, 19.2e-6, LIM[c])[0] == pytest.approx(num, rel=1e-5)
        assert t > 0


def _grad_gl16(tx, ty, dn, lim):
    """Reference: eq. (40) differentiated under the integral, 16 x 16 Gauss-Legendre."""
    x, w = np.polynomial.legendre.leggauss(16)
    out = np.empty((lim.shape[0], 2))
    for c, (w1, w2, w3, w4) in enumerate(lim):
        wx = 0.5 * (w2 + w1) + 0.5 * (w2 - w1) * x[:, None]
        wy = 0.5 * (w4 + w3) + 0.5 * (w4 - w3) * x[None, :]
        d = dn - wx * math.tan(ty) + wy * math.tan(tx)
        ww = np.outer(w, w) * 0.25 * (w2 - w1) * (w4 - w3) / d**2
        out[c] = (
            -EPS0 * np.sum(ww * wy) / math.cos(tx) ** 2,
            EPS0 * np.sum(ww * wx) / math.cos(ty) ** 2,
        )
    return out


@pytest.mark.parametrize(
    "tx,ty", [(0.0, 3e-3), (5e-6, -4e-3), (2.5e-3, 3e-3), (4e-2, 1e-3), (5.5e-2, -1e-3)]
)
def test_gradient_closed_form_inner_integral(tx, ty):
    """The emulator's gradient (closed-form w_Y integral + GL in w_X, series and log branches)
    against a 16 x 16 quadrature of eq. (40), asymmetric limits included."""
    lim = np.vstack([LIM, [[1e-4, 5e-4, -1e-4, 3e-4]]])
    g = dual_axis_gradient(tx, ty, 19.2e-6, lim)[0]
    ref = _grad_gl16(tx, ty, 19.2e-6, lim)
    np.testing.assert_allclose(g[:, 1], ref[:, 1], rtol=1e-11)
    np.testing.assert_allclose(g[:, 0], ref[:, 0], rtol=1e-9, atol=1e-13 * np.abs(ref).max())


def test_temperature_moves_gap_only_by_default():
    """Chen 2018 gives no stage temperature coefficient: wn and b_c stay put by default,
    D_n moves (re-identified in the paper); the tempcos remain study parameters."""
    st = MicroStage()
    wn, bc, gap = st.wn, st.b_c, st.gap
    st.set_temperature(35.7)
    assert (st.wn, st.b_c) == (wn, bc) and st.gap != gap
    st2 = MicroStage({"b_c_tempco_per_k": 1e-3})
    st2.set_temperature(35.7)
    assert st2.b_c == pytest.approx(bc * (1 + 12.8e-3))


def test_rate_range_matches_table_3_2():
    """omega_pp at 1700 Hz, 1.3 V from the simulated stage = 46.3 rad/s (Table 3.2)."""
    st = MicroStage({"ldv_noise_std": 0.0}, DriveSchedule([(1700.0, 1.3, 400)]), seed=1)
    rec = record(st)
    om = rec["omega"][-50000:, 0]
    assert np.ptp(om) == pytest.approx(46.3, rel=0.005)
    assert np.ptp(om) == pytest.approx(
        2 * 2 * np.pi * 1700 * steady_amplitude(P, 1700, 1.3), rel=2e-3
    )
    # off-axis motion = coupling x main (0.1 %)
    assert np.ptp(rec["omega"][-50000:, 1]) / np.ptp(om) == pytest.approx(1e-3, rel=1e-6)
    # LDV: delayed rate + bias: mean difference = bias
    assert np.mean(rec["ldv"][-50000:] - om) == pytest.approx(P["ldv_bias"], abs=2e-3)


def test_readout_noise_is_physical():
    """Zero drive, bias on: the ADC samples' std equals the documented noise sum."""
    sigma = readout_noise_std(P)
    B = P["sample_rate_hz"] / 2
    thermal = math.sqrt(4 * K_BOLTZMANN * P["readout_temperature_k"] * P["r_s_ohm"] * B)
    assert thermal < sigma < 3 * thermal
    st = MicroStage({"bias_switching": False}, DriveSchedule([(1700.0, 0.0, 100)]), seed=3)
    y = record(st)["y"]
    assert np.std(y, axis=0) == pytest.approx(np.full(4, sigma), rel=0.03)


def test_feedthrough_cancellation():
    """Bias on/off cancellation removes the feedthrough: same seed with and without it."""
    sched = DriveSchedule([(1700.0, 1.2, 40)])
    a = record(MicroStage({}, sched, seed=5))
    b = record(MicroStage({"feedthrough_enabled": False}, sched, seed=5))
    ft = np.sqrt(np.mean((a["y"] - b["y"]) ** 2))
    assert ft > 5 * readout_noise_std(P)  # the feedthrough is large in the raw signal
    ca, cb = cancelled(a), cancelled(b)
    ok = np.isfinite(ca[:, 0])
    assert ok.mean() > 0.4
    resid = np.sqrt(np.mean((ca[ok] - cb[ok]) ** 2))
    assert resid < 0.01 * ft


def test_off_axis_rejection_1_percent():
    ph = np.linspace(0, 1, 2000, endpoint=False)
    th, om = 3e-3 * np.sin(2 * np.pi * ph), 3e-3 * 2 * np.pi * 1700 * np.cos(2 * np.pi * ph)
    assert off_axis_rejection(th, om, 0.01, 19.2e-6, LIM) >= 0.9998


@pytest.mark.xfail(
    strict=True,
    reason="measured R_off 99.974 % (10 %) and 99.871 % (50 %) vs "
    "asked 99.98 / 99.90 %: with Table A.1/A.2 geometry and +-3 mrad main-axis "
    "motion the leakage is second order in the off-axis angle (R_off = 1 - "
    "2.6e-3 r); the paper's flat 99.98 % at 1 % and 10 % is not reproduced",
)
@pytest.mark.parametrize("ratio,target", [(0.1, 0.9998), (0.5, 0.9990)])
def test_off_axis_rejection_table_3_4(ratio, target):
    ph = np.linspace(0, 1, 2000, endpoint=False)
    th, om = 3e-3 * np.sin(2 * np.pi * ph), 3e-3 * 2 * np.pi * 1700 * np.cos(2 * np.pi * ph)
    assert off_axis_rejection(th, om, ratio, 19.2e-6, LIM) >= target


def test_bad_input_refused():
    with pytest.raises(ParameterError, match="safe_tilt_rad"):
        MicroStage({}, DriveSchedule([(1714.5, 2.0, 10)]))
    for fs in (0.0, -625e3):
        with pytest.raises(ParameterError, match="sample_rate_hz"):
            MicroStage({"sample_rate_hz": fs})
    with pytest.raises(ParameterError):
        DriveSchedule([(1700.0, 1.0, 3)])
    with pytest.raises(ParameterError, match="neutral_gap_m"):
        MicroStage({"neutral_gap_m": -1.0})


def test_temperature_moves_gap():
    st = MicroStage({"temperature_c": 35.7})
    assert st.gap == pytest.approx(19.2e-6 * (1 + 4e-4 * 12.8))


def test_deterministic():
    s = DriveSchedule([(1700.0, 1.0, 4)])
    a, b = record(MicroStage({}, s, seed=9)), record(MicroStage({}, s, seed=9))
    np.testing.assert_array_equal(a["y"], b["y"])
    c = record(MicroStage({}, s, seed=9), frame=333)
    np.testing.assert_array_equal(a["y"], c["y"])


def test_gyro_model():
    """k_I(T): -5.43 % per 12.8 C; 0.1 dps rms noise; 16-bit +-2000 dps; own clock."""
    g = MemsGyro(temperature_c=35.7)
    assert g.scale_factor() == pytest.approx(1 - 0.0543, rel=1e-12)
    assert g.lsb == pytest.approx(2000 * DPS / 32768)
    st = MicroStage({}, DriveSchedule([(1700.0, 1.0, 200)]), seed=2)
    rec = record(st, MemsGyro(seed=2))
    dt = np.diff(rec["gyro_t"])
    assert np.allclose(dt, 1 / (8000 * (1 + 150e-6)))
    # exact input: gyro truth vs linear interpolation of the stage rate (error ~1e-5 rel)
    interp = np.interp(rec["gyro_t"], np.arange(rec["omega"].shape[0]) / st.fs, rec["omega"][:, 0])
    assert np.max(np.abs(rec["gyro_true"] - interp)) < 1e-3
    noise = rec["gyro_value"] - (rec["gyro_true"] + 2.0 * DPS)
    assert np.std(noise) == pytest.approx(math.sqrt((0.1 * DPS) ** 2 + g.lsb**2 / 12), rel=0.05)


def test_adc_clipping_counted():
    """Codes clip at the 16-bit range and every clipped code is counted."""
    st = MicroStage({"adc_full_scale_v": 0.002}, DriveSchedule([(1700.0, 1.3, 40)]), seed=1)
    f = st.step(30000)
    expected = int(np.count_nonzero(np.abs(np.rint(f.y / st.lsb)) > st.code_max))
    assert f.saturated == expected > 0
    assert f.codes.max() == st.code_max and f.codes.min() == -st.code_max - 1
    inside = np.abs(f.y / st.lsb) < st.code_max
    np.testing.assert_array_equal(f.codes[inside], np.rint(f.y[inside] / st.lsb))

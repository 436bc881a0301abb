"""Force-rebalance accelerometer core (Zhang 2010): physics against the thesis's equations
and numbers, the three controller modes, bad input."""

import math

import numpy as np
import pytest

from mems_estimation.identification.signal_metrics import coherent_snr_db
from mems_sim.devices import accelerometer
from mems_sim.params import ParameterError

G = accelerometer.G0
P = accelerometer.validate_params({})
SKIP = 20_000  # 20 ms start-up at 1 MHz
N = 120_000  # 0.12 s: start-up + one 10 Hz period


def run(mode, amp_g, seed=1, n=N, **kw):
    d = accelerometer.ForceRebalanceAccelerometer(
        dict(mode=mode, accel_amplitude=amp_g * G, **kw), seed=seed
    )
    return d, d.step(n)


def output(d, f):
    """The device's acceleration output: readout voltage (open loop) or v_F (closed loops)."""
    return f.code * d.lsb if d.p["mode"] == "open_loop" else f.v_f


def snr(d, f):
    t = np.arange(f.x.size) / d.fs
    return coherent_snr_db(output(d, f)[SKIP:], t[SKIP:], d.p["accel_frequency"])


def test_table1_derived_numbers():
    """omega_n = 2.81e4 rad/s and the eigenvalues of A (5-1): -4.39e3, -1.798e5 (eq. 5-4)."""
    m, k, b = P["mass"], P["stiffness"], P["damping"]
    assert math.sqrt(k / m) == pytest.approx(2.81e4, rel=2e-3)
    eig = np.sort(np.linalg.eigvals(np.array([[0, 1], [-k / m, -b / m]])).real)
    assert eig[1] == pytest.approx(-4.39e3, rel=2e-3)
    assert eig[0] == pytest.approx(-1.798e5, rel=2e-3)


def test_readout_is_eq_2_9_and_linearises_to_2_10():
    h = accelerometer.readout_gain(P)
    assert h == pytest.approx(2 * accelerometer.EPS0 * 4 * 1.86e-6 * 0.6 / (20e-12 * 2.3e-6**2))
    x = 1e-10
    assert accelerometer.readout_voltage(x, P) == pytest.approx(-h * x, rel=1e-8)
    x = 0.3 * P["gap"]
    assert accelerometer.readout_voltage(x, P) == pytest.approx(-h * x / (1 - 0.09), rel=1e-12)


def test_electrostatic_force_forms():
    """(2-12) with v_F = V_B = 0; small-signal (2-16) with the factor 2 on the bias terms."""
    ea, d0, v1 = accelerometer.eps_area(P), P["gap"], P["carrier_amplitude"]
    x = 0.2 * d0
    f212 = ea * v1**2 / 4 * (1 / (d0 - x) ** 2 - 1 / (d0 + x) ** 2)  # <sin^2> = 1/2
    assert accelerometer.electrostatic_force(x, 0.0, 0.0, P) == pytest.approx(f212, rel=1e-12)
    vb, vf, x = 0.17, 0.01, 1e-11
    lin = -2 * ea * vb * vf / d0**2 + ea * x * (v1**2 + 2 * vb**2 + 2 * vf**2) / d0**3
    assert accelerometer.electrostatic_force(x, vf, vb, P) == pytest.approx(lin, rel=1e-6)
    # a positive v_F pushes the mass to negative x (sign convention of the module)
    assert accelerometer.electrostatic_force(0.0, 0.01, vb, P) < 0


def test_bias_voltage_eq_2_18_balances_half_range_at_half_bias():
    vb = accelerometer.bias_voltage(P)
    assert vb == pytest.approx(
        math.sqrt(P["mass"] * 10 * G * P["gap"] ** 2 / accelerometer.eps_area(P))
    )
    # (2-17) at v_F = V_B / 2 balances the full 10 g range
    f = 2 * accelerometer.eps_area(P) * vb * (vb / 2) / P["gap"] ** 2
    assert f == pytest.approx(P["mass"] * 10 * G, rel=1e-12)


def test_squeeze_film_damping_is_even_and_table1_at_rest():
    x = np.array([-0.3, -0.1, 0.0, 0.1, 0.3]) * P["gap"]
    b = accelerometer.damping(x, P)
    assert b[2] == pytest.approx(P["damping"])
    np.testing.assert_allclose(b, b[::-1])
    assert b[0] > b[1] > b[2]


@pytest.mark.parametrize(
    "name,value",
    [
        ("mass", 0.0),
        ("gap", -1e-6),
        ("stiffness", 0.0),
        ("sample_rate_hz", 1e3),
        ("mode", "bang_bang"),
    ],
)
def test_invalid_physical_parameters_refused(name, value):
    with pytest.raises(ParameterError, match=name):
        accelerometer.ForceRebalanceAccelerometer({name: value})


def test_profile_file_missing_or_bad(tmp_path):
    with pytest.raises(ParameterError, match="profile_file"):
        accelerometer.validate_params({"profile": "file"})
    bad = tmp_path / "p.csv"
    bad.write_text("0, 1\n0, 2\n")
    with pytest.raises(ParameterError, match="increase"):
        accelerometer.ForceRebalanceAccelerometer({"profile": "file", "profile_file": str(bad)})


def test_input_profiles(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("# t, a\n0, 0\n1e-3, 9.8\n2e-3, 9.8\n")
    d = accelerometer.ForceRebalanceAccelerometer({"profile": "file", "profile_file": str(f)})
    np.testing.assert_allclose(d.input_at(np.array([0.0, 5e-4, 1.5e-3, 5.0])), [0.0, 4.9, 9.8, 9.8])
    d = accelerometer.ForceRebalanceAccelerometer(
        {"profile": "step", "step_time": 1e-3, "accel_amplitude": 2.0}
    )
    np.testing.assert_array_equal(d.input_at(np.array([0.0, 0.999e-3, 1e-3])), [0, 0, 2.0])
    d = accelerometer.ForceRebalanceAccelerometer(
        {
            "profile": "chirp",
            "accel_frequency": 10.0,
            "chirp_end_frequency": 30.0,
            "chirp_duration": 1.0,
        }
    )
    t = np.linspace(0, 1, 200001)
    a = d.input_at(t)
    # linear sweep: the instantaneous frequency at mid-sweep is 20 Hz (zero-crossing spacing)
    zc = t[np.flatnonzero(np.diff(np.sign(a)) != 0)]
    mid = zc[np.argmin(np.abs(zc - 0.5)) + np.array([-1, 0, 1])]
    assert 1 / (2 * np.diff(mid).mean()) == pytest.approx(20.0, rel=0.01)


def test_blocks_are_seamless():
    """Ten blocks of 1000 samples equal one block of 10000 (state and noise carried over)."""
    a = accelerometer.ForceRebalanceAccelerometer({"mode": "ekf_rebalance"}, seed=3)
    b = accelerometer.ForceRebalanceAccelerometer({"mode": "ekf_rebalance"}, seed=3)
    one = a.step(10_000)
    parts = [b.step(1000) for _ in range(10)]
    np.testing.assert_array_equal(one.code, np.concatenate([p.code for p in parts]))
    np.testing.assert_array_equal(one.x, np.concatenate([p.x for p in parts]))
    np.testing.assert_array_equal(one.estimate, np.concatenate([p.estimate for p in parts]))


def test_plant_integration_converges():
    """Noise-free step response: RK4 with the default single step per sample agrees with 32
    substeps to 1e-7 relative and settles to the nonlinear static equilibrium
    k x - F_el(x) = m a."""
    kw = dict(
        profile="step",
        accel_amplitude=G,
        brownian_accel_std=0.0,
        electronic_accel_std=0.0,
        mode="open_loop",
    )
    d4 = accelerometer.ForceRebalanceAccelerometer(kw)
    d32 = accelerometer.ForceRebalanceAccelerometer(dict(kw, substeps=32))
    x4, x32 = d4.step(20_000).x, d32.step(20_000).x
    assert np.max(np.abs(x4 - x32)) <= 1e-7 * np.max(np.abs(x32))
    xs = np.linspace(0, 1e-7, 100001)
    x_eq = xs[np.argmin(np.abs(accelerometer.static_acceleration(xs, P) - G))]
    assert x4[-1] == pytest.approx(x_eq, rel=1e-4)


def test_open_loop_pull_in_from_the_physics():
    """The open loop has no static equilibrium above a_pi (eq. 2-12 softening); a sinusoid
    beyond it drives the mass to the stop (contact), one below does not."""
    a_pi, x_pi = accelerometer.pull_in_acceleration(P)
    assert 11 * G < a_pi < 13.5 * G  # 12.2 g with Table I
    assert 0.2 < x_pi / P["gap"] < 0.33
    _, f = run("open_loop", a_pi / G * 1.2, n=60_000)
    assert f.contact.any()
    _, f = run("open_loop", 1.0)
    assert not f.contact.any()


def x_max(f):
    return float(np.abs(f.x).max())


def test_table_i_open_loop_restated():
    """Table I as printed (k = 3 N/m, softened by the 0.6 V carrier, eq. 2-12, to 1.05 N/m):
    the open loop tracks 10 Hz at 12 g, reaches the stop at 13 g (static pull-in 12.2 g) and
    deflects 1.81e-7 m at 5 g (Zhang 2010 Table III has it fail at 5 g: see the reading
    below)."""
    assert accelerometer.pull_in_acceleration(P)[0] / G == pytest.approx(12.2, abs=0.05)
    _, f = run("open_loop", 12.0)
    assert not f.contact.any()
    _, f = run("open_loop", 13.0)
    assert f.contact.any()
    _, f = run("open_loop", 5.0)
    assert not f.contact.any()
    assert x_max(f) == pytest.approx(1.81e-7, rel=0.03)


def test_table_iii_reading_carrier_0675():
    """The reading that reproduces Zhang 2010 Table III: a 0.675 V carrier leaves
    k_eff = 0.53 N/m, so 1 g deflects 7e-8 m and the open loop (pull-in 4.06 g) tracks 4 g
    but fails at 5 g; the PI and EKF loops still track 10 g without contact."""
    v = accelerometer.TABLE_III_VARIANT
    p3 = accelerometer.validate_params(v)
    assert accelerometer.pull_in_acceleration(p3)[0] / G == pytest.approx(4.06, abs=0.02)
    _, f = run("open_loop", 1.0, **v)
    assert x_max(f) == pytest.approx(7.0e-8, rel=0.05)
    _, f = run("open_loop", 4.0, **v)
    assert not f.contact.any()
    _, f = run("open_loop", 5.0, **v)
    assert f.contact.any()
    for mode in ("pi_rebalance", "ekf_rebalance"):
        _, f = run(mode, 10.0, **v)
        assert not f.contact.any() and not f.saturated.any(), mode


def corner(sign_k: int, sign_d: int) -> dict:
    """A corner of the spread box (k +-10 %, d0 +-5 %, m -+2 %, b -+20 %)."""
    return dict(
        P,
        stiffness=P["stiffness"] * (1 + 0.10 * sign_k),
        gap=P["gap"] * (1 + 0.05 * sign_d),
        mass=P["mass"] * (1 - 0.02 * sign_k),
        damping=P["damping"] * (1 - 0.20 * sign_k),
    )


def test_design_is_nominal_on_a_device_of_the_batch():
    """V_B (eq. 2-18), the in-loop EKF's model and its conversion of the estimate to a
    readout voltage come from the nominal values, the plant from the device as built."""
    dev = corner(-1, -1)
    d = accelerometer.ForceRebalanceAccelerometer(
        dict(dev, mode="ekf_rebalance"), seed=1, nominal=dict(P, mode="ekf_rebalance")
    )
    assert d.v_b == pytest.approx(accelerometer.bias_voltage(P))
    np.testing.assert_array_equal(d.ekf_config.model, accelerometer.plant_vector(P, d.v_b))
    np.testing.assert_array_equal(
        d.mv, accelerometer.plant_vector(accelerometer.validate_params(dev), d.v_b)
    )


@pytest.mark.parametrize("signs", [(-1, -1), (1, 1)], ids=["soft", "stiff"])
def test_ekf_loop_gain_holds_at_the_corners_of_the_spread(signs):
    """The EKF loop's +6 dB over the PI loop (Zhang 2010 Table III, restated) with the
    filter on the nominal model, on the two corners of the spread box that move the
    effective stiffness most (-59 % and +54 %)."""
    dev = corner(*signs)
    for amp in (0.1, 1.0):
        s = {}
        for mode in ("pi_rebalance", "ekf_rebalance"):
            kw = dict(mode=mode, accel_amplitude=amp * G)
            d = accelerometer.ForceRebalanceAccelerometer(
                dict(dev, **kw), seed=7, nominal=dict(P, **kw)
            )
            f = d.step(N)
            assert not f.contact.any()
            s[mode] = snr(d, f)
        assert s["ekf_rebalance"] >= s["pi_rebalance"] + 6.0, (signs, amp, s)


@pytest.fixture(scope="module")
def table3():
    """Seeded Table III runs: (amplitude g, mode) -> (device, frame)."""
    return {(a, m): run(m, a) for a in (0.1, 1.0, 10.0) for m in accelerometer.MODES}


def test_closed_loops_track_10g_without_contact_and_shrink_displacement(table3):
    for mode in ("pi_rebalance", "ekf_rebalance"):
        d, f = table3[(10.0, mode)]
        assert not f.contact.any() and not f.saturated.any()
        assert snr(d, f) > 25
        for amp in (0.1, 1.0, 10.0):
            x_open = np.abs(table3[(amp, "open_loop")][1].x).max()
            assert np.abs(table3[(amp, mode)][1].x).max() * 10 <= x_open


def test_ekf_loop_beats_pi_loop_by_6db_with_the_same_displacement(table3):
    for amp in (0.1, 1.0):
        pi = snr(*table3[(amp, "pi_rebalance")])
        ekf = snr(*table3[(amp, "ekf_rebalance")])
        assert ekf >= pi + 6.0, (amp, pi, ekf)
        x_pi = np.abs(table3[(amp, "pi_rebalance")][1].x).max()
        x_ekf = np.abs(table3[(amp, "ekf_rebalance")][1].x).max()
        assert x_ekf <= 1.1 * x_pi


def test_pi_loop_is_noisier_than_open_loop(table3):
    """Chapter 3's finding (3-13 vs 3-17): the PI loop's SNR is below the open loop's."""
    for amp in (0.1, 1.0):
        assert snr(*table3[(amp, "pi_rebalance")]) < snr(*table3[(amp, "open_loop")]) - 10


def test_over_range_input_is_flagged_not_clipped():
    """50 g against a 10 g range: the feedback saturates and that is reported per sample."""
    d, f = run("pi_rebalance", 50.0, n=60_000)
    assert f.saturated.any()
    assert np.abs(f.v_f).max() == pytest.approx(d.v_b)

"""Hybrid EKF of the accelerometer (Zhang 2010, eqs. 4-48 .. 4-57): time update against the
exact (Van Loan) discretisation, measurement update against the textbook form,
consistency on seeded runs, Table IV's tuning direction."""

import numpy as np
import pytest
import scipy.linalg

from mems_estimation.filters.accelerometer_ekf import HybridEkf
from mems_estimation.identification.signal_metrics import coherent_snr_db, consistency
from mems_sim.devices import accelerometer
from mems_sim.kernels import accelerometer_ekf as he

G = accelerometer.G0
SKIP = 20_000


def config(**kw):
    p = accelerometer.validate_params(dict(mode="ekf_rebalance", **kw))
    return p, accelerometer.ekf_config(p, accelerometer.bias_voltage(p))


def linear_model(p, c):
    """Continuous (F, L Q L^T) of the model linearised at rest (x = v = 0, v_F = 0)."""
    m, k, b = p["mass"], p["stiffness"], p["damping"]
    vb = accelerometer.bias_voltage(p)
    ke = accelerometer.eps_area(p) * (p["carrier_amplitude"] ** 2 + 2 * vb**2) / p["gap"] ** 3
    f = np.array([[0, 1, 0], [(-k + ke) / m, -b / m, 1], [0, 0, 0]])
    qc = np.diag([0.0, c.q[0] / m**2, c.q[1]])
    return f, qc


def van_loan(f, qc, dt):
    n = f.shape[0]
    m = np.zeros((2 * n, 2 * n))
    m[:n, :n], m[:n, n:], m[n:, n:] = -f, qc, f.T
    e = scipy.linalg.expm(m * dt)
    phi = e[n:, n:].T
    return phi, phi @ e[:n, n:]


def test_time_update_matches_exact_discretisation():
    """RK4 on (4-52)/(4-53) over 1 us vs the matrix exponential: 1e-5 relative."""
    p, c = config()
    f, qc = linear_model(p, c)
    phi, qd = van_loan(f, qc, c.dt)
    p0 = np.diag(c.p0_diag) + 1e-3 * np.sqrt(np.outer(c.p0_diag, c.p0_diag))
    s = np.zeros(3)
    pm = p0.copy()
    he.ekf_predict(s, pm, 0.0, c.dt, c.q, c.model)
    exact = phi @ p0 @ phi.T + qd
    np.testing.assert_allclose(pm, exact, rtol=1e-5, atol=1e-12 * np.abs(exact).max())
    # a state off rest propagates like Phi s for small x (nonlinearity ~ (x/d0)^2)
    s0 = np.array([1e-11, 1e-6, 0.5])
    s = s0.copy()
    he.ekf_predict(s, pm, 0.0, c.dt, c.q, c.model)
    np.testing.assert_allclose(s, phi @ s0, rtol=1e-5, atol=1e-20)


def test_measurement_update_is_4_55_to_4_57():
    p, c = config()
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 3)) * np.sqrt(c.p0_diag)
    pm = a @ a.T + np.diag(c.p0_diag)
    s = np.array([2e-10, 1e-6, 0.3])
    y = -1e-4
    hx, hd = he.measurement(s[0], c.model)
    assert hx == pytest.approx(accelerometer.readout_voltage(s[0], p), rel=1e-12)
    eps = 1e-14
    assert hd == pytest.approx(
        (he.measurement(s[0] + eps, c.model)[0] - he.measurement(s[0] - eps, c.model)[0])
        / (2 * eps),
        rel=1e-6,
    )
    hm = np.array([[hd, 0, 0]])
    k = pm @ hm.T / (hm @ pm @ hm.T + c.r)
    s_ref = s + (k * (y - hx)).ravel()
    p_ref = (np.eye(3) - k @ hm) @ pm
    s2, p2 = s.copy(), pm.copy()
    he.ekf_update(s2, p2, y, c.r, c.model)
    np.testing.assert_allclose(s2, s_ref, rtol=1e-12)
    np.testing.assert_allclose(p2, p_ref, rtol=1e-9, atol=1e-12 * np.abs(p_ref).max())


def test_downstream_filter_reproduces_the_in_loop_estimate():
    """The same filter on the device's ADC and drive samples gives the in-loop estimate."""
    d = accelerometer.ForceRebalanceAccelerometer(
        {"mode": "ekf_rebalance", "accel_amplitude": G}, seed=2
    )
    f = d.step(30_000)
    ekf = HybridEkf(d.ekf_config)
    out = ekf.run(f.code * d.lsb, f.v_f)
    np.testing.assert_array_equal(out["estimate"], f.estimate)
    np.testing.assert_array_equal(out["variance"], f.variance)


@pytest.mark.parametrize(
    "mode,amp_g", [("pi_rebalance", 1.0), ("ekf_rebalance", 0.1), ("ekf_rebalance", 1.0)]
)
def test_displacement_error_is_consistent(mode, amp_g):
    """Consistency: x_hat - x has zero mean (within 3 standard errors, batch means) and its std
    matches the filter's predicted std within 20 %; P stays positive definite."""
    d = accelerometer.ForceRebalanceAccelerometer(
        {"mode": mode, "accel_amplitude": amp_g * G}, seed=4
    )
    f = d.step(120_000)
    ekf = HybridEkf(d.ekf_config)
    out = ekf.run(f.code * d.lsb, f.v_f)
    c = consistency(out["estimate"][SKIP:, 0] - f.x[SKIP:], out["variance"][SKIP:, 0])
    assert abs(c["mean"]) <= 3 * c["stderr"], c
    assert 0.8 <= c["std_ratio"] <= 1.2, c
    assert ekf.not_positive_definite == 0


def test_table_iv_tuning_direction():
    """At 0.1 g (electronic noise >> Brownian): Q/10 and R*10 raise the output SNR, Q*10 and
    R/10 lower it, Q/10 with R*10 is best (Zhang 2010 Table IV); P stays positive definite."""
    cases = {
        "exact": (1, 1),
        "Qx10": (10, 1),
        "Q/10": (0.1, 1),
        "Rx10": (1, 10),
        "R/10": (1, 0.1),
        "Rx10,Q/10": (0.1, 10),
    }
    snr = {}
    for name, (qs, rs) in cases.items():
        d = accelerometer.ForceRebalanceAccelerometer(
            dict(mode="ekf_rebalance", accel_amplitude=0.1 * G, ekf_q_scale=qs, ekf_r_scale=rs),
            seed=5,
        )
        f = d.step(120_000)
        t = np.arange(f.x.size) / d.fs
        snr[name] = coherent_snr_db(f.v_f[SKIP:], t[SKIP:], 10.0)
        assert f.positive_definite.all(), name
    assert snr["Q/10"] > snr["exact"] > snr["Qx10"]
    assert snr["Rx10"] > snr["exact"] > snr["R/10"]
    assert snr["Rx10,Q/10"] == max(snr.values())

"""Innovation variance of the accelerometer's hybrid EKF (Zhang 2010, eq. 4-55: the gain's
denominator S = H P H^T + R) and the normalised innovation squared nu^2 / S it gives the
consistency monitor: S against the textbook form, the update with S returned is the update
without it bit for bit, and the mean NIS of fault-free runs."""

import numpy as np

from mems_estimation.filters.accelerometer_ekf import HybridEkf
from mems_estimation.filters.consistency_monitor import NisMonitor
from mems_sim.devices import accelerometer
from mems_sim.kernels import accelerometer_ekf as he

G = accelerometer.G0


def _random_prior(c, seed):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((3, 3)) * np.sqrt(c.p0_diag)
    return np.array([2e-10, 1e-6, 0.3]), a @ a.T + np.diag(c.p0_diag)


def test_innovation_variance_is_h_p_h_plus_r_and_changes_nothing_else():
    """S = H P^- H^T + R from the a-priori P; state, covariance and innovation are those of
    ekf_update bit for bit."""
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "ekf_rebalance"}, seed=1)
    c = d.ekf_config
    for seed in range(5):
        s, pm = _random_prior(c, seed)
        hx, hd = he.measurement(s[0], c.model)
        hm = np.array([[hd, 0.0, 0.0]])
        s_ref = (hm @ pm @ hm.T).item() + c.r
        s1, p1, s2, p2 = s.copy(), pm.copy(), s.copy(), pm.copy()
        nu1 = he.ekf_update(s1, p1, -1e-4, c.r, c.model)
        nu2, sv = he.ekf_update_innovation(s2, p2, -1e-4, c.r, c.model)
        assert abs(sv - s_ref) <= 1e-14 * s_ref
        assert nu2 == nu1 == -1e-4 - hx
        assert s2.tobytes() == s1.tobytes() and p2.tobytes() == p1.tobytes()


def test_run_returns_the_innovation_variance_block_by_block():
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "pi_rebalance"}, seed=3)
    f = d.step(6000)
    y = f.code * d.lsb
    whole = HybridEkf(d.ekf_config).run(y, f.v_f)
    ekf = HybridEkf(d.ekf_config)
    parts = [ekf.run(y[a:b], f.v_f[a:b]) for a, b in ((0, 1000), (1000, 6000))]
    for key in ("estimate", "variance", "innovation", "innovation_variance"):
        joined = np.concatenate([p[key] for p in parts])
        assert joined.tobytes() == whole[key].tobytes(), key
    sv = whole["innovation_variance"]
    assert sv.shape == (6000,) and np.all(sv > d.ekf_config.r)


def test_mean_nis_of_a_fault_free_run_is_near_one():
    """Fault-free PI loop at 0.1 g (the readout nearly linear: |x| << d0): the mean of
    nu^2 / S over N = 199 000 samples. A consistent filter with white Gaussian innovations
    gives a chi-square(1) mean: 1 with standard error sqrt(2 / N) = 0.0032. Measured: this
    filter's S is slightly larger than the innovations' variance, the mean NIS 0.990 ..
    0.997 over seeds (0.9942 here; 0.990 over 2e6 samples of another run; 0.993 pooled over
    six seeds, 3.6 standard errors below 1), with a small negative lag-1 correlation of the
    normalised innovations (-0.015). So the band is 1 +- 3 standard errors, widened on the
    low side by a 1 % allowance for that overstated S."""
    d = accelerometer.ForceRebalanceAccelerometer(
        {"mode": "pi_rebalance", "accel_amplitude": 0.1 * G}, seed=4
    )
    f = d.step(200_000)
    out = HybridEkf(d.ekf_config).run(f.code * d.lsb, f.v_f)
    nis = (out["innovation"] ** 2 / out["innovation_variance"])[1000:]
    se = np.sqrt(2.0 / nis.size)
    assert 1.0 - 0.01 - 3 * se <= nis.mean() <= 1.0 + 3 * se, nis.mean()
    nu = out["innovation"][1000:] / np.sqrt(out["innovation_variance"][1000:])
    assert abs(np.corrcoef(nu[:-1], nu[1:])[0, 1]) < 0.03
    # the monitor's windows: 199 of 1000 samples at alpha = 1e-2, none at ERROR
    verdicts = NisMonitor(1000, 1e-2).update(nis)
    assert len(verdicts) == 199
    assert sum(v.level >= 1 for v in verdicts) <= 8  # expected 2 (Poisson: P(> 8) < 1e-4)
    assert all(v.level < 2 for v in verdicts)

"""Benchmark: EKF and UKF kernels of the shared-electrode scanner (Chen 2018 ch. 5).

Run:  .venv/bin/python bench/bench_scanner_ukf.py [n_samples]
Generates n AMDM samples (default 200,000 = 0.2 s at 1 MHz) with
:class:`mems_sim.devices.scanner_amdm.AmdmScannerDevice` (0..150 V drive, R = 1.92e-4 V^2), then prints
samples/s and the real-time factor of :func:`ekf_run` / :func:`ukf_run` (numba) on frames of
10,000 samples, of a plain per-sample numpy implementation of the same filters written here
(reference for "matching estimates"), and -- if ``filterpy`` is installed in the venv --
of filterpy's ExtendedKalmanFilter / UnscentedKalmanFilter on the same data with the same
model, reporting the ratio and the largest difference of the theta estimates.
(filterpy's UKF re-uses the propagated sigma points in the update, ours re-draws them from
the a-priori covariance, so its estimates match to a tolerance, not bit for bit.)
"""

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation.filters import scanner_amdm_ekf as sae
from mems_estimation.filters import scanner_amdm_tracking as su
from mems_estimation.filters import scanner_amdm_ukf as sau
from mems_sim.devices import scanner_amdm as sa

RUN = dict(
    drive_voltage_max=150.0,
    sweep_start_hz=31.32e3,
    sweep_end_hz=31.27e3,
    sweep_time_s=0.03,
    initial_angle=0.1,
)
FS = 1.0e6


def data(n: int):
    """(y, v2, x0, P0, filter) of n samples, acquisition done by ScannerFilter on the first
    frame so every implementation starts from the same state."""
    dev = sa.AmdmScannerDevice(RUN, seed=0)
    fr = dev.step(n)
    y = fr.codes * dev.lsb
    f = su.ScannerFilter("ukf", dict(chain_delay_s=dev.delay))
    v2 = su.DriveAligner(dev.delay * FS, f.model.vc2).push(0, fr.drive)
    k0 = 2000
    f.step(y[:k0], v2[:k0])
    assert f.tracking
    return y[k0:], v2[k0:], f.x.copy(), f.P.copy(), f


def g_np(x, v2, md):
    """Process model of the module (mid-step torque), numpy."""
    c0, th0 = md.meas[0], md.meas[1]
    tm = x[0] + 0.5 * md.T * x[1]
    u = -2 * c0 * tm / th0**2 * math.exp(-((tm / th0) ** 2)) * v2 / (2 * md.J)
    return md.Phi @ x + md.Gam * u


def h_np(th, md):
    c0, th0, cb, a, b, a2, ct, db = md.meas
    c = c0 * math.exp(-((th / th0) ** 2)) + cb
    return a * c + b + db + a2 * (c - ct) ** 2


def dh_np(th, md):
    c0, th0, cb, a, _, a2, ct, _ = md.meas
    e = math.exp(-((th / th0) ** 2))
    return (a + 2 * a2 * (c0 * e + cb - ct)) * c0 * (-2 * th / th0**2) * e


def ukf_numpy(y, v2, x, P, md, wm, wc, gamma):
    """Per-sample UKF in plain numpy (same algorithm as the kernel)."""
    x, P = x.copy(), P.copy()
    out = np.empty(y.size)
    for k in range(y.size):
        L = np.linalg.cholesky(P)
        S = np.vstack([x, x + gamma * L.T, x - gamma * L.T])[[0, 1, 3, 2, 4]]
        Xp = np.array([g_np(s, v2[k], md) for s in S])
        x = wm @ Xp
        d = Xp - x
        P = (wc[:, None] * d).T @ d + md.Q
        L = np.linalg.cholesky(P)
        S = np.vstack([x, x + gamma * L.T, x - gamma * L.T])[[0, 1, 3, 2, 4]]
        Y = np.array([h_np(s[0], md) for s in S])
        ym = wm @ Y
        dy = Y - ym
        py = wc @ (dy * dy) + md.R
        K = (wc * dy) @ (S - x) / py
        x = x + K * (y[k] - ym)
        P = P - np.outer(K, K) * py
        P = 0.5 * (P + P.T)
        out[k] = x[0]
    return out


def ekf_numpy(y, v2, x, P, md):
    """Per-sample EKF in plain numpy (Joseph form, same algorithm as the kernel)."""
    x, P = x.copy(), P.copy()
    c0, th0 = md.meas[0], md.meas[1]
    out = np.empty(y.size)
    for k in range(y.size):
        tm = x[0] + 0.5 * md.T * x[1]
        du = (
            2
            * c0
            / th0**2
            * (2 * (tm / th0) ** 2 - 1)
            * math.exp(-((tm / th0) ** 2))
            * v2[k]
            / (2 * md.J)
        )
        G = md.Phi + np.outer(md.Gam, [du, 0.5 * md.T * du])
        x = g_np(x, v2[k], md)
        P = G @ P @ G.T + md.Q
        H = np.array([dh_np(x[0], md), 0.0])
        s = H @ P @ H + md.R
        K = P @ H / s
        x = x + K * (y[k] - h_np(x[0], md))
        IKH = np.eye(2) - np.outer(K, H)
        P = IKH @ P @ IKH.T + np.outer(K, K) * md.R
        out[k] = x[0]
    return out


def kernel(kind, y, v2, x0, P0, f, frame=10_000):
    md = f.model
    x, P = x0.copy(), P0.copy()
    th = np.empty(y.size)
    t0 = time.perf_counter()
    for i in range(0, y.size, frame):
        sl = slice(i, i + frame)
        m = y[sl].size
        ox, op, on = np.empty((m, 2)), np.empty((m, 3)), np.empty(m)
        if kind == "ekf":
            sae.ekf_run(
                y[sl],
                v2[sl],
                x,
                P,
                md.Phi,
                md.Gam,
                md.Q,
                md.meas,
                md.J,
                md.R,
                md.T,
                True,
                ox,
                op,
                on,
            )
        else:
            sau.ukf_run(
                y[sl],
                v2[sl],
                x,
                P,
                md.Phi,
                md.Gam,
                md.Q,
                md.meas,
                md.J,
                md.R,
                md.T,
                f.wm,
                f.wc,
                f.gamma,
                True,
                ox,
                op,
                on,
            )
        th[sl] = ox[:, 0]
    return y.size / (time.perf_counter() - t0), th


def filterpy_runs(y, v2, x0, P0, f):
    """filterpy EKF / UKF on the same data and model; None if filterpy is missing."""
    try:
        from filterpy.kalman import (
            ExtendedKalmanFilter,
            MerweScaledSigmaPoints,
            UnscentedKalmanFilter,
        )
    except ImportError:
        return None
    md = f.model
    p = f.p
    pts = MerweScaledSigmaPoints(2, alpha=p["ukf_alpha"], beta=p["ukf_beta"], kappa=p["ukf_kappa"])
    ukf = UnscentedKalmanFilter(
        2,
        1,
        md.T,
        hx=lambda x: np.array([h_np(x[0], md)]),
        fx=lambda x, dt, v2: g_np(x, v2, md),
        points=pts,
    )
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), P0.copy(), md.Q.copy(), np.array([[md.R]])
    th_u = np.empty(y.size)
    t0 = time.perf_counter()
    for k in range(y.size):
        ukf.predict(v2=v2[k])
        ukf.update(np.array([y[k]]))
        th_u[k] = ukf.x[0]
    r_u = y.size / (time.perf_counter() - t0)

    class Ekf(ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = g_np(self.x, u, md)

    c0, th0 = md.meas[0], md.meas[1]
    ekf = Ekf(2, 1)
    ekf.x, ekf.P, ekf.Q, ekf.R = x0.copy(), P0.copy(), md.Q.copy(), np.array([[md.R]])
    th_e = np.empty(y.size)
    t0 = time.perf_counter()
    for k in range(y.size):
        tm = ekf.x[0] + 0.5 * md.T * ekf.x[1]
        du = (
            2
            * c0
            / th0**2
            * (2 * (tm / th0) ** 2 - 1)
            * math.exp(-((tm / th0) ** 2))
            * v2[k]
            / (2 * md.J)
        )
        ekf.F = md.Phi + np.outer(md.Gam, [du, 0.5 * md.T * du])
        ekf.predict(u=v2[k])
        ekf.update(
            np.array([y[k]]),
            lambda x: np.array([[dh_np(x[0], md), 0.0]]),
            lambda x: np.array([h_np(x[0], md)]),
        )
        th_e[k] = ekf.x[0]
    r_e = y.size / (time.perf_counter() - t0)
    return dict(ekf=(r_e, th_e), ukf=(r_u, th_u))


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200_000
    y, v2, x0, P0, f = data(n)
    kernel("ekf", y[:1000], v2[:1000], x0, P0, f)  # warm-up / numba cache
    kernel("ukf", y[:1000], v2[:1000], x0, P0, f)
    res = {k: kernel(k, y, v2, x0, P0, f) for k in ("ekf", "ukf")}
    for k, (r, _) in res.items():
        print(
            f"{k.upper()} kernel (numba): {r / 1e6:7.2f} Msamples/s = {r / FS:6.2f} x real time "
            f"at 1 MHz ({y.size} samples)"
        )
    m = min(y.size, 20_000)
    for k, fn in (
        ("ekf", lambda: ekf_numpy(y[:m], v2[:m], x0, P0, f.model)),
        ("ukf", lambda: ukf_numpy(y[:m], v2[:m], x0, P0, f.model, f.wm, f.wc, f.gamma)),
    ):
        t0 = time.perf_counter()
        th = fn()
        r = m / (time.perf_counter() - t0)
        dmax = float(np.max(np.abs(th - res[k][1][:m])))
        print(
            f"{k.upper()} plain numpy reference: {r / 1e3:7.1f} ksamples/s; kernel / numpy = "
            f"{res[k][0] / r:6.0f}x; max |theta diff| = {dmax:.1e} rad"
        )
    fp = filterpy_runs(y[:m], v2[:m], x0, P0, f)
    if fp is None:
        print("filterpy: not installed in .venv -- ratio to filterpy not measured")
    else:
        for k, (r, th) in fp.items():
            dmax = float(np.max(np.abs(th - res[k][1][:m])))
            print(
                f"filterpy {k.upper()}: {r / 1e3:7.1f} ksamples/s; kernel / filterpy = "
                f"{res[k][0] / r:6.0f}x; max |theta diff| = {dmax:.1e} rad"
            )


if __name__ == "__main__":
    main()

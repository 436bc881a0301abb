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

import numba
import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation.filters import scanner_amdm_tracking as su
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


@numba.njit(cache=True, inline="always")
def _lean_torque(th, v2, c0, th0, J):
    u = th / th0
    return -2.0 * c0 * u / th0 * math.exp(-u * u) * v2 / (2.0 * J)


@numba.njit(cache=True, inline="always")
def _lean_h(th, c0, th0, cb, acir, bcir, a2, ct, db):
    u = th / th0
    c = c0 * math.exp(-u * u) + cb
    dc = c - ct
    return acir * c + bcir + db + a2 * dc * dc


# Deliberately a second copy of the kernel's arithmetic (scanner_amdm_ukf.ukf_run), not an
# import: the yardstick the kernel's speed is measured against (lean_vs_kernel), written out
# per sigma point as the kernel is; its estimates must equal the kernel's.
@numba.njit(cache=True)
def lean_ukf(y, v2, x_in, P_in, Phi, Gam, Q, m, J, R, T, wm, wc, gamma, out_x, out_p, out_nis):
    """Lean reference loop of :func:`ukf_run`'s arithmetic (the yardstick of the kernel):
    state, covariance, the five sigma points and the weights in scalars, no repair branch
    (the data never needs one), the same outputs (state, variances and covariance, NIS).
    The same operations in the same order as the kernel, so its estimates equal the
    kernel's."""
    x0, x1 = x_in[0], x_in[1]
    p00, p01, p11 = P_in[0, 0], P_in[0, 1], P_in[1, 1]
    f00, f01, f10, f11, g0, g1 = Phi[0, 0], Phi[0, 1], Phi[1, 0], Phi[1, 1], Gam[0], Gam[1]
    q00, q01, q11 = Q[0, 0], Q[0, 1], Q[1, 1]
    wm0, wm1, wm2, wm3, wm4 = wm[0], wm[1], wm[2], wm[3], wm[4]
    wc0, wc1, wc2, wc3, wc4 = wc[0], wc[1], wc[2], wc[3], wc[4]
    c0, th0, cb, acir, bcir, a2, ct, db = m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7]
    for k in range(y.shape[0]):
        # sigma points of (x, P) and their propagation (torque at mid-step)
        l00 = math.sqrt(p00)
        l10 = p01 / l00
        l11 = math.sqrt(p11 - l10 * l10)
        vk = v2[k]
        s0, s1 = x0, x1
        u = _lean_torque(s0 + 0.5 * T * s1, vk, c0, th0, J)
        a0, a1 = f00 * s0 + f01 * s1 + g0 * u, f10 * s0 + f11 * s1 + g1 * u
        s0, s1 = x0 + gamma * l00, x1 + gamma * l10
        u = _lean_torque(s0 + 0.5 * T * s1, vk, c0, th0, J)
        b0, b1 = f00 * s0 + f01 * s1 + g0 * u, f10 * s0 + f11 * s1 + g1 * u
        s0, s1 = x0 - gamma * l00, x1 - gamma * l10
        u = _lean_torque(s0 + 0.5 * T * s1, vk, c0, th0, J)
        c0_, c1_ = f00 * s0 + f01 * s1 + g0 * u, f10 * s0 + f11 * s1 + g1 * u
        s0, s1 = x0, x1 + gamma * l11
        u = _lean_torque(s0 + 0.5 * T * s1, vk, c0, th0, J)
        d0, d1 = f00 * s0 + f01 * s1 + g0 * u, f10 * s0 + f11 * s1 + g1 * u
        s0, s1 = x0, x1 - gamma * l11
        u = _lean_torque(s0 + 0.5 * T * s1, vk, c0, th0, J)
        e0, e1 = f00 * s0 + f01 * s1 + g0 * u, f10 * s0 + f11 * s1 + g1 * u
        m0 = 0.0 + wm0 * a0 + wm1 * b0 + wm2 * c0_ + wm3 * d0 + wm4 * e0
        m1 = 0.0 + wm0 * a1 + wm1 * b1 + wm2 * c1_ + wm3 * d1 + wm4 * e1
        p00, p01, p11 = q00, q01, q11
        dd0, dd1 = a0 - m0, a1 - m1
        p00 += wc0 * dd0 * dd0
        p01 += wc0 * dd0 * dd1
        p11 += wc0 * dd1 * dd1
        dd0, dd1 = b0 - m0, b1 - m1
        p00 += wc1 * dd0 * dd0
        p01 += wc1 * dd0 * dd1
        p11 += wc1 * dd1 * dd1
        dd0, dd1 = c0_ - m0, c1_ - m1
        p00 += wc2 * dd0 * dd0
        p01 += wc2 * dd0 * dd1
        p11 += wc2 * dd1 * dd1
        dd0, dd1 = d0 - m0, d1 - m1
        p00 += wc3 * dd0 * dd0
        p01 += wc3 * dd0 * dd1
        p11 += wc3 * dd1 * dd1
        dd0, dd1 = e0 - m0, e1 - m1
        p00 += wc4 * dd0 * dd0
        p01 += wc4 * dd0 * dd1
        p11 += wc4 * dd1 * dd1
        x0, x1 = m0, m1
        # sigma points of the a-priori (x-, P-) and the measurement update
        l00 = math.sqrt(p00)
        l10 = p01 / l00
        l11 = math.sqrt(p11 - l10 * l10)
        sa0, sa1 = x0 + gamma * l00, x1 + gamma * l10
        sb0, sb1 = x0 - gamma * l00, x1 - gamma * l10
        sc1 = x1 + gamma * l11
        sd1 = x1 - gamma * l11
        h0 = _lean_h(x0, c0, th0, cb, acir, bcir, a2, ct, db)
        h1 = _lean_h(sa0, c0, th0, cb, acir, bcir, a2, ct, db)
        h2 = _lean_h(sb0, c0, th0, cb, acir, bcir, a2, ct, db)
        ym = 0.0 + wm0 * h0 + wm1 * h1 + wm2 * h2 + wm3 * h0 + wm4 * h0
        dy0, dy1, dy2 = h0 - ym, h1 - ym, h2 - ym
        py = R + wc0 * dy0 * dy0 + wc1 * dy1 * dy1 + wc2 * dy2 * dy2
        py = py + wc3 * dy0 * dy0 + wc4 * dy0 * dy0
        cx = 0.0 + wc0 * (x0 - x0) * dy0 + wc1 * (sa0 - x0) * dy1 + wc2 * (sb0 - x0) * dy2
        cx = cx + wc3 * (x0 - x0) * dy0 + wc4 * (x0 - x0) * dy0
        cw = 0.0 + wc0 * (x1 - x1) * dy0 + wc1 * (sa1 - x1) * dy1 + wc2 * (sb1 - x1) * dy2
        cw = cw + wc3 * (sc1 - x1) * dy0 + wc4 * (sd1 - x1) * dy0
        k0 = cx / py
        k1 = cw / py
        nu = y[k] - ym
        x0 += k0 * nu
        x1 += k1 * nu
        p00 = p00 - k0 * k0 * py
        p01 = p01 - k0 * k1 * py
        p11 = p11 - k1 * k1 * py
        out_x[k, 0] = x0
        out_x[k, 1] = x1
        out_p[k, 0] = p00
        out_p[k, 1] = p11
        out_p[k, 2] = p01
        out_nis[k] = nu * nu / py
    return x0, x1


def kernel(kind, y, v2, x0, P0, f, frame=10_000):
    """Samples/s and theta of the ``kind`` kernel (``ScannerFilter.run_frame``) over frames
    of ``frame`` samples, from (x0, P0)."""
    g = su.ScannerFilter(kind, f.p)
    g.x, g.P = x0.copy(), P0.copy()
    th = np.empty(y.size)
    t0 = time.perf_counter()
    for i in range(0, y.size, frame):
        sl = slice(i, i + frame)
        m = y[sl].size
        ox, op, on = np.empty((m, 2)), np.empty((m, 3)), np.empty(m)
        g.run_frame(y[sl], v2[sl], True, ox, op, on)
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


def best_interleaved(fns, repeats=7):
    """Best time of each function over ``repeats`` rounds, the functions taking turns (a
    load that comes and goes hits both alike)."""
    best = [math.inf] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def lean_vs_kernel(y, v2, x0, P0, f) -> float:
    """The UKF kernel against :func:`lean_ukf` on the same data, one call over every
    sample (best of 7, taking turns): speed ratio kernel / lean (acceptance >= 0.9) and the largest
    relative difference of theta (<= 1e-12). Returns the ratio."""
    md = f.model
    n = y.size

    def run_kernel():
        f.x, f.P = x0.copy(), P0.copy()
        ox, op, on = np.empty((n, 2)), np.empty((n, 3)), np.empty(n)
        f.run_frame(y, v2, True, ox, op, on)
        return ox, op, on

    def run_lean():
        ox, op, on = np.empty((n, 2)), np.empty((n, 3)), np.empty(n)
        lean_ukf(
            y, v2, x0.copy(), P0.copy(), md.Phi, md.Gam, md.Q, md.meas, md.J, md.R, md.T,
            f.wm, f.wc, f.gamma, ox, op, on,
        )  # fmt: skip
        return ox, op, on

    rel = max(
        float(np.max(np.abs(a - b)) / np.max(np.abs(b))) for a, b in zip(run_kernel(), run_lean())
    )
    t_k, t_l = best_interleaved((run_kernel, run_lean))
    ratio = t_l / t_k
    print(
        f"UKF kernel / lean numba loop of the same arithmetic: {ratio:5.2f}x "
        f"({n / t_k / 1e6:.2f} vs {n / t_l / 1e6:.2f} Msamples/s; asked >= 0.9); "
        f"max relative difference of the estimates {rel:.1e} (asked <= 1e-12)"
    )
    return ratio


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
    lean_vs_kernel(y, v2, x0, P0, f)
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

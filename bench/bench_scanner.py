"""Benchmark: chapter-4 micro-scanner (dc_transimpedance) graph and the threshold / EKF kernels.

Run:  .venv/bin/python bench/bench_scanner.py
Prints
* the device core (mechanics RK4 + readout) in samples/s and x real time at fs = 500 kHz;
* the ROS graph of scenario ``scanner_threshold`` (device node -> threshold/hybrid+plain EKF
  node -> MCAP recorder, one process, frames of 1000 samples, driven as fast as the consumers
  take the frames): simulated seconds per wall second (target >= 1 x real time);
* the online DOG+NMS detector and the EKF kernels (plain, hybrid with late detections) in
  samples/s, and their ratio to a straightforward numpy per-sample implementation of the
  same plain EKF (checked to give the same estimates), and to filterpy's
  ExtendedKalmanFilter if filterpy is installed in .venv (it is not pip-installed here).
Numba compile / cache load is done before timing.
"""

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation.filters.scanner_threshold_detector import Detections, OnlineThresholdDetector
from mems_estimation.filters.scanner_threshold_ekf import model_from_device, run_ekf, scanner_model
from mems_estimation.studies.scanner_threshold import DRIFTED_SENSOR
from mems_sim.devices.scanner import MicroScannerDevice, resolve_scanner

FS = 500e3


def numpy_ekf(y, v, p, x0=(0.0, 0.0)):
    """Plain EKF of mems_estimation.filters.scanner_threshold_ekf (Table 4.1, Joseph form) as a numpy loop."""
    m = scanner_model(p)
    x = np.array(x0, float)
    P = np.diag([p["initial_theta_std"] ** 2, p["initial_omega_std"] ** 2])
    out = np.empty((len(y), 2))
    full = m.full_jac
    for k in range(len(y)):
        if k > 0:
            u = (x[0] - m.theta_th) / m.dth0
            e = np.exp(-u * u)
            v2 = v[k - 1] ** 2
            acc = 0.5 * (-2 * m.dc0 * u / m.dth0 * e) * v2 / m.J
            dacc = 0.5 * (2 * m.dc0 / m.dth0**2 * (2 * u * u - 1) * e) * v2 / m.J
            G = m.Phi + np.outer(m.Gam, [dacc, 0.0])
            x = m.Phi @ x + m.Gam * acc
            P = G @ P @ G.T + m.Q
        u = (x[0] - m.theta_th) / m.sth0
        e = np.exp(-u * u)
        h = -m.gain * (-2 * m.sc0 * u / m.sth0 * e)
        hp = -m.gain * (2 * m.sc0 / m.sth0**2 * (2 * u * u - 1) * e)
        H = np.array([hp * x[1] if full else 0.0, h])
        S = H @ P @ H + m.r_cap
        K = P @ H / S
        x = x + K * (y[k] - h * x[1])
        A = np.eye(2) - np.outer(K, H)
        P = A @ P @ A.T + np.outer(K, K) * m.r_cap
        out[k] = x
    return out


def filterpy_ekf(y, v, p):
    """The same plain EKF through filterpy.kalman.ExtendedKalmanFilter (if installed)."""
    from filterpy.kalman import ExtendedKalmanFilter

    m = scanner_model(p)
    f = ExtendedKalmanFilter(dim_x=2, dim_z=1)
    f.x = np.zeros((2, 1))
    f.P = np.diag([p["initial_theta_std"] ** 2, p["initial_omega_std"] ** 2])
    f.R = np.array([[m.r_cap]])
    f.Q = m.Q
    out = np.empty((len(y), 2))

    def hx(x):
        u = (x[0, 0] - m.theta_th) / m.sth0
        return np.array([[-m.gain * (-2 * m.sc0 * u / m.sth0 * np.exp(-u * u)) * x[1, 0]]])

    def HJ(x):
        u = (x[0, 0] - m.theta_th) / m.sth0
        e = np.exp(-u * u)
        h = -m.gain * (-2 * m.sc0 * u / m.sth0 * e)
        hp = -m.gain * (2 * m.sc0 / m.sth0**2 * (2 * u * u - 1) * e)
        return np.array([[hp * x[1, 0] if m.full_jac else 0.0, h]])

    for k in range(len(y)):
        if k > 0:
            u = (f.x[0, 0] - m.theta_th) / m.dth0
            e = np.exp(-u * u)
            v2 = v[k - 1] ** 2
            acc = 0.5 * (-2 * m.dc0 * u / m.dth0 * e) * v2 / m.J
            dacc = 0.5 * (2 * m.dc0 / m.dth0**2 * (2 * u * u - 1) * e) * v2 / m.J
            G = m.Phi + np.outer(m.Gam, [dacc, 0.0])
            f.x = m.Phi @ f.x + m.Gam.reshape(2, 1) * acc
            f.P = G @ f.P @ G.T + f.Q
        f.update(np.array([[y[k]]]), HJ, hx)
        out[k] = f.x[:, 0]
    return out


def bench_graph(frame: int, record: bool) -> tuple[float, float]:
    """(simulated s, wall s) of the scanner_threshold graph without the offline studies."""
    from mems_scenarios import scanner_threshold as sc
    from mems_scenarios.base import Progress, ScenarioOptions

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "bench.mcap"
        opts = ScenarioOptions(seed=0, out=out, progress=False)
        r = sc.run_graph(
            opts,
            out,
            sc.DEFAULT_DURATION_S,
            Progress(1.0, False, "bench"),
            frame=frame,
            record=record,
        )
        return sc.DEFAULT_DURATION_S, r["wall_s"]  # publishing phase only (no set-up)


def _timed(n: int, fn, *args, **kw):
    """(fn(*args, **kw), n / its wall time in s): the result and the rate over n samples."""
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return out, n / (time.perf_counter() - t0)


def main() -> None:
    dev = MicroScannerDevice(DRIFTED_SENSOR, seed=0)
    dev.step(1000)
    t0 = time.perf_counter()
    fr = dev.step(dev.total_samples - 1000)
    r = fr.y.size / (time.perf_counter() - t0)
    print(f"device core (RK4 + readout): {r / 1e6:6.2f} Msamples/s = {r / FS:6.1f} x real time")
    det0 = OnlineThresholdDetector(dog_sigma=45.0)  # load the numba caches first
    det0.process(fr.y[:2000])
    run_ekf(fr.y[:2000], fr.drive[:2000], model_from_device(resolve_scanner({})))
    for frame, record in ((1000, True), (5000, True), (10000, True), (10000, False)):
        sim, wall = bench_graph(frame, record)
        print(
            f"dc_transimpedance graph (device node -> threshold+hybrid+plain EKF node"
            f"{' -> MCAP recorder' if record else ', no recorder'}), fs 500 kHz, frames of "
            f"{frame}: {sim / wall:5.2f} x real time  (target >= 1)"
        )
    y, v = fr.y, fr.drive
    n = y.size
    det = OnlineThresholdDetector(dog_sigma=45.0)
    det.process(y[:1000])
    det = OnlineThresholdDetector(dog_sigma=45.0)
    t0 = time.perf_counter()
    D = Detections.concat([det.process(y[a : a + 1000]) for a in range(0, n, 1000)])
    r_det = n / (time.perf_counter() - t0)
    print(f"online DOG+NMS detector (w 400): {r_det / 1e6:6.2f} Msamples/s")
    p = model_from_device(resolve_scanner({}))
    run_ekf(y[:2000], v[:2000], p, detections=None)
    for name, d in (("plain EKF", None), ("hybrid EKF (late detections, re-propagation)", D)):
        _, rk = _timed(n, run_ekf, y, v, p, detections=d, frame=1000)
        print(f"{name} kernel: {rk / 1e6:6.2f} Msamples/s = {rk / FS:5.1f} x real time")
    m = 20_000
    ref, r_np = _timed(m, numpy_ekf, y[:m], v[:m], p)
    ours, r_nb = _timed(m, run_ekf, y[:m], v[:m], p)
    err = np.abs(np.column_stack([ours.theta, ours.omega]) - ref).max(axis=0)
    print(
        f"plain EKF numba {r_nb / 1e3:8.0f} ksamples/s vs numpy loop {r_np / 1e3:6.1f} ksamples/s"
        f": x{r_nb / r_np:5.0f}; max |diff| theta {err[0]:.1e} rad, omega {err[1]:.1e} rad/s"
    )
    try:
        import filterpy  # noqa: F401  (only checks that the reference library is installed)
    except ImportError:
        print("filterpy: not installed in .venv -> ratio to filterpy not measured")
        return
    fp, r_fp = _timed(m, filterpy_ekf, y[:m], v[:m], p)
    err = np.abs(np.column_stack([ours.theta, ours.omega]) - fp).max(axis=0)
    print(
        f"filterpy ExtendedKalmanFilter {r_fp / 1e3:6.1f} ksamples/s: numba x{r_nb / r_fp:5.0f}; "
        f"max |diff| theta {err[0]:.1e} rad, omega {err[1]:.1e} rad/s"
    )


if __name__ == "__main__":
    main()

"""Benchmark and sensitivity study of the micro-stage EKF (Chen 2018 ch. 3, issue 3).

Run:  .venv/bin/python bench/bench_stage_ekf.py [--graph] [--sensitivity]

1. samples/s of the numba EKF kernel (eqs. 48-53, 4 channels), of the feedthrough
   canceller and of the stage emulator (real-time factor at fs = 625 kHz);
2. the kernel against a reference EKF on the same data: filterpy's ExtendedKalmanFilter
   when installed, otherwise the plain numpy matrix form of eqs. (48)-(53)
   (np.linalg.inv per sample); max relative difference of the estimates and speed ratio;
3. ``--graph``: real-time factor of the scenario's node graph (stage at 625 kHz + gyro +
   EKF + calibration + MCAP recorder in one process), one stage instance and both
   temperatures at once, as fast as possible and paced by the wall clock;
4. ``--sensitivity`` (Fig. 3.16): stage scale-factor error vs sensor-noise variance, split
   into the part caused by identifying (eta, D_n) from noisy training data (estimator run on
   noise-free test data) and the EKF's stochastic part (true sensor parameters, noisy test
   data); Monte Carlo over seeds.
"""
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation import stage_identification as si  # noqa: E402
from mems_estimation.stage_ekf import FeedthroughCanceller, StageEkf  # noqa: E402
from mems_sim.micro_stage import (EPS0, DriveSchedule, MicroStage, dcdtheta_single,  # noqa: E402
                                  record)
from mems_sim.scenarios.gyro_calibration import Plan, identify_stage  # noqa: E402


def _best(fn, repeats=3):
    fn()
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def reference_ekf(model, y, u):
    """filterpy ExtendedKalmanFilter if available, else the numpy matrix form."""
    A, B = model.matrices()
    ny = y.shape[1]

    def hvec(th):
        return np.array([model.eta[c] * dcdtheta_single(th, model.gap[c], model.limits[c, 0],
                                                        model.limits[c, 1], model.limits[c, 3]
                                                        - model.limits[c, 2], EPS0)
                         for c in range(ny)])
    out = np.empty((len(u), 2))
    try:
        from filterpy.kalman import ExtendedKalmanFilter
    except ImportError:
        ExtendedKalmanFilter = None
    if ExtendedKalmanFilter is not None:
        f = ExtendedKalmanFilter(dim_x=2, dim_z=ny, dim_u=1)
        f.F, f.B = A, B.reshape(2, 1)
        f.Q = B.reshape(2, 1) @ B.reshape(1, 2) * model.Q
        f.R = model.R
        f.x = np.zeros(2)
        f.P = np.diag([1e-6, 1.0])
        up = 0.0
        for k in range(len(u)):
            f.predict(u=np.array([up]))
            if np.all(np.isfinite(y[k])):
                f.update(y[k], lambda x: np.column_stack([np.zeros(ny), hvec(x[0])]),
                         lambda x: hvec(x[0]) * x[1])
            up = u[k]
            out[k] = f.x
        return out, "filterpy.ExtendedKalmanFilter"
    x = np.zeros(2)
    P = np.diag([1e-6, 1.0])
    Bc = B.reshape(2, 1)
    up = 0.0
    for k in range(len(u)):
        x = A @ x + B * up
        P = A @ P @ A.T + Bc @ Bc.T * model.Q
        if np.all(np.isfinite(y[k])):
            h = hvec(x[0])
            H = np.column_stack([np.zeros(ny), h])
            K = P @ H.T @ np.linalg.inv(H @ P @ H.T + model.R)
            x = x + K @ (y[k] - H @ x)
            P = P - K @ H @ P
        up = u[k]
        out[k] = x
    return out, "numpy matrix form (filterpy not installed in .venv)"


def bench(model):
    rec = record(MicroStage({}, DriveSchedule.amplitude_sweep(n_trials=2, periods=400), seed=1))
    fs = rec["fs"]
    n = rec["u"].size
    yc = FeedthroughCanceller(4, fs).step(rec["y"], rec["v_bias"], rec["f_drive"])
    t = _best(lambda: StageEkf(model).step(yc, rec["u"]))
    print(f"EKF kernel (4 channels):      {n / t / 1e6:7.2f} Msamples/s = {n / t / fs:6.1f} x "
          f"real time at {fs / 1e3:g} kHz")
    t = _best(lambda: FeedthroughCanceller(4, fs).step(rec["y"], rec["v_bias"], rec["f_drive"]))
    print(f"feedthrough canceller:        {n / t / 1e6:7.2f} Msamples/s")
    sched = DriveSchedule.amplitude_sweep(n_trials=2, periods=200)
    st = MicroStage({}, sched, seed=2)
    m = st.total_samples()
    t0 = time.perf_counter()
    for _ in range(m // 20000):
        st.step(20000)
    t = time.perf_counter() - t0
    print(f"stage emulator (frames 20k):  {m / t / 1e6:7.2f} Msamples/s = {m / t / fs:6.2f} x "
          "real time")
    k = 20000
    ekf = StageEkf(model)
    x, _ = ekf.step(yc[:k], rec["u"][:k], corrected=False)
    t_ref0 = time.perf_counter()
    xr, name = reference_ekf(model, yc[:k], rec["u"][:k])
    t_ref = time.perf_counter() - t_ref0
    t_k = _best(lambda: StageEkf(model).step(yc[:k], rec["u"][:k], corrected=False))
    rel = max(np.max(np.abs(x[:, j] - xr[:, j])) / np.max(np.abs(xr[:, j])) for j in range(2))
    print(f"reference: {name}")
    print(f"  max relative difference of the estimates: {rel:.2e} (asked <= 1e-9)")
    print(f"  speed ratio kernel / reference: {t_ref / t_k:8.0f} x")


def sensitivity(model, seeds=(1, 2, 3, 4), scales=(0.5, 1.0, 2.0, 4.0)):
    """Fig. 3.16: std of the stage scale-factor error [ppm] vs noise variance."""
    test_sched = DriveSchedule.amplitude_sweep(n_trials=4, periods=160)
    train_sched = DriveSchedule.amplitude_sweep(n_trials=4, periods=120)
    ref = MicroStage()

    def noise(s):
        return {"readout_noise_scale": s}

    def stage_scale(m, rec):
        x, _ = StageEkf(m).step(si.cancelled(rec), rec["u"])
        return si.evaluate(x[:, 1], rec["omega"][:, 0], rec["phase"], rec["segment"])["alpha"]

    print("noise var x | sigma_y [uV] | ident. error std [ppm] | EKF stochastic std [ppm]")
    clean = record(MicroStage(noise(0.0), test_sched, seed=99))
    for s in scales:
        ident, stoch = [], []
        for sd in seeds:
            tr = record(MicroStage(noise(s), train_sched, seed=1000 + sd))
            m = si.reidentify_gap(model, tr)        # (D_n, eta) from noisy training data
            m.R = model.R * s * s
            ident.append(stage_scale(m, clean))
            mt = si.reidentify_gap(model, tr)
            mt.gap = np.full(4, ref.gap)            # perfectly identified sensor model
            mt.eta = ref.eta_true.copy()
            mt.R = model.R * s * s
            mt.alpha, mt.beta = 1.0, 0.0
            test = record(MicroStage(noise(s), test_sched, seed=2000 + sd))
            stoch.append(stage_scale(mt, test))
        sig = MicroStage(noise(s)).noise_std
        print(f"{s * s:11.3g} | {sig * 1e6:12.1f} | {np.std(ident) * 1e6:22.0f} | "
              f"{np.std(stoch) * 1e6:24.0f}")


def graph_rtf(model, realtime: bool, two: bool = False, domain_id: int | None = None) -> dict:
    """Real-time factor of the node graph of the scenario (stage at 625 kHz + gyro + EKF +
    calibration + MCAP recorder, one process) over the 7 x 400-period calibration sweep:
    one stage instance (the issue's benchmark) or both temperatures at once (the scenario)."""
    import tempfile
    from pathlib import Path

    from mems_sim.scenarios import gyro_calibration as gc
    from mems_sim.scenarios.base import ScenarioOptions
    inst = gc.INSTANCES if two else {"stage_t1": gc.T1}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.mcap"
        opts = ScenarioOptions(seed=1, out=out, domain_id=domain_id, progress=False,
                               realtime=realtime)
        g = gc.run_graph(opts, Plan(), {gc.T1: model, gc.T2: model}, out, instances=inst)
    return {"rtf": g["simulated_s"] / g["wall_s"] * (2 if two else 1),
            "gaps": sum(g["recorder"]["gaps"].values()), "instances": len(inst)}


def main() -> None:
    model, _ = identify_stage(seed=5, plan=Plan.short())
    bench(model)
    if "--graph" in sys.argv:
        for two in (False, True):
            for rt in (False, True):
                r = graph_rtf(model, rt, two)
                print(f"graph, {r['instances']} stage(s), {'realtime' if rt else 'fast':8s}: "
                      f"{r['rtf']:5.2f} x real time (stage samples summed over instances), "
                      f"frame-index gaps {r['gaps']}")
    if "--sensitivity" in sys.argv:
        sensitivity(model)


if __name__ == "__main__":
    main()

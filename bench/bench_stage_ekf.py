"""Benchmark and sensitivity study of the micro-stage EKF (Chen 2018 ch. 3).

Run:  .venv/bin/python bench/bench_stage_ekf.py [--graph] [--graph-processes[=ROWS]]
                                                [--graph-periods=N] [--keep-bags=DIR]
                                                [--sensitivity] [--drift]

1. samples/s of the numba EKF kernel (eqs. 48-53, 4 channels), of the feedthrough
   canceller and of the stage emulator (real-time factor at fs = 625 kHz);
2. the kernel against a reference EKF on the same data: filterpy's ExtendedKalmanFilter
   when installed, otherwise the plain numpy matrix form of eqs. (48)-(53)
   (np.linalg.inv per sample); max relative difference of the estimates and speed ratio;
3. ``--graph``: real-time factor of the scenario's node graph (stage at 625 kHz + gyro +
   EKF + calibration + MCAP recorder in one process), one stage instance and both
   temperatures at once, as fast as possible and paced by the wall clock;
4. ``--graph-processes[=zstd,lz4,none,lz4-noimu,none:10000,zstd@1.5]``: the same graph (one
   stage, 22.9 C; ``:N`` frames of N samples, ``@R`` the stage paced at R x real time) the
   way ROS users run it, one process per node (stage_node paced by its own
   wall-clock timer, stage_ekf_node, stage_gyro_calibration_node, mcap_record --compression C;
   a row named zstd_fast, zstd_small or fastwrite records with that rosbag2 storage preset,
   ``mcap_record --storage-preset-profile P``; ``--keep-bags=DIR`` keeps each recording;
   ``--graph-periods=N``: drive periods per calibration trial, default 1600: 6.6 s of data,
   2400: 9.8 s, i.e. 6.5 s of wall time at 1.5 x),
   localhost discovery, ROS_DOMAIN_ID from the environment (77 if unset): the stage's
   real-time factor (first to last frame), frames published vs recorded, frame-index gaps
   in the MCAP, CPU per process; "DOES NOT KEEP UP" when the factor is below 0.99 or a
   frame is missing, and a last frame published > 1 s late is named; plus the one-process
   figures (fast and realtime). Both over the 6.6 s sweep :data:`BENCH_PLAN`;
5. ``--sensitivity`` (Fig. 3.16): stage scale-factor error vs sensor-noise variance, split
   into the part caused by identifying (eta, D_n) from noisy training data (estimator run on
   noise-free test data) and the EKF's stochastic part (true sensor parameters, noisy test
   data); Monte Carlo over seeds;
6. ``--drift``: scale-factor error when the actuator gain b_c drifts between identification
   (22.9 C) and calibration (35.7 C): default Q, the thesis' Q, and the default Q with the
   actuator gain as a state (:func:`actuator_drift`).
"""

import math
import os
import sys
import time

import numba
import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

from mems_estimation.filters.stage_ekf import FeedthroughCanceller, StageEkf
from mems_estimation.identification import stage_identification as si
from mems_estimation.identification.stage_gyro_calibration import (
    T1,
    T2,
    Plan,
    calibration_run,
    identify_stage,
    retrain_at,
    training_record,
)
from mems_sim.devices.stage import DriveSchedule, MicroStage, record
from mems_sim.devices.stage_capacitance import EPS0, GL8_NODES, GL8_WEIGHTS, dcdtheta_single

# the graph's processes and their CPU (bench/process_tools.py, shared with
# bench_device_processes.py)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from process_tools import cpu_ticks as _cpu_ticks
from process_tools import (
    device_parameters,
    device_timing,
    process_env,
    recorder_command,
    wait_quiet,
)
from process_tools import machine_ticks as _machine_ticks
from process_tools import reap as _reap


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
        return np.array(
            [
                model.eta[c]
                * dcdtheta_single(
                    th,
                    model.gap[c],
                    model.limits[c, 0],
                    model.limits[c, 1],
                    model.limits[c, 3] - model.limits[c, 2],
                    EPS0,
                )
                for c in range(ny)
            ]
        )

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
                f.update(
                    y[k],
                    lambda x: np.column_stack([np.zeros(ny), hvec(x[0])]),
                    lambda x: hvec(x[0]) * x[1],
                )
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


#: Gauss-Legendre nodes and weights of dcdtheta_single_tan (8 points).
_GL_X = np.array(GL8_NODES)
_GL_W = np.array(GL8_WEIGHTS)


# Deliberately a second copy of the kernel's arithmetic (stage_ekf.ekf_run), not an import:
# the yardstick the kernel's speed is measured against (lean_vs_kernel); its estimates must
# equal the kernel's.
@numba.njit(cache=True)
def lean_stage_ekf(y, u, A, B, Q, Rinv, eta, gap, lim, eps, x_in, P_in, u0, out_x, out_var):
    """Lean reference loop of the stage EKF kernel's arithmetic (eqs. 48-53; the yardstick
    of ``stage_ekf.ekf_run``): state, covariance, held input and model matrices in
    scalars, the per-channel quadrature nodes of h(theta) (w, w0 w, eps L h) computed once
    instead of per sample, the same outputs. The same operations in the same order on
    each sample, so its estimates equal the kernel's (a row of y with a NaN: no update)."""
    n, ny = y.shape
    a00, a01, a10, a11 = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    b0, b1 = B[0], B[1]
    bq0, bq1, bq2 = B[0] * B[0] * Q, B[0] * B[1] * Q, B[1] * B[1] * Q
    nodes = np.empty((ny, 8))  # w at the nodes
    weights = np.empty((ny, 8))  # w0 w
    scale = np.empty(ny)  # eps L h
    for c in range(ny):
        h = 0.5 * (lim[c, 1] - lim[c, 0])
        m = 0.5 * (lim[c, 1] + lim[c, 0])
        for a in range(8):
            nodes[c, a] = m + h * _GL_X[a]
            weights[c, a] = _GL_W[a] * nodes[c, a]
        scale[c] = eps * (lim[c, 3] - lim[c, 2]) * h
    hv = np.empty(ny)
    r = np.empty(ny)
    x0, x1, up = x_in[0], x_in[1], u0
    p00, p01, p11 = P_in[0, 0], P_in[0, 1], P_in[1, 1]
    for k in range(n):
        t = a00 * x0 + a01 * x1 + b0 * up
        w = a10 * x0 + a11 * x1 + b1 * up
        c00 = a00 * p00 + a01 * p01
        c01 = a00 * p01 + a01 * p11
        c10 = a10 * p00 + a11 * p01
        c11 = a10 * p01 + a11 * p11
        q00 = c00 * a00 + c01 * a01 + bq0
        q01 = c00 * a10 + c01 * a11 + bq1
        q11 = c10 * a10 + c11 * a11 + bq2
        ok = True
        for c in range(ny):
            if not math.isfinite(y[k, c]):
                ok = False
        if ok:
            tt = math.tan(t)
            sec2 = 1.0 + tt * tt
            for c in range(ny):
                acc = 0.0
                dn = gap[c]
                for a in range(8):
                    d = dn - nodes[c, a] * tt
                    acc += weights[c, a] / (d * d)
                hv[c] = eta[c] * (scale[c] * acc * sec2)
            for c in range(ny):
                acc = 0.0
                for j in range(ny):
                    acc += Rinv[c, j] * hv[j]
                r[c] = acc
            g = 0.0
            s = 0.0
            for c in range(ny):
                g += r[c] * hv[c]
                s += r[c] * (y[k, c] - hv[c] * w)
            den = 1.0 + q11 * g
            t += q01 * s / den
            w += q11 * s / den
            f = g / den
            q00, q01, q11 = q00 - q01 * q01 * f, q01 - q01 * q11 * f, q11 - q11 * q11 * f
        p00, p01, p11 = q00, q01, q11
        x0, x1 = t, w
        up = u[k]
        out_x[k, 0] = t
        out_x[k, 1] = w
        out_var[k, 0] = p00
        out_var[k, 1] = p11
    return x0, x1


def lean_vs_kernel(model, yc, u) -> float:
    """The stage EKF kernel (``StageEkf.step``, uncorrected) against :func:`lean_stage_ekf`
    on the same data in one call (best of 5, taking turns): speed ratio kernel / lean
    (acceptance >= 0.9) and the largest relative difference of the estimates (<= 1e-12).
    Returns the ratio."""
    from mems_estimation.filters.stage_ekf import ekf_run

    ekf = StageEkf(model)
    n = yc.shape[0]
    args = (
        float(model.Q),
        ekf.Rinv,
        np.asarray(model.eta, float),
        np.asarray(model.gap, float),
        np.ascontiguousarray(model.limits, float),
        ekf.eps,
    )
    y = np.ascontiguousarray(yc, float)
    u = np.ascontiguousarray(u, float)

    def run_kernel():
        ox, ov = np.empty((n, 2)), np.empty((n, 2))
        x, P, up = ekf.x.copy(), ekf.P.copy(), ekf.uprev.copy()
        ekf_run(y, u, ekf.A, ekf.B, *args, x, P, up, ox, ov)
        return ox, ov

    def run_lean():
        ox, ov = np.empty((n, 2)), np.empty((n, 2))
        lean_stage_ekf(y, u, ekf.A, ekf.B, *args, ekf.x, ekf.P, float(ekf.uprev[0]), ox, ov)
        return ox, ov

    rel = max(
        float(np.max(np.abs(a - b)) / np.max(np.abs(b))) for a, b in zip(run_kernel(), run_lean())
    )
    best = [math.inf, math.inf]
    for _ in range(5):
        for i, fn in enumerate((run_kernel, run_lean)):
            t0 = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t0)
    ratio = best[1] / best[0]
    print(
        f"EKF kernel / lean numba loop of the same arithmetic: {ratio:5.2f}x "
        f"({n / best[0] / 1e6:.2f} vs {n / best[1] / 1e6:.2f} Msamples/s; asked >= 0.9); "
        f"max relative difference of the estimates {rel:.1e} (asked <= 1e-12)"
    )
    return ratio


def bench(model):
    rec = record(MicroStage({}, DriveSchedule.amplitude_sweep(n_trials=2, periods=400), seed=1))
    fs = rec["fs"]
    n = rec["u"].size
    yc = FeedthroughCanceller(4, fs).step(rec["y"], rec["v_bias"], rec["f_drive"])
    t = _best(lambda: StageEkf(model).step(yc, rec["u"]))
    print(
        f"EKF kernel (4 channels):      {n / t / 1e6:7.2f} Msamples/s = {n / t / fs:6.1f} x "
        f"real time at {fs / 1e3:g} kHz"
    )
    t = _best(lambda: FeedthroughCanceller(4, fs).step(rec["y"], rec["v_bias"], rec["f_drive"]))
    lean_vs_kernel(model, yc, rec["u"])
    print(f"feedthrough canceller:        {n / t / 1e6:7.2f} Msamples/s")
    sched = DriveSchedule.amplitude_sweep(n_trials=2, periods=200)
    st = MicroStage({}, sched, seed=2)
    m = st.total_samples()
    t0 = time.perf_counter()
    for _ in range(m // 20000):
        st.step(20000)
    t = time.perf_counter() - t0
    print(
        f"stage emulator (frames 20k):  {m / t / 1e6:7.2f} Msamples/s = {m / t / fs:6.2f} x "
        "real time"
    )
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
            m = si.reidentify_gap(model, tr)  # (D_n, eta) from noisy training data
            m.R = model.R * s * s
            ident.append(stage_scale(m, clean))
            mt = si.reidentify_gap(model, tr)
            mt.gap = np.full(4, ref.gap)  # perfectly identified sensor model
            mt.eta = ref.eta_true.copy()
            mt.R = model.R * s * s
            mt.alpha, mt.beta = 1.0, 0.0
            test = record(MicroStage(noise(s), test_sched, seed=2000 + sd))
            stoch.append(stage_scale(mt, test))
        sig = MicroStage(noise(s)).noise_std
        print(
            f"{s * s:11.3g} | {sig * 1e6:12.1f} | {np.std(ident) * 1e6:22.0f} | "
            f"{np.std(stoch) * 1e6:24.0f}"
        )


class _WarmGainEkf:
    """:class:`~mems_estimation.filters.stage_ekf.GainAdaptiveStageEkf` started from a converged
    gain, as a filter that has been running before the sweep would be: a first pass over
    the same data converges g, the second starts from that g and its variance."""

    def __init__(self, model, gain_rw: float, output_correction) -> None:
        self.model, self.gain_rw, self.oc = model, gain_rw, output_correction

    def step(self, y, u, corrected: bool = True):
        from mems_estimation.filters.stage_ekf import GainAdaptiveStageEkf

        first = GainAdaptiveStageEkf(self.model, self.gain_rw, output_correction=self.oc)
        first.step(y, u, corrected)
        warm = GainAdaptiveStageEkf(
            self.model,
            self.gain_rw,
            p0=(1e-6, 1.0, first.P[2, 2]),
            output_correction=self.oc,
            gain0=first.x[2],
        )
        return warm.step(y, u, corrected)


def actuator_drift(seeds=(1, 2), tempcos=(0.0, 2e-4, 1e-3), gain_rw=0.0):
    """Scale-factor error when the stage's actuator gain b_c drifts with temperature
    (``b_c_tempco_per_k``; Chen 2018 gives no coefficient, the default is 0) and nothing but
    (D_n, eta) is re-identified at 35.7 C (as in the paper). Three estimators: the default
    Q (from the reference: model-driven EKF), the thesis' one-step Q (measurement-driven),
    and the default Q with the actuator gain as a state (:class:`_WarmGainEkf`, random walk
    ``gain_rw`` 1/sqrt(s), its output correction fitted on the 22.9 C training sweep like
    the default's). Short plan."""
    plan = Plan.short()
    print(
        "estimator | seed | b_c change 22.9->35.7 C | SF error [ppm] +- SE at 22.9 C | "
        "at 35.7 C | omega RMSE 35.7 C [rad/s]"
    )
    for kind in ("reference", "one_step", "gain"):
        for seed in seeds:
            model, _ = identify_stage(
                seed, plan, q_method="one_step" if kind == "one_step" else "reference"
            )
            oc = None
            if kind == "gain":
                tr = training_record(seed, plan)
                oc = si.output_correction(
                    model,
                    si.cancelled(tr),
                    tr["u"],
                    tr["ldv"],
                    tr["phase"],
                    tr["segment"],
                    model.extra["ldv_delay_s"],
                    model.extra["ldv_bias_rad_s"],
                    estimator=_WarmGainEkf(model, gain_rw, (1.0, 0.0)),
                )
            for tc in tempcos:
                sp = {"b_c_tempco_per_k": tc}
                ms = {T1: model, T2: retrain_at(model, T2, seed, plan, stage_params=sp)}
                r = {
                    T: calibration_run(
                        ms[T],
                        T,
                        seed,
                        plan,
                        stage_params=sp,
                        estimator=_WarmGainEkf(ms[T], gain_rw, oc) if oc else None,
                    )
                    for T in ms
                }
                print(
                    f"{kind:9s} | {seed:4d} | {100 * tc * (T2 - T1):+22.2f} % | "
                    + " | ".join(f"{r[T]['ppm']:+7.0f} +- {r[T]['se_ppm']:4.0f}" for T in ms)
                    + f" | {r[T2]['eval']['rmse']:.4f}"
                )


#: Calibration sweep of the graph benchmarks: 7 trials x 1600 drive periods at 1700 Hz
#: (6.6 simulated s). The scenario's own sweep (7 x 400 periods, 1.65 s) is so short that
#: start-up (DDS matching, first frames) and the pipeline's end latency (~2 frames of
#: 32 ms) decide its wall time; the longer sweep measures the steady state.
BENCH_PLAN = Plan(cal_periods=1600)


def graph_rtf(
    model, realtime: bool, two: bool = False, domain_id: int | None = None, plan: Plan = BENCH_PLAN
) -> dict:
    """Real-time factor of the node graph of the scenario (stage at 625 kHz + gyro + EKF +
    calibration + MCAP recorder, one process) over the calibration sweep ``plan``:
    one stage instance (the deployed graph's benchmark) or both temperatures at once (the
    scenario).

    ``rtf`` = simulated s / wall s from the stages' start to the last frame recorded and
    estimated; paced by the wall clock it is at most 1 - latency/duration, so ``latency_s``
    = wall - simulated (realtime only) says how far behind the graph ended: a graph that
    keeps up ends a constant pipeline latency behind, one that does not falls further
    behind the longer it runs."""
    import tempfile
    from pathlib import Path

    from mems_scenarios import gyro_calibration as gc
    from mems_scenarios.base import ScenarioOptions

    inst = gc.INSTANCES if two else {"stage_t1": T1}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.mcap"
        opts = ScenarioOptions(
            seed=1, out=out, domain_id=domain_id, progress=False, realtime=realtime
        )
        g = gc.run_graph(opts, plan, {T1: model, T2: model}, out, instances=inst)
    return {
        "rtf": g["simulated_s"] / g["wall_s"] * (2 if two else 1),
        "latency_s": g["wall_s"] - g["simulated_s"],
        "simulated_s": g["simulated_s"],
        "gaps": sum(g["recorder"]["gaps"].values()),
        "instances": len(inst),
    }


#: ``--graph-processes`` rows: recorder compression, ``-noimu`` with publish_imu off (the
#: stage publishes its per-sample sensor_msgs/Imu only while somebody subscribes, and
#: nobody does in this graph, so both variants should measure the same), ``:N`` with
#: frames of N samples instead of the scenario's 20000 (e.g. ``none:10000``)
GRAPH_PROCESS_ROWS = "zstd,lz4,none,lz4-noimu"

#: row names that are rosbag2 storage presets of the recorder (``mcap_record
#: --storage-preset-profile``) instead of a ``--compression`` value
PRESET_ROWS = ("zstd_fast", "zstd_small", "fastwrite")


def graph_processes(
    model,
    compression: str = "zstd",
    domain_id: int = 77,
    publish_imu: bool = True,
    plan: Plan | None = None,
    extra_env: dict | None = None,
    frame_size: int | None = None,
    pace: float = 1.0,
    keep_bag: str | None = None,
) -> dict:
    """The scenario's graph for one stage instance (22.9 C) the way ROS users run it: one
    process per node -- ``stage_node`` paced by its own wall-clock timer (its timer
    started once the subscribers are matched, its process ending once its schedule is
    acknowledged; its timing read back from the recording),
    ``stage_ekf_node`` (identified YAML), ``stage_gyro_calibration_node`` and ``mcap_record
    --compression C`` -- all with localhost discovery in ``domain_id``.

    Returns the stage's real-time factor (simulated / wall span from its first to its last
    frame) and worst lateness, frames published vs recorded per topic and frame-index gaps
    (from the MCAP), the lag of the last recorded estimate behind the stage's last frame,
    each topic's worst frame delay (recorder's log time - header stamp, beyond the median
    of the run) and how many frames were delayed > 0.2 s, and CPU seconds per process.
    ``frame_size``: samples per stage frame (default the scenario's ``FRAME``); ``pace``:
    the stage's ``realtime_factor`` (1.5: paced at 1.5 x its sample rate, the headroom
    asked for); ``compression``: a ``--compression`` value or a storage preset
    (:data:`PRESET_ROWS`); ``keep_bag``: copy the recording there."""
    import signal
    import subprocess
    import tempfile
    from pathlib import Path

    from mcap.reader import make_reader

    from mems_estimation.filters.stage_ekf import save_model
    from mems_scenarios import gyro_calibration as gc
    from mems_sim.bag.info import bag_info

    plan = plan or BENCH_PLAN
    frame_size = int(frame_size or gc.FRAME)
    ns = "/stage_t1"
    py = sys.executable
    env = process_env(domain_id)
    env.update(extra_env or {})
    topics = [f"{ns}/{t}" for t in gc.RECORDED] + ["/diagnostics"]
    frames_topics = ("adc", "drive", "truth", "estimate")
    ros = ["--ros-args", "--log-level", "warn", "-r", f"__ns:={ns}"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        yaml_path = tmp / "stage_params.yaml"
        save_model(model, str(yaml_path))
        out = tmp / "graph.mcap"
        cmds = {
            "recorder": recorder_command(
                out,
                ["--storage-preset-profile", compression]
                if compression in PRESET_ROWS
                else ["--compression", compression],
                topics,
            ),
            "ekf": [
                py,
                "-m",
                "mems_estimation.nodes.stage_ekf_node",
                *ros,
                "-p",
                f"device_namespace:={ns}",
                "-p",
                f"params_yaml:={yaml_path}",
            ],
            "calibration": [
                py,
                "-m",
                "mems_estimation.nodes.stage_gyro_calibration_node",
                *ros,
                "-p",
                f"device_namespace:={ns}",
                "-p",
                f"n_trials:={plan.cal_trials}",
            ],
            "stage": [
                py,
                "-m",
                "mems_sim.nodes.stage_node",
                *ros,
                *(
                    a
                    for k, v in device_parameters(
                        {
                            f"{ns}/adc": 2,
                            f"{ns}/drive": 3,
                            f"{ns}/truth": 1,
                            f"{ns}/gyro/adc": 2,
                            f"{ns}/estimate": 2,
                        }
                    ).items()
                    for a in ("-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}")
                ),
                "-p",
                f"seed:={1 * 100 + 50}",
                "-p",
                f"temperature_c:={T1}",
                "-p",
                f"n_trials:={plan.cal_trials}",
                "-p",
                f"periods_per_trial:={plan.cal_periods}",
                "-p",
                f"frame_size:={frame_size}",
                "-p",
                "frame_id:=stage_t1",
                # sensor time on the wall clock: the recorded log times are comparable
                # with the publication times
                "-p",
                "stamp_origin:=wall",
                "-p",
                f"realtime_factor:={float(pace)}",
                "-p",
                f"publish_imu:={'true' if publish_imu else 'false'}",
            ],
        }
        procs, logs, cpu = {}, {}, {}
        try:
            for name, cmd in cmds.items():
                logs[name] = open(tmp / f"{name}.log", "w+")
                procs[name] = subprocess.Popen(
                    cmd, env=env, stdout=logs[name], stderr=subprocess.STDOUT, cwd=str(tmp)
                )
            samples = []  # (monotonic, CPU ticks per process) while the stage runs
            deadline = time.monotonic() + 180.0
            while cpu.get("stage") is None:
                samples.append(
                    (
                        time.monotonic(),
                        dict({n: _cpu_ticks(p.pid) for n, p in procs.items()}, **_machine_ticks()),
                    )
                )
                cpu["stage"] = _reap(procs["stage"], 0.05)
                if time.monotonic() > deadline:
                    raise RuntimeError("the stage process did not finish in 180 s")
            # the consumers are done when they stop using CPU (no ROS participant of ours)
            rest = [procs[n] for n in ("ekf", "calibration", "recorder")]
            drain_s = wait_quiet(rest, 60.0)
            for name in ("calibration", "ekf", "recorder"):
                procs[name].send_signal(signal.SIGINT)
                cpu[name] = _reap(procs[name], 60.0)
        finally:
            for name, p in procs.items():
                if p.returncode is None and p.poll() is None:
                    p.kill()
                    p.wait()
            for f in logs.values():
                f.flush()
        texts = {}
        for name, f in logs.items():
            f.seek(0)
            texts[name] = f.read()
            f.close()
        if procs["stage"].returncode:
            raise RuntimeError("stage process failed:\n" + texts["stage"][-3000:])
        if procs["recorder"].returncode or not out.exists():
            raise RuntimeError("recorder failed:\n" + texts["recorder"][-3000:])
        st = device_timing(out, ns, pace)
        info = bag_info(str(out))
        if keep_bag:
            import shutil

            shutil.copyfile(out, keep_bag)
        times = {}  # topic -> [(log time = the frame's stamp, publish time = DDS source time)]
        with open(out, "rb") as f:
            for _, ch, m in make_reader(f).iter_messages(
                topics=[f"{ns}/{t}" for t in frames_topics]
            ):
                times.setdefault(ch.topic.rsplit("/", 1)[1], []).append(
                    (m.log_time, m.publish_time)
                )
    # latency of a frame: its publication (the stage's, or the EKF's for the estimate)
    # after its first sample was due on the wall clock (stamps run at the pacing's rate)
    t0 = min(lt for lt, _ in times.get("adc", [(0, 0)]))
    delayed, lag = {}, {}
    for t, tp_ in times.items():
        lt, pt = np.asarray(tp_, dtype=np.int64).T
        lat = (pt - (t0 + (lt - t0) / float(pace))) / 1e9
        d = lat - np.median(lat)
        delayed[t] = (float(d.max()), int(np.sum(d > 0.2)))
        lag[t] = float(lat[np.argmax(lt)])
    tp = info["topics"]
    recorded = {
        t: tp.get(f"{ns}/{t}", {}).get("count", 0)
        for t in frames_topics + ("gyro/adc", "gyro_scale_factor")
    }
    gaps = {
        t: tp[f"{ns}/{t}"]["gaps"]
        for t in frames_topics + ("gyro/adc",)
        if "gaps" in tp.get(f"{ns}/{t}", {})
    }
    missing = sum(tp[f"{ns}/{t}"].get("missing_samples", 0) for t in gaps)
    # CPU of each process while the stage published (first frame's start to last frame)
    hz = os.sysconf("SC_CLK_TCK")
    w0, w1 = st["t_first"] - st["frame_size"] / st["fs"], st["t_last"]
    inside = [s_ for s_ in samples if w0 <= s_[0] <= w1]
    run_cpu = {}
    if len(inside) >= 2:
        run_cpu = {
            n: (inside[-1][1][n] - inside[0][1][n]) / hz / (inside[-1][0] - inside[0][0])
            for n in inside[0][1]
            if n != "stage" or inside[-1][1][n]
        }
        # busy cores of other processes (another job on the machine slows the graph)
        machine = run_cpu.pop("machine")
        run_cpu["others"] = max(machine - sum(v for k, v in run_cpu.items() if k in procs), 0.0)
    return dict(
        compression=compression,
        publish_imu=publish_imu,
        rtf=st["rtf"],
        pace=float(pace),
        frame_size=frame_size,
        delayed=delayed,
        max_late_s=st["max_late_s"],
        sim_span_s=st["sim_span_s"],
        wall_span_s=st["wall_span_s"],
        published=st["frames"],
        recorded=recorded,
        gaps=sum(gaps.values()),
        gap_topics=gaps,
        missing_samples=missing,
        lag_s=lag,
        drain_s=drain_s,
        acked=procs["stage"].returncode == 0,  # exit_when_acknowledged: 0 once acknowledged
        cpu_s=cpu,
        run_cpu=run_cpu,
        stage_loop_cpu_s=run_cpu.get("stage", 0.0) * st["wall_span_s"],
        mb=info["file_size"] / 1e6,
        truncated=info["truncated"],
        lost=sum(max(st["frames"] - recorded[t], 0) for t in frames_topics),
    )


def print_graph_processes(r: dict) -> None:
    """One block per recorder compression; says so when the stage cannot keep up.

    Keeping up = the stage's factor >= 0.99 x its pacing with every frame recorded and no
    index gap.
    A last frame published more than 1 s after its first sample was due is named (for
    the estimate: the EKF's output). The MCAP holds each frame's stamp (log time) and the
    DDS source time of its publication (publish time), not when the recorder received
    it."""
    keeps = r["rtf"] >= 0.99 * r.get("pace", 1.0) and r["lost"] == 0 and r["gaps"] == 0
    late = {k: v for k, v in r["lag_s"].items() if v >= 1.0}
    cpu = ", ".join(f"{k} {v:.2f}" for k, v in r["cpu_s"].items() if v is not None)
    rec = ", ".join(f"{k} {v}" for k, v in r["recorded"].items())
    lag = ", ".join(f"{k} {v * 1e3:.0f}" for k, v in r["lag_s"].items())
    print(
        f"graph, 4 processes, realtime, recorder {r['compression']:4s}, "
        f"publish_imu {'on ' if r['publish_imu'] else 'off'}, frames of "
        f"{r['frame_size']}, paced at {r.get('pace', 1.0):g} x: {r['rtf']:5.3f} x real "
        f"time (stage, first to last frame: {r['sim_span_s']:.3f} sim s in "
        f"{r['wall_span_s']:.3f} wall s; worst frame {r['max_late_s'] * 1e3:.0f} ms late) -> "
        + ("keeps up" if keeps else "DOES NOT KEEP UP")
        + "".join(f"; last {k} frame published {v:.1f} s late" for k, v in late.items())
        + (
            f" (machine busy: other jobs {r['run_cpu']['others']:.2f} cores, hypervisor "
            f"steal {r['run_cpu']['steal']:.2f} cores)"
            if r["run_cpu"].get("others", 0.0) + r["run_cpu"].get("steal", 0.0) > 0.2
            else ""
        )
    )
    print(
        f"    frames published {r['published']}, recorded {rec}; frame-index gaps "
        f"{r['gaps']} ({r['missing_samples']} samples missing); last frame published "
        f"[ms after its first sample was due; the estimate: by the EKF]: {lag}"
    )
    dl = ", ".join(f"{k} {v[0] * 1e3:.0f} ({v[1]})" for k, v in r["delayed"].items())
    print(
        "    worst frame latency beyond the run's median [ms] (publication after the "
        f"frame's first sample was due; frames > 0.2 s): {dl}"
    )
    run = ", ".join(f"{k} {v:.2f}" for k, v in r["run_cpu"].items())
    need = sum(r["run_cpu"].get(k, 0.0) for k in r["cpu_s"]) / r["rtf"]
    print(
        f"    CPU [cores] while the stage published: {run} (of {os.cpu_count()}); "
        f"at 1.0 x real time the 4 processes need {need:.1f} cores; CPU s incl. start-up: "
        f"{cpu}; bag {r['mb']:.0f} MB"
    )


def _latency(r: dict, realtime: bool) -> str:
    """How far behind the wall clock a realtime graph ended (see :func:`graph_rtf`)."""
    if not realtime:
        return ""
    return (
        f" over {r['simulated_s']:.1f} sim s, ended {r['latency_s'] * 1e3:.0f} ms behind the"
        " wall clock"
    )


def main() -> None:
    model, _ = identify_stage(seed=5, plan=Plan.short())
    bench(model)
    if "--graph" in sys.argv:
        for two in (False, True):
            for rt in (False, True):
                r = graph_rtf(model, rt, two)
                print(
                    f"graph, {r['instances']} stage(s), {'realtime' if rt else 'fast':8s}: "
                    f"{r['rtf']:5.2f} x real time (stage samples summed over instances)"
                    + _latency(r, rt)
                    + f", frame-index gaps {r['gaps']}"
                )
    gp = [a for a in sys.argv if a.split("=")[0] == "--graph-processes"]
    if gp:
        rows = (gp[-1].split("=", 1)[1] if "=" in gp[-1] else GRAPH_PROCESS_ROWS).split(",")
        domain = int(os.environ.get("ROS_DOMAIN_ID") or 77)
        if "--graph" not in sys.argv:
            for rt in (False, True):
                r = graph_rtf(model, rt, domain_id=domain)
                print(
                    f"graph, 1 process, 1 stage, {'realtime' if rt else 'fast':8s}: "
                    f"{r['rtf']:5.3f} x real time"
                    + _latency(r, rt)
                    + f", frame-index gaps {r['gaps']}"
                )
        keep = [a.split("=", 1)[1] for a in sys.argv if a.startswith("--keep-bags=")]
        periods = [int(a.split("=", 1)[1]) for a in sys.argv if a.startswith("--graph-periods=")]
        gplan = Plan(cal_periods=periods[-1]) if periods else BENCH_PLAN
        for i, row in enumerate(rows):
            kept = None
            if keep:
                os.makedirs(keep[-1], exist_ok=True)
                kept = os.path.join(keep[-1], f"{i}_{row.replace(':', '_')}.mcap")
            row, _, pace = row.partition("@")
            row, _, frame = row.partition(":")
            comp, _, imu = row.partition("-")
            print_graph_processes(
                graph_processes(
                    model,
                    comp,
                    domain_id=domain,
                    publish_imu=imu != "noimu",
                    frame_size=int(frame) if frame else None,
                    pace=float(pace) if pace else 1.0,
                    keep_bag=kept,
                    plan=gplan,
                )
            )
    if "--drift" in sys.argv:
        actuator_drift()
    if "--sensitivity" in sys.argv:
        print("Fig. 3.16 with the thesis' one-step Q (measurement-driven EKF, the paper's setup):")
        sensitivity(identify_stage(seed=5, plan=Plan.short(), q_method="one_step")[0])
        print("with the default Q from the reference (model-driven EKF):")
        sensitivity(model)


if __name__ == "__main__":
    main()

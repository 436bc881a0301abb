"""Portability probe of the numba kernels: every kernel family on small fixed inputs, digested.

Each family of :data:`FAMILIES` runs the kernels of one device model, filter or
identification step through the public entry points the core tests call
(same constructors, fixed seeds, short inputs) and returns the raw outputs as a list of
numpy arrays (codes, states, variances, sums...). ``python test/portable_probe.py
[FAMILY ...]`` prints one JSON object: ``{family: sha256 of the outputs}`` (each array
made C-contiguous; its dtype and shape are hashed with its bytes) plus ``"_numba_cpu"``,
the CPU numba compiles for. A test runs it in subprocesses compiled for different CPU
targets (``--target generic``, ``--target haswell`` (:data:`TARGETS`), the host) and compares the digests bit
for bit: a family whose floats follow the vector width or the instruction set (fastmath
reassociation, FMA contraction) differs between them.

``--deliberate-fastmath`` adds the family ``deliberate_fastmath``: a ``fastmath=True`` sum
of squares defined here, whose floats legitimately depend on the vector width, so that the
comparison can be shown to catch a CPU-dependent kernel. Named on the command line, the
extra family ``_libm`` (glibc's exp, log, pow, sin, cos, tan, atan2 called from a numba
loop) digests the C library's results, which follow glibc's FMA or non-FMA variant.

Imports only the ROS-free core (mems_sim.devices, mems_sim.kernels, mems_estimation.filters,
mems_estimation.identification, mems_estimation.studies) and numpy; no rclpy, no mems_msgs.

Every ``numba.njit`` function of the kernel modules is reached by at least one family
(checked after a run of every family with an empty NUMBA_CACHE_DIR: each dispatcher has a
compiled signature; an ``inline="always"`` helper has none of its own, so by a call site
in a compiled kernel), except:

* ``mems_sim.devices.scanner._gauss_c`` and ``_gauss_d2c``: nothing calls them, in the
  package, the tests or the benchmarks (``capacitance`` and ``d2cap_dtheta2`` are numpy
  code; the kernels use only ``_gauss_dc``).

The private ``scanner_amdm_ukf._sigma`` is called directly, as test/mems_estimation/filters/test_scanner_amdm_ukf.py
does (``ukf_run`` has its arithmetic written out on scalars); ``resonator_observer_model.
_riccati_iterate`` is reached through ``KalmanObserver(..., steady_state=True)`` on a
noise-free model for which scipy's DARE solution fails its residual check.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import sys

#: LLVM features of an Intel Haswell (AVX2, FMA, no AVX-512). numba keeps the host's
#: features for any NUMBA_CPU_NAME but ``generic``, so a Haswell build names them.
HASWELL_FEATURES = (
    "+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+cx8,+f16c,+fma,+fsgsbase,+fxsr,+lzcnt,+mmx,"
    "+movbe,+pclmul,+popcnt,+rdrnd,+sahf,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave,"
    "+xsaveopt,-avx512f,-avx512cd,-avx512bw,-avx512dq,-avx512vl"
)
#: ``--target NAME``: the numba code generation of another CPU, on this one.
TARGETS = {
    "generic": {"NUMBA_CPU_NAME": "generic"},
    "haswell": {"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": HASWELL_FEATURES},
}


def _select_target(argv: list[str]) -> list[str]:
    """Apply ``--target NAME`` (before numba loads) and return the other arguments."""
    if "--target" not in argv:
        return argv
    i = argv.index("--target")
    name = argv[i + 1] if i + 1 < len(argv) else ""
    if name not in TARGETS:
        sys.exit(f"portable_probe: --target takes one of {sorted(TARGETS)}")
    os.environ.update(TARGETS[name])
    return argv[:i] + argv[i + 2 :]


if __name__ == "__main__":
    sys.argv[1:] = _select_target(sys.argv[1:])

if __package__ in (None, ""):  # run as a script: the checkout on the path
    sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))

# isort: off
import mems_sim  # noqa: E402, F401  (pins numpy's and OpenBLAS's kernels before numpy loads)
import numba  # noqa: E402  (after the pins above)
import numpy as np  # noqa: E402  (after the pins above)

# isort: on

# --------------------------------------------------------------------------- shared inputs
#: The resonator observer tests' constants: fs [Hz], f0 [Hz], Q [-].
FS_RES, F0_RES, Q_RES = 1e6, 5e4, 100.0
#: The chapter-5 run of the AMDM scanner and UKF tests.
AMDM_RUN = dict(
    drive_voltage_max=150.0, sweep_start_hz=31.32e3, sweep_end_hz=31.27e3, sweep_time_s=0.03
)
AMDM_TORQUE_STD = 1.15e-14 * math.sqrt(1.0e11 * 10)
AMDM_FS = 1.0e6
#: Samples of the chapter-4 scanner record (from the start of its drive programme).
SCANNER_N = 40_000
#: Rate samples of the Allan families and the frame of the streaming one.
ALLAN_N = 300_000
ALLAN_FRAME = 100


def _arrays(*items) -> list[np.ndarray]:
    """Every item as a numpy array (scalars as 0-d arrays)."""
    return [np.asarray(x) for x in items]


@functools.cache
def _stage_record():
    """A short amplitude sweep of the default (drawn) micro-stage with feedthrough."""
    from mems_sim.devices.stage import DriveSchedule, MicroStage, record

    st = MicroStage({}, DriveSchedule.amplitude_sweep(n_trials=2, periods=40), seed=5)
    return st, record(st, frame=7000)


@functools.cache
def _scanner_record():
    """The start of the chapter-4 scanner's drive programme with the drifted sensing comb."""
    from mems_estimation.studies.scanner_threshold import DRIFTED_SENSOR
    from mems_sim.devices.scanner import MicroScannerDevice

    dev = MicroScannerDevice(DRIFTED_SENSOR, seed=11)
    parts = [dev.step(7000) for _ in range(SCANNER_N // 7000)]
    parts.append(dev.step(SCANNER_N - 7000 * (SCANNER_N // 7000)))
    keys = ("drive", "theta", "omega", "y_clean", "y", "psd")
    rec = {k: np.concatenate([getattr(p, k) for p in parts]) for k in keys}
    return dev, rec


@functools.cache
def _scanner_detections():
    """Online DOG + NMS detections of :func:`_scanner_record` (frames of 777 samples)."""
    from mems_estimation.filters.scanner_threshold_detector import (
        Detections,
        OnlineThresholdDetector,
    )

    dev, rec = _scanner_record()
    det = OnlineThresholdDetector(dog_sigma=45.0, noise_std=max(dev.p["noise_std"], 1e-9))
    y = rec["y"]
    return Detections.concat([det.process(y[a : a + 777]) for a in range(0, y.size, 777)])


@functools.cache
def _amdm_record():
    """Chapter-5 scanner with the AMDM chain (test/mems_estimation/filters/test_scanner_amdm_ukf.py's run)."""
    from mems_sim.devices import scanner_amdm as sa

    dev = sa.AmdmScannerDevice(dict(AMDM_RUN, torque_noise_std=AMDM_TORQUE_STD), seed=11)
    parts = [dev.step(20_000), dev.step(15_000)]
    keys = ("codes", "y", "y_clean", "drive", "drive_freq", "theta", "omega")
    rec = {k: np.concatenate([getattr(p, k) for p in parts]) for k in keys}
    rec["saturated"] = np.array([p.saturated for p in parts])
    return dev, rec


@functools.cache
def _resonator_frame(**params):
    """One frame of the sigma-delta resonator device (cached per parameter set)."""
    from mems_sim.devices.resonator import SdResonatorDevice

    seed = params.pop("seed", 3)
    return SdResonatorDevice(params, seed=seed).step(6000)


def _io(fr):
    """Observer inputs of a device frame: bits, pulse heights, firing offsets, widths."""
    return fr.bits, fr.pulses, fr.pulse_start, fr.pulse_width


@functools.cache
def _allan_data() -> np.ndarray:
    """Fixed rate signal: white noise plus a slow random walk, ALLAN_N samples."""
    rng = np.random.default_rng(20240607)
    return 0.3 * rng.standard_normal(ALLAN_N) + 1e-3 * np.cumsum(rng.standard_normal(ALLAN_N))


# --------------------------------------------------------------------------- families
def imu_device() -> list[np.ndarray]:
    """ImuNoiseModel.generate (_noise_recursion; _lowpass with the ADIS16350 bandwidth)."""
    from mems_sim.devices.imu import ImuNoiseModel, truth_motion

    out = []
    m = ImuNoiseModel(seed=11)
    for f in (m.generate(2000), m.generate(1000, temperature_c=31.0)):
        out += _arrays(f.gyro_codes, f.accel_codes, f.gyro_si, f.accel_si, f.saturated)
    m2 = ImuNoiseModel({"preset": "adis16350"}, seed=3, temperature_c=35.0)
    g, a = truth_motion("static", 0, 2000, m2.fs)
    for f in (m2.generate(2000, g, a), m2.generate(500)):
        out += _arrays(f.gyro_codes, f.accel_codes, f.gyro_si, f.accel_si, f.saturated)
    return out


def accelerometer_device() -> list[np.ndarray]:
    """ForceRebalanceAccelerometer.step in its three modes (run_block, _plant_rhs; the
    in-loop hybrid EKF kernels of mems_sim.kernels.accelerometer_ekf in ekf_rebalance)."""
    from mems_sim.devices import accelerometer

    out = []
    for mode, amp in (("open_loop", 0.1), ("pi_rebalance", 1.0), ("ekf_rebalance", 1.0)):
        d = accelerometer.ForceRebalanceAccelerometer(
            {"mode": mode, "accel_amplitude": amp * accelerometer.G0}, seed=2
        )
        for n in (3000, 2000):
            f = d.step(n)
            out += _arrays(
                f.accel,
                f.x,
                f.v,
                f.code,
                f.v_f,
                f.contact,
                f.saturated,
                f.estimate,
                f.variance,
                f.positive_definite,
            )
        out.append(d.state.copy())
    return out


def accelerometer_ekf() -> list[np.ndarray]:
    """HybridEkf.run on the device's ADC and drive samples (_run), and the kernel functions
    of mems_sim.kernels.accelerometer_ekf as test/mems_sim/kernels/test_accelerometer_ekf.py calls them."""
    from mems_estimation.filters.accelerometer_ekf import HybridEkf
    from mems_sim.devices import accelerometer
    from mems_sim.kernels import accelerometer_ekf as he

    d = accelerometer.ForceRebalanceAccelerometer(
        {"mode": "ekf_rebalance", "accel_amplitude": accelerometer.G0}, seed=2
    )
    f = d.step(5000)
    ekf = HybridEkf(d.ekf_config)
    y = f.code * d.lsb
    out = []
    for a, b in ((0, 3000), (3000, 5000)):
        r = ekf.run(y[a:b], f.v_f[a:b])
        out += _arrays(r["estimate"], r["variance"], r["innovation"], r["positive_definite"])
    c = d.ekf_config
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 3)) * np.sqrt(c.p0_diag)
    pm = a @ a.T + np.diag(c.p0_diag)
    s = np.array([2e-10, 1e-6, 0.3])
    hx, hd = he.measurement(s[0], c.model)
    nu = he.ekf_update(s, pm, -1e-4, c.r, c.model)
    he.ekf_predict(s, pm, 0.01, c.dt, c.q, c.model, 4)
    pd = he.is_positive_definite(pm)
    out += _arrays(hx, hd, nu, s, pm, pd)
    return out


def stage_device() -> list[np.ndarray]:
    """MicroStage.step via record() (_simulate, _readout with the capacitance gradient,
    _ldv_run)."""
    st, rec = _stage_record()
    keys = ("y", "u", "u_applied", "v_bias", "f_drive", "phase", "segment", "theta", "omega")
    return [rec[k] for k in (*keys, "ldv", "cycle")] + [st._st.copy()]


def stage_capacitance() -> list[np.ndarray]:
    """Dual-axis capacitance and gradient (eq. 40: _cap_dual, _grad_dual with the small and
    the general off-axis branch) and the single-axis gradient (eq. 46)."""
    from mems_sim.devices.stage import MicroStage
    from mems_sim.devices.stage_capacitance import (
        channel_limits,
        dual_axis_capacitance,
        dual_axis_gradient,
        single_axis_dcdtheta,
    )

    lim = channel_limits(MicroStage({"idealised": True}).params)
    th = np.linspace(-2e-3, 2e-3, 41)
    out = []
    for tx in (1e-9, 5e-4, -3e-3):
        thx = np.full(th.size, tx)
        out.append(dual_axis_capacitance(thx, th, 19.2e-6, lim))
        out.append(dual_axis_gradient(thx, th, 19.2e-6, lim))
    out.append(dual_axis_gradient(th[::-1], th, 17.5e-6, lim, eps_r=1.0006))
    for c in range(lim.shape[0]):
        out.append(np.asarray(single_axis_dcdtheta(th, 19.2e-6, lim[c])))
    return out


def stage_ekf() -> list[np.ndarray]:
    """FeedthroughCanceller (cancel_run, streamed), StageEkf (ekf_run, output_h; measured,
    forced start, time updates) and GainAdaptiveStageEkf (gain_ekf_run)."""
    from mems_estimation.filters.stage_ekf import (
        FeedthroughCanceller,
        GainAdaptiveStageEkf,
        StageEkf,
        oracle_model,
    )

    st, rec = _stage_record()
    y, u = rec["y"], rec["u"]
    fc = FeedthroughCanceller(4, rec["fs"])
    yc = np.concatenate(
        [
            fc.step(y[a : a + 5000], rec["v_bias"][a : a + 5000], rec["f_drive"][a : a + 5000])
            for a in range(0, y.shape[0], 5000)
        ]
    )
    m = oracle_model(st, 1e-8)
    out = [yc]
    ekf = StageEkf(m)
    half = yc.shape[0] // 2
    for a, b in ((0, half), (half, yc.shape[0])):
        out += list(ekf.step(yc[a:b], u[a:b]))
    ekf.time_update(300)
    out += [ekf.x.copy(), ekf.P.copy()]
    forced = StageEkf(m)
    forced.start_forced(u[:3000], rec["f_drive"][:3000])
    out += list(forced.step(yc[:3000], u[:3000], corrected=False))
    gekf = GainAdaptiveStageEkf(m, gain_rw=1e-3)
    out += list(gekf.step(yc, u))
    return out


def stage_identification() -> list[np.ndarray]:
    """Harmonic least squares of the stage identification (_harmonic_normal) per trial, on
    the channels and on the LDV reference."""
    from mems_estimation.identification.stage_identification import harmonic_fit, ldv_bias

    _, rec = _stage_record()
    out = []
    for s in np.unique(rec["segment"]):
        sel = rec["segment"] == s
        out.append(harmonic_fit(rec["y"][sel], rec["phase"][sel]))
        out.append(harmonic_fit(rec["ldv"][sel], rec["phase"][sel], n_harm=5))
    out.append(np.asarray(ldv_bias(rec)))
    return out


def stage_insitu() -> list[np.ndarray]:
    """In-situ model correction from the cancelled channels (_signal_grid in the
    Gauss-Newton fit of each trial's tilt)."""
    from mems_estimation.filters.stage_ekf import oracle_model
    from mems_estimation.identification.stage_identification import cancelled
    from mems_estimation.identification.stage_insitu import insitu_correct

    st, rec = _stage_record()
    m, rep = insitu_correct(
        oracle_model(st, 1e-8),
        cancelled(rec),
        rec["u"],
        rec["phase"],
        rec["segment"],
        rec["f_drive"],
    )
    thetas = np.array([p["Theta"] for p in rep["phasors"]])
    return _arrays(m.wn, m.b_c, rep["G"], rep["scatter"], thetas)


def synchronous_average() -> list[np.ndarray]:
    """SynchronousAverager.step (_average_run) in frames, bias on/off and every period."""
    from mems_estimation.filters.synchronous_average import SynchronousAverager

    _, rec = _stage_record()
    y, fd, seg = rec["y"], rec["f_drive"], rec["segment"]
    out = []
    for kw in (dict(n_periods=8), dict(n_periods=5, period_step=1, skip_periods=3)):
        av = SynchronousAverager(4, rec["fs"], **kw)
        for a in range(0, y.shape[0], 6001):
            out += list(av.step(y[a : a + 6001], fd[a : a + 6001], seg[a : a + 6001]))
    return out


def scanner_device() -> list[np.ndarray]:
    """MicroScannerDevice.step (_mech_run with the RK4 step and the comb torque)."""
    dev, rec = _scanner_record()
    return [rec[k] for k in ("drive", "theta", "omega", "y_clean", "y", "psd")]


def scanner_threshold_detector() -> list[np.ndarray]:
    """OnlineThresholdDetector.process (_nms_run, _parabolic_delta, _timing_var) on short
    frames and on long ones (FFT path), and detect_offline."""
    from mems_estimation.filters.scanner_threshold_detector import (
        Detections,
        OnlineThresholdDetector,
        detect_offline,
    )

    dev, rec = _scanner_record()
    y = rec["y"]
    out = list(_scanner_detections())
    det = OnlineThresholdDetector()
    out += list(Detections.concat([det.process(y[a : a + 5000]) for a in range(0, y.size, 5000)]))
    off, r = detect_offline(y)
    return out + list(off) + [r]


def scanner_threshold_ekf() -> list[np.ndarray]:
    """run_ekf: the plain EKF and the hybrid with late detections (ekf_run), the
    full-Jacobian 4-state comb filter with the peak-slope angle (aug_run,
    peak_slope_angle), and the PCRB (_pcrb_run)."""
    from mems_estimation.filters.scanner_threshold_ekf import model_from_device, run_ekf
    from mems_estimation.studies.scanner_threshold import HYBRID, pcrb_theta
    from mems_sim.devices.scanner import resolve_scanner

    dev, rec = _scanner_record()
    y, v = rec["y"], rec["drive"]
    D = _scanner_detections()
    P = model_from_device(resolve_scanner({}))
    out = []
    for r in (
        run_ekf(y, v, P, frame=1000),
        run_ekf(y, v, P, detections=D, frame=1000),
        run_ekf(y, v, dict(P, r_theta_mode="canny", use_subsample=False), detections=D, frame=4000),
        run_ekf(y, v, dict(P, **HYBRID), detections=D, frame=5000),
    ):
        out += [np.asarray(x) for x in r if x is not None]
    out.append(pcrb_theta(rec["theta"], rec["omega"], v, dev.p))
    return out


def scanner_amdm_device() -> list[np.ndarray]:
    """AmdmScannerDevice.step (_drive_mechanics with the drive phase, _chain)."""
    dev, rec = _amdm_record()
    return [rec[k] for k in ("codes", "y", "y_clean", "drive", "drive_freq", "theta", "omega")] + [
        rec["saturated"]
    ]


def _amdm_filter(kind: str) -> list[np.ndarray]:
    """ScannerFilter as test/mems_estimation/filters/test_scanner_amdm_ukf.py runs it (acquisition, then tracking
    on 1000-sample frames), plus a run started explicitly at an off state."""
    from mems_estimation.filters import scanner_amdm_tracking as su

    dev, rec = _amdm_record()
    y = rec["codes"] * dev.lsb
    drive = rec["drive"]
    f = su.ScannerFilter(kind, dict(chain_delay_s=dev.delay))
    al = su.DriveAligner(dev.delay * AMDM_FS, f.model.vc2)
    out = []
    for i in range(0, y.size, 1000):
        o = f.step(y[i : i + 1000], al.push(i, drive[i : i + 1000]))
        out += [o["x"], o["p"], o["nis"], np.asarray(o["tracking"])]
    g = su.ScannerFilter(kind, dict(chain_delay_s=dev.delay))
    al2 = su.DriveAligner(dev.delay * AMDM_FS, g.model.vc2)
    g.start([0.1, -2000.0], np.diag([1e-3, 1e6]))
    a = 25_000
    o = g.step(y[a : a + 4000], al2.push(a, drive[a : a + 4000]))
    out += [o["x"], o["p"], o["nis"], np.array([f.acquisitions, f.pd_failures, g.pd_failures])]
    return out


def scanner_amdm_ekf() -> list[np.ndarray]:
    """The AMDM EKF (ekf_run with the measurement model of scanner_amdm_model)."""
    return _amdm_filter("ekf")


def scanner_amdm_ukf() -> list[np.ndarray]:
    """The AMDM UKF (ukf_run, _chol with the measurement model) and the sigma points
    (_sigma) as test/mems_estimation/filters/test_scanner_amdm_ukf.py computes them."""
    from mems_estimation.filters.scanner_amdm_ukf import _sigma, ukf_weights

    out = _amdm_filter("ukf")
    wm, wc, g = ukf_weights(2, 1.0, 2.0, 1.0)
    S = np.empty((5, 2))
    x = np.array([0.1, -3e3])
    ok = _sigma(x, np.array([[4e-4, 0.3], [0.3, 1e4]]), g, S)
    bad = _sigma(x, np.array([[1.0, 2.0], [2.0, 1.0]]), g, S.copy())
    return out + _arrays(wm, wc, g, S, ok, bad)


def resonator_device() -> list[np.ndarray]:
    """SdResonatorDevice.step (_device_run, _pulse_simple/_pulse_general, _position_at,
    _pulse_cache) in observer (steady-state and full KF), comparator, bit-stream
    comparator, on-sample, stand-in quantiser and varying-f0 configurations, and the
    resonator_models functions the tests call (modulate, interval_input, next_crossing,
    next_spill, resonator_zoh_dt, segment_response)."""
    from mems_sim.kernels.resonator_models import (
        interval_input,
        modulate,
        next_crossing,
        next_spill,
        resonator_zoh_dt,
        resonator_zoh_np,
        segment_response,
    )

    configs = (
        dict(seed=0),
        dict(output_noise_std=0.5, seed=3),
        dict(fast=False, output_noise_std=0.25, state_noise_std=5e-4, seed=5),
        dict(mode="comparator", output_noise_std=0.05, f0_step_fraction=0.02, f0_step_time_s=2e-3),
        dict(mode="comparator", comparator_input="bitstream", f0_drift_ppm_per_s=500.0),
        dict(pulse_timing="on_sample", output_noise_std=0.1, seed=8),
        dict(quantizer="gaussian", seed=2),
    )
    out = []
    for cfg in configs:
        fr = _resonator_frame(**cfg)
        out += [np.asarray(x) for x in fr]
    rng = np.random.default_rng(1)
    k = np.arange(4000)
    x = 0.5 * np.sin(2 * np.pi * 0.05 * k) + 0.3 * rng.standard_normal(k.size)
    for c in (0.5, 0.0):
        out += list(modulate(x, c))
    z = np.empty(6)
    for dt in (0.25, 1.0, 1.7):
        resonator_zoh_dt(F0_RES, Q_RES, FS_RES, dt / FS_RES, z)
        out.append(z.copy())
    out += list(resonator_zoh_np(F0_RES, Q_RES, FS_RES))
    gam = resonator_zoh_np(F0_RES, Q_RES, FS_RES)[1]
    io, zz, wc = np.empty(2), np.empty(6), np.full(3, -1.0)
    for s, w, spill_u, spill_end in (
        (0.1, 0.3, 0.0, 0.0),
        (0.8, 0.5, 0.3, 0.4),
        (0.0, 1.0, 0.0, 0),
    ):
        interval_input(F0_RES, Q_RES, FS_RES, gam, spill_u, spill_end, 0.7, s, w, io, zz, wc)
        sp = np.zeros(2)
        next_spill(0.7, s, w, sp)
        out += [io.copy(), sp]
        segment_response(F0_RES, Q_RES, FS_RES, s, s + w, 1.0, io, zz)
        out.append(io.copy())
    tc = [
        next_crossing(F0_RES, Q_RES, FS_RES, yy, yd, 0.05, 1.05)
        for yy, yd in ((0.1, -5e3), (-0.2, 1e4), (0.3, 1.0))
    ]
    out.append(np.array(tc))
    return out


def resonator_observer() -> list[np.ndarray]:
    """KalmanObserver.step (_kf_run: kf_update6, kf_predict6, cov_predict6, add_pulse_input)
    and the steady-state paths (_ss_run_innov, _ss_run_states), the linear-output
    variant, the frame checks, and the generic and structured Kalman kernels as
    test/mems_sim/kernels/test_resonator_kernels.py calls them."""
    from mems_sim.kernels.resonator_kf_steps import (
        cov_predict,
        cov_predict6,
        cov_predict_sd,
        kf_predict,
        kf_predict6,
        kf_update,
        kf_update6,
        predicted_output,
        predicted_output_sd,
        predictor_gain_sd,
        ss_step,
        ss_step6,
    )
    from mems_sim.kernels.resonator_observer import KalmanObserver
    from mems_sim.kernels.resonator_observer_model import observer_model, steady_state_gains

    fr = _resonator_frame(output_noise_std=0.5, seed=3)
    out = []
    ko = KalmanObserver(
        F0_RES,
        Q_RES,
        FS_RES,
        0.5,
        0.0,
        initial_state=[0.3, -0.2, 0, 0, 0, 0],
        initial_cov=np.diag([0.25, 0.25, 1, 1, 1, 1]),
    )
    io = _io(fr)
    out += list(ko.step(*(x[:3500] for x in io)))
    out += list(ko.step(*(x[3500:] for x in io)))
    out += [ko.x.copy(), ko.P.copy(), ko.last_innovations]
    fast = KalmanObserver(F0_RES, Q_RES, FS_RES, 0.25, 5e-4, steady_state=True)
    out += list(fast.step(*(x[:3000] for x in io)))
    out.append(fast.step_states(*(x[3000:] for x in io)))
    out += [fast.last_innovations, fast.L, np.asarray(fast.cpk)]
    out.append(KalmanObserver(F0_RES * 1.02, 80.0, FS_RES, 0.5, 1e-4).step(fr.bits, fr.pulses)[0])
    frg = _resonator_frame(quantizer="gaussian", seed=2)
    lin = KalmanObserver(F0_RES, Q_RES, FS_RES, 0.0, 0.0, linear_output=True, quantizer_gain=1.0)
    out += list(lin.step(*_io(frg)))
    # noise-free model with c = 0: the DARE solution fails its residual check, the
    # steady state comes from the Riccati iteration (_riccati_iterate)
    it = KalmanObserver(F0_RES, Q_RES, FS_RES, 0.0, 0.0, steady_state=True, sd_feedforward=0.0)
    out += [it.ss["P"], it.L, np.asarray(it.ss["method"] == "iteration")]
    out += list(it.step(*(x[:2000] for x in io)))
    # the generic n x n loops next to the structured ones, as the kernel tests run them
    rng = np.random.default_rng(7)
    for m in (
        observer_model(F0_RES, Q_RES, FS_RES, 0.25, 5e-4),
        observer_model(1.05 * F0_RES, 80.0, FS_RES, 0.5, 0.0, quantizer_gain=1.247),
    ):
        a = rng.standard_normal((6, 6))
        P0 = a @ a.T + np.eye(6) * 1e-3
        x0 = rng.standard_normal(6)
        xa, Pa, xb, Pb = x0.copy(), P0.copy(), x0.copy(), P0.copy()
        xf, PC, L, AP, tmp = np.empty(6), np.empty(6), np.empty(6), np.empty((6, 6)), np.empty(6)
        PCb, Lb = np.empty(6), np.empty(6)
        for v in np.sign(rng.standard_normal(200)):
            ra = kf_update(xa, Pa, m.C, m.G, m.C_pos, v, xf, PC)
            rb = kf_update6(xb, Pb, m.C, m.G, v, PCb)
            kf_predict(xa, Pa, m.A, m.B, m.F, m.M, 0.0, ra[0], ra[1], PC, L, AP, tmp)
            kf_predict6(xb, Pb, m.A, m.F, m.M, rb[0], rb[1], PCb, Lb)
        out += _arrays(ra, rb, xa, Pa, xb, Pb, L, Lb)
        yh = predicted_output(xa, Pa, m.C, m.G, PC)
        yh6 = predicted_output_sd(xb, Pb, m.C, m.G, PCb)
        S = float(yh[1])
        Ls = np.empty(6)
        predictor_gain_sd(m.A, m.M, PCb, S, Ls)
        P1, P2, P3 = Pa.copy(), Pa.copy(), Pa.copy()
        cov_predict(P1, m.A, m.F, Ls, S, np.empty((6, 6)))
        cov_predict_sd(P2, m.A, m.F, Ls, S, np.empty((6, 6)))
        cov_predict6(P3, m.A, m.F, Ls, S)
        out += _arrays(yh, yh6, Ls, P1, P2, P3)
        ss = steady_state_gains(m)
        cpk = float(m.C_pos @ ss["K"])
        xs, xs6 = np.zeros(6), np.zeros(6)
        pos = []
        for k, v in enumerate(np.sign(rng.standard_normal(300))):
            u = 0.2 if k % 10 == 0 else 0.0
            pos.append(ss_step(xs, m.A, m.B, m.C, ss["L"], cpk, v, u, np.empty(6)))
            pos.append(ss_step6(xs6, m.A, m.B, m.C, ss["L"], cpk, v, u))
        out += _arrays(pos, xs, xs6, ss["P"], ss["L"])
    return out


def resonator_adaptive_observer() -> list[np.ndarray]:
    """AdaptiveObserver.step (_ekf_run with _pulse_dlog, _pulse_scaled, _cov_predict_ekf)
    from a 5 % f0 error, with and without the Q state."""
    from mems_estimation.filters.resonator_adaptive_observer import AdaptiveObserver

    out = []
    fr = _resonator_frame(fast=False, output_noise_std=0.25, state_noise_std=5e-4, seed=5)
    io = _io(fr)
    for kw in (dict(), dict(estimate_q=True, q_random_walk_ppm=0.1)):
        ao = AdaptiveObserver(
            F0_RES * 1.05,
            Q_RES,
            FS_RES,
            0.25,
            5e-4,
            f0_random_walk_ppm=0.2,
            warmup_periods=20.0,
            **kw,
        )
        out += [np.asarray(x) for x in ao.step(*(x[:2500] for x in io))]
        out += [np.asarray(x) for x in ao.step(*(x[2500:] for x in io))]
        out += [ao.x.copy(), ao.P.copy(), np.asarray(ao.resets)]
    return out


def allan_batch() -> list[np.ndarray]:
    """oadev (_phase_from_rate, _sums_for_ms, _sum_sq_second_diff, _block_sum) on the
    fixed signal, octave and decade grids."""
    from mems_estimation.identification.allan import oadev

    y = _allan_data()
    out = []
    for kind in ("octave", "decade"):
        out += list(oadev(y, 100.0, kind))
    return out


def allan_streaming() -> list[np.ndarray]:
    """StreamingAllan.add in 100-sample frames (_stream_update) and sums() (_pending_sums),
    with the default exact range and with a small one (the thinned sums)."""
    from mems_estimation.identification.allan_stream import StreamingAllan

    y = _allan_data()
    out = []
    for kw in (dict(), dict(exact_m_max=64)):
        st = StreamingAllan(1, 100.0, "octave", **kw)
        for a in range(0, y.size, ALLAN_FRAME):
            st.add(y[a : a + ALLAN_FRAME])
        out += list(st.sums())
        out.append(st.mean())
    return out


def piezo_hysteresis() -> list[np.ndarray]:
    """PiezoActuator.step (_piezo_run: the exact n = 1 segment map travel_n1 with _phi, the
    RK4 path _travel_rk4 with _rate for n = 2, the creep bank) in two blocks."""
    from mems_sim.hardware.piezo_hysteresis import PiezoActuator

    t = np.arange(6000) / 625e3
    u = 0.2 + np.sin(2 * np.pi * 1700 * t) + 0.3 * np.sin(2 * np.pi * 5610 * t + 0.4)
    out = []
    for params in ({}, {"bw_alpha": 0.3, "bw_beta": 0.6, "bw_gamma": 0.2, "bw_n": 2.0}):
        act = PiezoActuator(params, gain=3.26e-5, sample_rate_hz=625e3)
        for a, b in ((0, 2500), (2500, 6000)):
            out += list(act.step(u[a:b]))
        out.append(act.state)
    return out


FAMILIES = {
    "imu_device": imu_device,
    "accelerometer_device": accelerometer_device,
    "accelerometer_ekf": accelerometer_ekf,
    "stage_device": stage_device,
    "stage_capacitance": stage_capacitance,
    "stage_ekf": stage_ekf,
    "stage_identification": stage_identification,
    "stage_insitu": stage_insitu,
    "synchronous_average": synchronous_average,
    "scanner_device": scanner_device,
    "scanner_threshold_detector": scanner_threshold_detector,
    "scanner_threshold_ekf": scanner_threshold_ekf,
    "scanner_amdm_device": scanner_amdm_device,
    "scanner_amdm_ekf": scanner_amdm_ekf,
    "scanner_amdm_ukf": scanner_amdm_ukf,
    "resonator_device": resonator_device,
    "resonator_observer": resonator_observer,
    "resonator_adaptive_observer": resonator_adaptive_observer,
    "allan_batch": allan_batch,
    "allan_streaming": allan_streaming,
    "piezo_hysteresis": piezo_hysteresis,
}


# --------------------------------------------------------------------------- deliberate
#: Length of the deliberately CPU-dependent sum (odd: a scalar remainder after any vector).
FASTMATH_N = 1_000_003


@numba.njit(fastmath=True, cache=True)
def _fastmath_sum_sq(x):
    """sum x^2 with fastmath: LLVM reassociates it into as many partial sums as the
    vector width (and interleave) of the target, so the floats follow the CPU."""
    s = 0.0
    for i in range(x.shape[0]):
        s += x[i] * x[i]
    return s


def deliberate_fastmath() -> list[np.ndarray]:
    """A kernel whose result legitimately depends on the vector width (not a project one)."""
    x = np.random.default_rng(1_000_003).standard_normal(FASTMATH_N)
    return [np.asarray(_fastmath_sum_sq(x))]


#: Arguments of the libm probe (and their number).
LIBM_N = 100_000


@numba.njit(cache=True)
def _libm_kernel(x, out):
    """exp, log, pow, sin, cos, tan, atan2 of x: calls into the C library's libm (numba
    lowers these to libm calls without SVML), whose variant glibc picks by the CPU."""
    for i in range(x.shape[0]):
        a = x[i]
        out[0, i] = math.exp(a)
        out[1, i] = math.log(abs(a) + 1e-3)
        out[2, i] = math.pow(abs(a) + 0.5, 1.37)
        out[3, i] = math.sin(a)
        out[4, i] = math.cos(a)
        out[5, i] = math.tan(a)
        out[6, i] = math.atan2(a, 1.7)


def libm() -> list[np.ndarray]:
    """``_libm``: libm's results on fixed arguments (not a project kernel: glibc's FMA and
    non-FMA variants of these functions differ in the last bit for some arguments)."""
    x = np.random.default_rng(7).uniform(-20.0, 20.0, LIBM_N)
    out = np.empty((7, LIBM_N))
    _libm_kernel(x, out)
    return [out]


# --------------------------------------------------------------------------- digest
def digest(arrays) -> str:
    """sha256 over (dtype, shape, bytes) of every array, C-contiguous."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        if a.dtype == object:
            raise TypeError("object array in a probe family's outputs")
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def numba_cpu() -> str:
    """The CPU name numba compiles for (NUMBA_CPU_NAME or the host's), with ``+features``
    when NUMBA_CPU_FEATURES names them."""
    if numba.config.CPU_NAME:
        name = str(numba.config.CPU_NAME)
    else:
        import llvmlite.binding as ll

        name = ll.get_host_cpu_name()
    return name + ("+features" if numba.config.CPU_FEATURES else "")


#: Families run only when named (or, the first, with ``--deliberate-fastmath``): not
#: kernels of the project, so not in :data:`FAMILIES`.
EXTRAS = {"deliberate_fastmath": deliberate_fastmath, "_libm": libm}


def run(names=None, deliberate: bool = False) -> dict[str, str]:
    """Digests of the families ``names`` (default: all of :data:`FAMILIES`, and
    ``deliberate_fastmath`` if ``deliberate``), plus ``_numba_cpu``."""
    families = {**FAMILIES, **EXTRAS}
    names = list(names or [])
    if not names:
        names = list(FAMILIES)
    if deliberate and "deliberate_fastmath" not in names:
        names.append("deliberate_fastmath")
    unknown = [n for n in names if n not in families]
    if unknown:
        raise KeyError(f"unknown probe families {unknown}; known: {sorted(families)}")
    out = {n: digest(families[n]()) for n in names}
    out["_numba_cpu"] = numba_cpu()
    return out


def main(argv=None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    deliberate = "--deliberate-fastmath" in args
    names = [a for a in args if a != "--deliberate-fastmath"]
    try:
        result = run(names, deliberate)
    except KeyError as e:
        print(e.args[0], file=sys.stderr)
        return 2
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())

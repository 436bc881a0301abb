"""Fault detection on the force-rebalance accelerometer: the downstream hybrid EKF
(Zhang 2010, eqs. 4-48 .. 4-57) with its windowed NIS monitor (Bar-Shalom, Li &
Kirubarajan 2001, Sec. 5.4.2; thresholds of the scaled chi-square of the filter's measured
fault-free moments, Satterthwaite 1946) against scheduled readout faults, on the cores.

One trial run (:func:`run_trial`) is the device in PI rebalance (the table's defaults, the
plant drawn for ``device_seed``; the EKF on the nominal model, as the node has it) with a
schedule of ``faults_per_run`` faults of one kind and magnitude, each ``fault_s`` long and
``spacing_s`` apart, their onsets staggered against the monitor's windows; the filter and
the monitor run as the node runs them (a divergence re-initialises both). Per fault:
detected or not within ``horizon_s`` and the delay (:mod:`detection_metrics`); per run the
false alarms outside the faults and their settling guard, whether every estimate was
finite, and the recovery ratio: the RMS acceleration error over ``recovery_s`` starting
``settle_s`` after each fault's end against the fault-free run of the same seeds over the
same samples.

Magnitudes are in the kind's unit on the readout [V] except ``bias_step`` and ``spikes``,
given in innovation standard deviations sigma_nu = sqrt(mean S) of the fault-free run
(:func:`innovation_sigma`), and ``bias_ramp``, in sigma_nu per millisecond.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from mems_estimation.filters.accelerometer_ekf import (
    FAULT_FREE_NIS_DISPERSION,
    FAULT_FREE_NIS_MEAN,
    HEALTH_WINDOW,
    HybridEkf,
)
from mems_estimation.filters.consistency_monitor import NisMonitor, nis_moments
from mems_estimation.identification.detection_metrics import (
    Detection,
    FalseAlarms,
    Fault,
    Verdicts,
    detection_curve,
    detections,
    false_alarms,
    magnitude_at,
)
from mems_sim.devices import accelerometer
from mems_sim.hardware.fault_schedule import parse_schedule
from mems_sim.hardware.sensor_faults import SensorFaultInjector
from mems_sim.params import draw_device

#: Samples per block of a trial (the node's frames are 10000).
BLOCK = 100_000
#: The kinds a campaign runs, with their magnitude grids (see the module docstring for
#: units) and the spike rate [Hz].
GRID = {
    "bias_step": (1.0, 2.0, 3.0, 4.0, 5.0, 6.0),
    "noise_burst": (1.05, 1.1, 1.2, 1.5, 2.0),
    "spikes": (1.0, 2.0, 3.0, 4.0, 6.0),
    "scale_step": (0.02, 0.05, 0.1, 0.2, 0.5),
    "bias_ramp": (0.1, 1.0, 10.0),
    "saturation": (0.5, 1.0, 2.0),
    "stuck_at": (0.0,),
    "sign_flip": (0.0,),
}
SPIKE_RATE_HZ = 5000.0
#: Noise seeds of the bench runs that calibrate the monitor (never evaluation seeds).
TRAINING_SEEDS = (1, 2)
#: Magnitudes given in sigma_nu (bias_ramp: sigma_nu per ms); the others in the kind's unit.
IN_SIGMA = ("bias_step", "spikes", "bias_ramp", "saturation")


@dataclass(frozen=True)
class TrialConfig:
    """One trial run's design (times in s at the device's 1 MHz)."""

    faults_per_run: int = 20
    fault_s: float = 0.01
    spacing_s: float = 0.04
    lead_s: float = 0.02
    horizon_s: float = 0.01
    guard_s: float = 0.01
    settle_s: float = 0.005
    recovery_s: float = 0.01
    window: int = HEALTH_WINDOW
    false_alarm: float = 1e-3
    #: the monitor's calibration (mean NIS, dispersion): the filter's table values, or
    #: those measured on the device's own fault-free bench runs (:func:`bench_moments`)
    moments: tuple[float, float] = (FAULT_FREE_NIS_MEAN, FAULT_FREE_NIS_DISPERSION)


@dataclass
class TrialResult:
    """What one trial run measured."""

    kind: str
    magnitude: float
    noise_seed: int
    device_seed: int | None
    scores: list[Detection]
    scores_two_sided: list[Detection]
    false_alarms: FalseAlarms
    finite: bool
    resets: int
    recovery: np.ndarray  # per fault: RMS error after the fault / fault-free RMS, -
    during: np.ndarray  # per fault: RMS error during the fault / fault-free RMS, -
    sigma_nu: float
    extra: dict = field(default_factory=dict)


def device_params(device_seed: int | None) -> tuple[dict, dict]:
    """(device as built, nominal) for ``device_seed`` (None: the nominal device)."""
    nominal = accelerometer.validate_params({})
    drawn = draw_device(accelerometer.ACCEL_SPECS, nominal, device_seed)
    return accelerometer.validate_params(drawn), nominal


def _device_and_filter(noise_seed: int, device_seed: int | None):
    """The device in PI rebalance (drawn for ``device_seed``, noise of ``noise_seed``) and
    the hybrid EKF on its nominal model, as the node builds it."""
    p, nominal = device_params(device_seed)
    d = accelerometer.ForceRebalanceAccelerometer(p, seed=noise_seed, nominal=nominal)
    return d, HybridEkf(accelerometer.ekf_config(nominal, accelerometer.bias_voltage(nominal)))


def _stream(noise_seed, device_seed, n, schedule, cfg):
    """Run device, EKF and monitor for ``n`` samples; return NIS verdicts, the
    acceleration error per sample, the S per sample, finiteness and resets."""
    d, ekf = _device_and_filter(noise_seed, device_seed)
    if schedule:
        d.faults = SensorFaultInjector(schedule, d.fs, noise_seed, (d.v_noise_std,))

    def monitor():
        return NisMonitor.moment_matched(cfg.window, cfg.false_alarm, *cfg.moments)

    mon, base = monitor(), 0
    firsts, levels, lows = [], [], []
    err = np.empty(n)
    s_var = np.empty(n)
    finite, resets = True, 0
    for k in range(0, n, BLOCK):
        m = min(BLOCK, n - k)
        f = d.step(m)
        out = ekf.run(f.code * d.lsb, f.v_f)
        est = out["estimate"]
        ok = np.isfinite(est).all() and np.isfinite(out["variance"]).all()
        if ekf.diverged() or not ok:
            finite = finite and ok
            ekf.reset()
            mon, base, resets = monitor(), k + m, resets + 1
            err[k : k + m] = np.nan
            s_var[k : k + m] = np.nan
            continue
        err[k : k + m] = est[:, 2] - f.accel
        s_var[k : k + m] = out["innovation_variance"]
        for v in mon.update(out["innovation"] ** 2 / out["innovation_variance"]):
            firsts.append(base + v.first)
            levels.append(v.level)
            lows.append(v.low)
    verdicts = Verdicts.of(firsts, np.full(len(firsts), cfg.window), levels, lows)
    return verdicts, err, s_var, finite, resets


def innovation_sigma(noise_seed: int, device_seed: int | None, cfg: TrialConfig) -> float:
    """sigma_nu = sqrt(mean S) [V] of the fault-free run over its first 0.1 s after the
    lead (the magnitudes' unit for bias steps and spikes)."""
    lead = int(cfg.lead_s * 1e6)
    _, _, s_var, _, _ = _stream(noise_seed, device_seed, lead + 100_000, (), cfg)
    return float(np.sqrt(np.nanmean(s_var[lead:])))


def fault_entries(kind: str, magnitude: float, sigma_nu: float, cfg: TrialConfig) -> list[dict]:
    """The schedule of one trial run: ``faults_per_run`` faults of ``kind``, onsets
    ``lead_s + j spacing_s`` plus a stagger of (j * 337) mod window samples."""
    fs = 1e6
    out = []
    for j in range(cfg.faults_per_run):
        e = {
            "kind": kind,
            "channel": "readout",
            "start_sample": int(round((cfg.lead_s + j * cfg.spacing_s) * fs))
            + (j * 337) % cfg.window,
            "duration_samples": int(round(cfg.fault_s * fs)),
        }
        if kind in ("stuck_at", "sign_flip"):
            pass
        elif kind == "bias_ramp":
            e["magnitude"] = magnitude * sigma_nu * 1e3
        elif kind in IN_SIGMA:
            e["magnitude"] = magnitude * sigma_nu
        else:
            e["magnitude"] = magnitude
        if kind == "spikes":
            e["rate_hz"] = SPIKE_RATE_HZ
        out.append(e)
    return out


def run_length(cfg: TrialConfig) -> int:
    """Samples of a trial run: the last onset plus a spacing and a lead."""
    last = int(round((cfg.lead_s + (cfg.faults_per_run - 1) * cfg.spacing_s) * 1e6))
    return (
        last
        + (((cfg.faults_per_run - 1) * 337) % cfg.window)
        + int(round((cfg.spacing_s + cfg.lead_s) * 1e6))
    )


def clean_run(noise_seed: int, device_seed: int | None, cfg: TrialConfig):
    """The fault-free run of a trial's seeds (its length :func:`run_length`)."""
    return _stream(noise_seed, device_seed, run_length(cfg), (), cfg)


def run_trial(
    kind: str,
    magnitude: float,
    noise_seed: int,
    device_seed: int | None = None,
    cfg: TrialConfig = TrialConfig(),
    sigma_nu: float | None = None,
    clean=None,
) -> TrialResult:
    """One trial run (module docstring); ``clean``: the fault-free run of the same seeds
    (``_stream`` output) when the caller has it."""
    fs = 1e6
    sigma_nu = innovation_sigma(noise_seed, device_seed, cfg) if sigma_nu is None else sigma_nu
    entries = fault_entries(kind, magnitude, sigma_nu, cfg)
    n = run_length(cfg)
    sched = parse_schedule({"faults": entries}, ("readout",), ("V",), fs)
    verdicts, err, _, finite, resets = _stream(noise_seed, device_seed, n, sched, cfg)
    if clean is None:
        clean = clean_run(noise_seed, device_seed, cfg)
    faults = [Fault(e.first, e.end, e.kind, magnitude) for e in sched]
    horizon = int(cfg.horizon_s * fs)
    scores = detections(faults, verdicts, horizon)
    two_sided = detections(faults, verdicts, horizon, two_sided=True)
    fa = false_alarms(faults, verdicts, int(cfg.guard_s * fs))

    def ratio(a: int, b: int) -> float:
        return float(np.sqrt(np.mean(err[a:b] ** 2)) / np.sqrt(np.mean(clean[1][a:b] ** 2)))

    settle, span = int(cfg.settle_s * fs), int(cfg.recovery_s * fs)
    rec = [ratio(f.end + settle, f.end + settle + span) for f in faults]
    during = [ratio(f.first, f.end) for f in faults]
    return TrialResult(
        kind,
        magnitude,
        noise_seed,
        device_seed,
        scores,
        two_sided,
        fa,
        finite,
        resets,
        np.asarray(rec),
        np.asarray(during),
        sigma_nu,
    )


def campaign(
    kinds: Iterable[str] = tuple(GRID),
    noise_seeds: Sequence[int] = (3, 4),
    device_seeds: Sequence[int | None] = (None,),
    cfg: TrialConfig = TrialConfig(),
    grid: dict | None = None,
    progress=None,
    calibration: str = "bench",
    training_seeds: Sequence[int] = TRAINING_SEEDS,
    training_samples: int = 5_000_000,
) -> dict:
    """Every kind x magnitude x noise seed x device seed of ``grid`` (default
    :data:`GRID`); per kind the detection curve, the magnitude at 95 % detection (in
    the grid's unit; upper test and two-sided), the delays [s], the error ratios during and
    after the faults and the false alarms.

    ``calibration``: "bench", the monitor on each device's own NIS moments measured on
    fault-free runs of ``training_seeds`` (:func:`bench_moments`), which must not be
    evaluation seeds; "table", on the filter's moments of the nominal device (an oracle
    for a drawn device).
    ``progress``: called with each finished trial."""
    grid = GRID if grid is None else grid
    unknown = sorted(set(kinds) - set(grid))
    if unknown:
        raise ValueError(f"kinds without a magnitude grid: {', '.join(unknown)}")
    if calibration not in ("table", "bench"):
        raise ValueError(f"calibration must be 'table' or 'bench', not {calibration!r}")
    if calibration == "bench" and set(training_seeds) & set(noise_seeds):
        raise ValueError("training seeds must not be evaluation seeds")
    trials: list[TrialResult] = []
    moments = {}
    for ds in device_seeds:
        dcfg = cfg
        if calibration == "bench":
            moments[ds] = bench_moments(ds, training_seeds, training_samples, cfg.window)
            dcfg = replace(cfg, moments=moments[ds])
        for ns in noise_seeds:
            sigma = innovation_sigma(ns, ds, dcfg)
            clean = clean_run(ns, ds, dcfg)
            for kind in kinds:
                for mag in grid[kind]:
                    t = run_trial(kind, mag, ns, ds, dcfg, sigma, clean)
                    trials.append(t)
                    if progress is not None:
                        progress(t)
    out = summarise(trials)
    out["calibration"] = calibration
    out["moments"] = {str(k): v for k, v in moments.items()}
    return out


def summarise(trials: Sequence[TrialResult], fs: float = 1e6) -> dict:
    """Per kind: magnitudes, detection probability and trials per magnitude, the
    magnitude at 95 %, the median and 95th-percentile delay [s] of the detected faults at
    each magnitude, the error ratios during and after the faults, non-finite runs and resets; over all runs
    the false alarms (episodes, alarming windows, fault-free windows and hours)."""
    out: dict = {"kinds": {}}
    for kind in dict.fromkeys(t.kind for t in trials):
        ts = [t for t in trials if t.kind == kind]
        scores = [s for t in ts for s in t.scores]
        mags, p, n = detection_curve(scores)
        _, p2, _ = detection_curve([s for t in ts for s in t.scores_two_sided])
        delays = []
        for m in mags:
            d = [s.delay for s in scores if s.fault.magnitude == m and s.detected]
            delays.append(
                (float(np.median(d)) / fs, float(np.percentile(d, 95)) / fs) if d else None
            )
        rec = np.concatenate([t.recovery for t in ts])
        during = np.concatenate([t.during for t in ts])
        out["kinds"][kind] = dict(
            magnitudes=mags.tolist(),
            probability=p.tolist(),
            probability_two_sided=p2.tolist(),
            trials=n.tolist(),
            magnitude_95=magnitude_at(mags, p),
            magnitude_95_two_sided=magnitude_at(mags, p2),
            delays_s=delays,
            recovery_max=float(np.nanmax(rec)),
            recovery_median=float(np.nanmedian(rec)),
            during_median=float(np.nanmedian(during)),
            during_max=float(np.nanmax(during)),
            non_finite_runs=sum(not t.finite for t in ts),
            resets=sum(t.resets for t in ts),
        )
    fa = [t.false_alarms for t in trials]
    windows = sum(f.windows for f in fa)
    out["false_alarms"] = dict(
        episodes=sum(f.episodes for f in fa),
        alarm_windows=sum(f.alarm_windows for f in fa),
        windows=windows,
        hours=sum(f.samples for f in fa) / fs / 3600.0,
    )
    return out


def fault_free_nis(
    noise_seed: int, device_seed: int | None, n_samples: int, skip: int = 20_000
) -> np.ndarray:
    """The NIS per sample of a fault-free run (the first ``skip`` samples, the filter's
    start, left out)."""
    d, ekf = _device_and_filter(noise_seed, device_seed)
    parts = []
    for k in range(0, n_samples, BLOCK):
        f = d.step(min(BLOCK, n_samples - k))
        out = ekf.run(f.code * d.lsb, f.v_f)
        parts.append(out["innovation"] ** 2 / out["innovation_variance"])
    return np.concatenate(parts)[skip:]


def bench_moments(
    device_seed: int | None,
    noise_seeds: Sequence[int] = TRAINING_SEEDS,
    n_samples: int = 5_000_000,
    window: int = HEALTH_WINDOW,
) -> tuple[float, float]:
    """The monitor's calibration on the bench: (mean NIS, dispersion) of fault-free runs
    of this device (:func:`nis_moments` over the training ``noise_seeds``)."""
    nis = np.concatenate([fault_free_nis(s, device_seed, n_samples) for s in noise_seeds])
    return nis_moments(nis, window)


def false_alarm_rates(
    noise_seeds: Sequence[int],
    n_samples: int,
    alphas: Sequence[float] = (1e-2, 1e-3),
    device_seed: int | None = None,
    window: int = HEALTH_WINDOW,
    moments: tuple[float, float] = (FAULT_FREE_NIS_MEAN, FAULT_FREE_NIS_DISPERSION),
) -> dict:
    """Fault-free alarm windows per designed alpha over ``noise_seeds`` runs of
    ``n_samples`` of the device ``device_seed``, thresholds of the scaled chi-square of
    ``moments`` (the table's, or :func:`bench_moments`): per alpha the alarming windows,
    the windows, the designed count and the ratio measured/designed."""
    nis = [fault_free_nis(s, device_seed, n_samples) for s in noise_seeds]
    out = {}
    for a in alphas:
        alarms = windows = 0
        for x in nis:
            mon = NisMonitor.moment_matched(window, a, *moments)
            lv = np.array([v.level for v in mon.update(x)])
            alarms += int(np.count_nonzero(lv >= 1))
            windows += lv.size
        out[a] = dict(
            alarm_windows=alarms,
            windows=windows,
            designed=a * windows,
            ratio=alarms / (a * windows),
        )
    return out

"""Scenario ``scanner_threshold``: comb-drive micro-scanner, causal threshold detection and the
hybrid EKF of Table 4.1 (Chen 2018, chapter 4, Table 4.3).

Graph: ``/scanner`` (:class:`mems_sim.nodes.scanner_node.ScannerNode`, ``dc_transimpedance``:
0-60 V sweep 1600 -> 1250 Hz into parametric resonance, 50 ms hold, cut-off, 100 ms ring-down,
fs 500 kHz, sigma_n 0.0435 V) and ``/scanner`` estimator
(:class:`mems_estimation.nodes.scanner_threshold_ekf_node.ScannerThresholdEkfNode`: online DOG + NMS, hybrid
and plain EKF), recorded to MCAP.  The emulated sensing comb has drifted from the identified
analog map (gain +20 %, width +10 %: :data:`mems_estimation.filters.scanner_threshold_ekf.DRIFTED_SENSOR`, the
temperature effect that motivates chapter 4, Sec. 4.2.1); theta_th is unchanged.

Identification on the bench first (:func:`bench_identification`, Sec. 4.4.2): the same device
(``--device-seed``, ``--set scanner.*``, ``--temperature``) before the drift, with the sensing
comb of its identified analog map, runs the drive programme once (ROS-free cores, its own noise
seed); the ring-down of its PSD gives wn, which sets the hold frequency of the programme
(:func:`hold_frequency`: the thesis' 1250 Hz for its 624.6 Hz mirror, scaled: the resonance
search a lab does so that the sweep finds a drawn device's parametric resonance); a second
bench run with that programme gives the model (ring-down fit, sensing-comb map, threshold
angle, drive torque: :mod:`mems_estimation.identification.scanner_threshold_identification`),
written as ``<out>-seed<N>-scanner_params.yaml``, the estimator node's ``params_yaml``. The
filters never read the emulator's table; the nominal model (the table's) stays as the
figure group ``oracle.*`` (rows "oracle" of the table).

Results, from the recording:

* Table 4.3 form: theta RMSE of EKF and HYB per ring-down segment of SNR ~85/22/5/1 and
  overall, and theta RMSE over the 50 samples after each detection (theta_RMSE,th).
* Detection-error study (Sec. 4.5-4.6.1): normality (Kolmogorov-Smirnov against the fitted
  normal) of e_theta,th per segment; variance of e_theta,th vs sigma_DOG per segment (Fig. 4.11)
  with the hybrid's NRMSE (Fig. 4.12); variance vs sampling rate on the paper's sinusoidal
  set-up (Fig. 4.6(a): A = 0.15 rad, 625 Hz, filter size scaled with fs, sigma_n x 1 and x 10).
* PNGs: Fig. 4.10 analogue (snapshots, trajectories, y_cap + DOG response) and the study.
"""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import numpy as np
from scipy import stats

from mems_estimation.filters.scanner_threshold_detector import (
    Detections,
    OnlineThresholdDetector,
    detect_offline,
)
from mems_estimation.filters.scanner_threshold_ekf import run_ekf
from mems_estimation.identification.scanner_threshold_identification import (
    MODEL_KEYS,
    save_identification,
)
from mems_estimation.nodes.scanner_threshold_ekf_node import detections_from_rows
from mems_estimation.studies import scanner_threshold as studies
from mems_estimation.studies.scanner_threshold import (
    BASELINE,
    BENCH_SEED_OFFSET,
    DRIFTED_SENSOR,
    HYBRID,
    detection_errors,
    drift_evaluation,
    rmse,
    snr_segments,
)
from mems_scenarios import bag_frames, base, contract, delivery
from mems_scenarios.scanner_threshold_report import plot, records, table
from mems_sim.devices.scanner import (
    SCANNER_SPECS,
    dc_transimpedance_output,
    resolve_scanner,
    scanner_params,
)
from mems_sim.params import draw_device
from mems_sim.ros.flow import progress_of

NAME = "scanner_threshold"
DESCRIPTION = (
    "comb-drive micro-scanner (Chen ch. 4): causal DOG threshold detector + hybrid EKF "
    "vs plain EKF by SNR segment (Table 4.3), detection-error study"
)
DEFAULT_DURATION_S = 0.4  # the whole drive programme: 0.25 + 0.05 + 0.1 s
DOG_SIGMA = 45.0  # sigma_DOG of the hybrid (Sec. 4.6.1: large sigma_DOG better)
SIGMAS = (5.0, 15.0, 30.0, 45.0)  # sigma_DOG sweep (paper: 1.5 .. 45)
NS = "scanner"
FRAME = 5000  # samples per frame (10 ms at 500 kHz)


def device_overrides(duration: float, hold_hz: float | None = None) -> dict:
    """Device parameters: drifted sensing comb; the ring-down fills the rest of ``duration``;
    ``hold_hz``: the programme's hold frequency (:func:`hold_frequency`; None: the table's)."""
    p = dict(DRIFTED_SENSOR)
    p["ringdown_time_s"] = round(duration - 0.25 - 0.05, 9)
    if hold_hz is not None:
        p["sweep_end_hz"] = float(hold_hz)
    return p


#: Fully qualified names of the emulator and the estimator.
EMULATOR = f"/{NS}/scanner"
ESTIMATOR = f"/{NS}/threshold/scanner_threshold_ekf"
#: The recorded data topics (each device topic's end-of-stream record besides).
TOPICS = tuple(
    f"/{NS}/{t}"
    for t in ("adc", "drive", "truth", "psd", "estimate", "estimate_plain", "threshold_detections")
)


def _device_entry(options: base.ScenarioOptions, params: dict) -> contract.NodeEntry:
    return contract.NodeEntry(
        "scanner_node",
        "scanner",
        NS,
        dict(params, seed=int(options.seed)),
        consumers="adc:2,drive:2",  # the threshold EKF and the recorder
    )


def _as_built(params: dict, fixed=()) -> dict:
    """The device the emulator node builds from its parameter values ``params``: its
    :data:`SCANNER_SPECS` values drawn for ``device_seed`` and moved to ``temperature_c``
    (:func:`~mems_sim.params.draw_device`, as the node does; ``fixed``: the values the
    user set, left as given), validated."""
    from mems_sim.params import spec_table

    specs = spec_table(contract.node_class("scanner_node").SPECS)
    drawn = draw_device(
        SCANNER_SPECS,
        {s.name: params[s.name] for s in SCANNER_SPECS},
        params["device_seed"],
        params["temperature_c"] - float(specs["temperature_c"].default),
        fixed=fixed,
    )
    return resolve_scanner(drawn)


def bench_device(options: base.ScenarioOptions, duration_s: float) -> dict:
    """The device's parameters as the emulator node draws them (the scenario's values, the
    user's ``--set`` of the emulator, ``--device-seed`` and ``--temperature``; the drift is
    set aside by the bench, :func:`~mems_estimation.studies.scanner_threshold.bench_identification`)."""
    entry = _device_entry(options, device_overrides(duration_s))
    variation = dict(device_seed=options.device_seed, temperature_c=options.temperature_c)
    values = contract.full_parameters(entry, options.overrides, variation)
    return _as_built(values, {o.name for o in options.overrides if _reaches_emulator(o)})


def _adc(y: np.ndarray) -> np.ndarray:
    """y [V] as the emulator node's ADC delivers it (its default bits and full scale)."""
    from mems_sim.nodes.scanner_node import NODE_SPECS, quantize
    from mems_sim.params import spec_table

    t = spec_table(NODE_SPECS)
    codes, lsb, _ = quantize(y, t["adc_bits"].default, t["adc_full_scale"].default)
    return codes * lsb


def bench_identification(options: base.ScenarioOptions, duration_s: float) -> dict:
    """The bench (module doc): the device of :func:`bench_device`, its resonance search
    (none when the user set the hold, ``sweep_end_hz``) and its identification
    (:func:`~mems_estimation.studies.scanner_threshold.bench_identification`, noise seeds
    from the run seed + :data:`BENCH_SEED_OFFSET`). Raises :class:`ScenarioError` when the
    device shows no usable motion on the bench or a fit fails."""
    search = not any(o.name == "sweep_end_hz" for o in options.overrides if _reaches_emulator(o))
    try:
        return studies.bench_identification(
            bench_device(options, duration_s),
            int(options.seed) + BENCH_SEED_OFFSET,
            adc=_adc,
            search=search,
        )
    except ValueError as exc:
        raise base.ScenarioError(f"{NAME}: bench identification failed: {exc}") from None


def _reaches_emulator(o) -> bool:
    """Whether the override ``o`` reaches the emulator node."""
    from mems_sim.ros.params_file import node_matches

    return node_matches(o.node, EMULATOR)


def identified(options: base.ScenarioOptions, duration_s: float, out=None) -> dict:
    """:func:`bench_identification`, its model written as the estimator's parameter YAML
    beside the MCAP file ``out`` (None: the options' ``out``, else ``runs/``) as
    ``<stem>-seed<N>-scanner_params.yaml``; the result with the YAML's ``path``."""
    bench = bench_identification(options, duration_s)
    out = Path(out or options.out or Path("runs") / f"{NAME}-{options.seed}.mcap")
    path = base.output_path(out, options.seed, "-scanner_params.yaml")
    path.parent.mkdir(parents=True, exist_ok=True)
    save_identification(bench["model"], str(path))
    return dict(bench, path=path.resolve())


def graph(
    options: base.ScenarioOptions,
    duration_s: float,
    frame: int = FRAME,
    bench: dict | None = None,
) -> contract.GraphSpec:
    """The scenario's graph: the drifted device in ``/scanner`` and the threshold/EKF node
    in ``/scanner/threshold`` with the identified model (``params_yaml``), recorded.
    ``frame``: samples per frame; ``bench``: :func:`bench_identification`'s result (None:
    identified here, :func:`identified`)."""
    if bench is None:
        bench = identified(options, duration_s)
    device = _device_entry(
        options,
        dict(
            device_overrides(duration_s, bench["hold_hz"]),
            duration_s=float(duration_s),
            frame_size=int(frame),
        ),
    )
    # the identified values also as the entry's parameters: a run record written without
    # making the node (--write-launch) holds the model the node loads from the YAML
    estimator = contract.NodeEntry(
        "scanner_threshold_ekf_node",
        "scanner_threshold_ekf",
        f"{NS}/threshold",
        dict(
            {k: bench["model"][k] for k in MODEL_KEYS},
            device_namespace=f"/{NS}",
            dog_sigma=DOG_SIGMA,
            params_yaml=str(bench["path"]),
        ),
    )
    return contract.GraphSpec(
        NAME, (device, estimator), (*TOPICS, f"/{NS}/end_of_stream", contract.RUN_INFO_TOPIC)
    )


def run_graph(
    options: base.ScenarioOptions,
    out: Path,
    duration: float,
    progress: base.Progress,
    frame: int = FRAME,
    record: bool = True,
) -> dict:
    """Bench identification, then device + threshold/EKF node + recorder (:func:`graph`);
    returns publish counts and recorder summary. ``frame``: samples per frame; ``record``:
    False leaves the recorder out (benchmark)."""
    spec = graph(options, duration, frame, identified(options, duration, out))
    graph_ = base.graph_for(options)
    nodes = graph_.build(spec, realtime=options.realtime)
    dev, est = nodes[EMULATOR], nodes[ESTIMATOR]
    rec = None
    if record:
        regex = rf"^/{NS}/|^{re.escape(contract.RUN_INFO_TOPIC)}$"
        rec = graph_.recorder(str(out), regex=regex, exclude=base.NOT_RECORDED)
        graph_.publish_run_info(
            spec,
            options,
            nodes,
            duration_s=duration,
            fixed_parameters={EMULATOR: sorted(dev.fixed_parameters)},
        )

    def delivered(d) -> int:
        """Progress [samples] of the estimator; the recorder counts for the device's topics
        in the skeleton, and here for the detections the estimator publishes per frame."""
        done = progress_of(est) or 0
        if rec is None:
            return done
        return min(rec.received(f"/{NS}/threshold_detections") * d.p["frame_size"], done)

    try:
        nsub = 2 if rec is not None else 1
        graph_.spin_until(
            lambda: (
                dev.pub_adc.get_subscription_count() >= nsub
                and dev.pub_drive.get_subscription_count() >= nsub
                and (
                    rec is None
                    or (
                        dev.pub_psd.get_subscription_count() >= 1
                        and est.pub_hyb.get_subscription_count() >= 1
                        and est.pub_plain.get_subscription_count() >= 1
                        and est.pub_det.get_subscription_count() >= 1
                    )
                )
            ),
            30.0,
            "the recorder and the estimator to subscribe",
        )
        t_start = time.perf_counter()
        delivery.publish_all(
            graph_,
            [dev],
            delivered,
            progress,
            realtime=options.realtime,
            realtime_timeout_s=duration * 50 + 60,
        )
        t_run = time.perf_counter() - t_start
        est.flush()
        n_est = est.frames_done + 1
        graph_.spin_until(
            lambda: (
                rec is None
                or (
                    rec.received(f"/{NS}/estimate") >= n_est
                    and rec.received(f"/{NS}/estimate_plain") >= n_est
                )
            ),
            60.0,
            "the last estimates",
        )
        for _ in range(20):
            graph_.executor.spin_once(timeout_sec=0.01)
        if rec is not None:
            graph_.wait_run_info(rec)
        published = dev.frames_published
        counts = est.hybrid.counts
    finally:
        summary = None
        if rec is not None:
            rec.close()
            summary = rec.report()
        graph_.close()
    return dict(published=published, recorder=summary, detector_counts=counts, wall_s=t_run)


def _seg_stats(th, est, segs):
    return [rmse(est[lo:hi], th[lo:hi]) for lo, hi, _ in segs]


def _rmse_after(th, est, det_idx, segs, n_after=50):
    """theta RMSE over the ``n_after`` samples after each detection, per segment (Table 4.3)."""
    out = []
    for lo, hi, _ in segs:
        c = det_idx[(det_idx >= lo) & (det_idx < hi)]
        idx = (c[:, None] + np.arange(n_after)[None, :]).ravel() if c.size else np.zeros(0, int)
        idx = idx[idx < th.size]
        out.append(rmse(est[idx], th[idx]))
    return out


def sampling_rate_study(
    seed: int,
    rates=(1.0e5, 2.5e5, 5.0e5, 1.0e6, 2.5e6),
    noise_factors=(1.0, 10.0),
    duration_s: float = 0.04,
) -> dict:
    """Var(e_theta,th) vs fs on the paper's set-up (Sec. 4.5.1): theta = 0.15 sin(2 pi 625 t),
    y from eq. (71) (nominal comb) + noise sigma_n x factor; sigma_DOG = 15 and w_DOG = 400
    scaled with fs / 500 kHz (fixed ratio of filter size to period)."""
    sp = scanner_params()
    rng = np.random.default_rng(seed + 1000)
    res = {}
    for fac in noise_factors:
        for fs in rates:
            t = np.arange(int(duration_s * fs)) / fs
            w = 2 * math.pi * 625.0
            th = 0.15 * np.sin(w * t + 0.3)
            om = 0.15 * w * np.cos(w * t + 0.3)
            y = dc_transimpedance_output(th, om, sp) + rng.standard_normal(t.size) * 0.0435 * fac
            scale = fs / 5.0e5
            sig = 15.0 * scale
            width = max(int(round(400 * scale)), int(math.ceil(6 * sig)) + 2)
            D, _ = detect_offline(
                y,
                dog_sigma=sig,
                dog_width=width,
                nms_half_window=max(1, int(round(100 * scale))),
                noise_std=0.0435 * fac,
            )
            e, et = detection_errors(th, D, sp.theta_th)
            ok = np.abs(et) < 50 * scale
            res[(fac, fs)] = (float(np.var(e[ok])) if ok.sum() > 2 else math.nan, int(ok.sum()))
    return res


def configured_device(record: dict | None) -> dict:
    """The device as the emulator built it (:data:`SCANNER_SPECS`, validated; drawn for its
    ``device_seed``, at its ``temperature_c``): the scenario's values and the user's
    overrides, from the run record -- the ``oracle`` step (what only the simulation knows)."""
    params = contract.node_parameters(record, EMULATOR, "the device's parameters")
    return _as_built(params, record.get("fixed_parameters", {}).get(EMULATOR, ()))


def identification_error(model: dict, dp: dict) -> dict:
    """The identified model against the device as built ``dp`` (oracle): relative errors of
    wn, zeta, the sensing comb's C0 and theta0 (its values before the drift: the bench's
    comb) and the drive torque's C_dr0/J, -; the threshold angle's error, rad."""
    return {
        "natural_freq_hz": model["model_natural_freq_hz"] / dp["natural_freq_hz"] - 1,
        "damping_ratio": model["model_damping_ratio"] / dp["damping_ratio"] - 1,
        "threshold_angle": model["model_threshold_angle"] - dp["threshold_angle"],
        "sense_c0": model["model_sense_c0"] / dp["sense_c0"] - 1,
        "sense_theta0": model["model_sense_theta0"] / dp["sense_theta0"] - 1,
        "drive_c0_over_inertia": (model["model_drive_c0"] / model["model_inertia"])
        / (dp["drive_c0"] / dp["inertia"])
        - 1,
    }


def estimator_parameters(record: dict | None) -> dict:
    """The EKF parameters the estimator ran with (the identified model it loaded from its
    ``params_yaml``), from the run record."""
    from mems_estimation.filters.scanner_threshold_specs import EKF_SPECS
    from mems_sim.params import resolve

    params = contract.node_parameters(record, ESTIMATOR, "the estimator's model")
    return resolve(EKF_SPECS, {s.name: params[s.name] for s in EKF_SPECS})


def figures(path: Path, dp: dict, seed: int, P: dict | None = None) -> dict:
    """Every result of the scenario from the recorded MCAP (plus the offline studies):
    ``dp``: the device's parameters (:func:`configured_device`); ``seed``: the run seed
    (the sampling-rate study's noise); ``P``: the estimator's EKF parameters
    (:func:`estimator_parameters`; None: the oracle's, the nominal table's)."""
    sp = scanner_params(dp)
    fs = dp["sample_rate_hz"]
    fr = bag_frames.topics_frames(
        path,
        [
            f"/{NS}/{t}"
            for t in ("truth", "adc", "drive", "estimate", "estimate_plain", "threshold_detections")
        ],
    )
    truth = fr[f"/{NS}/truth"]["data"]
    th, om = truth[:, 0], truth[:, 1]
    y = fr[f"/{NS}/adc"]["data"][:, 0]
    v = fr[f"/{NS}/drive"]["data"][:, 0]
    hyb = fr[f"/{NS}/estimate"]
    pla = fr[f"/{NS}/estimate_plain"]
    n = th.size
    if hyb["data"].shape[0] != n or pla["data"].shape[0] != n or hyb["first_index"] != 0:
        raise base.ScenarioError(
            f"estimates cover {hyb['data'].shape[0]} / {pla['data'].shape[0]} of {n} samples"
        )
    dt = fr[f"/{NS}/threshold_detections"]
    D = detections_from_rows(dt["data"], dt["first_index"])
    y_clean = dc_transimpedance_output(th, om, sp, dp["sense_resistance"], dp["bias_voltage"])
    cutoff = int(round((dp["sweep_time_s"] + dp["hold_time_s"]) * fs))
    segs = snr_segments(y_clean, dp["noise_std"], cutoff, fs)
    allseg = segs + [(segs[0][0], segs[-1][1], math.nan)]
    th_h, th_p = hyb["data"][:, 0], pla["data"][:, 0]
    f: dict = {"segments": segs}
    f["rmse_ekf"] = _seg_stats(th, th_p, allseg)
    f["rmse_hyb"] = _seg_stats(th, th_h, allseg)
    f["reduction"] = [1 - h / p for h, p in zip(f["rmse_hyb"], f["rmse_ekf"])]
    f["rmse_th_ekf"] = _rmse_after(th, th_p, D.index, allseg)
    f["rmse_th_hyb"] = _rmse_after(th, th_h, D.index, allseg)
    amp = []
    for lo, hi, _ in allseg:
        amp.append(float(np.mean(np.abs(th[lo:hi])) * math.pi / 2))  # mean amplitude of a sine
    f["nrmse_hyb"] = [r / a for r, a in zip(f["rmse_hyb"], amp)]
    # consistency: PD throughout and the normalised error
    for name, e in (("hyb", hyb), ("ekf", pla)):
        var = e["variances"]
        f[f"min_var_{name}"] = float(var.min())
        f[f"max_var_theta_{name}"] = float(var[:, 0].max())
        z = (e["data"][cutoff:, 0] - th[cutoff:]) / np.sqrt(var[cutoff:, 0])
        f[f"z99_{name}"] = float(np.percentile(np.abs(z), 99))
    # detection errors of the online detections
    e_th, e_t = detection_errors(th, D, sp.theta_th)
    f["latency"] = int(np.unique(D.arrival - D.index)[0]) if D.index.size else None
    ks = []
    for lo, hi, _ in segs:
        m = (D.index >= lo) & (D.index < hi) & (np.abs(e_t) < 50)
        ee = e_th[m]
        p = stats.kstest((ee - ee.mean()) / ee.std(), "norm").pvalue if ee.size >= 8 else math.nan
        ks.append(
            (
                int(m.sum()),
                float(ee.mean()) if ee.size else math.nan,
                float(ee.std()) if ee.size else math.nan,
                float(p),
            )
        )
    f["ks"] = ks
    # online vs offline (same filter, non-causal)
    P_oracle = studies.oracle_parameters()
    P = P_oracle if P is None else P
    noise = math.sqrt(P["r_cap"])  # the detector's noise level, as the node sets it
    off, r_off = detect_offline(y, dog_sigma=DOG_SIGMA, noise_std=noise)
    f["online_offline_same"] = bool(
        off.index.size == D.index.size and np.all(np.abs(off.index - D.index) <= 1)
    )
    f["n_detections"] = int(D.index.size)
    # sigma_DOG sweep (Fig. 4.11, 4.12): offline detections on the recorded y, hybrid EKF re-run
    sweep = {}
    for sig in SIGMAS:
        det = OnlineThresholdDetector(dog_sigma=sig, noise_std=noise)
        Ds = Detections.concat([det.process(y[a : a + 1000]) for a in range(0, n, 1000)])
        e_s, et_s = detection_errors(th, Ds, sp.theta_th)
        var_seg = []
        for lo, hi, _ in segs:
            m = (Ds.index >= lo) & (Ds.index < hi) & (np.abs(et_s) < 50)
            var_seg.append(float(np.var(e_s[m])) if m.sum() > 2 else math.nan)
        hr = run_ekf(y, v, P, detections=Ds, frame=1000)
        nr = [rmse(hr.theta[lo:hi], th[lo:hi]) / a for (lo, hi, _), a in zip(allseg, amp)]
        sweep[sig] = dict(var=var_seg, nrmse=nr)
    f["sigma_sweep"] = sweep
    # the same filters with the full measurement Jacobian [h' omega, h] instead of Table 4.1's
    # [0, h] (offline, on the recorded y and the online detections)
    Pf = dict(P, jacobian="full")
    f["rmse_full_ekf"] = _seg_stats(th, run_ekf(y, v, Pf, frame=1000).theta, allseg)
    f["rmse_full_hyb"] = _seg_stats(th, run_ekf(y, v, Pf, detections=D, frame=1000).theta, allseg)
    f["fs_study"] = sampling_rate_study(seed)
    f["drift"] = drift_evaluation(th, om, y, v, D, dp, segs, P)
    # oracle: the same filters with the emulator's nominal table as their model
    f["oracle"] = dict(
        rmse_ekf=_seg_stats(th, run_ekf(y, v, P_oracle, frame=1000).theta, allseg),
        rmse_hyb=_seg_stats(th, run_ekf(y, v, P_oracle, detections=D, frame=1000).theta, allseg),
        drift=dict(
            base=_seg_stats(
                th, run_ekf(y, v, dict(P_oracle, **BASELINE), frame=5000).theta, allseg
            ),
            hyb=_seg_stats(
                th, run_ekf(y, v, dict(P_oracle, **HYBRID), detections=D, frame=5000).theta, allseg
            ),
        ),
    )
    f["model"] = {k: P[k] for k in MODEL_KEYS}
    f["identification_error"] = identification_error(f["model"], dp)
    f["drift_setting"] = (dp["sense_gain_drift"], dp["sense_width_drift"])
    f["series"] = dict(
        th=th, th_h=th_h, th_p=th_p, y=y, r=r_off, det=D.index, segs=segs, fs=fs, e_th=e_th, e_t=e_t
    )
    return f


def _check_duration(duration: float) -> None:
    if not 0.38 <= duration <= 2.0:
        raise base.ScenarioError(
            f"--duration = {duration!r} is invalid for {NAME}: 0.38 .. 2 s (sweep "
            "0.25 s + hold 0.05 s + a ring-down of at least 80 ms, Sec. 4.4.1)"
        )


def analyse(bag, pngs=None) -> contract.ScenarioResult:
    """The scenario's figures from its recording ``bag`` alone: the device's topics and
    the estimates, with the device's parameters and the run seed from the run record (an
    :class:`AnalysisError` without it). ``pngs``: the two PNG paths (Fig. 4.10 analogue,
    detection study), or one path (the second named ``<stem>-detection.png``), or None."""
    record = contract.read_run_info(bag)
    dp = configured_device(record)
    f = figures(Path(bag), dp, int(record["options"]["seed"]), estimator_parameters(record))
    paths = []
    if pngs is not None:
        if isinstance(pngs, str | Path):
            first = Path(pngs)
            pngs = (first, first.with_name(first.stem + "-detection.png"))
        paths = [Path(q) for q in pngs]
        plot(f, *paths)
    values = {k: v for k, v in f.items() if k != "series"}
    return contract.ScenarioResult(
        NAME, records(f), table(f), paths, oracle_only=list(ORACLE_ONLY), values=values
    )


#: Figure groups of the ``oracle`` path: the filters with the emulator's nominal table as
#: their model (for comparison; the estimator runs with the identified model).
ORACLE_ONLY = ("oracle.* (the filters with the emulator's nominal table as model)",)
#: The headline figures: a run whose value of one of them is not finite fails.
HEADLINE = tuple(
    f"{g}.{k}"
    for g in ("seg1", "seg2", "seg3", "seg4", "overall")
    for k in ("ekf.theta_rmse", "hyb.theta_rmse", "theta_rmse_reduction")
)


def run(options: base.ScenarioOptions) -> dict:
    """Run the scenario and analyse its recording (:func:`analyse`); return the table,
    figures and paths. Raises :class:`ScenarioError` when a headline figure
    (:data:`HEADLINE`) is not finite (a ring-down that never reaches the table's SNR)."""
    out = base.run_recorded(
        options,
        name=NAME,
        default_duration_s=DEFAULT_DURATION_S,
        check_duration=_check_duration,
        run_graph=run_graph,
        analyse=analyse,
        png_suffixes=("", "-detection"),
    )
    bad = [x.name for x in out["figures"] if x.name in HEADLINE and not x.finite]
    if bad:
        raise base.ScenarioError(
            f"{NAME}: {', '.join(bad)} not finite (the ring-down's SNR segments were not "
            f"reached; recording {out['mcap']})"
        )
    return out

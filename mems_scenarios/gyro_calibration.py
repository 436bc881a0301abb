"""Scenario ``gyro_calibration``: piezo tilt micro-stage, capacitive EKF, in-situ gyro
scale-factor calibration at two temperatures (Chen 2018, chapter 3, Tables 3.4-3.6).

Steps (all seeded; identification never reads the emulator's truth):

1. identification at 22.9 C: stepped-sine sweep 1711-1719 Hz at 0.8 V (circle fit ->
   wn, zeta, b_c, LDV delay), training amplitude sweep 1.0-1.3 V at 1700 Hz with the LDV
   (D_n, eta per channel; Q; output correction), zero drive (R);
2. at 22.9 C and at 35.7 C (sensor parameters D_n, eta re-identified there from a
   training sweep): a separate calibration amplitude sweep with the on-stage gyro;
   EKF on the feedthrough-cancelled channels; peak-to-peak pairing; eq. (27);
3. table in the form of Tables 3.4-3.6 and PNG figures.

Two devices. The stage's default physics drifts with temperature (wn -30 ppm/K, actuator
gain +0.1 %/K, readout gain; damping and stator registration drawn from the device seed:
:mod:`mems_sim.devices.stage`); the thesis' procedure above identifies at 22.9 C and
re-identifies only D_n and eta at 35.7 C. Steps 1-3 run on the ``idealised`` (drift-free)
stage, whose figures are those this scenario always printed; unless the scenario is run
``idealised`` (``options.idealised``, or ``--set stage.idealised=true``), the same
procedure then runs on the default drifting device (same seeds) with the in-situ
correction of the stage model (Chen 2018 eqs. 44-47) and its rows follow, marked against
the targets of the drifting case (scale-factor error <= 300 ppm RMS, the thesis 286 ppm;
off-axis rejection read as the RMS leakage, worst over the off-axis phase, on the design
layout and on the device with its stator misregistration).

Identification (step 1) runs the ROS-free cores on emulator records (drive, cancelled ADC
channels, LDV); the calibration (step 2) runs through the node graph: per temperature a
``stage_node`` (namespaces ``/stage_t1`` = 22.9 C, ``/stage_t2`` = 35.7 C) with its
gyro, a ``stage_ekf_node`` loading the identified parameter YAML and a
``stage_gyro_calibration_node`` publishing ``/<stage>/gyro_scale_factor``. The drifting
device's calibration joins the same graph (:data:`DRIFTING`: ``/stage_d1`` at 22.9 C,
``/stage_d2`` at 35.7 C with the model of 22.9 C, ``/stage_d2r`` at 35.7 C with D_n, eta
re-identified there; each stage seeded as the cores' calibration sweep, its EKF in the
in-situ mode, which processes the sweep once the stage announced its end, as the thesis
processes a sweep after its acquisition). Everything is recorded to one MCAP file and the
tables are an analysis of the recording (:func:`analyse`: the recorded streams, the
published results, the EKFs' /diagnostics and the run record, which holds the plan and the
identified models); the gyro's true scale factor, the drifting device as built and the
drifting table's context row (the thesis' procedure without the in-situ correction) and
ablation row, which run on the cores, are its :func:`oracle` (labelled so).
:func:`run_pipeline` is the drift-free scenario on the cores only (no ROS).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mems_estimation.filters.stage_ekf import model_from_dict, model_to_dict, save_model
from mems_estimation.identification.stage_gyro_calibration import (
    T1,
    T2,
    Plan,
    calibration_run,
    calibration_seeds,
    identify_stage,
    off_axis_table,
    retrain_at,
)
from mems_estimation.identification.stage_identification import evaluate
from mems_scenarios.contract import RUN_INFO_TOPIC, AnalysisError, ScenarioResult, read_run_info
from mems_scenarios.gyro_calibration_drifting import (
    DRIFTING,
    INSTANCES,
    drifting_cores,
    drifting_models,
    drifting_plan,
    drifting_table,
    off_axis_target_text,
)
from mems_scenarios.gyro_calibration_report import (
    figure_records,
    instance_figures,
    main_table,
    write_plots,
)
from mems_scenarios.stage_graph import (  # noqa: F401  (FRAME, RECORDED: public names of the scenario)
    FRAME,
    RECORDED,
    recorded_counters,
    run_stage_graph,
)
from mems_sim.devices.stage import STAGE_SPECS
from mems_sim.devices.stage_gyro import GYRO_SPECS
from mems_sim.table import format_table

NAME = "gyro_calibration"
DESCRIPTION = (
    "piezo tilt micro-stage (Chen 2018 ch. 3): capacitive sensing + EKF, in-situ "
    "MPU-6500-like gyro scale-factor calibration at 22.9 and 35.7 C"
)
#: simulated calibration span per temperature (7 trials x 400 periods at 1700 Hz); fixed by
#: the drive schedules (``--duration`` is refused)
DEFAULT_DURATION_S = round(7 * 400 / 1700.0, 3)


def run_pipeline(
    seed: int = 0, plan: Plan | None = None, out_dir: Path | None = None, plots: bool = True
) -> dict:
    """Whole scenario without ROS; returns figures, table text and file paths."""
    from mems_scenarios.base import output_path

    plan = plan or Plan()
    sp = IDEALISED  # the scenario's drift-free stage (:func:`drifting_device`: the other)
    model, rep = identify_stage(seed, plan, sp)
    models = {T1: model, T2: retrain_at(model, T2, seed, plan, sp)}
    runs = {T: calibration_run(models[T], T, seed, plan, sp) for T in (T1, T2)}
    limits = model.limits
    rows = [
        [
            "off-axis rejection R_off",
            f"{100 * r:g} % off-axis",
            f"{100 * v:.3f} %",
            off_axis_target_text(r),
        ]
        for r, v in off_axis_table(float(np.mean(model.gap)), limits)
    ]
    ev = runs[T1]["eval"]
    rows += [
        ["omega RMSE (1 period avg)", f"{T1} C", f"{ev['rmse']:.4f} rad/s", "<= 0.114"],
        ["stage alpha", f"{T1} C", f"{ev['alpha']:.5f}", "|a-1| <= 8e-4"],
        ["stage beta", f"{T1} C", f"{ev['beta']:.4f} rad/s", "(paper -0.0207)"],
    ]
    for T in (T1, T2):
        r = runs[T]
        rows.append(
            [
                f"SF_IMU by stage (true {r['k_true']:.5f})",
                f"{T} C",
                f"{r['cal']['scale_factor']:.5f} +- {r['cal']['scale_factor_se']:.5f}",
                f"{r['ppm']:+.0f} ppm",
            ]
        )
    rms = math.sqrt(np.mean([runs[T]["ppm"] ** 2 for T in (T1, T2)]))
    rows.append(["SF error RMS over temps", f"{T1}/{T2} C", f"{rms:.0f} ppm", "<= 100 ppm"])
    table = format_table(["quantity", "condition", "value", "target / note"], rows)
    paths = []
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        stem = out_dir / f"{NAME}.mcap"
        save_model(model, str(output_path(stem, seed, f"-stage_params_{T1}C.yaml")))
        save_model(models[T2], str(output_path(stem, seed, f"-stage_params_{T2}C.yaml")))
        if plots:
            paths = write_plots(stem, runs, seed)
    return {
        "table": table,
        "model": model,
        "models": models,
        "runs": runs,
        "sf_rms_ppm": rms,
        "identification": rep,
        "plots": paths,
    }


#: the drift-free stage the scenario's graph runs (its historical figures)
IDEALISED = {"idealised": True}
#: the stage node's parameters that describe the device: the stage's physics, spreads and
#: temperature coefficients (``freq_tempco_per_k`` of wn, ``b_c_tempco_per_k`` of the
#: actuator gain b_c of eq. 33, ``damping_ratio`` zeta, ...) and its gyro's. A ``--set
#: stage.PARAM=V`` of one describes the drifting device and reaches its three stage nodes,
#: its identification and its context and ablation rows on the cores alike
#: (:func:`device_parameters`); the drift-free stage (:data:`INSTANCES`) is the historical
#: reference and takes none of them
DEVICE_PARAMETERS = frozenset(s.name for s in STAGE_SPECS + GYRO_SPECS) - {
    "idealised",
    "temperature_c",
}
#: the name under which ``options.applied`` records the overrides the cores took
CORES = "(cores) drifting device: identification, context and ablation rows"


def device_parameters(options, drifting: bool = True) -> tuple[dict, dict]:
    """The drifting device's stage and gyro parameters as its stage nodes take them: the
    user's overrides of :data:`DEVICE_PARAMETERS` that match its stage nodes (validated
    against the node's table, later wins) on top of ``--device-seed``; (stage_params,
    gyro_params) for the cores (:func:`drifting_models`, :func:`drifting_device`), recorded
    in ``options.applied`` under :data:`CORES`. ``drifting`` False (the ``idealised`` run):
    none is accepted. Refused (:class:`ScenarioError`): ``temperature_c`` on a stage node
    (the scenario's temperatures are its subject), a device parameter that would reach
    only the drift-free stage or only some of the drifting stage nodes (the device is
    identified once: graph and cores must see the same one)."""
    from mems_scenarios.base import ScenarioError
    from mems_sim.params import ParameterError, spec_table
    from mems_sim.ros.params_file import node_matches

    specs = spec_table(STAGE_SPECS + GYRO_SPECS)
    stage_names = {s.name for s in STAGE_SPECS}
    sp: dict = {}
    gp: dict = {}
    if drifting and options.device_seed is not None:
        sp["device_seed"] = int(options.device_seed)
        options.applied[(CORES, "device_seed")] = (sp["device_seed"], "--device-seed")
    drift_fqns = [f"/{ns}/stage" for ns in DRIFTING]
    ideal_fqns = [f"/{ns}/stage" for ns in INSTANCES]
    for o in options.overrides:
        hits = [f for f in drift_fqns if node_matches(o.node, f)]
        ideal = [f for f in ideal_fqns if node_matches(o.node, f)]
        if o.name == "temperature_c" and (hits or ideal):
            raise ScenarioError(
                f"{o.where()}: {NAME} sets temperature_c of its stages itself ({T1:g} and {T2:g} C)"
            )
        if o.name not in DEVICE_PARAMETERS or not (hits or ideal):
            continue
        if not drifting:
            raise ScenarioError(
                f"{o.where()}: the drift-free (idealised) stage is the scenario's historical "
                "stage and takes no device parameter; without idealised the drifting device "
                "takes it"
            )
        if not hits:
            raise ScenarioError(
                f"{o.where()}: reaches only the drift-free stage, the scenario's historical "
                f"stage, which takes no device parameter: set stage.{o.name} for the "
                "drifting device"
            )
        if len(hits) < len(drift_fqns):
            raise ScenarioError(
                f"{o.where()}: reaches {', '.join(hits)} only: the drifting device is "
                "identified once, so a device parameter applies to all of its stage nodes "
                f"({', '.join(drift_fqns)}): set stage.{o.name}"
            )
        try:
            value = specs[o.name].validate(o.value)
        except ParameterError as exc:
            raise ScenarioError(f"{o.where()}: {exc}") from None
        (sp if o.name in stage_names else gp)[o.name] = value
        options.applied.pop((CORES, o.name), None)
        options.applied[(CORES, o.name)] = (value, o.origin)
    return sp, gp


def run_graph(
    options,
    plan: Plan,
    models: dict,
    out: Path,
    instances: dict | None = None,
    drifting: dict | None = None,
    run_info: dict | None = None,
) -> dict:
    """Calibration phase through the node graph: per temperature one stage_node
    (+ gyro), stage_ekf_node (identified YAML) and stage_gyro_calibration_node; one recorder.
    ``instances``: namespace -> temperature (default :data:`INSTANCES`, both temperatures
    at once; the benchmark runs one). ``drifting``: the drifting device's models by
    temperature (:func:`drifting_models`; None: not run): its instances :data:`DRIFTING`
    join the same graph and recording, each a drifting stage_node seeded as the cores'
    calibration sweep, a stage_ekf_node in its in-situ mode (Chen 2018 eqs. 44-47: the
    sweep processed once complete) and a calibration node. The drift-free stage nodes take
    none of the user's overrides of :data:`DEVICE_PARAMETERS` (the drifting ones do).
    ``run_info``: extra keys of the run record (None: none recorded)."""
    INSTANCES = instances or globals()["INSTANCES"]

    from mems_scenarios.base import output_path

    seed = int(options.seed)
    # namespace -> (stage node parameters, parameter YAML of its EKF, EKF parameters)
    layout: dict[str, tuple[dict, Path, dict]] = {}
    for k, (ns, T) in enumerate(INSTANCES.items()):
        yaml_path = output_path(out, options.seed, f"-stage_params_{T}C.yaml")
        save_model(models[T], str(yaml_path))
        stage = dict(
            seed=seed * 100 + 50 + k,
            idealised=True,
            temperature_c=T,
            n_trials=plan.cal_trials,
            periods_per_trial=plan.cal_periods,
        )
        layout[ns] = (stage, yaml_path, {})
    shielded = {ns: DEVICE_PARAMETERS for ns in layout}  # the drift-free stage: historical
    if drifting is not None:
        dplan = drifting_plan(plan)
        for ns, (T, T_model) in DRIFTING.items():
            yaml_path = output_path(out, options.seed, f"-drifting_stage_params_{T_model}C.yaml")
            save_model(drifting[T_model], str(yaml_path))
            stage_seed, gyro_seed = calibration_seeds(T, seed)
            stage = dict(
                seed=stage_seed,
                gyro_seed=gyro_seed,
                idealised=False,
                temperature_c=T,
                n_trials=dplan.cal_trials,
                periods_per_trial=dplan.cal_periods,
            )
            layout[ns] = (stage, yaml_path, {"insitu": True})

    return run_stage_graph(options, layout, out, NAME, shielded, run_info)


def published_calibration(bag, ns: str) -> dict:
    """The last result instance ``ns``'s calibration node published
    (``/<ns>/gyro_scale_factor``, eq. 27): scale_factor, bias, their standard errors
    (``*_se``), pairs ``n`` and ``residual_rms``."""
    from mems_sim.bag.player import read_messages

    msg = None
    for _, _, _, m in read_messages(str(bag), [f"/{ns}/gyro_scale_factor"]):
        msg = m
    if msg is None:
        raise AnalysisError(f"{ns}: no message on /{ns}/gyro_scale_factor in {bag}")
    (sf, bias), (sf_se, bias_se) = msg.values, msg.standard_errors
    return dict(
        scale_factor=sf,
        bias=bias,
        scale_factor_se=sf_se,
        bias_se=bias_se,
        n=int(msg.num_points),
        residual_rms=msg.residual_rms,
    )


def recorded_run(bag, ns: str, k_true: float) -> dict:
    """One instance's figures from the recording ``bag`` (estimate, truth, drive: omega
    RMSE, alpha, beta over one averaged period) and its published calibration result
    (:func:`published_calibration`), with the true gyro scale factor ``k_true``
    (:func:`oracle`) and the error [ppm]."""
    from mems_scenarios.bag_frames import topics_frames

    fr = topics_frames(bag, [f"/{ns}/{t}" for t in ("estimate", "truth", "drive")])
    est, tru, drv = (fr[f"/{ns}/{t}"]["data"] for t in ("estimate", "truth", "drive"))
    n = min(len(est), len(tru), len(drv))
    ev = evaluate(est[:n, 1], tru[:n, 1], drv[:n, 3], drv[:n, 4].astype(int))
    r = published_calibration(bag, ns)
    return dict(
        eval=ev,
        cal=r,
        k_true=k_true,
        ppm=(r["scale_factor"] / k_true - 1) * 1e6,
        se_ppm=r["scale_factor_se"] / k_true * 1e6,
        est=est[:n],
        truth=tru[:n],
        drive=drv[:n],
    )


def recorded_pairs(bag, ns: str, run: dict) -> list[dict]:
    """The peak-to-peak pairs of instance ``ns`` (for the Fig. 3.15-like plot), paired
    again from the recording as the calibration node pairs them (Chen 2018 eq. 27:
    :class:`~mems_estimation.identification.stage_gyro_calibration.StreamingCalibrator`;
    gyro samples placed on the stage index through their frames' stamps). ``run``: the
    instance's :func:`recorded_run`."""
    from mems_estimation.identification.stage_gyro_calibration import StreamingCalibrator
    from mems_sim.bag.player import read_messages
    from mems_sim.ros.frames import adc_physical, time_to_ns

    fs = t0 = None
    cal = None
    for topic, _, _, msg in read_messages(str(bag), [f"/{ns}/drive", f"/{ns}/gyro/adc"]):
        if topic.endswith("/drive"):
            if t0 is None:
                fs = float(msg.sample_rate_hz)
                first = int(msg.first_sample_index)
                t0 = time_to_ns(msg.header.stamp) - round(first * 1e9 / fs)
                cal = StreamingCalibrator(fs)
                drv = run["drive"]
                names = list(msg.channel_names)
                cols = [names.index(c) for c in ("phase", "f_drive", "trial")]
                om = run["est"][:, 1]
                cal.add_stage(
                    0, om, drv[:, cols[0]], drv[:, cols[1]], drv[:, cols[2]].astype(np.int64)
                )
            continue
        if cal is None:
            continue
        v = adc_physical(msg)[:, 0]
        rate = float(msg.sample_rate_hz)
        k = ((time_to_ns(msg.header.stamp) - t0) / 1e9 + np.arange(v.size) / rate) * fs
        cal.add_gyro(k, v)
    if cal is None:
        return []
    cal.finish()
    return list(cal.pairs)


def without_run_record(bag) -> ScenarioResult:
    """The figures a recording without the scenario's run record gives (a user's own
    recording of the drift-free instances): :func:`instance_figures` of each instance
    whose topics it holds, one line for the rest."""
    from mems_scenarios.base import ScenarioError
    from mems_scenarios.figures import figure_table

    figures, unavailable = [], []
    for ns, T in INSTANCES.items():
        try:
            f = recorded_run(bag, ns, math.nan)
        except (AnalysisError, ScenarioError) as exc:
            unavailable.append((f"{ns}.*", str(exc)))
            continue
        figures += instance_figures(ns, T, f["eval"], f["cal"])
    why = (
        f"{bag}: no run record of {NAME} ({RUN_INFO_TOPIC}): it holds the identified "
        "models, the plan and the stage nodes' parameters"
    )
    if not figures:
        raise AnalysisError(why)
    unavailable.append(
        ("off_axis_*, *.scale_factor_true, *.scale_factor_error, *_rms, graph.*, drifting.*", why)
    )
    return ScenarioResult(NAME, figures, figure_table(figures), unavailable=unavailable)


def oracle(record: dict) -> dict:
    """What only the simulation knows, from the run record: per stage instance the gyro's
    true scale factor k_I(T) (:class:`~mems_sim.devices.stage_gyro.MemsGyro` of the stage
    node's parameters); with the drifting device, its rows that run on the ROS-free cores
    beside the graph (:func:`drifting_cores`: the thesis' procedure without the in-situ
    correction, the ablation, the device's off-axis rejection as built)."""
    from mems_sim.devices.stage_gyro import MemsGyro

    k_true = {}
    for fqn, node in record["nodes"].items():
        if node["executable"] == "stage_node":
            p = node["parameters"]
            gyro = MemsGyro(
                {s.name: p[s.name] for s in GYRO_SPECS}, temperature_c=p["temperature_c"]
            )
            k_true[fqn.strip("/").split("/")[0]] = gyro.scale_factor()
    out = {"k_true": k_true, "drifting": None}
    if record.get("drifting_models") is not None:
        models = {T: model_from_dict(record["drifting_models"][str(T)]) for T in (T1, T2)}
        out["drifting"] = drifting_cores(
            int(record["options"]["seed"]),
            Plan(**record["plan"]),
            record["device"]["stage"],
            record["device"]["gyro"],
            models,
        )
    return out


#: figure groups :func:`oracle` gives (the simulation's knowledge)
ORACLE_ONLY = [
    "*.scale_factor_true, *.scale_factor_error, *scale_factor_error_rms* (the gyro's truth)",
    "drifting.off_axis_*, drifting.stator_offset_y (the drifting device as built)",
    "drifting.scale_factor_error_rms.thesis_procedure, drifting.ablation_no_channels_35.7C "
    "(ROS-free cores)",
]


def analyse(bag, pngs=None) -> ScenarioResult:
    """The scenario's figures from its recording ``bag``: per instance the recorded
    estimate, truth and drive and the published ``gyro_scale_factor``; the identified
    models, the plan and the graph's times from the run record; the EKFs' in-situ
    counters from ``/diagnostics``; the gyro's truth and the cores' rows from
    :func:`oracle`. ``pngs``: the period and peak-to-peak PNG paths (one path: both named
    after it; None: no plots)."""
    record = read_run_info(bag)
    if record is None or "models" not in record:
        return without_run_record(bag)
    ora = oracle(record)
    models = {T: model_from_dict(record["models"][str(T)]) for T in (T1, T2)}
    model = models[T1]
    off_axis = off_axis_table(float(np.mean(model.gap)), model.limits)
    figs = {T: recorded_run(bag, ns, ora["k_true"][ns]) for ns, T in INSTANCES.items()}
    rms = math.sqrt(np.mean([figs[T]["ppm"] ** 2 for T in (T1, T2)]))
    g = dict(simulated_s=record["simulated_s"], wall_s=record["wall_s"])
    figures = figure_records(off_axis, figs, rms, g)
    table = main_table(figures, off_axis, figs, rms, g, bool(record["options"]["realtime"]))
    counters = recorded_counters(bag)
    drift = None
    if ora["drifting"] is not None:
        graph_runs = {}
        for ns in DRIFTING:
            c = counters.get(f"/{ns}/stage_ekf", {})
            graph_runs[ns] = dict(
                recorded_run(bag, ns, ora["k_true"][ns]),
                **{k: c.get(k) for k in ("insitu_wn_ratio", "insitu_b_c_ratio", "insitu_sweeps")},
            )
        drift = drifting_table(ora["drifting"], graph_runs)
        figures += drift["figures"]
        device = record["device"]
        table += "\n\n" + format_table(
            [
                "drifting device ("
                + ("parameters set" if device["stage"] or device["gyro"] else "default physics")
                + ")",
                "condition",
                "value",
                "target / note",
                "met",
            ],
            drift["rows"],
        )
    plots = []
    if pngs:
        if isinstance(pngs, str | Path):
            p = Path(pngs)
            pngs = (p.with_name(p.stem + "-period.png"), p.with_name(p.stem + "-peak_to_peak.png"))
        plots = _graph_plots(bag, pngs, figs)
    layout = [fqn.strip("/").split("/")[0] for fqn in ora["k_true"]]
    rejected = {ns: counters.get(f"/{ns}/stage_ekf", {}).get("rejected_frames", 0) for ns in layout}
    return ScenarioResult(
        NAME,
        figures,
        table,
        list(plots),
        oracle_only=ORACLE_ONLY[: 3 if drift is not None else 1],
        values=dict(figs=figs, drifting=drift, rejected=rejected, sf_rms_ppm=rms, model=model),
    )


def run(options) -> dict:
    """``run_scenario gyro_calibration``: identification (ROS-free cores), then the
    calibration at both temperatures through the node graph, recorded to MCAP with the
    identified models in the run record, then :func:`analyse` of the recording.
    ``options.short`` selects the short plan (tests)."""
    import dataclasses

    from mems_scenarios.base import ScenarioError, output_path

    if options.duration_s not in (None, 0.0):
        raise ScenarioError(
            "gyro_calibration: the duration follows from the drive schedules "
            "(7 trials x 400 periods at 1700 Hz); omit --duration"
        )
    plan = Plan.short() if options.short else Plan()
    out = Path(options.out or Path("runs") / f"{NAME}-{options.seed}.mcap")
    out.parent.mkdir(parents=True, exist_ok=True)
    seed = int(options.seed)
    # the drift-free stage: as its graph nodes, with --device-seed only (no device override)
    ideal = dict(IDEALISED)
    if options.device_seed is not None:
        ideal["device_seed"] = int(options.device_seed)
    drifting = not idealised_only(options)
    # the drifting device as its stage nodes take it (the user's device parameters)
    sp, gp = device_parameters(options, drifting)
    model, _ = identify_stage(seed, plan, ideal)
    models = {T1: model, T2: retrain_at(model, T2, seed, plan, ideal)}
    # the drifting device's identification (cores); its calibration joins the graph
    drift_models = drifting_models(seed, plan, sp) if drifting else None
    run_info = dict(
        plan=dataclasses.asdict(plan),
        models={str(T): model_to_dict(m) for T, m in models.items()},
        drifting_models=None
        if drift_models is None
        else {str(T): model_to_dict(m) for T, m in drift_models.items()},
        device=dict(stage=sp, gyro=gp),
    )
    g = run_graph(options, plan, models, out, drifting=drift_models, run_info=run_info)
    pngs = None
    if options.plots:
        pngs = tuple(
            output_path(out, options.seed, s) for s in ("-period.png", "-peak_to_peak.png")
        )
    result = analyse(out, pngs)
    v = result.values
    return {
        "drifting": v["drifting"],
        "table": result.table,
        "duration_s": g["simulated_s"],
        "mcap": str(out),
        "recorder": g["recorder"],
        "figure": ", ".join(str(p) for p in result.plots),
        "figures": result.figures,
        "values": v["figs"],
        "sf_rms_ppm": v["sf_rms_ppm"],
        "rejected": v["rejected"],
        "published": g["published"],
        "model": model,
        "result": result,
    }


def _graph_plots(bag, pngs: tuple, figs: dict) -> list:
    """PNG figures from the recording (Fig. 3.14 / 3.15 forms) at ``pngs`` (period,
    peak-to-peak)."""
    runs = {}
    for ns, T in INSTANCES.items():
        f = figs[T]
        rec = {
            "segment": f["drive"][:, 4].astype(int),
            "phase": f["drive"][:, 3],
            "omega": f["truth"][:, [1, 3]],
        }
        cal = dict(f["cal"], pairs=recorded_pairs(bag, ns, f))
        runs[T] = {"rec": rec, "x": f["est"], "cal": cal}
    return write_plots(Path(bag), runs, 0, paths=pngs)


def idealised_only(options) -> bool:
    """The scenario's ``idealised`` switch: ``options.idealised`` or a ``--set`` of
    ``idealised`` true on its stage nodes: only the drift-free stage (the historical run)."""
    from mems_scenarios.base import ScenarioError

    if options.idealised:
        return True
    if any(o.name == "idealised" and o.value is False for o in options.overrides):
        raise ScenarioError(
            "gyro_calibration: idealised=false is refused: the graph runs the drift-free "
            "stage and the default run adds the drifting device's table; "
            "--set stage.idealised=true runs the drift-free stage only"
        )
    return any(o.name == "idealised" and o.value is True for o in options.overrides)


def drifting_device(
    seed: int,
    plan: Plan,
    stage_params: dict | None = None,
    models: dict | None = None,
    graph_runs: dict | None = None,
    gyro_params: dict | None = None,
) -> dict:
    """Steps 1-3 on the default (drifting) stage, same seeds.

    Identification at T1 (reference Q, LDV training sweep) on the ROS-free cores
    (:func:`drifting_models`, or ``models`` as it returned them), then per temperature one
    calibration sweep (:data:`INSITU_PERIODS` periods per trial) evaluated by the in-situ
    corrected EKF (:mod:`mems_estimation.identification.stage_insitu`: the stage model's
    response at the drive frequency re-measured by the capacitive channels of the sweep
    itself) with two sets of sensor parameters (D_n, eta): those of the training
    temperature (reference at T1 only) and, at T2, those re-identified there with the
    LDV-like reference (the thesis' procedure; a separate, labelled row). ``graph_runs``:
    those rows from the node graph (namespace of :data:`DRIFTING` -> the figures of
    :func:`recorded_run`: the recording and the published ``gyro_scale_factor``); None:
    from the cores. For context, on the cores (labelled so), the thesis' procedure
    without the in-situ correction (model-driven EKF, output correction of T1) and the
    ablation (every capacitive channel removed at T2). Off-axis rejection in the RMS
    reading, worst over the off-axis phase 0-180 deg (design layout and the as-built
    stator misregistration). ``stage_params`` / ``gyro_params``: the device (the scenario's
    :func:`device_parameters`; None: the default drifting device). Returns dict(figures,
    rows, runs, rms_ppm, off_axis)."""
    sp = dict(stage_params or {})
    models = models or drifting_models(seed, plan, sp)
    cores = drifting_cores(seed, plan, sp, gyro_params, models, graph_runs is not None)
    return drifting_table(cores, graph_runs)

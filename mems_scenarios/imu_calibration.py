"""Scenario ``imu_calibration``: multi-position and rate-table calibration of the
ADIS16350-like IMU (Titterton & Weston Sec. 8.3-8.4; Syed et al. 2007), judged against the
emulator's truth.

Graph (one process): ``/imu/imu`` (mems_sim.nodes.imu_node, ``preset`` adis16350, ``motion``
profile, ``motion_profile`` multi_position: six static positions, then +-100 deg/s on the
rate table about each axis, 60 s each, 720 s) publishes ``adc``, ``truth``,
``temperature_sensor`` and once ``truth_calibration``; ``/imu/imu_calibration``
(mems_estimation.nodes.imu_calibration_node, the segment-mean covariance from the preset's
noise model, temperature from the paired temperature_sensor frames) publishes
``/imu/calibration`` at the profile's end and writes the calibration YAML next to the MCAP;
the recorder writes everything. The figures are an analysis of the recording
(:func:`analyse`: the published calibration against ``/imu/truth_calibration``); the
emulator's nominal B comes from the run record (:func:`oracle`). The contract: docs/scenarios.md.

Figures (targets of the multi-position calibration, per sensor): RMS scale-factor error
(diagonal of C) [ppm] <= 300; RMS misalignment error (off-diagonal of C, small angles)
[deg] <= 0.05; RMS accelerometer bias error [mg] <= 1; RMS gyro bias error in units of the
gyro's bias instability B <= 3; coverage of the 95 % intervals (estimated parameters whose
interval holds the truth): at least the 1 % binomial quantile of the run's count (one run
has 33 correlated parameters: the acceptance campaign pools 20 seeds against >= 0.9).
``imu_thermal_calibration`` (:mod:`mems_scenarios.imu_thermal_calibration`) runs the
thermal_ramp profile with the same graph.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import stats

from mems_estimation.identification import imu_calibration as ic
from mems_estimation.identification import imu_calibration_io as icio
from mems_scenarios import base, contract, delivery
from mems_scenarios.figures import Figure, cell, figure_table, project_criterion
from mems_sim.devices.imu_profiles import load_profile

NAME = "imu_calibration"
DESCRIPTION = (
    "ADIS16350-like IMU on a multi-position / rate-table profile -> GLS calibration of "
    "matrices, biases, g-sensitivity with 95 % intervals vs the emulator's truth -> MCAP"
)
PROFILE = "multi_position"
DEFAULT_DURATION_S = 720.0
FAST_FRAME = 100
REALTIME_FRAME = 10
WINDOW = 50
TOPICS = [
    "/imu/adc",
    "/imu/truth",
    "/imu/temperature_sensor",
    "/imu/truth_calibration",
    "/imu/calibration",
    "/imu/end_of_stream",
    "/diagnostics",
]
#: Targets (module docstring).
SF_PPM, MISALIGN_DEG, ACCEL_BIAS_MG, GYRO_BIAS_B, COVERAGE, TEMPCO_REL = (
    300.0,
    0.05,
    1.0,
    3.0,
    0.9,
    0.10,
)


#: Fully qualified names of the emulator and the calibration node.
EMULATOR = "/imu/imu"
CALIBRATOR = "/imu/imu_calibration"


def graph(
    options: base.ScenarioOptions,
    duration_s: float | None,
    *,
    profile: str = PROFILE,
    out=None,
    name: str = NAME,
) -> contract.GraphSpec:
    """The graph of scenario ``name`` on ``profile``: the emulator and the calibration node
    in ``/imu`` (``duration_s`` None: the profile's), recorded; the calibration node writes
    its YAML beside the MCAP file ``out``."""
    emu_params = {
        "seed": int(options.seed),
        "preset": "adis16350",
        "motion": "profile",
        "motion_profile": profile,
        "frame_size": REALTIME_FRAME if options.realtime else FAST_FRAME,
        "publish_imu": False,
    }
    if duration_s is not None:
        emu_params["duration_s"] = float(duration_s)
    out = Path(out or Path("runs") / f"{name}-{options.seed}.mcap")
    cal_params = {
        "profile": profile,
        "noise_model": "adis16350",
        "temperature_source": "sensor",
        "output_yaml": str(base.output_path(out, options.seed, "-calibration.yaml")),
    }
    emulator = contract.NodeEntry("imu_node", "imu", "imu", emu_params)
    calibrator = contract.NodeEntry("imu_calibration_node", "imu_calibration", "imu", cal_params)
    return contract.GraphSpec(name, (emulator, calibrator), (*TOPICS, contract.RUN_INFO_TOPIC))


def build_graph(
    options: base.ScenarioOptions, out: Path, profile: str, duration_s: float | None, name: str
):
    """Context, the nodes of :func:`graph` and the recorder; the run record names the
    emulator's parameters given explicitly (:func:`oracle`: its nominal device)."""
    spec = graph(options, duration_s, profile=profile, out=out, name=name)
    g = base.graph_for(options)
    nodes = g.build(spec, realtime=options.realtime)
    rec = g.recorder(str(out), topics=list(spec.recorded))
    given = set(spec.node(EMULATOR).parameters)
    given |= {n for (fqn, n) in options.applied if fqn == EMULATOR}
    g.publish_run_info(spec, options, nodes, emulator_given=sorted(given))
    return g, nodes[EMULATOR], nodes[CALIBRATOR], rec


def _rms(x) -> float:
    x = np.asarray(list(x), float)
    return float(math.sqrt(np.mean(x * x))) if x.size else math.nan


def compare(cal, truth: dict[str, float]) -> list[dict]:
    """Per estimated parameter of the published calibration ``cal`` (a CalibrationResult:
    its aliased parameters are left out): estimate, truth, error, 95 % interval (eq. of
    :meth:`~mems_estimation.identification.imu_calibration.ImuCalibration.ci95`), covered."""
    rows = []
    for n, v, se in zip(cal.names, cal.values, cal.standard_errors):
        if n not in truth:
            continue
        lo, hi = v - ic.Z95 * se, v + ic.Z95 * se
        rows.append(
            dict(
                name=n,
                estimate=v,
                truth=truth[n],
                error=v - truth[n],
                ci95=(lo, hi),
                covered=bool(lo <= truth[n] <= hi),
                unit=ic.parameter_unit(n),
            )
        )
    return rows


#: Where the targets come from (the figures' ``source``).
CALIBRATION_SOURCE = project_criterion(
    "a multi-position and rate-table calibration on this IMU's noise and 60 s positions"
)
COVERAGE_SOURCE = project_criterion(
    "calibrated 95 % intervals fall below this count in < 1 % of runs (binomial quantile; "
    "correlated intervals make the test stricter)"
)
#: False-fail probability of the per-run coverage test, -.
COVERAGE_ALPHA = 0.01


def _target(
    value: float, limit: float, text: str, unit: str, name: str, ge=False, source=None
) -> Figure:
    ok = math.isfinite(value) and (value >= limit if ge else value <= limit)
    target = f"{'>=' if ge else '<='} {limit:g}{text}"
    return Figure(name, value, unit, target, ok, source or CALIBRATION_SOURCE)


def coverage_floor(total: int, level: float = 0.95, alpha: float = COVERAGE_ALPHA) -> int:
    """The least count of ``total`` independent intervals of coverage ``level`` that holds
    with probability >= 1 - ``alpha``: the ``alpha`` quantile of Binomial(total, level)."""
    return int(stats.binom.ppf(alpha, total, level)) if total else 0


def multi_position_figures(rows: list[dict], gyro_b: float | None) -> list[Figure]:
    """The figures of the module docstring (``gyro_b`` None: without the gyro bias ones)."""
    err = {r["name"]: r["error"] for r in rows}
    out = []
    for s in ic.SENSORS:
        diag = [err[f"{s}_matrix_{a}{a}"] for a in ic.AXES if f"{s}_matrix_{a}{a}" in err]
        off = [
            err[f"{s}_matrix_{a}{b}"]
            for a in ic.AXES
            for b in ic.AXES
            if a != b and f"{s}_matrix_{a}{b}" in err
        ]
        out.append(_target(_rms(diag) * 1e6, SF_PPM, " ppm", "ppm", f"{s}.scale_factor_error_rms"))
        out.append(
            _target(
                math.degrees(_rms(off)), MISALIGN_DEG, " deg", "deg", f"{s}.misalignment_error_rms"
            )
        )
    ab = [err[f"accel_bias_{a}"] for a in ic.AXES if f"accel_bias_{a}" in err]
    out.append(_target(_rms(ab) / 9.80665e-3, ACCEL_BIAS_MG, " mg", "mg", "accel.bias_error_rms"))
    if gyro_b is None:  # the emulator's B (its run record, :func:`oracle`) is unknown
        return out
    gb = [err[f"gyro_bias_{a}"] for a in ic.AXES if f"gyro_bias_{a}" in err]
    out.append(_target(_rms(gb) / gyro_b, GYRO_BIAS_B, " B", "B", "gyro.bias_error_rms"))
    out.append(Figure("gyro.bias_instability_B", gyro_b, "rad/s"))
    return out


def thermal_figures(rows: list[dict]) -> list[Figure]:
    """Relative errors of the estimated temperature coefficients and their RMS."""
    out, rel = [], []
    for r in rows:
        if "tempco" in r["name"] and r["truth"] != 0:
            e = r["error"] / abs(r["truth"])
            rel.append(e)
            out.append(Figure(f"{r['name']}.rel_error", e, "1"))
    source = project_criterion("temperature coefficients of a 20-60 C ramp at 1 K/min")
    out.append(_target(_rms(rel), TEMPCO_REL, "", "1", "tempco.rel_error_rms", source=source))
    return out


def coverage_figures(rows: list[dict]) -> list[Figure]:
    """Covered and total count of the 95 % intervals and their ratio."""
    covered = sum(r["covered"] for r in rows)
    total = len(rows)
    return [
        Figure("coverage.covered", covered, ""),
        Figure("coverage.total", total, ""),
        _coverage_target(covered, total),
    ]


def _coverage_target(covered: int, total: int) -> Figure:
    """Coverage against :func:`coverage_floor` (a count of one run's intervals; the pooled
    coverage over seeds, >= :data:`COVERAGE`, is the acceptance campaign's)."""
    if not total:
        return Figure("coverage", None, "1", "> 0 intervals", False, COVERAGE_SOURCE)
    k = coverage_floor(total)
    return Figure(
        "coverage",
        covered / total,
        "1",
        f">= {k / total:.4g} ({k} of {total})",
        covered >= k,
        COVERAGE_SOURCE,
    )


def results_table(rows: list[dict]) -> str:
    """parameter, unit, truth, estimate, +-95 %, error, covered."""
    body = [
        [
            r["name"],
            r["unit"],
            cell(r["truth"], ".6g"),
            cell(r["estimate"], ".6g"),
            cell(0.5 * (r["ci95"][1] - r["ci95"][0]), ".3g"),
            cell(r["error"], "+.3g"),
            "yes" if r["covered"] else "NO",
        ]
        for r in rows
    ]
    return base.format_table(
        ["parameter", "unit", "truth", "estimate", "+-95 %", "error", "covered"], body
    )


def last_message(bag, topic: str):
    """The last message on ``topic`` of the recording ``bag`` (None: none)."""
    from mems_sim.bag.player import read_messages

    msg = None
    for _, _, _, m in read_messages(str(bag), [topic]):
        msg = m
    return msg


def oracle(record: dict) -> dict:
    """What only the simulation knows, from the run record: the emulator's nominal gyro
    bias instability B [rad/s] (its preset's, or the value set explicitly; the unit of
    the gyro bias figure), as the emulator resolves its nominal device
    (:func:`mems_sim.devices.imu_specs.imu_values` of the parameters given explicitly)."""
    from mems_sim.devices.imu_specs import IMU_SPECS, imu_values

    params = contract.node_parameters(record, EMULATOR, "gyro.bias_error_rms")
    names = {s.name for s in IMU_SPECS}
    given = set(record.get("emulator_given", ())) | {"preset"}
    nominal = imu_values({n: params[n] for n in sorted(given & names) if n in params})
    return {"gyro_bias_instability": float(nominal["gyro_bias_instability"])}


def aliases_of(bag, params: dict) -> dict[str, str]:
    """The parameters the profile cannot separate (estimated name -> text, as
    :func:`~mems_estimation.identification.imu_calibration.calibrate_profile` names them):
    the calibration node's GLS, with its parameters, on the recorded ``/imu/adc`` (and
    ``/imu/temperature_sensor``); the aliases follow from the profile's design, not from
    the noise, so the recording gives them."""
    from mems_estimation.tools.calibrate_imu import read_adc
    from mems_scenarios.bag_frames import topics_frames

    idx, vals, fs, _ = read_adc(Path(bag), "/imu/adc")
    temperature = None
    if params.get("temperature_source") == "sensor":
        fr = topics_frames(bag, ["/imu/temperature_sensor"], missing_ok=True)
        t = fr.get("/imu/temperature_sensor")
        if t is not None and t["first_index"] == idx[0] and len(t["data"]) == idx.size:
            temperature = np.ascontiguousarray(t["data"][:, list(t["names"]).index("temperature")])
    cal = ic.calibrate_profile(
        vals[:, :3],
        vals[:, 3:],
        load_profile(params["profile"]),
        fs,
        index=idx,
        temperature=temperature,
        device_temperature_c=params["device_temperature_c"],
        noise=icio.noise_option(params["noise_model"]),
        thermal={"auto": None, "on": True, "off": False}[params["thermal"]],
        base=icio.load_yaml(params["base_yaml"]) if params.get("base_yaml") else None,
    )
    return dict(cal.aliases)


def analyse_profile(bag, name: str, thermal: bool, pngs=None) -> contract.ScenarioResult:
    """The figures of ``name`` from its recording ``bag``: the published calibration
    (``/imu/calibration``) against the emulator's realised error terms
    (``/imu/truth_calibration``); the gyro bias in units of B from :func:`oracle` (the
    run record); the notes on inseparable parameters from :func:`aliases_of`. No plots."""
    cal = last_message(bag, "/imu/calibration")
    truth_msg = last_message(bag, "/imu/truth_calibration")
    missing = [
        t
        for t, m in (("/imu/calibration", cal), ("/imu/truth_calibration", truth_msg))
        if m is None
    ]
    if missing:
        return contract.ScenarioResult(
            name, [], "", unavailable=[("*", f"{bag}: no message on {', '.join(missing)}")]
        )
    truth = dict(zip(truth_msg.names, truth_msg.values))
    rows = compare(cal, truth)
    record = contract.read_run_info(bag)
    unavailable, oracle_only = [], []
    figures = []
    if not thermal:
        oracle_only.append("gyro.bias_error_rms, gyro.bias_instability_B")
        try:
            gyro_b = oracle(record)["gyro_bias_instability"]
        except contract.AnalysisError as exc:
            gyro_b = None
            unavailable.append((oracle_only[0], str(exc)))
        figures += multi_position_figures(rows, gyro_b)
    else:
        figures += thermal_figures(rows)
    figures += coverage_figures(rows)
    table = results_table(rows) + "\n\n" + figure_table(figures)
    try:
        params = contract.node_parameters(record, CALIBRATOR, "notes on inseparable parameters")
        notes = [
            f"{n} {t} (not separable in {params['profile']}: not judged)"
            for n, t in aliases_of(bag, params).items()
        ]
    except (contract.AnalysisError, ValueError, ic.CalibrationError) as exc:
        notes = []
        unavailable.append(("notes on inseparable parameters", str(exc)))
    return contract.ScenarioResult(
        name,
        figures,
        table + ("\n" + "\n".join(notes) if notes else ""),
        unavailable=unavailable,
        oracle_only=oracle_only,
        values=dict(rows=rows, truth=truth, calibration=cal),
    )


def run_profile(options: base.ScenarioOptions, name: str, profile: str, thermal: bool) -> dict:
    """Run the graph on ``profile`` and analyse its recording (:func:`analyse_profile`)."""
    prof = load_profile(profile)
    duration = options.duration_s
    if duration is not None and duration <= 0:
        raise base.ScenarioError(f"--duration {duration!r} must be > 0 s")
    out = Path(options.out or Path("runs") / f"{name}-{options.seed}.mcap")
    out.parent.mkdir(parents=True, exist_ok=True)
    graph, emu, cal, rec = build_graph(options, out, profile, duration, name)
    total = duration if duration is not None else prof.duration_s()
    progress = base.Progress(total, options.progress, name)
    try:
        delivery.publish_all(
            graph,
            [emu],
            delivery.consumed(cal),
            progress,
            realtime=options.realtime,
            realtime_timeout_s=total * 2 + 60,
            window=WINDOW,
        )
        progress.close()
        before = rec.received("/imu/calibration")
        if not cal.results:
            cal.publish_result()
        if not cal.results:
            raise base.ScenarioError(
                "no calibration: too little data for the profile "
                f"{prof.name!r} ({prof.duration_s():g} s; give a longer --duration)"
            )
        graph.spin_until(
            lambda: rec.received("/imu/calibration") > before or before >= 1,
            20.0,
            "the recorder to receive the calibration",
        )
        graph.wait_run_info(rec)
    finally:
        progress.close()
        rec.close()
        summary = rec.report(text=True)
        graph.close()
    result = analyse_profile(out, name, thermal)
    yaml_path = base.output_path(out, options.seed, "-calibration.yaml")
    return dict(
        table=result.table,
        figures=result.figures,
        rows=result.values["rows"],
        calibration=icio.load_yaml(yaml_path),
        truth=result.values["truth"],
        mcap=out,
        yaml=yaml_path,
        recorder=summary,
        duration_s=total,
        result=result,
    )


def analyse(bag, pngs=None) -> contract.ScenarioResult:
    """The figures of ``imu_calibration`` from its recording (:func:`analyse_profile`)."""
    return analyse_profile(bag, NAME, thermal=False, pngs=pngs)


def run(options: base.ScenarioOptions) -> dict:
    """Run the scenario (multi_position profile)."""
    return run_profile(options, NAME, PROFILE, thermal=False)

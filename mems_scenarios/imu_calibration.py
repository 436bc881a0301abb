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
the recorder writes everything.

Figures (targets of the multi-position calibration, per sensor): RMS scale-factor error
(diagonal of C) [ppm] <= 300; RMS misalignment error (off-diagonal of C, small angles)
[deg] <= 0.05; RMS accelerometer bias error [mg] <= 1; RMS gyro bias error in units of the
gyro's bias instability B <= 3; coverage of the 95 % intervals (estimated parameters whose
interval holds the truth) >= 0.9 (one run has 33 correlated parameters: the acceptance
campaign pools 20 seeds). ``imu_thermal_calibration`` (:mod:`mems_scenarios.imu_thermal_calibration`)
runs the thermal_ramp profile with the same graph.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mems_estimation.identification import imu_calibration as ic
from mems_estimation.nodes.imu_calibration_node import ImuCalibrationNode
from mems_scenarios.base import (
    Progress,
    ScenarioError,
    ScenarioOptions,
    format_table,
    graph_for,
    output_path,
    publish_all,
)
from mems_scenarios.figures import Figure, cell, figure_table
from mems_sim.devices.imu_profiles import load_profile
from mems_sim.nodes.imu_node import ImuNoiseNode

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


def build_graph(options: ScenarioOptions, out: Path, profile: str, duration_s: float | None):
    """Context, emulator, calibration node and recorder."""
    graph = graph_for(options)
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
    emu = graph.add_device(ImuNoiseNode, emu_params, realtime=options.realtime)
    cal = graph.node(
        ImuCalibrationNode,
        {
            "profile": profile,
            "noise_model": "adis16350",
            "temperature_source": "sensor",
            "output_yaml": str(output_path(out, options.seed, "-calibration.yaml")),
        },
        namespace="imu",
    )
    rec = graph.recorder(str(out), topics=TOPICS)
    return graph, emu, cal, rec


def _rms(x) -> float:
    x = np.asarray(list(x), float)
    return float(math.sqrt(np.mean(x * x))) if x.size else math.nan


def compare(cal: ic.ImuCalibration, truth: dict[str, float]) -> list[dict]:
    """Per estimated parameter: estimate, truth, error, 95 % interval, covered (aliased
    parameters -- not the parameter alone -- are left out)."""
    rows = []
    for n in cal.estimated:
        if n in cal.aliases or n not in truth:
            continue
        lo, hi = cal.ci95(n)
        rows.append(
            dict(
                name=n,
                estimate=cal.values[n],
                truth=truth[n],
                error=cal.values[n] - truth[n],
                ci95=(lo, hi),
                covered=bool(lo <= truth[n] <= hi),
                unit=ic.parameter_unit(n),
            )
        )
    return rows


def _target(value: float, limit: float, text: str, unit: str, name: str, ge=False) -> Figure:
    ok = math.isfinite(value) and (value >= limit if ge else value <= limit)
    return Figure(name, value, unit, f"{'>=' if ge else '<='} {limit:g}{text}", ok)


def multi_position_figures(rows: list[dict], gyro_b: float) -> list[Figure]:
    """The figures of the module docstring."""
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
    out.append(_target(_rms(rel), TEMPCO_REL, "", "1", "tempco.rel_error_rms"))
    return out


def coverage_figures(rows: list[dict]) -> list[Figure]:
    """Covered and total count of the 95 % intervals and their ratio."""
    covered = sum(r["covered"] for r in rows)
    total = len(rows)
    return [
        Figure("coverage.covered", covered, ""),
        Figure("coverage.total", total, ""),
        _target(covered / total if total else math.nan, COVERAGE, "", "1", "coverage", ge=True),
    ]


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
    return format_table(
        ["parameter", "unit", "truth", "estimate", "+-95 %", "error", "covered"], body
    )


def run_profile(options: ScenarioOptions, name: str, profile: str, thermal: bool) -> dict:
    """Run the graph on ``profile``; figures of the multi-position (and thermal) kind."""
    prof = load_profile(profile)
    duration = options.duration_s
    if duration is not None and duration <= 0:
        raise ScenarioError(f"--duration {duration!r} must be > 0 s")
    out = options.out or Path("runs") / f"{name}-{options.seed}.mcap"
    out.parent.mkdir(parents=True, exist_ok=True)
    graph, emu, cal, rec = build_graph(options, out, profile, duration)
    total = duration if duration is not None else prof.duration_s()
    progress = Progress(total, options.progress, name)
    try:
        publish_all(
            graph,
            [emu],
            lambda _: cal.frames_done,
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
            raise ScenarioError(
                "no calibration: too little data for the profile "
                f"{prof.name!r} ({prof.duration_s():g} s; give a longer --duration)"
            )
        graph.spin_until(
            lambda: rec.received("/imu/calibration") > before or before >= 1,
            20.0,
            "the recorder to receive the calibration",
        )
        truth = {n: v for n, v, _ in emu.model.calibration_truth()}
        gyro_b = float(emu.nominal["gyro_bias_instability"])
        result = cal.results[-1]
    finally:
        progress.close()
        rec.close()
        summary = dict(
            counts=rec.counts(), gaps=rec.gaps(), losses=rec.losses(), text=rec.summary()
        )
        graph.close()
    rows = compare(result, truth)
    figures = []
    if not thermal:
        figures += multi_position_figures(rows, gyro_b)
    else:
        figures += thermal_figures(rows)
    figures += coverage_figures(rows)
    table = results_table(rows) + "\n\n" + figure_table(figures)
    notes = [
        f"{n} {t} (not separable in {prof.name}: not judged)" for n, t in result.aliases.items()
    ]
    return dict(
        table=table + ("\n" + "\n".join(notes) if notes else ""),
        figures=figures,
        rows=rows,
        calibration=result,
        truth=truth,
        mcap=out,
        yaml=output_path(out, options.seed, "-calibration.yaml"),
        recorder=summary,
        duration_s=total,
    )


def run(options: ScenarioOptions) -> dict:
    """Run the scenario (multi_position profile)."""
    return run_profile(options, NAME, PROFILE, thermal=False)

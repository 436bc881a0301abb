"""Study ``stage_sf_curve``: the on-stage gyro's scale-factor curve SF(T) over 20-45 C from
in-situ calibrations on the drifting micro-stage (Chen 2018 ch. 3, sec. 3.3.1 eqs. 20-27 and
sec. 3.6.3, at more temperatures than the thesis' two).

Steps (all seeded; nothing reads the emulator's truth except the evaluation figures):

1. identification of the stage at 22.9 C (:func:`identify_stage`: frequency sweep, LDV
   training sweep, zero drive), on the ROS-free cores;
2. per calibration temperature (default 20, 25, ..., 45 C): (D_n [m], eta [-]) re-identified
   there with the LDV-like reference (eq. 55; the thesis' procedure at its second
   temperature: labelled "D_n, eta re-identified at each temperature") on the cores
   (:func:`reidentify_point`); then the calibration sweep with the gyro through ONE node
   graph (:func:`run_graph`): per temperature a drifting ``stage_node`` (namespace
   ``/stage_<T>C``, e.g. ``/stage_20C``, ``/stage_32p5C``; seeded as the cores' sweep, so
   its record equals theirs sample for sample), a ``stage_ekf_node`` in its in-situ mode
   loading the model re-identified at that temperature (eqs. 44-47 on the whole sweep,
   then the EKF of eqs. 48-53 on the corrected model) and a
   ``stage_gyro_calibration_node`` publishing ``/stage_<T>C/gyro_scale_factor`` (eq. 27),
   everything recorded to the MCAP file ``options.out``. The point SF(T_i) = k_I|S [-] is
   the recorded ``gyro_scale_factor``; the bootstrap over the training trials (the
   re-identification) and over the calibration trials runs on the cores, fed from the
   recording (the cancelled ADC channels' harmonics) and the published peak-to-peak pairs
   (:func:`graph_points`, :func:`bootstrap_point`);
3. SF(T) fitted linearly in T (the emulated MPU-6500-like gyro's scale factor is linear in
   T) with its 95 % band; written as a calibration YAML (format
   ``mems_emulator/gyro_sf_curve``) and plotted against the gyro's true curve.

The graph's points equal the cores' (:func:`run_pipeline`,
:func:`mems_estimation.studies.stage_sf_curve.sf_curve_study`, all on the cores) to
~1e-7 relative: the estimates are the same bit for bit, and the calibration node places the
gyro samples through their frames' integer-ns stamps, the core through exact times.

It is not (yet) a ``run_scenario`` scenario: run it with ``python -m
mems_scenarios.stage_sf_curve [--seed N] [--device-seed N] [--set stage.PARAM=VALUE ...]
[--out DIR] [--json] [--no-plots]`` (~1.2 min at the full plan); it writes the MCAP file
``<out>/stage_sf_curve-<N>.mcap``, the calibration YAML and the figure. Stage and gyro
parameters: ``--set stage.PARAM=VALUE`` (any of the stage node's device and gyro
parameters, reaching every stage node of the graph and the cores alike, e.g.
``stage.freq_tempco_per_k``, ``stage.b_c_tempco_per_k``, ``stage.damping_ratio``,
``stage.gyro_sf_tempco_per_k``), ``--device-seed``; ``--temperature`` is refused (the
scenario sets the temperatures). Options (:class:`SfCurveOptions`): ``short`` (test plan, 3
temperatures, 20 replicates), ``temperatures``, ``n_boot``, ``order``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mems_estimation.filters.stage_ekf import save_model
from mems_estimation.identification.stage_gyro_calibration import T1, Plan, identify_stage
from mems_estimation.studies.stage_sf_curve import (
    COVER_TARGET,
    DEFAULT_TEMPERATURES,
    MAX_DEV_TARGET_PPM,
    RANGE_C,
    CurvePoint,
    bootstrap_point,
    calibration_seeds,
    evaluate_curve,
    fit_sf_curve_points,
    point_rng,
    reidentify_point,
    save_yaml,
    sf_curve_study,
)
from mems_scenarios.figures import Figure, cell, met_cell, project_criterion
from mems_scenarios.gyro_calibration_drifting import ALPHA_SOURCE, OMEGA_RMSE_SOURCE
from mems_scenarios.stage_graph import run_stage_graph
from mems_sim.bag.output_paths import write_output
from mems_sim.devices.stage import STAGE_SPECS
from mems_sim.devices.stage_gyro import GYRO_SPECS, MemsGyro

NAME = "stage_sf_curve"
DESCRIPTION = (
    "drifting piezo micro-stage (Chen 2018 ch. 3): in-situ gyro scale-factor calibration at "
    "6 temperatures over 20-45 C, SF(T) fit with a bootstrap 95 % band -> calibration YAML"
)
#: simulated time per temperature (training 7 x 200 + calibration 7 x 400 periods at
#: 1700 Hz) times the 6 temperatures
DEFAULT_DURATION_S = round(6 * 7 * 600 / 1700.0, 3)
#: bootstrap replicates per temperature
N_BOOT = 100
#: the stage node's parameters that describe the device (the stage's physics, spreads and
#: temperature coefficients, its gyro's): the ones ``--set stage.PARAM=V`` may set
DEVICE_PARAMETERS = frozenset(s.name for s in STAGE_SPECS + GYRO_SPECS) - {
    "idealised",
    "temperature_c",
}


def namespace(temperature_c: float) -> str:
    """The namespace of the stage instance at ``temperature_c`` [C]: ``stage_20C``,
    ``stage_32p5C`` (a ROS name has no dot), ``stage_m5C``."""
    return "stage_" + f"{temperature_c:g}".replace(".", "p").replace("-", "m") + "C"


def stage_and_gyro_params(options, temperatures=DEFAULT_TEMPERATURES) -> tuple[dict, dict]:
    """Stage and gyro parameters from ``--set stage.PARAM=VALUE`` (reaching every stage node
    ``/stage_<T>C/stage`` of the run alike: the device is identified once, so graph and
    cores must see the same one) and ``--device-seed``, for the cores (identification and
    re-identification); the graph's stage nodes take the same overrides. ScenarioError for
    anything else."""
    from mems_scenarios.base import ScenarioError
    from mems_sim.ros.params_file import node_matches

    stage_names = {s.name: s for s in STAGE_SPECS}
    gyro_names = {s.name: s for s in GYRO_SPECS}
    fqns = [f"/{namespace(T)}/stage" for T in temperatures]
    sp, gp = {}, {}
    if options.temperature_c is not None:
        raise ScenarioError(
            f"{NAME}: --temperature does not apply: the scenario calibrates at "
            f"{', '.join(f'{t:g}' for t in temperatures)} C"
        )
    if options.device_seed is not None:
        sp["device_seed"] = int(options.device_seed)
    for o in options.overrides:
        hits = [f for f in fqns if node_matches(o.node, f)]
        if len(hits) < len(fqns):
            raise ScenarioError(
                f"{o.where()}: {NAME} takes device parameters of its stage nodes, all alike "
                f"({', '.join(fqns)}): set stage.PARAM"
            )
        if o.name in ("temperature_c", "idealised"):
            raise ScenarioError(f"{o.where()}: {NAME} sets {o.name} itself")
        if o.name not in DEVICE_PARAMETERS:
            raise ScenarioError(f"{o.where()}: the stage node has no device parameter {o.name!r}")
        specs = stage_names if o.name in stage_names else gyro_names
        try:
            value = specs[o.name].validate(o.value)
        except Exception as exc:  # ParameterError: one line naming the range
            raise ScenarioError(f"{o.where()}: {exc}") from None
        (sp if specs is stage_names else gp)[o.name] = value
    return sp, gp


def write_plot(path: Path, res: dict, ev: dict) -> Path:
    """SF(T): calibration points (bootstrap 95 % bars), fitted curve, band and the true
    curve; lower panel: deviation from the true curve [ppm] with the band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve, pts = res["curve"], res["points"]
    T = ev["temperatures"]
    lo, hi = curve.band(T)
    fig, (ax, ad) = plt.subplots(
        2, 1, figsize=(6.5, 6), sharex=True, gridspec_kw={"height_ratios": [2, 1]}
    )
    ax.fill_between(T, lo, hi, color="tab:blue", alpha=0.25, label="95 % band")
    ax.plot(T, curve(T), "b-", label=f"fit (order {curve.order})")
    ax.plot(T, ev["true"], "k--", label="true k_I(T) (emulator)")
    tp = np.array([p.temperature_c for p in pts])
    sf = np.array([p.scale_factor for p in pts])
    sd = np.array([np.std(p.boot, ddof=1) for p in pts])
    ax.errorbar(tp, sf, yerr=curve.t_quantile * sd, fmt="o", color="tab:red", label="eq. 27")
    ax.set_ylabel("gyro scale factor k_I [-]")
    ax.set_title("gyro SF(T) by in-situ stage calibration (D_n, eta re-id. per T)")
    ax.legend(fontsize=8)
    ad.fill_between(
        T, (lo / ev["true"] - 1) * 1e6, (hi / ev["true"] - 1) * 1e6, color="tab:blue", alpha=0.25
    )
    ad.plot(T, ev["deviation_ppm"], "b-")
    ptrue = np.array([MemsGyro(res.get("gyro_params")).scale_factor(t) for t in tp])
    ad.errorbar(
        tp,
        (sf / ptrue - 1) * 1e6,
        yerr=curve.t_quantile * sd / ptrue * 1e6,
        fmt="o",
        color="tab:red",
    )
    ad.axhline(0.0, color="k", lw=0.5)
    for s in (-1, 1):
        ad.axhline(s * MAX_DEV_TARGET_PPM, color="gray", lw=0.5, ls=":")
    ad.set_xlabel("temperature [C]")
    ad.set_ylabel("SF / true - 1 [ppm]")
    fig.tight_layout()
    write_output(path, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)
    return path


def figure_records(res: dict, ev: dict) -> list[Figure]:
    """Figures: per temperature the SF error [ppm] against the true k_I(T), the bootstrap
    standard deviation [ppm], the in-situ EKF's omega RMSE [rad/s] and alpha (targets of
    the thesis' Table 3.5: <= 0.114 rad/s, |alpha - 1| <= 8e-4); the curve's max deviation
    from the true curve [ppm] (<= 600), the share of test temperatures with the true curve
    inside the 95 % band (>= 0.85; the acceptance pools it over seeds), the fitted and true
    sf_tempco [1/K], the Birge ratio and the band's largest half width [ppm]."""
    figs = []
    for p in res["points"]:
        key = f"T{p.temperature_c:g}C"
        figs += [
            Figure(f"{key}.scale_factor", p.scale_factor, "1"),
            Figure(f"{key}.scale_factor_true", p.k_true, "1"),
            Figure(f"{key}.scale_factor_error", p.ppm, "ppm"),
            Figure(f"{key}.bootstrap_sd", p.boot_sd_ppm, "ppm"),
            Figure(
                f"{key}.omega_rmse",
                p.omega_rmse,
                "rad/s",
                "<= 0.114 rad/s",
                p.omega_rmse <= 0.114,
                OMEGA_RMSE_SOURCE,
            ),
            Figure(
                f"{key}.alpha",
                p.alpha,
                "1",
                "|alpha - 1| <= 8e-4",
                abs(p.alpha - 1) <= 8e-4,
                ALPHA_SOURCE,
            ),
        ]
    c = res["curve"]
    cover = float(np.mean(ev["inside"]))
    figs += [
        Figure(
            "curve.max_deviation",
            ev["max_dev_ppm"],
            "ppm",
            f"<= {MAX_DEV_TARGET_PPM:g} ppm",
            ev["max_dev_ppm"] <= MAX_DEV_TARGET_PPM,
            project_criterion("twice the drifting stage's per-point 300 ppm, over 20-45 C"),
        ),
        Figure(
            "curve.band_coverage",
            cover,
            "1",
            f">= {COVER_TARGET:g}",
            cover >= COVER_TARGET,
            project_criterion("a 95 % band, per run; the acceptance pools it over seeds"),
        ),
        Figure("curve.band_half_width_max", float(np.max(ev["half_width_ppm"])), "ppm"),
        Figure("curve.birge_ratio", c.birge, "1"),
        Figure("curve.sf_tempco", c.sf_tempco, "1/K"),
        Figure("curve.sf_tempco_true", ev["sf_tempco_true"], "1/K"),
        Figure("curve.scale_factor_t_ref", float(c.coef[0]), "1"),
    ]
    return figs


def run_pipeline(
    seed: int,
    plan: Plan | None = None,
    stage_params: dict | None = None,
    gyro_params: dict | None = None,
    temperatures=DEFAULT_TEMPERATURES,
    n_boot: int = N_BOOT,
    order: int = 1,
) -> dict:
    """Steps 1-3 all on the ROS-free cores (:func:`sf_curve_study`; no node graph) and the
    figure records: the reference the graph's points equal."""
    res = sf_curve_study(seed, plan, stage_params, gyro_params, temperatures, n_boot, order)
    res["figures"] = figure_records(res, res["evaluation"])
    return res


def run_graph(options, plan: Plan, models: dict, out: Path) -> dict:
    """Step 2 through one node graph, recorded to ``out``: per temperature T of ``models``
    (T -> the stage model with D_n, eta re-identified at T: :func:`reidentify_point`) a
    drifting ``stage_node`` in the namespace :func:`namespace` seeded as the cores'
    calibration sweep (:func:`calibration_seeds`: its record equals the cores' sample for
    sample), a ``stage_ekf_node`` in its in-situ mode loading that model's parameter YAML
    (Chen 2018 eqs. 44-47: the sweep processed once the stage announced its end, then the
    EKF of eqs. 48-53 on the corrected model) and a ``stage_gyro_calibration_node``
    publishing ``/<ns>/gyro_scale_factor`` (eq. 27). Returns the published results (with
    their peak-to-peak pairs), the true k_I(T) per namespace, the recorder's summary, the
    frames published and rejected, the in-situ corrections, simulated and wall time [s]."""
    from mems_scenarios.base import output_path

    seed = int(options.seed)
    layout: dict[str, tuple[dict, Path]] = {}
    for T, model in models.items():
        ns = namespace(T)
        yaml_path = output_path(out, seed, f"-stage_params_{ns.removeprefix('stage_')}.yaml")
        save_model(model, str(yaml_path))
        stage_seed, gyro_seed = calibration_seeds(T, seed)
        stage = dict(
            seed=stage_seed,
            gyro_seed=gyro_seed,
            idealised=False,
            temperature_c=float(T),
            n_trials=plan.cal_trials,
            periods_per_trial=plan.cal_periods,
        )
        layout[ns] = (stage, yaml_path)

    return run_stage_graph(
        options,
        {ns: (stage, yaml_path, {"insitu": True}) for ns, (stage, yaml_path) in layout.items()},
        out,
        NAME,
    )


def graph_points(
    out: Path, g: dict, models: dict, fits: dict, seed: int, n_boot: int
) -> list[CurvePoint]:
    """The calibration points from the recording ``out`` and the graph's results ``g``
    (:func:`run_graph`): SF(T) = k_I|S [-] and its standard error are the recorded
    ``gyro_scale_factor`` (eq. 27); the omega RMSE [rad/s] and alpha of the recorded
    estimates against the recorded truth; the bootstrap (:func:`bootstrap_point`) on the
    same data: the recorded ADC channels, feedthrough-cancelled, give the per-trial
    harmonics and pooled response G of the in-situ correction (eqs. 44, 46-47, as the EKF
    node computed them), the calibration node's published pairs the peak-to-peak pairs,
    ``fits`` (T -> the training trials' fits) the re-identification's trials."""
    from mems_estimation.filters.stage_ekf import FeedthroughCanceller
    from mems_estimation.identification.stage_identification import evaluate
    from mems_estimation.identification.stage_insitu import insitu_correct
    from mems_scenarios.bag_frames import topics_frames
    from mems_scenarios.base import ScenarioError
    from mems_sim.bag.player import read_messages

    nss = {namespace(T): T for T in models}
    fr = topics_frames(
        out, [f"/{ns}/{t}" for ns in nss for t in ("adc", "drive", "truth", "estimate")]
    )
    sf_topics = [f"/{ns}/gyro_scale_factor" for ns in nss]
    recorded = {t: m for t, _, _, m in read_messages(str(out), sf_topics)}  # the last one
    pts = []
    for ns, T in nss.items():
        m = models[T]
        if f"/{ns}/gyro_scale_factor" not in recorded:
            raise ScenarioError(f"{out}: no gyro_scale_factor recorded for /{ns}")
        msg = recorded[f"/{ns}/gyro_scale_factor"]
        drv, adc = fr[f"/{ns}/drive"], fr[f"/{ns}/adc"]
        est, tru = fr[f"/{ns}/estimate"]["data"], fr[f"/{ns}/truth"]

        def col(frame, name):
            return np.ascontiguousarray(frame["data"][:, list(frame["names"]).index(name)])

        u, vb, fd, phase = (col(drv, c) for c in ("u", "v_bias", "f_drive", "phase"))
        trial = col(drv, "trial").astype(int)
        y = np.ascontiguousarray(adc["data"][:, [list(adc["names"]).index(c) for c in m.channels]])
        yc = FeedthroughCanceller(len(m.channels), m.fs).step(y, vb, fd)
        _, rep = insitu_correct(m, yc, u, phase, trial, fd)
        n = min(len(est), len(phase))
        ev = evaluate(est[:n, 1], col(tru, "omega_y")[:n], phase[:n], trial[:n])
        boot = bootstrap_point(
            m,
            fits[T],
            rep["harmonics"],
            rep["G"],
            g["results"][ns]["pairs"],
            n_boot,
            point_rng(seed, T),
        )
        pts.append(
            CurvePoint(
                float(T),
                float(msg.values[0]),
                float(msg.standard_errors[0]),
                boot,
                float(g["k_true"][ns]),
                float(ev["rmse"]),
                float(ev["alpha"]),
                complex(rep["G"]),
                m.gap,
                m.eta,
                g["results"][ns]["pairs"],
            )
        )
    return pts


def run_graph_pipeline(
    options,
    out: Path,
    plan: Plan,
    stage_params: dict,
    gyro_params: dict,
    temperatures,
    n_boot: int,
    order: int,
) -> dict:
    """Steps 1-3 with step 2 through the node graph: the identification at 22.9 C and the
    (D_n, eta) re-identification per temperature on the cores (:func:`identify_stage`,
    :func:`reidentify_point`), the calibration sweeps through one recorded graph
    (:func:`run_graph`), the points from the recording (:func:`graph_points`), the fit
    and its evaluation; the figure records."""
    seed = int(options.seed)
    model, _ = identify_stage(seed, plan, stage_params)
    models, fits = {}, {}
    for T in temperatures:
        models[T], fits[T] = reidentify_point(model, T, seed, plan, stage_params)
    g = run_graph(options, plan, models, out)
    pts = graph_points(out, g, models, fits, seed, n_boot)
    res = {"points": pts, "curve": fit_sf_curve_points(pts, order), "model": model}
    res["gyro_params"] = gyro_params
    res["graph"] = g
    res["evaluation"] = evaluate_curve(res["curve"], gyro_params)
    res["figures"] = figure_records(res, res["evaluation"]) + [
        Figure("graph.simulated_time", g["simulated_s"], "s"),
        Figure("graph.wall_time", g["wall_s"], "s"),
    ]
    return res


def table_rows(res: dict) -> list[list[str]]:
    """The scenario's table: one row per temperature and the curve's rows."""
    F = {f.name: f for f in res["figures"]}
    ev, c = res["evaluation"], res["curve"]
    rows = []
    for p in res["points"]:
        key = f"T{p.temperature_c:g}C"
        rows.append(
            [
                f"SF_IMU (true {cell(p.k_true, '.5f')})",
                f"{p.temperature_c:g} C",
                f"{cell(p.scale_factor, '.5f')} ({cell(p.ppm, '+.0f')} ppm, boot. sd "
                f"{cell(p.boot_sd_ppm, '.0f')})",
                f"RMSE {cell(p.omega_rmse, '.4f')} rad/s, alpha {cell(p.alpha, '.5f')}",
                met_cell(F[f"{key}.omega_rmse"], F[f"{key}.alpha"]),
            ]
        )
    rows += [
        [
            f"SF(T) fit, order {c.order}: max |dev.|",
            f"{RANGE_C[0]:g}-{RANGE_C[1]:g} C",
            f"{cell(ev['max_dev_ppm'], '.0f')} ppm",
            f"<= {MAX_DEV_TARGET_PPM:g} ppm",
            met_cell(F["curve.max_deviation"]),
        ],
        [
            "true curve inside the 95 % band",
            f"{ev['inside'].size} temps, 1 K apart",
            f"{cell(100 * F['curve.band_coverage'].value, '.0f')} %, half width <= "
            f"{cell(F['curve.band_half_width_max'].value, '.0f')} ppm",
            f">= {100 * COVER_TARGET:g} % (pooled over seeds)",
            met_cell(F["curve.band_coverage"]),
        ],
        [
            "sf_tempco (fit / true)",
            f"t_ref {c.t_ref_c:g} C",
            f"{cell(1e6 * c.sf_tempco, '.1f')} / {cell(1e6 * ev['sf_tempco_true'], '.1f')} ppm/K",
            f"Birge ratio {cell(c.birge, '.2f')}",
            "-",
        ],
    ]
    return rows


def options_class():
    """The study's options: :class:`~mems_scenarios.base.ScenarioOptions` with
    ``temperatures`` [degC] (None: the plan's), ``n_boot`` (bootstrap replicates, None: the
    plan's) and ``order`` (polynomial order of SF(T), None: 1)."""
    from dataclasses import dataclass

    from mems_scenarios.base import ScenarioOptions

    @dataclass
    class SfCurveOptions(ScenarioOptions):
        temperatures: tuple[float, ...] | None = None
        n_boot: int | None = None
        order: int | None = None

    return SfCurveOptions


def run(options) -> dict:
    """The study ``stage_sf_curve``: identification and re-identification per temperature
    on the cores, the calibration sweeps through the node graph recorded to
    ``options.out``, SF(T) fit, YAML and figure."""
    from mems_scenarios.base import ScenarioError, format_table, output_path

    if options.duration_s not in (None, 0.0):
        raise ScenarioError(f"{NAME}: the duration follows from the drive schedules; omit it")
    short = bool(options.short)
    plan = Plan.short() if short else Plan()
    temps = tuple(
        float(t)
        for t in getattr(options, "temperatures", None)
        or ((20.0, 32.5, 45.0) if short else DEFAULT_TEMPERATURES)
    )
    n_boot = int(getattr(options, "n_boot", None) or (20 if short else N_BOOT))
    order = int(getattr(options, "order", None) or 1)
    if len(temps) < order + 2 or min(temps) < -60 or max(temps) > 150:
        raise ScenarioError(f"{NAME}: needs >= {order + 2} temperatures in [-60, 150] C")
    if len({namespace(t) for t in temps}) < len(temps):
        raise ScenarioError(f"{NAME}: the temperatures must be distinct")
    sp, gp = stage_and_gyro_params(options, temps)
    seed = int(options.seed)
    out = Path(options.out or Path("runs") / f"{NAME}-{seed}.mcap")
    out.parent.mkdir(parents=True, exist_ok=True)
    res = run_graph_pipeline(options, out, plan, sp, gp, temps, n_boot, order)
    g = res["graph"]
    yaml_path = output_path(out, seed, "-sf_curve.yaml")
    save_yaml(
        res["curve"],
        yaml_path,
        info={
            "seed": seed,
            "stage_params": {k: (float(v) if isinstance(v, float) else v) for k, v in sp.items()},
            "gyro_params": {k: float(v) for k, v in gp.items()},
            "training_temperature_c": T1,
            "sensor_parameters": "D_n, eta re-identified at each temperature (LDV-like reference)",
            "bootstrap_replicates": n_boot,
            "calibration_trials": plan.cal_trials,
            "periods_per_trial": plan.cal_periods,
        },
    )
    plots = []
    if options.plots:
        plots.append(write_plot(output_path(out, seed, "-sf_curve.png"), res, res["evaluation"]))
    table = format_table(
        ["quantity", "condition", "value", "target / note", "met"], table_rows(res)
    )
    table += (
        "\nSF(T) from D_n, eta re-identified at each temperature with the LDV-like "
        "reference (cores); calibration sweeps through the node graph "
        f"({', '.join('/' + namespace(t) for t in temps)}), recorded to {out}; "
        f"calibration YAML: {yaml_path}"
    )
    return {
        "table": table,
        "figures": res["figures"],
        "duration_s": g["simulated_s"],
        "wall_s": g["wall_s"],
        "mcap": str(out),
        "recorder": g["recorder"],
        "published": g["published"],
        "rejected": g["rejected"],
        "insitu": g["insitu"],
        "figure": ", ".join(str(p) for p in plots),
        "curve": res["curve"],
        "points": res["points"],
        "model": res["model"],
        "evaluation": res["evaluation"],
        "yaml": str(yaml_path),
        "sf_max_dev_ppm": res["evaluation"]["max_dev_ppm"],
    }


def main(argv: list[str] | None = None) -> int:
    """``python -m mems_scenarios.stage_sf_curve``: the study for one seed (module docstring).
    Exit status 0, or 2 with one line on bad input."""
    import argparse
    import sys

    from mems_scenarios.base import ScenarioError, ScenarioOptions
    from mems_scenarios.figures import result_json
    from mems_sim.params import ParameterError
    from mems_sim.ros.params_file import ParamsFileError, parse_set

    p = argparse.ArgumentParser(prog="python -m mems_scenarios.stage_sf_curve")
    p.add_argument("--seed", type=int, default=1, metavar="N", help="run seed (default 1)")
    p.add_argument("--device-seed", type=int, default=None, metavar="N")
    p.add_argument("--set", dest="set_params", action="append", default=[], metavar="stage.P=V")
    p.add_argument("--out", type=Path, default=Path("runs"), metavar="DIR")
    p.add_argument("--json", action="store_true", help="print the figures as JSON records")
    p.add_argument("--no-plots", action="store_true")
    args = p.parse_args(argv)
    try:
        if args.seed < 0 or (args.device_seed is not None and args.device_seed < 0):
            raise ScenarioError("--seed and --device-seed must be >= 0")
        args.out.mkdir(parents=True, exist_ok=True)
        options = ScenarioOptions(
            seed=args.seed,
            out=args.out / f"{NAME}-{args.seed}.mcap",
            progress=False,
            plots=not args.no_plots,
            overrides=[parse_set(text) for text in args.set_params],
            device_seed=args.device_seed,
        )
        result = run(options)
    except (ScenarioError, ParameterError, ParamsFileError, OSError, ValueError) as exc:
        print(f"stage_sf_curve: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if args.json:
        print(result_json(NAME, result["figures"]))
    else:
        print(result["table"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The report of scenario ``gyro_calibration`` from its figures: the figure records of the
instances, the main table and the PNG figures in the forms of the thesis' Figs. 3.14-3.15
(the scenario itself: :mod:`mems_scenarios.gyro_calibration`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mems_estimation.identification.stage_gyro_calibration import T1, T2
from mems_estimation.identification.stage_identification import fold_period
from mems_scenarios.figures import Figure, cell, is_finite, met_cell, project_criterion
from mems_scenarios.gyro_calibration_drifting import (
    ALPHA_SOURCE,
    INSTANCES,
    OFF_AXIS_SOURCE,
    OFF_AXIS_WORST_TARGETS,
    OMEGA_RMSE_SOURCE,
    off_axis_target_text,
)
from mems_sim.bag.output_paths import write_output
from mems_sim.table import format_table

#: Where the drift-free stage's scale-factor target comes from.
SF_SOURCE = project_criterion(
    "a stage without drift, well below the thesis' 286 ppm RMS (Chen 2018 Table 3.6)"
)


def write_plots(out: Path, runs: dict, seed: int, paths: tuple | None = None) -> list[Path]:
    """Fig. 3.14-like averaged period and Fig. 3.15-like peak-to-peak plot, beside the MCAP
    file ``out`` and named with the run seed (``<stem>-seed<N>-period.png``,
    ``-peak_to_peak.png``), or at ``paths`` (period, peak-to-peak)."""
    import matplotlib

    from mems_scenarios.base import output_path

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    r = runs[T1]
    rec = r["rec"]
    last = rec["segment"] == rec["segment"].max()
    idx = np.flatnonzero(last)
    idx = idx[idx.size // 2 :]
    fe = fold_period(r["x"][idx, 1], rec["phase"][idx])
    ft = fold_period(rec["omega"][idx, 0], rec["phase"][idx])
    fig, (ax, ae) = plt.subplots(
        2, 1, figsize=(6, 5), sharex=True, gridspec_kw={"height_ratios": [2, 1]}
    )
    ph = (np.arange(fe.size) + 0.5) / fe.size
    ax.plot(ph, ft, "k-", label="truth")
    ax.plot(ph, fe, "r--", label="EKF (stage)")
    ax.set_ylabel("omega [rad/s]")
    ax.legend()
    ax.set_title(f"one averaged period, last trial, 1700 Hz, {T1} C")
    err = fe - ft  # the estimate's error is small against omega: its own panel
    ae.plot(ph, 1e3 * err, "r-")
    ae.axhline(0.0, color="k", lw=0.5)
    ae.set_xlabel("drive phase [cycles]")
    ae.set_ylabel("EKF - truth [mrad/s]")
    ae.set_title(f"error, RMS {1e3 * np.sqrt(np.mean(err**2)):.2f} mrad/s", fontsize=9)
    fig.tight_layout()
    if paths is None:
        paths = (output_path(out, seed, "-period.png"), output_path(out, seed, "-peak_to_peak.png"))
    p = paths[0]
    write_output(p, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)
    written.append(p)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for (T, r), color in zip(runs.items(), ("tab:blue", "tab:red")):
        s = np.array([q["stage_pp"] for q in r["cal"]["pairs"]])
        g = np.array([q["gyro_pp"] for q in r["cal"]["pairs"]])
        ax.plot(s, g, "o", color=color, label=f"{T} C")
        xs = np.linspace(s.min(), s.max(), 2)
        ax.plot(
            xs,
            r["cal"]["scale_factor"] * xs + r["cal"]["bias"],
            "-",
            color=color,
            label=f"eq. 27 fit: SF {r['cal']['scale_factor']:.5f} "
            f"+- {r['cal']['scale_factor_se']:.5f}",
        )
    ax.set_xlabel("stage omega_pp [rad/s]")
    ax.set_ylabel("gyro omega_pp [rad/s]")
    ax.set_title("gyro vs stage peak-to-peak rate per trial")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = paths[1]
    write_output(p, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)
    written.append(p)
    return written


def instance_figures(ns: str, T: float, ev: dict, cal: dict) -> list[Figure]:
    """The figures of stage instance ``ns`` at ``T`` [C] that its recording gives: omega
    RMSE [rad/s], alpha, beta [rad/s] (``ev``) and the published scale factor with its
    standard error (``cal``)."""
    return [
        Figure(f"{ns}.temperature", T, "C"),
        Figure(
            f"{ns}.omega_rmse",
            ev["rmse"],
            "rad/s",
            "<= 0.114 rad/s",
            ev["rmse"] <= 0.114,
            OMEGA_RMSE_SOURCE,
        ),
        Figure(
            f"{ns}.alpha",
            ev["alpha"],
            "1",
            "|alpha - 1| <= 8e-4",
            abs(ev["alpha"] - 1) <= 8e-4,
            ALPHA_SOURCE,
        ),
        Figure(f"{ns}.beta", ev["beta"], "rad/s"),
        Figure(f"{ns}.scale_factor", cal["scale_factor"], "1"),
        Figure(f"{ns}.scale_factor_se", cal["scale_factor_se"], "1"),
    ]


def figure_records(off_axis: list, figs: dict, rms: float, g: dict) -> list[Figure]:
    """The scenario's figures as data: off-axis rejection (fraction) per off-axis share, per
    stage instance omega RMSE [rad/s], alpha, beta [rad/s], the gyro scale factor, its
    standard error, the true one and the error [ppm]; the RMS error over the temperatures
    [ppm]; the graph's simulated and wall time [s]."""
    out = [
        Figure(
            f"off_axis_{100 * r:g}pct.rejection",
            v,
            "1",
            f">= {OFF_AXIS_WORST_TARGETS[r]:g}",
            v >= OFF_AXIS_WORST_TARGETS[r],
            OFF_AXIS_SOURCE,
        )
        for r, v in off_axis
    ]
    for ns, T in INSTANCES.items():
        f = figs[T]
        out += instance_figures(ns, T, f["eval"], f["cal"]) + [
            Figure(f"{ns}.scale_factor_true", f["k_true"], "1"),
            Figure(f"{ns}.scale_factor_error", f["ppm"], "ppm"),
        ]
    out += [
        Figure("scale_factor_error_rms", rms, "ppm", "<= 100 ppm", rms <= 100, SF_SOURCE),
        Figure("graph.simulated_time", g["simulated_s"], "s"),
        Figure("graph.wall_time", g["wall_s"], "s"),
    ]
    return out


def main_table(figures: list, off_axis: list, figs: dict, rms: float, g: dict, realtime: bool):
    """The drift-free stage's table in the form of Tables 3.4-3.6."""

    F = {r.name: r for r in figures}
    rows = [
        [
            "off-axis rejection R_off",
            f"{100 * r:g} % off-axis",
            cell(100 * v if is_finite(v) else v, ".3f", " %"),
            off_axis_target_text(r),
            met_cell(F[f"off_axis_{100 * r:g}pct.rejection"]),
        ]
        for r, v in off_axis
    ]
    for ns, T in INSTANCES.items():
        rows += [
            [
                "omega RMSE (1 period avg)",
                f"{T} C",
                f"{cell(F[f'{ns}.omega_rmse'].value, '.4f')} rad/s",
                "<= 0.114 (paper 0.1140)",
                met_cell(F[f"{ns}.omega_rmse"]),
            ],
            [
                "stage alpha / beta",
                f"{T} C",
                f"{cell(F[f'{ns}.alpha'].value, '.5f')} / {cell(F[f'{ns}.beta'].value, '+.4f')}",
                "|a-1| <= 8e-4 (paper 1.0008/-0.0207)",
                met_cell(F[f"{ns}.alpha"]),
            ],
        ]
    for ns, T in INSTANCES.items():
        f = figs[T]
        rows.append(
            [
                f"SF_IMU by stage (true {cell(f['k_true'], '.5f')})",
                f"{T} C",
                f"{cell(f['cal']['scale_factor'], '.5f')} +- "
                f"{cell(f['cal']['scale_factor_se'], '.5f')}",
                f"{cell(f['ppm'], '+.0f')} ppm (paper -340/+220)",
                "-",
            ]
        )
    rows.append(
        [
            "SF error RMS over temps",
            f"{T1}/{T2} C",
            f"{cell(rms, '.0f')} ppm",
            "<= 100 ppm (paper 286)",
            met_cell(F["scale_factor_error_rms"]),
        ]
    )
    rows.append(
        [
            "graph",
            "fast" if not realtime else "realtime",
            f"{g['simulated_s']:.2f} s sim in {g['wall_s']:.1f} s wall",
            f"RTF {g['simulated_s'] / g['wall_s']:.2f}",
            "-",
        ]
    )
    return format_table(["quantity", "condition", "value", "target / note", "met"], rows)

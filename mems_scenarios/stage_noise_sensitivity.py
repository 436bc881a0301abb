"""Study ``stage_noise_sensitivity``: standard deviation of the gyro scale-factor error [ppm]
against the capacitive readout's noise variance, split by the mechanism through which the
noise acts (Chen 2018 sec. 3.6, Fig. 3.16), for the project's in-situ calibration design at
the temperature of use (35.7 C, sensor parameters D_n, eta re-identified there with the
LDV-like reference, eq. 55; in-situ correction of wn, b_c; EKF eqs. 48-53 with alpha = 1,
beta = 0; eq. 27).

Mechanisms, each isolated (everything else true and noise-free; the study reads the
emulator's truth, as a sensitivity analysis does): identification of D_n, of eta (the
thesis' G), of both jointly; the in-situ phasor fit; the EKF fed the noisy channels with a
perfectly identified model (the "stochastic error", with the design's model-driven Q and
with the thesis' measurement-driven Q); and the design end to end. Details:
:mod:`mems_estimation.studies.stage_noise_sensitivity`.

Run: ``python -m mems_scenarios.stage_noise_sensitivity [--seeds 2,3,...] [--scales
0.5,1,2,4] [--short] [--out DIR] [--no-plots]``; prints the table and writes
``DIR/stage_noise_sensitivity.png`` (log-log, like Fig. 3.16). The default (the design's
plan: 7 training trials of 200 periods, 7 calibration trials of 400 periods, 4 levels x 10
seeds) takes about 3-4 minutes of one core; ``--short`` uses the short plan.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mems_estimation.identification.stage_gyro_calibration import Plan
from mems_estimation.studies.stage_noise_sensitivity import (
    IDENTIFICATION,
    MECHANISMS,
    NOISE_SCALES,
    noise_sensitivity_study,
)
from mems_sim.bag.output_paths import write_output
from mems_sim.table import format_table

NAME = "stage_noise_sensitivity"
#: default evaluation seeds (seed 1, the tuning seed of the design, excluded)
DEFAULT_SEEDS = tuple(range(2, 12))
#: column labels of the mechanisms
LABELS = {
    "dn": "D_n id.",
    "eta": "eta id.",
    "dn_eta": "D_n+eta id.",
    "insitu": "in-situ fit",
    "ekf": "EKF (stoch.)",
    "ekf_md": "EKF, meas.-driven Q",
    "design": "design end-to-end",
}
STYLES = {
    "dn": ("tab:red", "o-"),
    "eta": ("tab:orange", "s-"),
    "dn_eta": ("tab:brown", "D-"),
    "insitu": ("tab:purple", "^-"),
    "ekf": ("tab:blue", "v-"),
    "ekf_md": ("tab:cyan", "v--"),
    "design": ("k", "x-"),
}


def table(res: dict) -> str:
    """One row per noise level: scale on the RMS, variance [V^2], std [ppm] of every
    mechanism, the covariance predictions of the stochastic error [ppm], the root-sum-square
    of the design's independent contributions [ppm] and whether the identification terms
    exceed the stochastic term (lower 95 % bound of the identification std above the upper
    bound of the EKF's)."""
    header = ["s (x RMS)", "var [V^2]"] + [LABELS[m] for m in MECHANISMS]
    header += ["cov. pred. EKF / meas.-dr.", "RSS id+fit+EKF", "id > stoch."]
    rows = []
    for lv in res["summary"]:
        lo_id = min(lv.interval[m][0] for m in IDENTIFICATION)
        rows.append(
            [f"{lv.noise_scale:g}", f"{lv.variance_v2:.3g}"]
            + [f"{lv.std[m]:.3g}" for m in MECHANISMS]
            + [
                f"{lv.cov_pred['ekf']:.3g} / {lv.cov_pred['ekf_md']:.3g}",
                f"{lv.rss:.3g}",
                "yes" if lo_id > lv.interval["ekf"][1] else "NO",
            ]
        )
    means = [
        [f"{lv.noise_scale:g}", "mean [ppm]"] + [f"{lv.mean[m]:+.3g}" for m in MECHANISMS]
        for lv in res["summary"]
    ]
    ident = []
    for lv in res["summary"]:
        cs = [c for c in res["cells"] if c["noise_scale"] == lv.noise_scale]
        rms = {
            k: float(np.sqrt(np.mean(np.concatenate([c[k] for c in cs]) ** 2)))
            for k in ("gap_rel_error", "eta_rel_error", "eta_tg_rel_error")
        }
        ident.append(
            [
                f"{lv.noise_scale:g}",
                f"{1e6 * rms['gap_rel_error']:.3g}",
                f"{1e6 * rms['eta_rel_error']:.3g}",
                f"{1e6 * rms['eta_tg_rel_error']:.3g}",
            ]
        )
    plan = res["plan"]
    n = res["summary"][0].n
    return "\n".join(
        [
            "std of the SF error [ppm] over "
            f"{n} seeds ({', '.join(str(s) for s in res['seeds'])}) at "
            f"{res['temperature_c']:g} C; default readout RMS "
            f"{res['noise_std_default_v']:.3g} V per sample",
            format_table(header, rows),
            "",
            "mean SF error [ppm] per mechanism (method bias; noise-free pipeline with the true "
            f"model: {res['baseline_ppm']:+.2f} ppm)",
            format_table(["s (x RMS)", ""] + [LABELS[m] for m in MECHANISMS], means),
            "",
            "identified sensor parameters, RMS relative error over seeds and channels [ppm]",
            format_table(["s (x RMS)", "D_n (eq. 55 a)", "eta, joint", "eta, true D_n"], ident),
            "",
            f"plan: training {plan.train_trials} x {plan.train_periods} periods, calibration "
            f"{plan.cal_trials} x {plan.cal_periods} periods; {len(res['cells'])} cells in "
            f"{res['seconds']:.0f} s",
        ]
    )


def write_plot(path: Path, res: dict) -> Path:
    """Log-log std [ppm] against the readout noise variance [V^2] per mechanism (with 95 %
    intervals of the std), like Chen 2018 Fig. 3.16; the covariance prediction of the
    stochastic error dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sm = res["summary"]
    v = np.array([lv.variance_v2 for lv in sm])
    fig, ax = plt.subplots(figsize=(7, 5))
    for m in MECHANISMS:
        c, ls = STYLES[m]
        y = np.array([lv.std[m] for lv in sm])
        lo = np.array([lv.interval[m][0] for lv in sm])
        hi = np.array([lv.interval[m][1] for lv in sm])
        ax.errorbar(v, y, yerr=[y - lo, hi - y], fmt=ls, color=c, capsize=3, label=LABELS[m])
    ax.plot(
        v, [lv.cov_pred["ekf"] for lv in sm], ":", color="tab:blue", label="EKF cov. prediction"
    )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("readout noise variance per sample [V^2]")
    ax.set_ylabel("std of SF calibration error [ppm]")
    ax.set_title(
        f"SF error by mechanism, in-situ design at {res['temperature_c']:g} C "
        f"({sm[0].n} seeds; cf. Chen 2018 Fig. 3.16)",
        fontsize=9,
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    write_output(path, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)
    return path


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(t) for t in text.split(",") if t.strip())


def main(argv: list[str] | None = None) -> int:
    """``python -m mems_scenarios.stage_noise_sensitivity``: the study (module doc); exit
    status 0, or 2 with one line on bad input."""
    import argparse
    import sys

    p = argparse.ArgumentParser(prog=f"python -m mems_scenarios.{NAME}")
    p.add_argument(
        "--seeds",
        default=",".join(str(s) for s in DEFAULT_SEEDS),
        metavar="N,N,...",
        help="evaluation seeds (default 2-11)",
    )
    p.add_argument(
        "--scales",
        default=",".join(f"{s:g}" for s in NOISE_SCALES),
        metavar="S,S,...",
        help="factors on the readout's RMS noise (default 0.5,1,2,4)",
    )
    p.add_argument("--short", action="store_true", help="short plan (test size)")
    p.add_argument("--out", type=Path, default=Path("runs"), metavar="DIR")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--progress", action="store_true", help="one line per cell on stderr")
    args = p.parse_args(argv)
    try:
        seeds = tuple(int(s) for s in _floats(args.seeds))
        scales = _floats(args.scales)
        if len(seeds) < 2 or min(seeds) < 0:
            raise ValueError("--seeds: at least two seeds >= 0")
        if not scales or min(scales) <= 0 or not all(math.isfinite(s) for s in scales):
            raise ValueError("--scales: positive factors")
        progress = None
        if args.progress:

            def progress(c):
                print(
                    f"s={c['noise_scale']:g} seed={c['seed']}: "
                    + " ".join(f"{k}={v:+.1f}" for k, v in c["ppm"].items())
                    + f" ({c['seconds']:.1f} s)",
                    file=sys.stderr,
                )

        res = noise_sensitivity_study(
            scales, seeds, Plan.short() if args.short else Plan(), progress=progress
        )
        print(table(res))
        if not args.no_plots:
            args.out.mkdir(parents=True, exist_ok=True)
            print(f"figure: {write_plot(args.out / f'{NAME}.png', res)}")
    except (ValueError, OSError) as exc:
        print(f"{NAME}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

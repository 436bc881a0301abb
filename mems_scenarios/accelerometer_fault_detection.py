"""Study ``accelerometer_fault_detection``: how well the accelerometer's downstream EKF
(Zhang 2010, eqs. 4-48 .. 4-57) finds readout faults with its windowed NIS monitor, per
fault kind and magnitude, over noise seeds and drawn devices; its ROS-free core is
:mod:`mems_estimation.studies.accelerometer_fault_detection` (design, units of the
magnitudes, scoring).

The EKF runs on the nominal model (an ``oracle`` model for a drawn device). The monitor's
calibration is each device's own NIS moments from fault-free bench runs on noise seeds 1
and 2 (``--calibration bench``, the default), or the filter's table moments, measured on
the nominal device (``--calibration table``: an oracle for a drawn device; it gives 0 to
700x the designed false alarms on drawn devices 13 and 14).

Run: ``python -m mems_scenarios.accelerometer_fault_detection [--seeds 3,4]
[--devices nominal,11] [--kinds bias_step,...] [--calibration bench|table]
[--fault-free-samples N] [--out DIR] [--no-plots] [--json] [--progress]``; prints one row
per kind (detection probability per magnitude, the magnitude at 95 %, delays, error ratios)
and the fault-free false alarms against the designed rate, and writes
``DIR/accelerometer_fault_detection.png`` (detection curves). The default (2 seeds, the
nominal device, every kind) takes about a minute of one core.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from mems_estimation.studies import accelerometer_fault_detection as study
from mems_sim.bag.output_paths import write_output
from mems_sim.table import format_table

NAME = "accelerometer_fault_detection"
UNITS = {
    "bias_step": "sigma_nu",
    "spikes": "sigma_nu",
    "saturation": "sigma_nu",
    "bias_ramp": "sigma_nu/ms",
    "noise_burst": "x std",
    "scale_step": "-",
    "stuck_at": "-",
    "sign_flip": "-",
}


def _g(x) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.3g}"


def table(res: dict) -> str:
    """One row per kind and magnitude, then the false alarms."""
    header = [
        "kind",
        "magnitude",
        "trials",
        "P(detect)",
        "P two-sided",
        "delay med / p95 [ms]",
        "err during / after (x fault-free)",
    ]
    rows = []
    for kind, k in res["kinds"].items():
        for i, m in enumerate(k["magnitudes"]):
            d = k["delays_s"][i]
            rows.append(
                [
                    kind if i == 0 else "",
                    f"{m:g} {UNITS.get(kind, '')}",
                    str(k["trials"][i]),
                    f"{k['probability'][i]:.2f}",
                    f"{k['probability_two_sided'][i]:.2f}",
                    "-" if d is None else f"{1e3 * d[0]:.2f} / {1e3 * d[1]:.2f}",
                    f"{k['during_median']:.3g} / {k['recovery_median']:.3g}" if i == 0 else "",
                ]
            )
    m95 = [
        [
            kind,
            _g(k["magnitude_95"]),
            _g(k["magnitude_95_two_sided"]),
            f"{k['recovery_max']:.3g}",
            str(k["non_finite_runs"]),
            str(k["resets"]),
        ]
        for kind, k in res["kinds"].items()
    ]
    fa = res["false_alarms"]
    lines = [
        format_table(header, rows),
        "",
        format_table(
            ["kind", "95 % at", "95 % two-sided", "max err after", "non-finite runs", "resets"],
            m95,
        ),
        "",
        f"alarm episodes outside faults: {fa['episodes']} in {fa['windows']} windows "
        f"({fa['hours'] * 3600:.2f} s); monitor calibration: {res['calibration']}",
    ]
    for dev, rates in res.get("fault_free", {}).items():
        for a, r in rates.items():
            lines.append(
                f"fault-free, device {dev}, alpha {a:g}: {r['alarm_windows']} alarming of "
                f"{r['windows']} windows, designed {r['designed']:.1f}, "
                f"ratio {r['ratio']:.2f}"
            )
    return "\n".join(lines)


def write_plot(path: Path, res: dict) -> Path:
    """Detection probability against magnitude per kind (upper test solid, two-sided
    dashed), one panel per kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = list(res["kinds"])
    cols = 4
    rows = (len(kinds) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    for ax, kind in zip(axes.flat, kinds):
        k = res["kinds"][kind]
        m = np.asarray(k["magnitudes"], float)
        ax.plot(m, k["probability"], "o-", label="upper (NIS high)")
        ax.plot(m, k["probability_two_sided"], "s--", label="two-sided")
        ax.axhline(0.95, color="0.6", lw=0.8)
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(kind, fontsize=9)
        ax.set_xlabel(UNITS.get(kind, ""), fontsize=8)
        if m.size == 1:  # a kind without a magnitude (stuck_at, sign_flip)
            ax.set_xticks(m, ["(no magnitude)"])
        elif m.min() > 0 and m.max() / m.min() >= 50:
            ax.set_xscale("log")
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(kinds) :]:
        ax.set_visible(False)
    axes.flat[0].set_ylabel("P(detect)")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(
        f"accelerometer EKF NIS monitor: detection per fault kind ({res['calibration']} "
        "calibration)",
        fontsize=10,
    )
    fig.tight_layout()
    write_output(path, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)
    return path


def _ints(text: str, what: str) -> tuple[int, ...]:
    try:
        out = tuple(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise ValueError(f"{what}: comma-separated integers, not {text!r}") from None
    if not out or min(out) < 0:
        raise ValueError(f"{what}: at least one integer >= 0")
    return out


def _devices(text: str) -> tuple[int | None, ...]:
    out = []
    for t in text.split(","):
        t = t.strip()
        if t == "nominal":
            out.append(None)
        elif t:
            out.extend(_ints(t, "--devices"))
    if not out:
        raise ValueError("--devices: 'nominal' or device seeds")
    return tuple(out)


def main(argv: list[str] | None = None) -> int:
    """``python -m mems_scenarios.accelerometer_fault_detection``: the study (module doc);
    exit status 0, or 2 with one line on bad input."""
    import argparse

    p = argparse.ArgumentParser(prog=f"python -m mems_scenarios.{NAME}")
    p.add_argument("--seeds", default="3,4", metavar="N,N,...", help="evaluation noise seeds")
    p.add_argument(
        "--devices", default="nominal", metavar="D,D,...", help="'nominal' and device seeds"
    )
    p.add_argument("--kinds", default=",".join(study.GRID), metavar="KIND,...")
    p.add_argument(
        "--calibration",
        choices=("table", "bench"),
        default="bench",
        help="the monitor's NIS moments: each device's own, from fault-free bench runs on "
        "noise seeds 1 and 2 (default), or the filter's table (measured on the nominal "
        "device: an oracle for a drawn one)",
    )
    p.add_argument(
        "--fault-free-samples",
        type=int,
        default=0,
        metavar="N",
        help="also measure the fault-free alarm rate on N samples per seed and device",
    )
    p.add_argument("--out", type=Path, default=Path("runs"), metavar="DIR")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--json", action="store_true", help="the results as JSON on stdout")
    p.add_argument("--progress", action="store_true", help="a progress bar on stderr")
    args = p.parse_args(argv)
    try:
        seeds = _ints(args.seeds, "--seeds")
        devices = _devices(args.devices)
        kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip())
        if args.fault_free_samples < 0:
            raise ValueError("--fault-free-samples: N >= 0")
        bar = None
        if args.progress:
            from tqdm import tqdm

            total = len(seeds) * len(devices) * sum(len(study.GRID.get(k, ())) for k in kinds)
            bar = tqdm(total=total, unit="trial", file=sys.stderr)
        res = study.campaign(
            kinds,
            seeds,
            devices,
            grid=study.GRID,
            progress=None if bar is None else (lambda t: bar.update(1)),
            calibration=args.calibration,
        )
        if bar is not None:
            bar.close()
        if args.fault_free_samples:
            res["fault_free"] = {}
            for ds in devices:
                mom = res["moments"].get(str(ds))
                res["fault_free"]["nominal" if ds is None else str(ds)] = study.false_alarm_rates(
                    seeds,
                    args.fault_free_samples,
                    device_seed=ds,
                    **({} if mom is None else {"moments": tuple(mom)}),
                )
        if args.json:
            print(json.dumps(res, indent=1, default=float))
        else:
            print(table(res))
        if not args.no_plots:
            args.out.mkdir(parents=True, exist_ok=True)
            path = write_plot(args.out / f"{NAME}.png", res)
            print(f"figure: {path}", file=sys.stderr if args.json else sys.stdout)
    except (ValueError, OSError) as exc:
        print(f"{NAME}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

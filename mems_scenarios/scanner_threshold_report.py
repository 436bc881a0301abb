"""The report of scenario ``scanner_threshold`` from its figures: the figure records, the
criteria, the tables and the plots (the scenario itself: :mod:`mems_scenarios.scanner_threshold`).
The thesis' values the table sets beside the results live here too, so the scenario module
imports them (one direction, no cycle).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import stats

from mems_scenarios import base
from mems_scenarios.figures import Figure, cell, is_finite, project_criterion
from mems_sim.bag.output_paths import write_output

#: Chen 2018, Table 4.3: theta RMSE [rad] of the EKF and the hybrid per SNR segment and
#: overall, and the hybrid's reduction [%].
PAPER = dict(
    ekf=(0.0050, 0.0029, 0.0026, 0.0025, 0.0034),
    hyb=(0.0047, 0.0023, 0.0019, 0.0018, 0.0029),
    red=(6.9, 21.4, 27.6, 30.3, 15.1),
)


def _segment_names(f: dict) -> list[str]:
    """``seg1`` .. ``segN`` (ring-down segments in order of falling SNR), then ``overall``."""
    return [f"seg{i + 1}" for i in range(len(f["segments"]))] + ["overall"]


def records(f: dict) -> list[Figure]:
    """The scenario's figures as data (angles in rad; no targets: the table sets the results
    beside the paper's, it does not judge them)."""
    segs = _segment_names(f)
    out = [Figure(f"{g}.snr", snr, "1") for g, (_, _, snr) in zip(segs, f["segments"])]
    per_segment = (
        ("ekf.theta_rmse", "rmse_ekf", "rad"),
        ("hyb.theta_rmse", "rmse_hyb", "rad"),
        ("theta_rmse_reduction", "reduction", "1"),
        ("ekf_full_jacobian.theta_rmse", "rmse_full_ekf", "rad"),
        ("hyb_full_jacobian.theta_rmse", "rmse_full_hyb", "rad"),
        ("ekf.theta_rmse_th", "rmse_th_ekf", "rad"),
        ("hyb.theta_rmse_th", "rmse_th_hyb", "rad"),
    )
    for name, key, unit in per_segment:
        out += [Figure(f"{g}.{name}", x, unit) for g, x in zip(segs, f[key])]
    out[out.index(next(x for x in out if x.name == "overall.theta_rmse_reduction"))] = _table_4_3(f)
    out += [
        Figure(f"{g}.theta_rmse_th_reduction", _reduction(h, p), "1")
        for g, h, p in zip(segs, f["rmse_th_hyb"], f["rmse_th_ekf"])
    ]
    for g, (n, mean, std, p) in zip(segs, f["ks"]):
        out += [
            Figure(f"{g}.e_theta_th.n", n, ""),
            Figure(f"{g}.e_theta_th.mean", mean, "rad"),
            Figure(f"{g}.e_theta_th.std", std, "rad"),
            Figure(f"{g}.e_theta_th.ks_p", p, "1"),
        ]
    for sig, d in f["sigma_sweep"].items():
        out += [
            Figure(f"{g}.sigma_dog_{sig:g}.var_e_theta", x, "rad^2") for g, x in zip(segs, d["var"])
        ]
        out += [
            Figure(f"{g}.sigma_dog_{sig:g}.hyb_nrmse", x, "1") for g, x in zip(segs, d["nrmse"])
        ]
    for (fac, fs), (var, n) in sorted(f["fs_study"].items()):
        out += [
            Figure(f"fs_study.sigma_n_x{fac:g}.fs_{fs:.0f}hz.var_e_theta_th", var, "rad^2"),
            Figure(f"fs_study.sigma_n_x{fac:g}.fs_{fs:.0f}hz.detections", n, ""),
        ]
    dr = f["drift"]
    out += [
        Figure("drift.sense_gain_drift", f["drift_setting"][0], "1"),
        Figure("drift.sense_width_drift", f["drift_setting"][1], "1"),
    ]
    for i, g in enumerate(segs):
        red = _reduction(dr["hyb"][i], dr["base"][i])
        if g != "overall":  # overall: with its target (:func:`criteria`)
            out.append(Figure(f"{g}.hybrid_vs_baseline_reduction", red, "1"))
        out += [
            Figure(f"{g}.baseline_full_jacobian.theta_rmse", dr["base"][i], "rad"),
            Figure(f"{g}.hybrid_comb.theta_rmse", dr["hyb"][i], "rad"),
            Figure(f"{g}.comb_plain.theta_rmse", dr["comb_plain"][i], "rad"),
            Figure(f"{g}.pcrb_theta", dr["pcrb"][i], "rad"),
            Figure(f"{g}.hybrid_over_pcrb", dr["hyb"][i] / dr["pcrb"][i], "1"),
            Figure(
                f"{g}.hybrid_vs_pseudo_jacobian_reduction",
                _reduction(dr["hyb"][i], dr["paper"][i]),
                "1",
            ),
            Figure(f"{g}.detection_bias", dr["det_bias"][i][0], "rad"),
            Figure(f"{g}.detection_error_std", dr["det_bias"][i][1], "rad"),
        ]
    out += criteria(dr, f["drift_setting"])
    od = f["oracle"]["drift"]
    out += [
        Figure(f"oracle.{g}.{name}", x, "rad")
        for name, key in (("ekf.theta_rmse", "rmse_ekf"), ("hyb.theta_rmse", "rmse_hyb"))
        for g, x in zip(segs, f["oracle"][key])
    ]
    out += [
        Figure(f"oracle.{g}.theta_rmse_reduction", _reduction(h, p), "1")
        for g, h, p in zip(segs, f["oracle"]["rmse_hyb"], f["oracle"]["rmse_ekf"])
    ]
    out += [
        Figure(f"oracle.{g}.hybrid_vs_baseline_reduction", _reduction(h, b), "1")
        for g, h, b in zip(segs[:-1], od["hyb"], od["base"])
    ]
    out += [Figure(f"oracle.{x.name}", x.value, x.unit) for x in criteria(od, f["drift_setting"])]
    out += [Figure(f"identified.{k}", v, EKF_UNITS[k]) for k, v in f["model"].items()]
    out += [
        Figure(f"oracle.identification_error.{k}", v, "rad" if k == "threshold_angle" else "1")
        for k, v in f["identification_error"].items()
    ]
    out += [
        Figure("detector.latency", f["latency"], "samples"),
        Figure("detector.online_detections", f["n_detections"], ""),
        Figure("detector.online_equals_offline", f["online_offline_same"], ""),
    ]
    for k in ("hyb", "ekf"):
        out += [
            Figure(f"{k}.min_variance", f[f"min_var_{k}"], "state unit^2"),
            Figure(f"{k}.max_var_theta", f[f"max_var_theta_{k}"], "rad^2"),
            Figure(f"{k}.ringdown_abs_z_p99", f[f"z99_{k}"], "1"),
        ]
    return out


#: Target of the Table 4.3 overall reduction (hybrid vs Table 4.1's EKF).
TABLE_4_3_TARGET = ">= 0.10"
TABLE_4_3_SOURCE = "Chen 2018 Table 4.3: overall 15.1 %, asked >= 10 %"
#: Targets of the restated criterion (docs/scanner.md, "Restated criterion"): hybrid vs the
#: full-Jacobian EKF, on a drifted comb and on the nominal comb.
DRIFT_TARGET = ">= 0.10"
DRIFT_SOURCE = project_criterion("the hybrid >= 10 % better than the EKF over the drift grid")
NOMINAL_TARGET = "<= 0.05"
NOMINAL_SOURCE = project_criterion("the hybrid <= 5 % worse than the EKF on the nominal comb")
#: Units of the identified model's parameters.
EKF_UNITS = {
    "model_natural_freq_hz": "Hz",
    "model_damping_ratio": "1",
    "model_inertia": "kg m^2",
    "model_threshold_angle": "rad",
    "model_sense_c0": "F",
    "model_sense_theta0": "rad",
    "model_drive_c0": "F",
    "model_drive_theta0": "rad",
    "sense_resistance": "Ohm",
    "bias_voltage": "V",
    "sample_rate_hz": "Hz",
    "r_cap": "V^2",
}


def _table_4_3(f: dict) -> Figure:
    """The Table 4.3 overall reduction with its target."""
    x = f["reduction"][-1]
    return Figure(
        "overall.theta_rmse_reduction",
        x,
        "1",
        target=TABLE_4_3_TARGET,
        passed=bool(x >= 0.10),
        source=TABLE_4_3_SOURCE,
    )


def criteria(dr: dict, drift_setting) -> list[Figure]:
    """The restated criterion's figures of one drift evaluation ``dr``: on a drifted comb
    the overall and SNR <= 5 reductions (targets >= 10 %), on the nominal comb the hybrid's
    overall degradation (target <= 5 %)."""
    out = []
    overall = _reduction(dr["hyb"][-1], dr["base"][-1])
    low = [i for i in (2, 3) if math.isfinite(dr["base"][i])]  # SNR ~5 and ~1 (Table 4.3)
    red_low = math.nan
    if low:
        hb = math.sqrt(np.nanmean([dr["hyb"][i] ** 2 for i in low]))
        bb = math.sqrt(np.nanmean([dr["base"][i] ** 2 for i in low]))
        red_low = _reduction(hb, bb)
    if tuple(drift_setting) == (0.0, 0.0):
        out.append(Figure("overall.hybrid_vs_baseline_reduction", overall, "1"))
        out.append(Figure("snr_le_5.hybrid_vs_baseline_reduction", red_low, "1"))
        deg = -overall
        out.append(
            Figure(
                "nominal.hybrid_degradation",
                deg,
                "1",
                target=NOMINAL_TARGET,
                passed=bool(deg <= 0.05),
                source=NOMINAL_SOURCE,
            )
        )
        return out
    for name, x in (("overall", overall), ("snr_le_5", red_low)):
        out.append(
            Figure(
                f"{name}.hybrid_vs_baseline_reduction",
                x,
                "1",
                target=DRIFT_TARGET,
                passed=bool(x >= 0.10),
                source=DRIFT_SOURCE,
            )
        )
    return out


def _reduction(h: float, p: float) -> float:
    return 1 - h / p if p else math.nan


def _pct(x: float) -> str:
    return cell(100 * x if is_finite(x) else x, ".1f", "%")


def table(f: dict) -> str:
    """Table 4.3 form + detection study, next to the paper's figures."""
    hdr = ["", *[f"SNR {s:.0f}" for _, _, s in f["segments"]], "overall"]

    def mrad(x: float) -> str:
        return cell(1e3 * x if is_finite(x) else x, ".2f")

    r = [
        ["EKF theta_RMSE [rad]", *[cell(x, ".5f") for x in f["rmse_ekf"]]],
        ["HYB theta_RMSE [rad]", *[cell(x, ".5f") for x in f["rmse_hyb"]]],
        ["theta_RMSE reduction", *[_pct(x) for x in f["reduction"]]],
        ["  paper reduction", *[f"{x}%" for x in PAPER["red"]]],
        ["oracle EKF theta_RMSE [rad]", *[cell(x, ".5f") for x in f["oracle"]["rmse_ekf"]]],
        ["oracle HYB theta_RMSE [rad]", *[cell(x, ".5f") for x in f["oracle"]["rmse_hyb"]]],
        [
            "oracle theta_RMSE reduction",
            *[
                _pct(_reduction(h, p))
                for h, p in zip(f["oracle"]["rmse_hyb"], f["oracle"]["rmse_ekf"])
            ],
        ],
        [
            "HYB vs full-Jacobian EKF",
            *[_pct(_reduction(h, b)) for h, b in zip(f["drift"]["hyb"], f["drift"]["base"])],
        ],
        [
            "  oracle",
            *[
                _pct(_reduction(h, b))
                for h, b in zip(f["oracle"]["drift"]["hyb"], f["oracle"]["drift"]["base"])
            ],
        ],
        ["EKF, full Jacobian [rad]", *[cell(x, ".5f") for x in f["rmse_full_ekf"]]],
        ["HYB, full Jacobian [rad]", *[cell(x, ".5f") for x in f["rmse_full_hyb"]]],
        ["EKF theta_RMSE,th", *[cell(x, ".5f") for x in f["rmse_th_ekf"]]],
        ["HYB theta_RMSE,th", *[cell(x, ".5f") for x in f["rmse_th_hyb"]]],
        [
            "theta_RMSE,th reduction",
            *[_pct(_reduction(h, p)) for h, p in zip(f["rmse_th_hyb"], f["rmse_th_ekf"])],
        ],
        ["  paper", "26.0%", "11.6%", "2.6%", "8.1%", "12.3%"],
        [
            "e_theta,th n / mean / std [mrad]",
            *[f"{k[0]} / {mrad(k[1])} / {mrad(k[2])}" for k in f["ks"]],
            "-",
        ],
        ["KS p-value (normal if > 0.05)", *[cell(k[3], ".2f") for k in f["ks"]], "-"],
    ]
    for sig, d in f["sigma_sweep"].items():
        r.append(
            [f"var(e_theta) sigma_DOG={sig:g} [rad^2]", *[cell(x, ".2e") for x in d["var"]], "-"]
        )
    for sig, d in f["sigma_sweep"].items():
        r.append([f"HYB NRMSE sigma_DOG={sig:g}", *[cell(x, ".4f") for x in d["nrmse"]]])
    out = "identified on the bench (before the drift): " + ", ".join(
        f"{k.removeprefix('model_')} {cell(v, '.5g')} {EKF_UNITS[k]}"
        for k, v in f["model"].items()
        if k not in ("sense_resistance", "bias_voltage", "sample_rate_hz", "model_inertia")
    )
    out += "\noracle: identification error against the device as built: " + ", ".join(
        f"{k} {cell(v, '+.2e')}{' rad' if k == 'threshold_angle' else ''}"
        for k, v in f["identification_error"].items()
    )
    out += "\n(the oracle rows: the same filters with the emulator's nominal table)\n\n"
    out += base.format_table(hdr, r)
    out += "\n\n" + base.format_table(
        ["criterion", "value", "target", "source", "met"],
        [
            [x.name, _pct(x.value), x.target, x.source, "yes" if x.passed else "NO"]
            for x in [*criteria(f["drift"], f["drift_setting"]), _table_4_3(f)]
            if x.target is not None
        ],
    )
    rates = sorted({fs for (_, fs) in f["fs_study"]})
    facs = sorted({fac for (fac, _) in f["fs_study"]})
    r2 = [
        [
            f"sigma_n x {fac:g}",
            *[
                f"{cell(f['fs_study'][(fac, fs)][0], '.2e')} ({f['fs_study'][(fac, fs)][1]})"
                for fs in rates
            ],
        ]
        for fac in facs
    ]
    out += "\n\nvar(e_theta,th) [rad^2] (detections) vs sampling rate, sinusoid 0.15 rad 625 Hz:\n"
    out += base.format_table(["", *[f"{fs / 1e3:g} kHz" for fs in rates]], r2)
    out += (
        f"\n\ndetector latency {f['latency']} samples; {f['n_detections']} online detections;"
        f" online = offline within one sample: {f['online_offline_same']}; "
        f"min variance (PD): HYB {cell(f['min_var_hyb'], '.2e')}, "
        f"EKF {cell(f['min_var_ekf'], '.2e')}; "
        f"max var(theta) HYB {cell(f['max_var_theta_hyb'], '.2e')}, "
        f"EKF {cell(f['max_var_theta_ekf'], '.2e')};"
        f" 99th pct |err|/sigma in the ring-down: HYB {cell(f['z99_hyb'], '.1f')}, "
        f"EKF {cell(f['z99_ekf'], '.1f')} (overconfident under the drifted analog map)"
    )
    return out


def plot(f: dict, path: Path, path2: Path) -> None:
    """Fig. 4.10 analogue (path) and the detection-error study (path2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = f["series"]
    fs = s["fs"]
    t = np.arange(s["th"].size) / fs * 1e3
    fig = plt.figure(figsize=(13, 11))
    gs = fig.add_gridspec(4, 4)
    det = s["det"]
    for i, (lo, hi, snr) in enumerate(s["segs"]):
        c = det[(det >= lo) & (det < hi)]
        if not c.size:
            continue
        c0 = int(c[len(c) // 2])
        k = np.arange(max(0, c0 - 60), min(s["th"].size, c0 + 120))
        ax = fig.add_subplot(gs[0, i])
        ax.plot(t[k], s["th"][k], "k", lw=1.5, label="truth")
        ax.plot(t[k], s["th_p"][k], "C0--", label="EKF")
        ax.plot(t[k], s["th_h"][k], "C3", label="HYB")
        ax.axvline(t[c0], color="g", ls=":")
        ax.set_title(f"(a) SNR {snr:.0f}", fontsize=9)
        ax.set_xlabel("t [ms]", fontsize=8)
        if i == 0:
            ax.set_ylabel("theta [rad]")
            ax.legend(fontsize=7)
        ax2 = fig.add_subplot(gs[3, i])
        ax2.plot(t[k], s["y"][k], lw=0.6, label="y_cap")
        rr = s["r"][k]
        ax2.plot(
            t[k], rr / np.nanmax(np.abs(rr)) * np.abs(s["y"][k]).max(), "C3", label="DOG (scaled)"
        )
        ax2.axvline(t[c0], color="g", ls=":")
        ax2.set_title(f"(d) SNR {snr:.0f}", fontsize=9)
        ax2.set_xlabel("t [ms]", fontsize=8)
        if i == 0:
            ax2.set_ylabel("y_cap [V]")
            ax2.legend(fontsize=7)
    ax = fig.add_subplot(gs[1, :])
    ax.plot(t, s["th"], "k", lw=0.4, label="truth")
    ax.plot(t, s["th_p"], "C0", lw=0.3, label="EKF")
    ax.plot(t, s["th_h"], "C3", lw=0.3, label="HYB")
    for lo, hi, _ in s["segs"]:
        ax.axvspan(t[lo], t[min(hi, t.size - 1)], alpha=0.08)
    ax.set(ylabel="theta [rad]", title="(b) tilting angle: sweep, hold, cut-off, ring-down")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(gs[2, :])
    ax.plot(t, s["y"], lw=0.3, label="y_cap")
    ax.plot(t, s["r"] / np.nanmax(np.abs(s["r"])) * 2, "C3", lw=0.4, label="DOG response (scaled)")
    ax.set(xlabel="time [ms]", ylabel="[V]", title="(c) sensing signal and DOG response")
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_output(path, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    segs = s["segs"]
    for i, (lo, hi, snr) in enumerate(segs):
        ax[0].semilogy(
            list(f["sigma_sweep"]),
            [d["var"][i] for d in f["sigma_sweep"].values()],
            "o-",
            label=f"SNR {snr:.0f}",
        )
    ax[0].set(
        xlabel="sigma_DOG [samples]",
        ylabel="var(e_theta,th) [rad^2]",
        title="Fig. 4.11: detection-error variance vs sigma_DOG",
    )
    ax[0].legend(fontsize=8)
    rates = sorted({fs_ for (_, fs_) in f["fs_study"]})
    for fac in sorted({fac for (fac, _) in f["fs_study"]}):
        ax[1].loglog(
            np.array(rates) / 1e3,
            [f["fs_study"][(fac, r)][0] for r in rates],
            "o-",
            label=f"sigma_n x {fac:g}",
        )
    ax[1].set(
        xlabel="fs [kHz]",
        ylabel="var(e_theta,th) [rad^2]",
        title="Fig. 4.6(a): variance vs sampling rate",
    )
    ax[1].legend(fontsize=8)
    lo, hi, snr = segs[1]
    m = (s["det"] >= lo) & (s["det"] < hi) & (np.abs(s["e_t"]) < 50)
    e = s["e_th"][m] * 1e3
    if e.size > 2:
        ax[2].hist(e, bins=15, density=True, alpha=0.6, label=f"e_theta,th (SNR {snr:.0f})")
        xx = np.linspace(e.min(), e.max(), 200)
        ax[2].plot(xx, stats.norm.pdf(xx, e.mean(), e.std()), "k", label="normal fit")
    ax[2].set(xlabel="e_theta,th [mrad]", title="Fig. 4.8/4.9: error vs normal")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    write_output(path2, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)

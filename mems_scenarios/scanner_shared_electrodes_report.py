"""The report of scenario ``scanner_shared_electrodes`` from its figures: the figure
records, the table in the form of Chen 2018 Table 5.3 and the plots in the forms of
Figs. 5.8 and 5.9 (the scenario itself: :mod:`mems_scenarios.scanner_shared_electrodes`).
The evaluation window, the sample rate and the acquisition study's settings the report
reads live here too, so the scenario module imports them (one direction, no cycle).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mems_estimation.filters import scanner_amdm_model as sam
from mems_estimation.filters import scanner_amdm_tracking as su
from mems_scenarios.figures import Figure, cell, met_cell, project_criterion
from mems_sim.bag.output_paths import write_output
from mems_sim.table import format_table

T_EVAL = 0.02  # motion grown and both filters acquired [s]
FS = 1.0e6
KINDS = ("ekf", "ukf")
PAPER = {"ekf": (5.04, 1.82), "ukf": (0.63, 0.39)}  # Table 5.3: amplitude, phase [deg]
TARGET_PHASE_DEG = 0.18  # eqs. (78)-(79) as printed (see PHASE_SOURCE)
TARGET_AMP_DEG = 0.63  # Table 5.3, the thesis's UKF (see AMP_SOURCE)
RATIO_TOL = 0.01  # EKF and UKF within +-1 % of each other (the scenario's module doc)
#: Where the targets come from (the figures' ``source``).
AMP_SOURCE = (
    "Chen 2018 Table 5.3: the UKF's 0.63 deg, asked of both filters (equally accurate at "
    "the paper's R)"
)
PHASE_SOURCE = (
    "Chen 2018 eqs. 78-79: 0.18 deg as printed (the equation gives 1.12 deg; the stricter kept)"
)
RATIO_SOURCE = project_criterion("at R = 1.92e-4 V^2 the EKF and UKF are equally accurate")
NEES_SOURCE = project_criterion("NEES per state within 0.5-2: the filter's variance is honest")
PD_SOURCE = project_criterion("the covariance stays positive definite")
OFF_SOURCE = project_criterion(
    "off resonance nothing moves; the filter warns of low signal and claims no tracking"
)
#: The Table 5.3 targets on a drawn device: the bench's model is good enough for the paper's
#: purpose (the identified RMSE within 10 % of the oracle's, the stricter criterion, needs
#: the inertia to 0.1 % and w_n to 5 ppm: context, docs/scanner.md).
DRAWN_SOURCE = project_criterion(
    "the bench's model of a drawn device meets the accuracy of Chen 2018 Table 5.3 and eqs. 78-79"
)
ACQUIRE_SOURCE = project_criterion("every start from a wrong state is acquired within 3 ms")
# acquisition study (the scenario's module doc): starts a quarter motion period apart after
# the growth
STRESS_START_S = 0.03
STRESS_STARTS = 4
STRESS_SPACING = 16  # samples, ~1/4 of the 64 us motion period
STRESS_N = 3000  # samples per started run (3 ms, ~47 motion periods)
STRESS_TOL = 1.0e-3  # rad: acquired once the error stays below (~20x the tracking RMSE)
STRESS_CASES = {"stress": 0.25 * 0.2, "acquire_0p1rad": 0.1}  # initial error [rad]


def ratio(a: float, b: float) -> float:
    return a / b if b else math.nan


def _pooled(rmse: np.ndarray) -> float:
    """RMSE pooled over runs of equal length [same unit]."""
    return float(np.sqrt(np.mean(np.asarray(rmse) ** 2))) if np.size(rmse) else math.nan


#: The acquisition study of a recording without the oracle's delay: no starts.
_NO_STUDY = su.AcquisitionStudy(*(np.zeros(0) for _ in su.AcquisitionStudy._fields))


def _stress_records(f: dict) -> list[Figure]:
    # without motion (the drive missed the parametric resonance) there is nothing to acquire
    moving = f["stress_motion_rad"] >= 0.03
    out = [
        Figure(
            "stress.truth_amplitude",
            f["stress_motion_rad"],
            "rad",
            ">= 0.03 rad",
            moving,
            project_criterion("the acquisition study needs the scanner in motion"),
        )
    ]
    for case, dth in STRESS_CASES.items():
        st = f["stress"][case] if f["stress"] is not None else dict.fromkeys(KINDS, _NO_STUDY)
        for k in ("ekf", "ukf"):
            a = st[k]
            ok = np.isfinite(a.time)
            frac = float(np.mean(ok)) if ok.size and moving else math.nan
            tmax = float(np.max(a.time)) * 1e6 if ok.size and ok.all() else math.nan
            out += [
                Figure(f"{case}.{k}.initial_error", dth, "rad"),
                Figure(f"{case}.{k}.acquired", frac, "1", "== 1", frac == 1.0, ACQUIRE_SOURCE),
                Figure(
                    f"{case}.{k}.acquire_time_median",
                    float(np.median(a.time)) * 1e6 if ok.size and ok.all() else math.nan,
                    "us",
                ),
                Figure(f"{case}.{k}.acquire_time_max", tmax, "us"),
                Figure(f"{case}.{k}.theta_rmse", math.degrees(_pooled(a.rmse)), "deg"),
            ]
        out.append(
            Figure(
                f"{case}.ukf_ekf.theta_rmse_ratio",
                ratio(_pooled(st["ukf"].rmse), _pooled(st["ekf"].rmse)),
                "1",
            )
        )
    return out


def _paper(name: str, value, target: str, ok: bool, source: str, drawn: bool) -> Figure:
    """A figure judged against the paper's target; on a drawn device against the same
    number as this project's criterion (:data:`DRAWN_SOURCE`)."""
    return Figure(name, value, "deg", target, ok, DRAWN_SOURCE if drawn else source)


def _identified_records(f: dict) -> list[Figure]:
    """The oracle filters' Table 5.3 figures (context), the identified filters' over theirs
    (judged) and the bench's identification errors against the device as built (context,
    the oracle's)."""
    out = []
    o = f.get("oracle")
    for k in ("ekf", "ukf") if o is not None else ():
        for q, name in (("amp", "amplitude"), ("phase", "phase")):
            out.append(Figure(f"oracle.{k}.{name}_rmse", o[f"{k}_{q}_deg"], "deg"))
            r = ratio(f[f"{k}_{q}_deg"], o[f"{k}_{q}_deg"])
            # context: within 10 % of the oracle needs J to 0.1 % and w_n to 5 ppm (docs)
            out.append(Figure(f"identified_vs_oracle.{k}.{name}_rmse_ratio", r, "1"))
    for name, v in (f.get("identification_error") or {}).items():
        out.append(Figure(f"device.identified_{name}_error", v, "1"))
    return out


def records(f: dict) -> list[Figure]:
    """The scenario's figures as data (angles in deg, as the table prints them)."""
    out = []
    drawn = bool(f.get("drawn"))
    for k in ("ekf", "ukf"):
        amp, phase = f[f"{k}_amp_deg"], f[f"{k}_phase_deg"]
        out += [
            _paper(
                f"{k}.amplitude_rmse",
                amp,
                f"<= {TARGET_AMP_DEG:g} deg",
                amp <= TARGET_AMP_DEG,
                AMP_SOURCE,
                drawn,
            ),
            _paper(
                f"{k}.phase_rmse",
                phase,
                f"<= {TARGET_PHASE_DEG:g} deg",
                phase <= TARGET_PHASE_DEG,
                PHASE_SOURCE,
                drawn,
            ),
        ]
        out += [
            Figure(f"{k}.phase_bias", f[f"{k}_phase_bias_deg"], "deg"),
            Figure(f"{k}.extrema_pairs", f[f"{k}_pairs"], ""),
        ]
    for q, name in (("amp", "amplitude"), ("phase", "phase")):
        r = ratio(f[f"ukf_{q}_deg"], f[f"ekf_{q}_deg"])
        out.append(
            Figure(
                f"ukf_ekf.{name}_rmse_ratio",
                r,
                "1",
                f"{1 - RATIO_TOL:g}-{1 + RATIO_TOL:g}",
                abs(r - 1.0) <= RATIO_TOL,
                RATIO_SOURCE,
            )
        )
    for k in ("ekf", "ukf"):
        nees = f[f"{k}_nees"]
        out += [
            Figure(f"{k}.theta_rmse", f[f"{k}_theta_rmse_deg"], "deg"),
            Figure(f"{k}.nees", nees, "1", "0.5-2", 0.5 <= nees <= 2.0, NEES_SOURCE),
            Figure(
                f"{k}.pd_failures",
                f[f"{k}_pd_failures"],
                "",
                "== 0",
                f[f"{k}_pd_failures"] == 0,
                PD_SOURCE,
            ),
            Figure(
                f"{k}.min_variance",
                f[f"{k}_min_var"],
                "state unit^2",
                "> 0",
                f[f"{k}_min_var"] > 0,
                PD_SOURCE,
            ),
        ]
    out += [
        Figure(
            "off.final_theta_true",
            f["off_final_amplitude"],
            "rad",
            "< 1e-3 rad",
            f["off_final_amplitude"] < 1e-3,
            OFF_SOURCE,
        ),
        Figure("off.final_theta_estimate", f["off_final_theta_est"], "rad"),
        Figure(
            "off.low_signal_warned",
            f["off_low_signal_warned"],
            "",
            "true",
            bool(f["off_low_signal_warned"]),
            OFF_SOURCE,
        ),
        Figure("off.tracking", f["off_tracking"], "", "false", not f["off_tracking"], OFF_SOURCE),
        Figure("off.extrema", f["off_events"], ""),
        Figure("off.finite", f["off_finite"], "", "true", bool(f["off_finite"]), OFF_SOURCE),
    ]
    return out + _stress_records(f) + _identified_records(f)


def table(f: dict) -> str:
    """Table 5.3 form next to the paper, plus consistency and the off-resonance check."""
    F = {r.name: r for r in records(f)}

    def c(name: str, spec: str) -> str:
        return cell(F[name].value, spec)

    rows = []
    for k in ("ekf", "ukf"):
        rows.append(
            [
                f"{k.upper()} RMSE amplitude [deg]",
                f"{PAPER[k][0]:.2f}",
                f"<= {TARGET_AMP_DEG:g}",
                c(f"{k}.amplitude_rmse", ".3f"),
                met_cell(F[f"{k}.amplitude_rmse"]),
            ]
        )
        rows.append(
            [
                f"{k.upper()} RMSE phase shift [deg]",
                f"{PAPER[k][1]:.2f}",
                f"<= {TARGET_PHASE_DEG:g} (eqs. 78-79 as printed)",
                f"{c(f'{k}.phase_rmse', '.3f')} (bias {c(f'{k}.phase_bias', '+.3f')}, "
                f"{f[f'{k}_pairs']} extrema)",
                met_cell(F[f"{k}.phase_rmse"]),
            ]
        )
    rows.append(
        [
            "UKF/EKF RMSE ratio, amplitude and phase",
            "0.13, 0.21",
            f"{1 - RATIO_TOL:g}-{1 + RATIO_TOL:g}",
            f"{c('ukf_ekf.amplitude_rmse_ratio', '.4f')}, {c('ukf_ekf.phase_rmse_ratio', '.4f')}",
            met_cell(F["ukf_ekf.amplitude_rmse_ratio"], F["ukf_ekf.phase_rmse_ratio"]),
        ]
    )
    for k in ("ekf", "ukf"):
        rows.append(
            [
                f"{k.upper()} theta RMSE (sign-aligned) [deg] / NEES",
                "-",
                "consistent: NEES 0.5-2",
                f"{c(f'{k}.theta_rmse', '.3f')} / {c(f'{k}.nees', '.2f')}",
                met_cell(F[f"{k}.nees"]),
            ]
        )
        rows.append(
            [
                f"{k.upper()} covariance PD over the run (failures, min var)",
                "-",
                "0",
                f"{f[f'{k}_pd_failures']}, {c(f'{k}.min_variance', '.1e')}",
                met_cell(F[f"{k}.pd_failures"], F[f"{k}.min_variance"]),
            ]
        )
    rows.append(
        [
            "off resonance (25 kHz): final |theta| true / est [rad]",
            "-",
            "no motion",
            f"{c('off.final_theta_true', '.1e')} / {c('off.final_theta_estimate', '.1e')}",
            met_cell(F["off.final_theta_true"]),
        ]
    )
    rows.append(
        [
            "off resonance: low-signal diagnostics, no extrema, finite",
            "-",
            "yes",
            f"warned={f['off_low_signal_warned']}, tracking={f['off_tracking']}, "
            f"extrema={f['off_events']}, finite={f['off_finite']}",
            met_cell(F["off.low_signal_warned"], F["off.tracking"], F["off.finite"]),
        ]
    )
    for case, dth in STRESS_CASES.items():
        for k in ("ekf", "ukf"):
            rows.append(
                [
                    f"{k.upper()} started {dth:g} rad off ({dth / 0.2:g} theta_0): "
                    "time to acquire median / max [us], theta RMSE [deg]",
                    "-",
                    f"acquired ({STRESS_STARTS * 2} starts)",
                    f"{c(f'{case}.{k}.acquire_time_median', '.0f')} / "
                    f"{c(f'{case}.{k}.acquire_time_max', '.0f')}, "
                    f"{c(f'{case}.{k}.theta_rmse', '.3f')}",
                    met_cell(F[f"{case}.{k}.acquired"]),
                ]
            )
    main = format_table(["figure", "paper", "target", "measured", "met"], rows)
    return main + identification_table(f, F)


def identification_table(f: dict, F: dict) -> str:
    """The identified filters against the oracle filters (the device's own table) on the
    same recording, and the bench's errors against the device as built (oracle)."""
    if f.get("oracle") is None:
        return ""
    rows = []
    for k in ("ekf", "ukf"):
        for q, name in (("amp", "amplitude"), ("phase", "phase")):
            r = F[f"identified_vs_oracle.{k}.{name}_rmse_ratio"]
            rows.append(
                [
                    f"{k.upper()} RMSE {name} [deg]",
                    cell(f[f"{k}_{q}_deg"], ".3f"),
                    cell(f["oracle"][f"{k}_{q}_deg"], ".3f"),
                    cell(r.value, ".3f"),
                ]
            )
    out = "\n\nbench model vs oracle (the device's own table), same recording\n"
    out += format_table(["figure", "identified", "oracle", "identified / oracle"], rows)
    err = f.get("identification_error")
    if err:
        line = ", ".join(f"{k} {v:+.2%}" for k, v in err.items())
        out += f"\nidentified model vs the device as built (oracle): {line}"
    return out


def plot(f: dict, path58: Path, path59: Path) -> None:
    """Fig. 5.8 form (drive, angle, AMDM output) and Fig. 5.9 form (per-extremum amplitude,
    phase and their errors)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = f["series"]
    t, d = s["t"], s["delay"]
    k = slice(int(0.04 * FS), int(0.04 * FS) + 300)
    sign = {}
    for name, th in s["est"].items():
        sign[name] = np.sign(np.sum(th[k] * np.interp(t[k] - d, t, s["truth"]))) or 1.0
    fig, ax = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    ax[0].plot(t[k] * 1e3, s["drive"][k], "k")
    ax[0].set(ylabel="V_dr [V]", title="Fig. 5.8 form: drive, tilt angle, AMDM output")
    ax[1].plot(t[k] * 1e3, np.degrees(s["truth"][k]), "k", lw=2, label="truth")
    for name, c in (("ekf", "C0--"), ("ukf", "C1:")):
        ax[1].plot(
            (t[k] - d) * 1e3, np.degrees(sign[name] * s["est"][name][k]), c, label=name.upper()
        )
    ax[1].set(ylabel="theta [deg]")
    ax[1].legend(fontsize=8)
    p = sam.resolve_estimator(dict(chain_delay_s=d))
    ax[2].plot(t[k] * 1e3, s["y"][k], "k.", ms=2, label="measured y_cap")
    for name, c in (("ekf", "C0-"), ("ukf", "C1--")):
        ax[2].plot(
            t[k] * 1e3, sam.filter_measurement(s["est"][name][k], p), c, label=f"h({name.upper()})"
        )
    ax[2].set(xlabel="time [ms]", ylabel="y_cap [V]")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    write_output(path58, lambda tmp: fig.savefig(tmp, dpi=110), overwrite=True)
    plt.close(fig)

    ref = s["ref"]
    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    ax[0, 0].plot(ref.t * 1e3, np.degrees(ref.amplitude), "k", lw=2, label="truth")
    ax[0, 1].plot(ref.t * 1e3, np.degrees(ref.phase), "k", lw=2, label="truth")
    for name, c in (("ekf", "C0"), ("ukf", "C1")):
        ev = s["ev"][name]
        te, dph, dam = su.match_events(ev, ref, 0.25 / 31.3e3)
        ax[0, 0].plot(ev.t * 1e3, np.degrees(ev.amplitude), c, lw=0.8, label=name.upper())
        ax[0, 1].plot(ev.t * 1e3, np.degrees(ev.phase), c, lw=0.8, label=name.upper())
        ax[1, 0].plot(
            te * 1e3,
            np.degrees(dam),
            c,
            lw=0.8,
            label=f"{name.upper()} RMSE {f[name + '_amp_deg']:.3f} deg",
        )
        ax[1, 1].plot(
            te * 1e3,
            np.degrees(dph),
            c,
            lw=0.8,
            label=f"{name.upper()} RMSE {f[name + '_phase_deg']:.3f} deg",
        )
    for a in ax.ravel():
        a.axvline(T_EVAL * 1e3, color="g", ls=":")
        a.legend(fontsize=8)
        a.set_xlabel("time [ms]")
    ax[0, 0].set(
        ylabel="amplitude |theta| at extrema [deg]", title="Fig. 5.9 form: per-extremum amplitude"
    )
    ax[0, 1].set(ylabel="phase shift [deg of motion period]", title="phase shift")
    ax[1, 0].set(ylabel="amplitude error [deg]", ylim=(-0.5, 0.5))
    ax[1, 1].set(ylabel="phase error [deg]", ylim=(-1.5, 1.5))
    fig.tight_layout()
    write_output(path59, lambda tmp: fig.savefig(tmp, dpi=110), overwrite=True)
    plt.close(fig)

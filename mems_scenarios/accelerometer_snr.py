"""Scenario ``accelerometer_snr``: force-to-rebalance accelerometer, open loop vs PI loop vs
hybrid-EKF loop (Zhang 2010, chapter 5, Tables III and IV).

Device instances run side by side in one graph, each on its own namespace, all with
the thesis's chapter-5 noise (500 ug Brownian, 0.02 g electronic, per sample at 1 MHz)
and a 10 Hz sinusoidal input:

``/acc_<mode>_<amp>``  Table III: modes ``open``, ``pi``, ``ekf`` at 0.1, 1, 5, 10 g, plus
                       the open loop at 15 g (above its computed pull-in acceleration);
``/acc_qr_<case>``     Table IV: the EKF loop at 0.1 g with Q x10, Q/10, R x10, R/10 and
                       R x10 with Q/10 (same seed as ``/acc_ekf_0g1``, the "exact" case);
``/acc_pi_1g/hybrid_ekf``  a downstream hybrid EKF node on the PI loop's raw frames.

Output SNR (same definition for every mode, :mod:`mems_estimation.identification.signal_metrics`): the
device's output — the readout voltage in open loop, the feedback voltage v_F in the
closed loops — is fitted with a 10 Hz tone over the analysis window (one whole period
after a 20 ms start-up); SNR = tone power / residual variance, at the 1 MHz output rate
(full bandwidth, no post-filtering). Every figure is computed from the recorded MCAP.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mems_estimation.identification.signal_metrics import coherent_snr_db, consistency
from mems_estimation.nodes.accelerometer_ekf_node import HybridEkfNode
from mems_scenarios.base import (
    NOT_RECORDED,
    Progress,
    ScenarioError,
    ScenarioOptions,
    format_table,
    graph_for,
    publish_all,
    run_recorded,
    topic_frames,
)
from mems_scenarios.figures import Figure, cell
from mems_sim.devices import accelerometer as fra
from mems_sim.nodes.accelerometer_node import FrAccelerometerNode

NAME = "accelerometer_snr"
DESCRIPTION = (
    "force-rebalance accelerometer (Zhang 2010): open loop vs PI vs hybrid-EKF loop, "
    "output SNR and displacement (Table III), Q/R tuning (Table IV)"
)
DEFAULT_DURATION_S = 0.12
FS = 1.0e6
F_IN = 10.0
SKIP_S = 0.02
G = fra.G0
AMPS = {"0g1": 0.1, "1g": 1.0, "5g": 5.0, "10g": 10.0}
MODES = {"open": "open_loop", "pi": "pi_rebalance", "ekf": "ekf_rebalance"}
QR_CASES = {
    "exact": (1.0, 1.0),
    "qx10": (10.0, 1.0),
    "q_10": (0.1, 1.0),
    "rx10": (1.0, 10.0),
    "r_10": (1.0, 0.1),
    "rx10_q_10": (0.1, 10.0),
}
QR_LABELS = {
    "exact": "exact Q, R",
    "qx10": "Q x 10",
    "q_10": "Q / 10",
    "rx10": "R x 10",
    "r_10": "R / 10",
    "rx10_q_10": "R x 10 and Q / 10",
}
#: Thesis Table III: (SNR dB, max displacement m) per (amplitude, mode); None: not given.
PAPER_III = {
    ("0g1", "open"): (">40", 7e-9),
    ("0g1", "pi"): ("4", 4e-10),
    ("0g1", "ekf"): ("12", 4e-10),
    ("1g", "open"): (">40", 7e-8),
    ("1g", "pi"): ("24", 4e-9),
    ("1g", "ekf"): ("32", 4e-9),
    ("5g", "open"): ("unstable", None),
    ("10g", "pi"): (">40", 4e-8),
    ("10g", "ekf"): (">40", 4e-8),
}
PAPER_IV = {
    "exact": "12",
    "qx10": "10",
    "q_10": "24",
    "rx10": "24",
    "r_10": "10",
    "rx10_q_10": ">40",
}
OPEN_OVER = "open_15g"


def device_cases() -> dict[str, dict]:
    """Device parameters of every instance (namespace -> ACCEL_SPECS overrides)."""
    cases = {
        f"acc_{m}_{a}": dict(mode=mode, accel_amplitude=amp * G)
        for a, amp in AMPS.items()
        for m, mode in MODES.items()
    }
    cases[f"acc_{OPEN_OVER}"] = dict(mode="open_loop", accel_amplitude=15.0 * G)
    for case, (qs, rs) in QR_CASES.items():
        if case != "exact":
            cases[f"acc_qr_{case}"] = dict(
                mode="ekf_rebalance", accel_amplitude=0.1 * G, ekf_q_scale=qs, ekf_r_scale=rs
            )
    return cases


def _seed(options: ScenarioOptions, ns: str, k: int) -> int:
    """Run seed of one device; the Q/R sweep shares the seed of its exact case."""
    if ns.startswith("acc_qr_"):
        k = list(device_cases()).index("acc_ekf_0g1")
    return int(options.seed) * 100 + k


def build_graph(options: ScenarioOptions, out: Path, duration: float):
    """Devices, the downstream hybrid EKF and the recorder in one context."""
    graph = graph_for(options)
    devices = {}
    for k, (ns, params) in enumerate(device_cases().items()):
        p = dict(params, seed=_seed(options, ns, k), duration_s=float(duration), frame_size=10000)
        devices[ns] = graph.add_device(
            FrAccelerometerNode, p, realtime=options.realtime, namespace=ns
        )
    ekf = graph.node(
        HybridEkfNode,
        dict(
            device_cases()["acc_pi_1g"],
            device_namespace="/acc_pi_1g",
            output_topic="/acc_pi_1g/hybrid_ekf/estimate",
        ),
        namespace="acc_pi_1g",
    )
    rec = graph.recorder(str(out), regex=r"^/acc_", exclude=NOT_RECORDED)
    return graph, devices, ekf, rec


def _topics(device) -> list[str]:
    ns = device.get_namespace()
    names = ["adc", "drive", "truth"] + (["loop_estimate"] if device.ekf_mode else [])
    return [f"{ns}/{t}" for t in names]


def run_graph(options: ScenarioOptions, out: Path, duration: float, progress: Progress) -> dict:
    """Run until every device published ``duration``; return counts and device diagnostics."""
    graph, devices, ekf, rec = build_graph(options, out, duration)
    n_topics = sum(len(_topics(d)) for d in devices.values()) + 1
    ekf_topic = "/acc_pi_1g/hybrid_ekf/estimate"

    def delivered(device) -> int | None:
        """Frames the downstream EKF took (the recorder counts in the skeleton)."""
        return ekf.frames_done if device.get_namespace() == "/acc_pi_1g" else None

    try:
        graph.spin_until(
            lambda: (
                len(rec.recorded_topics()) >= n_topics
                and ekf.pub.get_subscription_count() >= 1
                and devices["acc_pi_1g"].pub_adc.get_subscription_count() >= 2
            ),
            30.0,
            "the recorder and the hybrid EKF node to subscribe",
        )
        publish_all(
            graph,
            list(devices.values()),
            delivered,
            progress,
            realtime=options.realtime,
            realtime_timeout_s=duration * 200 + 60,
            window=20,
        )
        graph.spin_until(
            lambda: rec.received(ekf_topic) >= ekf.frames_done, 60.0, "the last estimates"
        )
        published = {ns: d.frames_published for ns, d in devices.items()}
        diagnostics = {ns: dict(d.diag.counters) for ns, d in devices.items()}
    finally:
        rec.close()
        summary = dict(counts=rec.counts(), gaps=rec.gaps(), losses=rec.losses())
        graph.close()
    return dict(published=published, recorder=summary, diagnostics=diagnostics)


def _device_figures(path: Path, ns: str, ekf: bool) -> dict:
    """SNR, displacement, contact, saturation (and EKF errors) of one device from the MCAP."""
    truth = topic_frames(path, f"/{ns}/truth")["data"]
    mode = ns.split("_")[1]
    out = (
        topic_frames(path, f"/{ns}/adc")["data"][:, 0]
        if mode == "open"
        else topic_frames(path, f"/{ns}/drive")["data"][:, 0]
    )
    k0 = int(SKIP_S * FS)
    t = np.arange(truth.shape[0]) / FS
    f = dict(
        snr=coherent_snr_db(out[k0:], t[k0:], F_IN),
        x_max=float(np.abs(truth[:, 1]).max()),
        contact=bool(truth[:, 3].any()),
        saturated=bool(truth[:, 4].any()),
        series=dict(t=t, a=truth[:, 0], x=truth[:, 1], out=out),
    )
    if ekf:
        est = topic_frames(path, f"/{ns}/loop_estimate")
        err = est["data"][k0:, 0] - truth[k0:, 1]
        f.update(
            accel_snr=coherent_snr_db(est["data"][k0:, 2], t[k0:], F_IN),
            err_max=float(np.abs(err).max()),
            err_std=float(err.std()),
            consistency=consistency(err, est["variances"][k0:, 0]),
        )
    return f


def figures(path: Path, diagnostics: dict) -> dict:
    """Every figure of the scenario, from the recorded MCAP (device counters for P > 0)."""
    f: dict = {"devices": {}}
    for ns, params in device_cases().items():
        f["devices"][ns] = _device_figures(path, ns, params["mode"] == "ekf_rebalance")
        f["devices"][ns]["not_pd"] = int(
            diagnostics.get(ns, {}).get("covariance_not_pd_samples", 0)
        )
    k0 = int(SKIP_S * FS)
    truth = topic_frames(path, "/acc_pi_1g/truth")["data"]
    est = topic_frames(path, "/acc_pi_1g/hybrid_ekf/estimate")
    f["downstream"] = consistency(est["data"][k0:, 0] - truth[k0:, 1], est["variances"][k0:, 0])
    t = np.arange(truth.shape[0]) / FS
    f["downstream"]["accel_snr"] = coherent_snr_db(est["data"][k0:, 2], t[k0:], F_IN)
    p = fra.validate_params({})
    f["pull_in_g"] = fra.pull_in_acceleration(p)[0] / G
    f["checks"] = checks(f)
    return f


def _dev(f: dict, a: str, m: str) -> dict:
    return f["devices"][f"acc_{m}_{a}"]


def _qr(f: dict, case: str) -> dict:
    return f["devices"]["acc_ekf_0g1" if case == "exact" else f"acc_qr_{case}"]


def table3(f: dict) -> str:
    """Table III form: output SNR and max displacement per input and mode, thesis alongside."""
    rows = []
    for a in AMPS:
        row = [f"{AMPS[a]:g} g"]
        for m in MODES:
            d = _dev(f, a, m)
            paper = PAPER_III.get((a, m))
            state = "CONTACT" if d["contact"] else ("v_F clipped" if d["saturated"] else "")
            row += [
                cell(d["snr"], ".1f"),
                cell(d["x_max"], ".2e"),
                state,
                "-"
                if paper is None
                else f"{paper[0]} / " + ("-" if paper[1] is None else f"{paper[1]:.0e}"),
            ]
        rows.append(row)
    d = f["devices"][f"acc_{OPEN_OVER}"]
    rows.append(
        [
            "15 g",
            cell(d["snr"], ".1f"),
            cell(d["x_max"], ".2e"),
            "CONTACT" if d["contact"] else "",
            "-",
        ]
        + [""] * 8
    )
    head = ["input"]
    for m in ("open loop", "PI loop", "EKF loop"):
        head += [f"{m} SNR dB", "max |x| m", "flag", "thesis SNR / x"]
    return format_table(head, rows)


def table4(f: dict) -> str:
    """Table IV form: EKF loop at 0.1 g with scaled Q and R."""
    rows = []
    for case in QR_CASES:
        d = _qr(f, case)
        rows.append(
            [
                QR_LABELS[case],
                cell(d["snr"], ".1f"),
                cell(d["accel_snr"], ".1f"),
                cell(d["err_max"], ".2e"),
                cell(d["err_std"], ".2e"),
                "yes" if d["not_pd"] == 0 else f"NO ({d['not_pd']} samples)",
                PAPER_IV[case],
            ]
        )
    return format_table(
        [
            "EKF loop, 0.1 g",
            "output SNR dB",
            "a_hat SNR dB",
            "max |x_hat - x| m",
            "std m",
            "P > 0 throughout",
            "thesis SNR dB",
        ],
        rows,
    )


def checks(f: dict) -> list[tuple[str, str, str, str, bool]]:
    """Acceptance items this scenario measures: (item, paper, asked, measured, met)."""
    out = []
    open_ok = [not _dev(f, a, "open")["contact"] for a in ("0g1", "1g")]
    d5 = _dev(f, "5g", "open")
    out.append(
        (
            "open loop tracks 0.1 g and 1 g (no contact)",
            "yes",
            "yes",
            f"{'yes' if all(open_ok) else 'NO'}",
            all(open_ok),
        )
    )
    out.append(
        (
            "open loop at 5 g",
            "unstable, exceeds the stop",
            "contact",
            "contact"
            if d5["contact"]
            else f"tracks, max |x| {cell(d5['x_max'], '.2e')} m; static pull-in at "
            f"{cell(f['pull_in_g'], '.1f')} g",
            d5["contact"],
        )
    )
    d15 = f["devices"][f"acc_{OPEN_OVER}"]
    out.append(
        (
            f"open loop at 15 g (> pull-in {f['pull_in_g']:.1f} g)",
            "-",
            "contact",
            "contact" if d15["contact"] else "no contact",
            d15["contact"],
        )
    )
    for m in ("pi", "ekf"):
        d = _dev(f, "10g", m)
        ok = not d["contact"] and not d["saturated"]
        out.append(
            (
                f"{m.upper()} loop tracks 10 g without contact",
                "yes",
                "yes",
                f"SNR {cell(d['snr'], '.1f')} dB, max |x| {cell(d['x_max'], '.2e')} m",
                ok,
            )
        )
    ratio = min(
        _dev(f, a, "open")["x_max"] / _dev(f, a, m)["x_max"]
        for a in ("0g1", "1g")
        for m in ("pi", "ekf")
    )
    out.append(
        (
            "open-loop / closed-loop max displacement (0.1 g, 1 g)",
            "17.5",
            ">= 10",
            cell(ratio, ".1f"),
            ratio >= 10,
        )
    )
    for a in ("0g1", "1g"):
        gain = _dev(f, a, "ekf")["snr"] - _dev(f, a, "pi")["snr"]
        xr = _dev(f, a, "ekf")["x_max"] / _dev(f, a, "pi")["x_max"]
        out.append(
            (
                f"EKF loop - PI loop SNR at {AMPS[a]:g} g (max |x| ratio)",
                "+8 dB",
                ">= +6 dB, same |x|",
                f"{cell(gain, '+.1f')} dB ({cell(xr, '.2f')})",
                gain >= 6 and xr <= 1.1,
            )
        )
    s = {c: _qr(f, c)["snr"] for c in QR_CASES}
    direction = s["q_10"] > s["exact"] > s["qx10"] and s["rx10"] > s["exact"] > s["r_10"]
    out.append(
        (
            "Q/R sweep: Q/10, R x10 raise SNR; Q x10, R/10 lower it",
            "yes",
            "yes",
            "yes" if direction else "NO",
            direction,
        )
    )
    pd = all(_qr(f, c)["not_pd"] == 0 for c in QR_CASES)
    out.append(
        (
            "covariance positive definite in every Q/R case",
            "fails if pushed",
            "flagged",
            "all PD" if pd else "some not PD (see Table IV)",
            True,
        )
    )
    for label, c in (
        ("in-loop EKF, 1 g", _dev(f, "1g", "ekf")["consistency"]),
        ("downstream EKF on the PI loop, 1 g", f["downstream"]),
    ):
        ok = abs(c["mean"]) <= 3 * c["stderr"] and 0.8 <= c["std_ratio"] <= 1.2
        out.append(
            (
                f"{label}: x error mean / std vs predicted",
                "zero mean, 1e-10",
                "|mean| <= 3 se, std within 20 %",
                f"{cell(c['mean'], '.1e')} (se {cell(c['stderr'], '.1e')}) / "
                f"{cell(c['std'], '.2e')} vs {cell(c['predicted_std'], '.2e')} "
                f"({cell(c['std_ratio'], '.2f')})",
                ok,
            )
        )
    return out


#: Stable names of the acceptance items of :func:`checks`, in its order.
CHECK_NAMES = (
    "check.open_loop_tracks_0g1_1g",
    "check.open_loop_contact_5g",
    "check.open_loop_contact_15g",
    "check.pi_loop_tracks_10g",
    "check.ekf_loop_tracks_10g",
    "check.open_closed_x_max_ratio",
    "check.ekf_minus_pi_snr_0g1",
    "check.ekf_minus_pi_snr_1g",
    "check.qr_sweep_direction",
    "check.qr_covariance_pd_flagged",
    "check.ekf_1g_consistency",
    "check.downstream_ekf_1g_consistency",
)


def _consistency_records(prefix: str, c: dict) -> list[Figure]:
    return [
        Figure(f"{prefix}.x_err_mean", c["mean"], "m"),
        Figure(f"{prefix}.x_err_mean_stderr", c["stderr"], "m"),
        Figure(f"{prefix}.x_err_std", c["std"], "m"),
        Figure(f"{prefix}.x_err_predicted_std", c["predicted_std"], "m"),
        Figure(f"{prefix}.x_err_std_ratio", c["std_ratio"], "1"),
    ]


def records(f: dict) -> list[Figure]:
    """The scenario's figures as data: per device (namespace) output SNR [dB], max |x| [m],
    contact and clipping flags, the EKF loops' a_hat SNR and x errors [m], the Table IV
    covariance check, the consistency figures, and the acceptance items (value: the measured
    text of the item)."""
    out = []
    for ns, params in device_cases().items():
        d = f["devices"][ns]
        out += [
            Figure(f"{ns}.output_snr", d["snr"], "dB"),
            Figure(f"{ns}.x_max", d["x_max"], "m"),
            Figure(f"{ns}.contact", d["contact"], ""),
            Figure(f"{ns}.v_f_clipped", d["saturated"], ""),
        ]
        if params["mode"] == "ekf_rebalance":
            out += [
                Figure(f"{ns}.accel_snr", d["accel_snr"], "dB"),
                Figure(f"{ns}.x_err_max", d["err_max"], "m"),
                Figure(f"{ns}.x_err_std", d["err_std"], "m"),
            ]
        if ns == "acc_ekf_0g1" or ns.startswith("acc_qr_"):
            out.append(Figure(f"{ns}.not_pd_samples", d["not_pd"], "", "== 0", d["not_pd"] == 0))
    out += _consistency_records("acc_ekf_1g.consistency", f["devices"]["acc_ekf_1g"]["consistency"])
    out += _consistency_records("acc_pi_1g.hybrid_ekf.consistency", f["downstream"])
    out.append(Figure("acc_pi_1g.hybrid_ekf.accel_snr", f["downstream"]["accel_snr"], "dB"))
    out.append(Figure("pull_in", f["pull_in_g"], "g"))
    items = f["checks"]
    if len(items) != len(CHECK_NAMES):
        raise ScenarioError(f"{len(items)} acceptance items, {len(CHECK_NAMES)} names")
    for name, (_, _, asked, measured, ok) in zip(CHECK_NAMES, items):
        out.append(Figure(name, measured, "", asked, bool(ok)))
    return out


def table(f: dict) -> str:
    """All three tables."""
    rows = [[i, p, a, m, "yes" if ok else "NO"] for i, p, a, m, ok in checks(f)]
    return "\n\n".join(
        [
            "Table III form (10 Hz input; SNR over one period at the 1 MHz output rate):",
            table3(f),
            "Table IV form:",
            table4(f),
            "Acceptance items:",
            format_table(["item", "thesis", "asked", "measured", "met"], rows),
        ]
    )


def plot(f: dict, path: Path) -> None:
    """Output vs input and displacement at 1 g for the three modes; Table IV's SNRs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 1, figsize=(11, 11))
    k0 = int(SKIP_S * FS)
    for m, label in (("open", "open loop"), ("pi", "PI loop"), ("ekf", "hybrid-EKF loop")):
        s = _dev(f, "1g", m)["series"]
        # the output in acceleration units: least-squares gain against the input
        gain = float(np.dot(s["out"][k0:], s["a"][k0:]) / np.dot(s["a"][k0:], s["a"][k0:]))
        step = 50
        ax[0].plot(s["t"][::step] * 1e3, s["out"][::step] / gain / G, lw=0.4, label=label)
        ax[1].plot(s["t"][::step] * 1e3, s["x"][::step] * 1e9, lw=0.6, label=label)
    s = _dev(f, "1g", "open")["series"]
    ax[0].plot(s["t"] * 1e3, s["a"] / G, "k-", lw=1.2, label="input")
    ax[0].set(
        xlabel="time [ms]",
        ylabel="output / gain [g]",
        title="1 g, 10 Hz input: outputs scaled by their fitted gain (every 50th sample)",
    )
    ax[0].legend(fontsize=8)
    ax[1].set(
        xlabel="time [ms]",
        ylabel="proof-mass displacement [nm]",
        title="1 g: displacement (open loop vs rebalanced)",
    )
    ax[1].legend(fontsize=8)
    cases = list(QR_CASES)
    ax[2].bar(range(len(cases)), [_qr(f, c)["snr"] for c in cases], color="C2")
    ax[2].set_xticks(range(len(cases)), [QR_LABELS[c] for c in cases], fontsize=8)
    ax[2].set(ylabel="output SNR [dB]", title="Table IV: EKF loop at 0.1 g, scaled Q and R")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _check_duration(duration: float) -> None:
    if duration < SKIP_S + 1.0 / F_IN - 1e-9:
        raise ScenarioError(
            f"--duration = {duration!r} is too short for {NAME}: at least "
            f"{SKIP_S + 1.0 / F_IN:g} s (start-up and one 10 Hz period)"
        )


def run(options: ScenarioOptions) -> dict:
    """Run the scenario; return the tables, figures and paths."""
    r = run_recorded(
        options,
        name=NAME,
        default_duration_s=DEFAULT_DURATION_S,
        check_duration=_check_duration,
        run_graph=run_graph,
        figures=lambda out, res, _d: figures(out, res["diagnostics"]),
        records=records,
        table=table,
        plot=plot,
    )
    f = r["values"]
    r["values"] = dict(
        devices={
            ns: {k: v for k, v in d.items() if k != "series"} for ns, d in f["devices"].items()
        },
        downstream=f["downstream"],
        pull_in_g=f["pull_in_g"],
        checks=f["checks"],
    )
    return r

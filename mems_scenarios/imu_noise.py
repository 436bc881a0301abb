"""Scenario ``imu_noise``: IMU noise emulator -> Allan noise identification -> MCAP.

Graph (one process): ``/imu/imu_noise`` (mems_sim.nodes.imu_node) publishes
``/imu/adc``, ``/imu/truth`` (and ``/imu/data``, sensor_msgs/Imu per sample, in
--realtime runs, and in fast runs with ``--set imu.publish_imu=true``);
``/imu/noise_identifier`` identifies N, B, K, T per axis from ``/imu/adc`` and
publishes ``/imu/noise_model``; the recorder writes everything to MCAP.
Prints configured vs identified N, B, K, T per axis and writes an Allan
deviation figure with the fitted terms.
"""

from __future__ import annotations

import math
from pathlib import Path

from mems_estimation.identification.imu_noise_fit import crb_relative_se
from mems_estimation.identification.imu_noise_plots import plot_allan
from mems_scenarios import base, contract, delivery
from mems_scenarios.figures import Figure, cell, is_finite, project_criterion
from mems_sim.ros.frames import index_to_ns
from mems_sim.table import yes_no

NAME = "imu_noise"
DESCRIPTION = (
    "ADIS16350-like IMU at rest (Petkov): emulator -> Allan-variance identification "
    "of N, B, K, T per axis -> MCAP"
)
DEFAULT_DURATION_S = 10000.0
#: Frame size in fast runs (1 s of data per frame at 100 Hz) and in real-time runs.
FAST_FRAME = 100
REALTIME_FRAME = 10
#: Frames the emulator may run ahead of the slowest consumer in fast runs.
WINDOW = 50
TOPICS = ["/imu/adc", "/imu/truth", "/imu/noise_model", "/imu/end_of_stream", "/diagnostics"]

PARAM_NAMES = (
    ("N", "noise_density"),
    ("B", "bias_instability"),
    ("K", "random_walk"),
    ("T", "correlation_time"),
)
#: Fully qualified names of the emulator and the identifier.
EMULATOR = "/imu/imu"
IDENTIFIER = "/imu/imu_noise_identifier"
FIELD = {
    "N": "white_noise_density",
    "B": "bias_instability",
    "K": "random_walk",
    "T": "correlation_time",
}


def graph(options: base.ScenarioOptions, duration_s: float) -> contract.GraphSpec:
    """The scenario's graph: the emulator and the identifier in ``/imu``, recorded."""
    emulator = contract.NodeEntry(
        "imu_node",
        "imu",
        "imu",
        {
            "seed": int(options.seed),
            "duration_s": float(duration_s),
            "frame_size": REALTIME_FRAME if options.realtime else FAST_FRAME,
            "publish_imu": bool(options.realtime),
        },
        consumers="adc:2",  # the identifier and the recorder
    )
    identifier = contract.NodeEntry(
        "imu_noise_identifier_node",
        "imu_noise_identifier",
        "imu",
        {"publish_period_s": 0.0 if duration_s < 7200 else 3600.0},
    )
    return contract.GraphSpec(NAME, (emulator, identifier), (*TOPICS, contract.RUN_INFO_TOPIC))


def build_graph(options: base.ScenarioOptions, out: Path, duration_s: float):
    """Create the context, the nodes of :func:`graph` and the recorder; publish the run
    record."""
    spec = graph(options, duration_s)
    g = base.graph_for(options)
    nodes = g.build(spec, realtime=options.realtime)
    emu, ident = nodes[EMULATOR], nodes[IDENTIFIER]
    # sensor_msgs/Imu (one per sample) whenever the emulator publishes it: on by default in
    # --realtime runs, in fast runs with publish_imu set (lossless through drive_fast's flow
    # control, which counts every data topic the recorder records)
    topics = list(spec.recorded) + (["/imu/data"] if emu.pub_imu is not None else [])
    rec = g.recorder(str(out), topics=topics)
    g.publish_run_info(spec, options, nodes, duration_s=duration_s)
    return g, emu, ident, rec


def _wait_matched(graph: base.Graph, emu, ident, rec) -> None:
    def matched() -> bool:
        return (
            emu.pub_adc.get_subscription_count() >= 2
            and emu.pub_truth.get_subscription_count() >= 1
            and (emu.pub_imu is None or emu.pub_imu.get_subscription_count() >= 1)
            and ident.pub.get_subscription_count() >= 1
        )

    graph.spin_until(matched, 20.0, "the recorder and identifier to subscribe")


def run_fast(graph: base.Graph, emu, ident, rec, progress: base.Progress) -> None:
    """Step the emulator as fast as the consumers take its frames (no loss, deterministic)."""
    # the recorder counts for every topic the emulator publishes (the skeleton's flow
    # control): a reader that falls more than the publisher's history behind would lose
    # frames (reliable KEEP_LAST overwrites them)
    delivery.drive_fast(graph, [emu], delivery.consumed(ident), progress, WINDOW)


def run_realtime(graph: base.Graph, emu, progress: base.Progress) -> None:
    """Spin with the emulator's own wall-clock timer until its duration is published."""
    delivery.prepare_delivery(graph, [emu])
    emu.start()
    while not emu.finished:
        graph.executor.spin_once(timeout_sec=0.05)
        graph.publish_clock(index_to_ns(emu.next_index, emu.fs))
        progress.update_to(emu.next_index / emu.fs)


def drain(graph: base.Graph, emu, ident, rec) -> None:
    """Wait until every message reached the identifier and the recorder (a loss raises
    ScenarioError naming the topic); have the identifier publish its final model (its
    end-of-input service, as at shutdown) and wait until the recorder holds it."""
    delivery.finish_delivery(graph, [emu], delivery.consumed(ident))
    before = rec.received("/imu/noise_model")
    if ident.finish() is None:
        raise base.ScenarioError(
            "no noise model: too little data (use --duration of at least "
            f"{ident.p['min_duration_s']:.0f} s)"
        )
    graph.spin_until(
        lambda: rec.received("/imu/noise_model") > before,
        20.0,
        "the recorder to receive the final noise model",
    )
    graph.wait_run_info(rec)


def configured_values(params: dict) -> dict:
    """Configured N, B, K, T of the gyro and accelerometer (SI) from the emulator's
    parameter values, and ``Nq``: the white-noise density the codes carry
    (:func:`quantised_density`), which the identified N estimates."""
    out = {}
    for s in ("gyro", "accel"):
        out[s] = {sym: params[f"{s}_{name}"] for sym, name in PARAM_NAMES}
        out[s]["Nq"] = quantised_density(out[s]["N"], params[f"{s}_lsb"], params["sample_rate_hz"])
    return out


def quantised_density(n: float, lsb: float, fs: float) -> float:
    """White-noise density of a converter's codes: ``sqrt(N^2 + LSB^2 / (12 fs))``.

    Rounding to one LSB adds white noise of variance LSB^2/12 per sample when the noise
    spans several codes (uniform quantisation noise: Bennett, "Spectra of quantized
    signals", Bell Syst. Tech. J. 27, 1948; Widrow and Kollar, Quantization Noise, 2008,
    ch. 4): +0.85 % of N for the accelerometer of the default preset at 100 Hz.

    Args:
        n: configured noise density [unit/sqrt(Hz)]; lsb: code step [unit]; fs: sample rate [Hz].
    """
    return math.sqrt(n * n + lsb * lsb / (12.0 * fs))


#: The headline N is judged: its error within this many standard errors of the identifier's
#: own 95 % interval (a calibrated interval: 93-95 % coverage over seeds 2-21).
N_TOLERANCE_SE = 4.0
N_TARGET = "|rel_error| <= 4 s.e. of the 95 % interval"
N_SOURCE = project_criterion(
    "beyond 4 standard errors of the identifier's own interval the estimate is biased, not unlucky"
)


def n_verdict(term, ref: float | None) -> bool | None:
    """Whether the identified N ``term`` (value, ci_low, ci_high) lies within
    :data:`N_TOLERANCE_SE` standard errors (the 95 % interval's half-width / 1.96) of the
    density the codes carry ``ref``; None where either is missing or not finite."""
    if not ref or not all(is_finite(v) for v in (term.value, term.ci_low, term.ci_high)):
        return None
    se = (term.ci_high - term.ci_low) / (2.0 * 1.959964)
    return abs(term.value - ref) <= N_TOLERANCE_SE * se


def results_table(model, configured: dict | None) -> tuple[str, list[dict]]:
    """Configured vs identified N, B, K, T per axis with relative errors and the Cramer-Rao
    standard error of each for a record of this length (at the identified values)."""
    rows, records = [], []
    for axis in model.axes:
        sensor = "gyro" if axis.axis.startswith("gyro") else "accel"
        vals = [getattr(axis, FIELD[sym]).value for sym in ("N", "B", "K", "T")]
        crb = crb_relative_se(*vals, model.sample_rate_hz, model.num_samples)
        for sym, _ in PARAM_NAMES:
            term = getattr(axis, FIELD[sym])
            # N: the density the codes carry, quantisation included (quantised_density)
            ref = "Nq" if sym == "N" else sym
            conf = configured[sensor][ref] if configured is not None else None
            rel = (term.value - conf) / conf if conf else math.nan
            unit = {
                "N": f"{axis.unit}/sqrt(Hz)",
                "B": axis.unit,
                "K": f"{axis.unit}/sqrt(s)",
                "T": "s",
            }[sym]
            rows.append(
                [
                    axis.axis,
                    sym,
                    unit,
                    cell(conf, ".4g"),
                    cell(term.value, ".4g"),
                    f"[{cell(term.ci_low, '.3g')}, {cell(term.ci_high, '.3g')}]",
                    cell(100 * rel if is_finite(rel) else rel, "+.1f", " %"),
                    cell(crb[sym] * term.value, ".3g"),
                    _met(n_verdict(term, conf)) if sym == "N" and configured else "-",
                ]
            )
            records.append(
                dict(
                    axis=axis.axis, param=sym, configured=conf, identified=term.value, rel_error=rel
                )
            )
    header = [
        "axis",
        "param",
        "unit",
        "configured",
        "identified",
        "95 % CI",
        "rel. error",
        "CRB s.e.",
        "met",
    ]
    note = (
        "\nN configured: the density the codes carry, sqrt(N^2 + LSB^2/(12 fs)) with the "
        "ADC's quantisation noise (Bennett 1948)"
        if configured is not None
        else ""
    )
    return base.format_table(header, rows) + note, records


def figure_records(model, configured: dict | None) -> list[Figure]:
    """The table as data, per axis and term (e.g. ``gyro_x.N.identified``): configured and
    identified value, 95 % CI bounds (unit as printed: SI per axis) and the relative error
    (a fraction; of N against ``configured_with_quantisation``, the density the codes
    carry, :func:`quantised_density`); without ``configured`` (a recording without run record) the identified
    ones only. N is judged (:data:`N_TARGET`); B, K and T are reported, not judged: over
    the paper's 10,000 s their errors reach tens of per cent at honest intervals."""
    out = []
    for axis in model.axes:
        sensor = "gyro" if axis.axis.startswith("gyro") else "accel"
        for sym, _ in PARAM_NAMES:
            term = getattr(axis, FIELD[sym])
            conf = configured[sensor][sym] if configured is not None else None
            ref = (
                configured[sensor]["Nq" if sym == "N" else sym] if configured is not None else None
            )
            rel = (term.value - ref) / ref if ref else math.nan
            unit = {"N": f"{axis.unit}/sqrt(Hz)", "B": axis.unit, "K": f"{axis.unit}/sqrt(s)"}
            unit = unit.get(sym, "s")
            key = f"{axis.axis}.{sym}"
            out += [
                Figure(f"{key}.identified", term.value, unit),
                Figure(f"{key}.ci_low", term.ci_low, unit),
                Figure(f"{key}.ci_high", term.ci_high, unit),
            ]
            if configured is not None:  # the emulator's parameters are in the run record
                out.insert(-3, Figure(f"{key}.configured", conf, unit))
                if sym == "N":
                    out.append(Figure(f"{key}.configured_with_quantisation", ref, unit))
                verdict = n_verdict(term, ref) if sym == "N" else None
                target = None if verdict is None else N_TARGET
                source = None if verdict is None else N_SOURCE
                out.append(Figure(f"{key}.rel_error", rel, "1", target, verdict, source))
    return out


def _met(verdict: bool | None) -> str:
    return "-" if verdict is None else yes_no(verdict)


def final_model(bag) -> object | None:
    """The identifier's final noise model: the last message on ``/imu/noise_model``."""
    from mems_sim.bag.player import read_messages

    model = None
    for _, _, _, msg in read_messages(str(bag), ["/imu/noise_model"]):
        model = msg
    return model


def analyse(bag, plots: Path | None = None) -> contract.ScenarioResult:
    """The scenario's figures from its recording ``bag`` alone: the final noise model
    (``/imu/noise_model``) against the emulator's configured terms (its parameters in the
    run record). ``plots``: the Allan figure's PNG path (None: none)."""
    model = final_model(bag)
    if model is None:
        return contract.ScenarioResult(
            NAME, [], "", unavailable=[("*", f"{bag}: no message on /imu/noise_model")]
        )
    unavailable = []
    try:
        configured = configured_values(
            contract.node_parameters(contract.read_run_info(bag), EMULATOR, "configured N, B, K, T")
        )
    except contract.AnalysisError as exc:
        configured, unavailable = None, [("*.configured, *.rel_error", str(exc))]
    table, records = results_table(model, configured)
    figures = figure_records(model, configured)
    paths = []
    if plots is not None:
        plot_allan(model, plots)
        paths.append(plots)
    return contract.ScenarioResult(
        NAME,
        figures,
        table,
        paths,
        unavailable,
        values=dict(records=records, model=model),
    )


def run(options: base.ScenarioOptions) -> dict:
    """Run the scenario and analyse its recording (:func:`analyse`); return a dict with the
    table, records, paths and counts."""
    duration = DEFAULT_DURATION_S if options.duration_s is None else options.duration_s
    out = options.out or Path("runs") / f"{NAME}-{options.seed}.mcap"
    out.parent.mkdir(parents=True, exist_ok=True)
    graph, emu, ident, rec = build_graph(options, out, duration)
    progress = base.Progress(duration, options.progress, NAME)
    try:
        _wait_matched(graph, emu, ident, rec)
        if options.realtime:
            run_realtime(graph, emu, progress)
        else:
            run_fast(graph, emu, ident, rec, progress)
        progress.close()
        drain(graph, emu, ident, rec)
        published = {
            "/imu/adc": emu.frames_published,
            "/imu/truth": emu.frames_published,
            "/imu/noise_model": len(ident.results),
        }
        if emu.pub_imu is not None:
            published["/imu/data"] = emu.next_index
    finally:
        progress.close()
        rec.close()
        summary = rec.report(text=True)
        graph.close()
    png = base.output_path(out, options.seed, "-allan.png") if options.plots else None
    result = analyse(out, png)
    return dict(
        table=result.table,
        figures=result.figures,
        records=result.values["records"],
        mcap=out,
        figure=png,
        model=result.values["model"],
        recorder=summary,
        published=published,
        duration_s=duration,
        result=result,
    )

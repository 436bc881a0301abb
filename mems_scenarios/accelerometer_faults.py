"""Scenario ``accelerometer_faults``: the force-rebalance accelerometer fails on schedule,
and the downstream hybrid EKF's innovation monitor finds it (fault detection on the graph).

Graph (one process): ``/acc/accelerometer`` (mems_sim.nodes.accelerometer_node, PI
rebalance, Zhang 2010 ch. 5 noise, 10 Hz input) with the fault schedule of the package's
``config/accelerometer_faults.yaml`` (200 ms fault-free, then 31 readout faults of 10 ms,
25 ms apart: bias steps
of 5 innovation standard deviations, frozen readouts, lowered rails, noise bursts, spikes
and a final sign flip; ``--faults FILE`` replaces it) publishes ``adc``, ``drive``,
``truth`` and the labelled truth ``faults``; ``/acc/accelerometer_ekf``
(mems_estimation.nodes.accelerometer_ekf_node) publishes ``estimate`` and its windowed NIS
verdicts on ``health``; the recorder writes them all. The filter's model is the device's,
identified on the bench before the graph runs (:mod:`mems_scenarios.accelerometer_bench`:
``<out>-seed<N>-accelerometer_params.yaml``, its ``params_yaml``; the run record holds the
bench's result).

Figures, from the recording alone (:func:`analyse`): per fault kind the share of faults
detected within 10 ms of their onset by an alarming window (upper test; two-sided for the
kinds that freeze or clip the readout, whose NIS falls), the median delay, the alarm
episodes outside the faults and their 10 ms settling guard against the designed count
(at most its Poisson 3-sigma bound plus 2: the monitor's calibration is the nominal
device's, which a drawn device, ``--device-seed``, keeps with the bench's model),
and the RMS acceleration error inside and outside the faults (scored by
:mod:`mems_estimation.identification.detection_metrics`). The same detection and false-alarm
figures again as ``bench.*``: the recorded window sums judged by a monitor calibrated on the
run's own fault-free start (the windows before the first fault; the mean NIS and dispersion
of their sums, as ``calibrate_health`` calibrates a node), which a drawn device passes. The detection statistics over
seeds and drawn devices are the study ``python -m
mems_scenarios.accelerometer_fault_detection``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from mems_estimation.filters.consistency_monitor import NisMonitor, window_moments
from mems_estimation.identification.detection_metrics import (
    Fault,
    Verdicts,
    detections,
    false_alarms,
)
from mems_scenarios import accelerometer_bench as accel_bench
from mems_scenarios import bag_frames, base, contract, delivery
from mems_scenarios.figures import Figure, figure_table, project_criterion
from mems_sim.ros.flow import progress_of

NAME = "accelerometer_faults"
DESCRIPTION = (
    "force-rebalance accelerometer with scheduled readout faults: detection by the "
    "downstream hybrid EKF's NIS monitor, from the recording"
)
DEFAULT_DURATION_S = 1.0
FS = 1e6
NS = "acc"
EMULATOR = f"/{NS}/accelerometer"
ESTIMATOR = f"/{NS}/accelerometer_ekf"
SCHEDULE_FILE = "accelerometer_faults.yaml"
#: A detection counts within this many samples of the onset (10 ms, ten windows).
HORIZON = 10_000
#: Windows after a fault's end left out of the false alarms (the loop's settling), samples.
GUARD = 10_000
#: Kinds whose NIS falls (a frozen or clipped readout has too little noise): scored with the
#: two-sided test.
LOW_KINDS = ("stuck_at", "saturation")
#: Detection share asked per kind of the default schedule (its magnitudes), -.
TARGETS = {
    "bias_step": 0.95,
    "stuck_at": 0.95,
    "saturation": 0.95,
    "noise_burst": 0.95,
    "spikes": 0.95,
    "sign_flip": 0.95,
}
#: Where the targets come from (the figures' ``source``).
DETECTION_SOURCE = project_criterion(
    "a fault of the default schedule's magnitude is seen within 10 ms in 95 % of its episodes"
)
FALSE_ALARM_SOURCE = project_criterion(
    "the monitor's designed false-alarm count, with a Poisson 3-sigma bound plus 2"
)
FINITE_SOURCE = project_criterion("a fault never drives the estimator to NaN or infinity")
TOPICS = [f"/{NS}/{t}" for t in ("adc", "drive", "truth", "faults", "estimate", "health")]


def schedule_path() -> Path:
    """The default schedule, installed with the package (share/mems_emulator/config)."""
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory(contract.PACKAGE)) / "config" / SCHEDULE_FILE


def _device(options: base.ScenarioOptions, duration_s: float) -> contract.NodeEntry:
    return contract.NodeEntry(
        "accelerometer_node",
        "accelerometer",
        NS,
        dict(
            seed=int(options.seed),
            duration_s=float(duration_s),
            frame_size=10000,
            fault_schedule=str(schedule_path()),
        ),
    )


def bench_identification(options: base.ScenarioOptions, out=None) -> dict:
    """The device identified on the bench, its model YAML written beside ``out``
    (:func:`mems_scenarios.accelerometer_bench.bench_identification`)."""
    device = _device(options, DEFAULT_DURATION_S)
    return accel_bench.bench_identification(options, device, NAME, out)


def prepare(options: base.ScenarioOptions) -> dict:
    """Make the model YAML :func:`graph` names before a runner of processes starts it
    (``run_scenario --write-launch``); returns what the run record adds."""
    return contract.bench_record(bench_identification(options))


def graph(
    options: base.ScenarioOptions, duration_s: float, bench: dict | None = None
) -> contract.GraphSpec:
    """The device (its default schedule) and the downstream EKF in ``/acc`` with the bench's
    model (``bench``: the YAML's path, :func:`~mems_scenarios.accelerometer_bench.bench_paths`
    by default), recorded."""
    if bench is None:
        bench = accel_bench.bench_paths(options, NAME)
    device = _device(options, duration_s)
    ekf = contract.NodeEntry(
        "accelerometer_ekf_node", "accelerometer_ekf", NS, dict(params_yaml=str(bench["path"]))
    )
    return contract.GraphSpec(
        NAME, (device, ekf), (*TOPICS, "/diagnostics", contract.RUN_INFO_TOPIC)
    )


def run_graph(
    options: base.ScenarioOptions, out: Path, duration: float, progress: base.Progress
) -> dict:
    """Run :func:`graph` until the device published ``duration`` and the EKF took it all;
    record it with the run record; return counts."""
    bench = bench_identification(options, out)
    spec = graph(options, duration, bench)
    g = base.graph_for(options)
    nodes = g.build(spec, realtime=options.realtime)
    device, ekf = nodes[EMULATOR], nodes[ESTIMATOR]
    regex = rf"^/{NS}/|^/diagnostics$|^{re.escape(contract.RUN_INFO_TOPIC)}$"
    rec = g.recorder(str(out), regex=regex, exclude=base.NOT_RECORDED)
    g.publish_run_info(spec, options, nodes, duration_s=duration, **contract.bench_record(bench))
    try:
        g.spin_until(
            lambda: (
                device.pub_adc.get_subscription_count() >= 2
                and device.pub_drive.get_subscription_count() >= 2
                and ekf.pub.get_subscription_count() >= 1
                and all(rec.matched(t) for t in TOPICS if t != f"/{NS}/faults")
                and (device.fault_topic.publisher is None or rec.matched(f"/{NS}/faults"))
            ),
            30.0,
            "the recorder and the hybrid EKF node to subscribe",
        )
        delivery.publish_all(
            g,
            [device],
            lambda _d: progress_of(ekf) or 0,
            progress,
            realtime=options.realtime,
            realtime_timeout_s=duration * 200 + 60,
            window=20,
        )
        g.spin_until(
            lambda: rec.received(f"/{NS}/estimate") >= ekf.frames_done,
            60.0,
            "the last estimates",
        )
        g.spin_until(
            lambda: rec.received(f"/{NS}/health") >= ekf.diag.counters["health_windows"],
            60.0,
            "the last health verdicts",
        )
        g.wait_run_info(rec)
        published = {f"/{NS}/adc": device.frames_published}
    finally:
        rec.close()
        counts = {t: n for t, n in rec.counts().items() if t != "/diagnostics"}
        summary = rec.report(counts)
        g.close()
    return dict(published=published, recorder=summary)


def _check_duration(duration: float) -> None:
    if duration < 0.25:
        raise base.ScenarioError(
            f"--duration = {duration!r} is too short for {NAME}: at least 0.25 s (the "
            "default schedule's first fault begins at 200 ms and a detection needs 10 ms)"
        )


def read_faults(bag) -> list[Fault]:
    """The labelled faults of the recording (``/acc/faults``, FaultEvent), in onset order."""
    from mems_sim.bag.player import read_messages

    out = []
    for _, _, _, m in read_messages(str(bag), [f"/{NS}/faults"]):
        first = int(m.first_faulty_sample)
        end = None if m.faulty_samples == 0 else first + int(m.faulty_samples)
        out.append(Fault(first, end, m.kind, float(m.magnitude)))
    return sorted(out, key=lambda f: f.first)


def read_verdicts(bag) -> tuple[Verdicts, np.ndarray, float, float, int]:
    """The health windows of the recording (``/acc/health``), each window's statistic (NIS
    sum, -), the designed false-alarm probability per window, the WARN threshold and the
    degrees of freedom per sample (of the last window)."""
    from mems_sim.bag.player import read_messages

    first, n, level, low, stat, alpha, warn, dof = [], [], [], [], [], None, None, 1
    for _, _, _, m in read_messages(str(bag), [f"/{NS}/health"]):
        v = {kv.key: kv.value for kv in m.values}
        first.append(int(v["first_sample_index"]))
        n.append(int(v["samples"]))
        level.append(m.level[0] if isinstance(m.level, bytes) else int(m.level))
        low.append(v["low"] == "true")
        stat.append(float(v["statistic"]))
        alpha, warn = float(v["false_alarm"]), float(v["threshold_warn"])
        dof = int(v.get("dof", 1))
    if not first:
        raise contract.AnalysisError(f"{bag}: no health verdicts on /{NS}/health")
    return Verdicts.of(first, n, level, low), np.asarray(stat), alpha, warn, dof


def _error_rms(bag, faults: list[Fault]) -> tuple[float, float, bool]:
    """RMS acceleration error [m/s^2] of the EKF inside and outside the faults (and their
    guard), and whether every estimate is finite."""
    fr = bag_frames.topics_frames(bag, [f"/{NS}/estimate", f"/{NS}/truth"])
    est, truth = fr[f"/{NS}/estimate"], fr[f"/{NS}/truth"]
    k0 = est["first_index"] - truth["first_index"]
    a_est = est["data"][:, 2]
    a_true = truth["data"][k0 : k0 + a_est.size, 0]
    err = a_est - a_true[: a_est.size]
    idx = est["first_index"] + np.arange(err.size)
    inside = np.zeros(err.size, bool)
    guard = np.zeros(err.size, bool)
    for f in faults:
        end = idx[-1] + 1 if f.end is None else f.end
        inside |= (idx >= f.first) & (idx < end)
        guard |= (idx >= f.first) & (idx < end + GUARD)
    finite = bool(np.isfinite(a_est).all())

    def rms(sel):
        return float(np.sqrt(np.mean(err[sel] ** 2))) if sel.any() else float("nan")

    return rms(inside), rms(~guard), finite


def plot(
    path: Path, faults: list[Fault], verdicts: Verdicts, statistic: np.ndarray, warn: float
) -> None:
    """The monitor's window statistic (NIS sum over the window's samples, log scale)
    against time, the faults shaded by kind and the WARN threshold dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mems_sim.bag.output_paths import write_output

    fig, ax = plt.subplots(figsize=(10, 3.6))
    colours = {}
    for f in faults:
        c = colours.setdefault(f.kind, f"C{len(colours) + 1}")
        end = verdicts.end[-1] if f.end is None else f.end
        ax.axvspan(f.first / FS, end / FS, color=c, alpha=0.25, lw=0)
    t = (verdicts.first + verdicts.n / 2) / FS
    ax.semilogy(t, np.maximum(statistic, 1e-3), ".", ms=2, color="C0")
    ax.axhline(warn, color="k", ls="--", lw=0.8, label="WARN threshold")
    for kind, c in colours.items():
        ax.plot([], [], "s", color=c, alpha=0.5, label=kind)
    ax.set_xlabel("sensor time [s]")
    ax.set_ylabel("NIS sum per window")
    ax.set_title(f"{NAME}: the EKF's innovation monitor against the scheduled faults", fontsize=9)
    ax.legend(fontsize=7, ncol=4, loc="upper left")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    write_output(path, lambda tmp: fig.savefig(tmp, dpi=100), overwrite=True)
    plt.close(fig)


def _scores(prefix: str, faults, scored, verdicts: Verdicts, alpha: float, bench_end: int):
    """Detection and false-alarm figures of ``verdicts`` (names ``prefix`` + ...): per kind
    of the ``scored`` faults the share detected and the median delay; the false-alarm
    episodes outside the faults, their guard and the bench part (samples before
    ``bench_end``) against the designed count."""
    out: list[Figure] = []
    for kind in dict.fromkeys(f.kind for f in scored):
        mine = [f for f in scored if f.kind == kind]
        s = detections(mine, verdicts, HORIZON, two_sided=kind in LOW_KINDS)
        share = sum(d.detected for d in s) / len(s)
        delays = [d.delay for d in s if d.detected]
        target = TARGETS.get(kind)
        out += [
            Figure(f"{prefix}{kind}.faults", len(s), ""),
            Figure(
                f"{prefix}{kind}.detected",
                share,
                "1",
                None if target is None else f">= {target:g}",
                None if target is None else share >= target,
                None if target is None else DETECTION_SOURCE,
            ),
            Figure(
                f"{prefix}{kind}.median_delay_ms",
                float(np.median(delays)) / FS * 1e3 if delays else None,
                "ms",
            ),
        ]
    excluded = [*faults, Fault(0, bench_end, "bench")] if bench_end > 0 else list(faults)
    fa = false_alarms(excluded, verdicts, GUARD)
    designed = alpha * fa.windows
    # a Poisson count's 3-sigma bound above the designed count, plus 2 for small counts
    limit = math.ceil(designed + 3.0 * math.sqrt(designed) + 2.0)
    return out + [
        Figure(
            f"{prefix}false_alarm.episodes",
            fa.episodes,
            "",
            f"<= {limit} (designed {designed:.2g})",
            fa.episodes <= limit,
            FALSE_ALARM_SOURCE,
        ),
        Figure(f"{prefix}false_alarm.windows", fa.windows, ""),
        Figure(f"{prefix}false_alarm.designed", designed, ""),
    ]


def bench_verdicts(
    verdicts: Verdicts, statistic: np.ndarray, alpha: float, dof: int, bench_end: int
) -> tuple[Verdicts, float, float, int]:
    """The windows judged again with the monitor calibrated on the run's own fault-free
    start (the windows ending by ``bench_end``): the scaled chi-square of their moments
    (:func:`~mems_estimation.filters.consistency_monitor.window_moments`; Satterthwaite
    1946), as ``calibrate_health`` calibrates a node. Returns the verdicts, the mean NIS
    and dispersion, and the training windows; ValueError for fewer than 30."""
    train = verdicts.end <= bench_end
    window = int(verdicts.n[0])
    mean, disp = window_moments(statistic[train], window, dof)
    m = NisMonitor.moment_matched(window, alpha, mean, disp, dof=dof)
    level = np.where(statistic > m.thresholds[1], 2, np.where(statistic > m.thresholds[0], 1, 0))
    judged = Verdicts.of(verdicts.first, verdicts.n, level, statistic < m.lower)
    return judged, mean, disp, int(np.count_nonzero(train))


def analyse(bag, pngs=None) -> contract.ScenarioResult:
    """The scenario's figures from its recording ``bag`` alone (module doc). ``pngs``: the
    PNG path of :func:`plot` (or a one-element sequence of it), None: no plot."""
    bag = Path(bag)
    faults = read_faults(bag)
    verdicts, statistic, alpha, warn, dof = read_verdicts(bag)
    last = int(verdicts.end[-1])
    scored = [f for f in faults if f.first + HORIZON <= last]
    bench_end = faults[0].first if faults else 0
    figures = _scores("", faults, scored, verdicts, alpha, bench_end)
    unavailable = []
    try:
        judged, mean, disp, n_train = bench_verdicts(verdicts, statistic, alpha, dof, bench_end)
    except ValueError as exc:
        unavailable.append(("bench.*", f"{bag}: the fault-free start: {exc}"))
    else:
        figures += [
            Figure("bench.windows", n_train, ""),
            Figure("bench.nis_mean", mean, "1"),
            Figure("bench.nis_dispersion", disp, "1"),
            *_scores("bench.", faults, scored, judged, alpha, bench_end),
        ]
    inside, outside, finite = _error_rms(bag, faults)
    figures += [
        Figure("error.rms_in_faults", inside, "m/s^2"),
        Figure("error.rms_outside_faults", outside, "m/s^2"),
        Figure("estimates.finite", finite, "", "true", finite, FINITE_SOURCE),
    ]
    if not faults:
        unavailable.append(("*.detected", f"{bag}: no labelled fault on /{NS}/faults"))
    table = figure_table(figures)
    paths = []
    if pngs is not None:
        paths = [Path(pngs)] if isinstance(pngs, str | Path) else [Path(q) for q in pngs]
        plot(paths[0], faults, verdicts, statistic, warn)
    return contract.ScenarioResult(
        NAME, figures, table, paths, unavailable, values=dict(faults=len(faults))
    )


def run(options: base.ScenarioOptions) -> dict:
    """Run the scenario and analyse its recording (:func:`analyse`)."""
    return base.run_recorded(
        options,
        name=NAME,
        default_duration_s=DEFAULT_DURATION_S,
        check_duration=_check_duration,
        run_graph=run_graph,
        analyse=analyse,
    )

"""Scenario ``sd_resonator``: pulse-actuated resonator, one-bit sigma-delta, Kalman observers.

Four device instances run side by side in one graph (Colinet et al., Sec. 6):

``/sd_comparator``  the naive loop of Fig. 1 (pulses from the comparator), output noise
                    std = the oscillation amplitude;
``/sd_observer``    the proposed loop (pulses from the in-loop Kalman observer, fired at the
                    crossing it predicts, sub-sample timing), same noise, exact model, no
                    state noise (the paper's case);
``/sd_noisy``       observer loop at 0.25 V with output noise 0.25 V and thermomechanical
                    state noise; downstream observer nodes: exact model (consistency),
                    5 % f0 error, and the adaptive observer started from that 5 % error;
``/sd_step``        comparator loop with low noise and a +2 % f0 step at mid-run; the
                    adaptive observer node tracks the frequency;
``/sd_standin``     as ``/sd_noisy`` with the linear-Gaussian stand-in of the quantiser
                    (``quantizer: gaussian``): Kalman theory applies as stated there;
``/sd_overload``    observer loop at 0.5 V with output noise 0.5 V and state noise: the
                    modulator overloads (reported, not judged).

Identification on the bench first (:func:`bench_identification`): the same device (one
draw of the batch with ``--device-seed``) in its comparator loop, ROS-free, rings down
again and again with the pulse driver off; f0 and Q from the ring-downs
(:mod:`mems_estimation.identification.resonator_identification`), written as
``<out>-seed<N>-resonator_params.yaml``, are the model of every in-loop observer
(``loop_params_yaml``) and downstream observer (``params_yaml``; the 5 % f0 error is 5 %
off the identified f0; the run record holds the bench's result, ``bench``). The
consistency re-runs of the analysis test Kalman theory, which holds for the true model
only: they run with the device's own f0 and Q (the oracle's, from the run record). The
oracle observer ``/sd_noisy/oracle`` runs beside them with the device's own
table (``...-resonator_oracle_params.yaml``), and so does the in-loop observer of
``/sd_observer``: Colinet's exact-model case is the oracle by its definition.

Every figure is computed from the recorded MCAP alone (:func:`analyse`, also
``run_scenario sd_resonator --analyse BAG``); the consistency figures run the exact-model
steady-state observer again on the recorded streams (Anderson & Moore 1979: white
innovations, NIS, NEES, the predicted error autocorrelation; Ljung & Box 1978); the
comparator input is replayed from the devices' seeds in the run record (:func:`oracle`).
Contract: docs/scenarios.md.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np

from mems_estimation.filters.resonator_consistency import (
    analyse_stream,
    ljung_box_pooled,
    pooled_acf,
    replay_comparator_input,
)
from mems_estimation.identification.resonator_identification import (
    MODEL_KEYS,
    save_identification,
)
from mems_estimation.studies import resonator_bench
from mems_scenarios import bag_frames, base, contract, delivery
from mems_scenarios.sd_resonator_report import ACF_LAGS, FS, plot, records, table
from mems_sim.devices.resonator import RESONATOR_SPECS, default_pulse_amplitude
from mems_sim.kernels.resonator_observer import observer_model, predicted_error_acf
from mems_sim.ros.flow import progress_of

NAME = "sd_resonator"
DESCRIPTION = (
    "pulse-actuated resonator through a one-bit sigma-delta (Colinet): comparator vs "
    "Kalman-observer loop, model error, adaptive f0 tracking"
)
DEFAULT_DURATION_S = 0.4
F0, Q = 5.0e4, 100.0
NOISE_LOOP = 0.5  # output noise std of the comparator/observer comparison [V]
AMP_NOISY, NOISE_NOISY, STATE_NOISE = 0.25, 0.25, 5e-4
NOISE_STEP = 0.05
SKIP_S = 0.05  # start-up excluded from steady-state figures [s]
AMP_OVER, NOISE_OVER, STATE_NOISE_OVER = 0.5, 0.5, 1e-3  # the overloaded case


def device_cases(duration: float) -> dict[str, dict]:
    """Device parameters of each instance (namespace -> overrides)."""
    noisy = dict(
        mode="observer",
        output_noise_std=NOISE_NOISY,
        state_noise_std=STATE_NOISE,
        observer_state_noise_std=STATE_NOISE,
        fast=False,
        pulse_amplitude=default_pulse_amplitude(AMP_NOISY),
    )
    return {
        "sd_comparator": dict(mode="comparator", output_noise_std=NOISE_LOOP),
        "sd_observer": dict(mode="observer", output_noise_std=NOISE_LOOP),
        "sd_noisy": noisy,
        "sd_step": dict(
            mode="comparator",
            output_noise_std=NOISE_STEP,
            state_noise_std=STATE_NOISE,
            f0_step_fraction=0.02,
            f0_step_time_s=round(duration / 2, 6),
        ),
        "sd_standin": dict(noisy, quantizer="gaussian", fast=True),
        "sd_overload": dict(
            mode="observer",
            output_noise_std=NOISE_OVER,
            state_noise_std=STATE_NOISE_OVER,
            observer_state_noise_std=STATE_NOISE_OVER,
            pulse_amplitude=default_pulse_amplitude(AMP_OVER),
        ),
    }


def device_seed(seed: int, k: int) -> int:
    """Run seed of the k-th device instance (order of :func:`device_cases`)."""
    return int(seed) * 10 + k


#: The bench's noise seed: :func:`device_seed` of this place (after every device's).
BENCH_K = 9
#: The observer loop of Colinet's exact-model case: its in-loop observer is given the
#: device's own table (the oracle: the paper's stated condition), every other loop the
#: identified model.
EXACT_LOOP = "sd_observer"


def observer_cases() -> dict[str, tuple[str, dict]]:
    """Downstream observer nodes: name -> (device namespace, parameters). Their model is
    the identified one (its YAML, set by :func:`graph`; ``f0_error`` and ``adaptive`` start
    5 % above its f0), the ``oracle`` observer's the device's own table."""
    noisy = dict(output_noise_std=NOISE_NOISY, state_noise_std=STATE_NOISE)
    return {
        "identified": ("sd_noisy", dict(noisy)),
        "f0_error": ("sd_noisy", dict(noisy, f0_error=0.05)),
        "adaptive": ("sd_noisy", dict(noisy, f0_error=0.05, adaptive=True)),
        "tracking": (
            "sd_step",
            dict(output_noise_std=NOISE_STEP, state_noise_std=STATE_NOISE, adaptive=True),
        ),
        "oracle": ("sd_noisy", dict(noisy)),
    }


#: Observers whose model is the device's table (the oracle's YAML), not the bench's.
ORACLE_OBSERVERS = ("oracle",)


def bench_device(options: base.ScenarioOptions) -> dict:
    """The part as the emulator nodes draw it (the table's values with the user's ``--set``
    of ``/sd_noisy``, ``--device-seed`` and ``--temperature``; not a case's noise or pulse
    settings, which are the scenario's conditions): its RESONATOR_SPECS values as built
    (:func:`~mems_sim.params.draw_device`, as the node does)."""
    from mems_sim.ros.params_file import node_matches

    entry = contract.NodeEntry("resonator_node", DEVICE_NODE, "sd_noisy", {})
    variation = dict(device_seed=options.device_seed, temperature_c=options.temperature_c)
    values = contract.full_parameters(entry, options.overrides, variation)
    fixed = {o.name for o in options.overrides if node_matches(o.node, entry.fqn)}
    return _as_built(values, fixed)


def _as_built(params: dict, fixed=()) -> dict:
    """The RESONATOR_SPECS values the node builds from its parameter values ``params``
    (drawn for ``device_seed``, moved to ``temperature_c``; ``fixed``: the values the user
    set, left as given)."""
    from mems_sim.params import draw_device, spec_table

    ref = float(spec_table(contract.node_class("resonator_node").SPECS)["temperature_c"].default)
    return draw_device(
        RESONATOR_SPECS,
        {s.name: params[s.name] for s in RESONATOR_SPECS},
        params["device_seed"],
        params["temperature_c"] - ref,
        fixed=fixed,
    )


def bench_paths(options: base.ScenarioOptions, out=None) -> dict:
    """Where the bench's results go, beside the MCAP file ``out`` (None: the options'
    ``out``, else ``runs/``): ``path`` ``<stem>-seed<N>-resonator_params.yaml`` (the
    identified model) and ``oracle_path`` ``...-resonator_oracle_params.yaml`` (the
    device's own f0 and Q)."""
    return base.bench_paths(options, NAME, "resonator", out)


def bench_identification(options: base.ScenarioOptions, out=None) -> dict:
    """The bench (module doc): :func:`bench_device`'s ring-downs identified
    (:func:`~mems_estimation.studies.resonator_bench.bench_identification`, noise seed
    ``device_seed(seed, BENCH_K)``), written to :func:`bench_paths`. Returns ``model``,
    ``fit``, ``path``, ``oracle_path``; ScenarioError when the fit fails."""
    dev = bench_device(options)
    try:
        bench = resonator_bench.bench_identification(dev, F0, Q, device_seed(options.seed, BENCH_K))
    except ValueError as exc:
        raise base.ScenarioError(f"{NAME}: bench identification failed: {exc}") from None
    paths = bench_paths(options, out)
    paths["path"].parent.mkdir(parents=True, exist_ok=True)
    save_identification(dict(bench["model"], fit=bench["fit"]), str(paths["path"]))
    save_identification({k: dev[k] for k in MODEL_KEYS}, str(paths["oracle_path"]))
    return dict(bench, **paths)


def prepare(options: base.ScenarioOptions) -> dict:
    """Make the files :func:`graph` names (the bench's model YAMLs) before a runner of
    processes starts the graph (``run_scenario --write-launch``); returns what the run
    record adds (the bench's result, ``bench``)."""
    bench = bench_identification(options)
    return contract.bench_record(bench)


#: Node names of the device and observer executables (their classes' NODE_NAME).
DEVICE_NODE, OBSERVER_NODE = "resonator", "resonator_observer"


def device_fqn(ns: str) -> str:
    """Fully qualified name of the device node in namespace ``ns``."""
    return f"/{ns}/{DEVICE_NODE}"


def device_topics(ns: str, params: dict) -> list[str]:
    """Topics the device in ``ns`` publishes (the loop estimate in observer mode)."""
    names = ["adc", "drive", "truth", "end_of_stream"]
    names += ["loop_estimate"] if params.get("mode") == "observer" else []
    return [f"/{ns}/{t}" for t in names]


def graph(
    options: base.ScenarioOptions, duration_s: float, bench: dict | None = None
) -> contract.GraphSpec:
    """The scenario's graph: the six devices (:func:`device_cases`; the observer loops with
    the identified model), then the observer nodes (:func:`observer_cases`), each in its
    own namespace; recorded: every device topic, every estimate and the run record.
    ``bench``: the model YAMLs' paths (:func:`bench_paths`, the default; the files are made
    by :func:`bench_identification`, or :func:`prepare`)."""
    if bench is None:
        bench = bench_paths(options)
    cases = observer_cases()
    readers = Counter(ns for ns, _ in cases.values())
    devices, recorded = [], []
    for k, (ns, params) in enumerate(device_cases(duration_s).items()):
        p = dict(
            params,
            seed=device_seed(options.seed, k),
            duration_s=float(duration_s),
            frame_size=10000,
        )
        if p.get("mode") == "observer":  # the paper's exact-model loop: the oracle
            p["loop_params_yaml"] = str(bench["oracle_path" if ns == EXACT_LOOP else "path"])
        # a process graph's device starts once its observers and the recorder subscribed
        consumers = f"adc:{readers[ns] + 1}"
        devices.append(
            contract.NodeEntry("resonator_node", DEVICE_NODE, ns, p, consumers=consumers)
        )
        recorded += device_topics(ns, p)
    observers = []
    for name, (ns, params) in cases.items():
        topic = f"/{ns}/{name}/estimate"
        model = bench["oracle_path" if name in ORACLE_OBSERVERS else "path"]
        p = dict(params, device_namespace=f"/{ns}", output_topic=topic, params_yaml=str(model))
        observers.append(
            contract.NodeEntry("resonator_observer_node", OBSERVER_NODE, f"{ns}/{name}", p)
        )
        recorded.append(topic)
    return contract.GraphSpec(NAME, (*devices, *observers), (*recorded, contract.RUN_INFO_TOPIC))


def build_graph(options: base.ScenarioOptions, out: Path, duration: float):
    """The bench, then devices, observer nodes (:func:`graph`) and the recorder in one
    context; the run record (with the bench's result) published."""
    bench = bench_identification(options, out)
    spec = graph(options, duration, bench)
    g = base.graph_for(options)
    nodes = g.build(spec, realtime=options.realtime)
    devices = {ns: nodes[device_fqn(ns)] for ns in device_cases(duration)}
    observers = {
        name: nodes[f"/{ns}/{name}/{OBSERVER_NODE}"] for name, (ns, _) in observer_cases().items()
    }
    rec = g.recorder(str(out), topics=spec.recorded)
    fixed = {device_fqn(ns): sorted(d.fixed_parameters) for ns, d in devices.items()}
    g.publish_run_info(
        spec,
        options,
        nodes,
        duration_s=duration,
        fixed_parameters=fixed,
        **contract.bench_record(bench),
    )
    return g, devices, observers, rec


def _delivered(rec, observers):
    by_ns: dict[str, list] = {}
    for name, (ns, _) in observer_cases().items():
        by_ns.setdefault(ns, []).append(observers[name])

    def delivered(device) -> int | None:
        """Progress [samples] of the device's slowest observer (the recorder counts in the
        skeleton)."""
        counts = [progress_of(o) or 0 for o in by_ns.get(device.get_namespace().lstrip("/"), [])]
        return min(counts) if counts else None

    return delivered


def run_graph(
    options: base.ScenarioOptions, out: Path, duration: float, progress: base.Progress
) -> dict:
    """Run the graph until every device published ``duration``; return publish counts."""
    graph, devices, observers, rec = build_graph(options, out, duration)
    delivered = _delivered(rec, observers)
    try:

        def matched() -> bool:
            return all(
                d.pub_adc.get_subscription_count() >= 1
                and d.pub_truth.get_subscription_count() >= 1
                and len(rec.recorded_topics()) >= 3 * len(devices)
                for d in devices.values()
            )

        graph.spin_until(matched, 30.0, "the recorder and observers to subscribe")
        graph.spin_until(
            lambda: all(o.pub.get_subscription_count() >= 1 for o in observers.values()),
            30.0,
            "the recorder to subscribe to the observers' estimates",
        )
        delivery.publish_all(
            graph,
            list(devices.values()),
            delivered,
            progress,
            realtime=options.realtime,
            realtime_timeout_s=duration * 50 + 60,
        )
        graph.spin_until(
            lambda: all(
                rec.received(f"/{ns}/{name}/estimate") >= observers[name].frames_done
                for name, (ns, _) in observer_cases().items()
            ),
            60.0,
            "the last estimates",
        )
        graph.wait_run_info(rec)
        published = {ns: d.frames_published for ns, d in devices.items()}
    finally:
        rec.close()
        summary = rec.report()
        graph.close()
    return dict(published=published, recorder=summary)


def _amp(x: np.ndarray) -> float:
    return math.sqrt(2.0) * float(np.std(x))


def _settling(rel: np.ndarray, k0: int, tol: float) -> int | None:
    """Samples after k0 until |rel| stays <= tol to the end (None: never settles)."""
    bad = np.flatnonzero(np.abs(rel[k0:]) > tol)
    if bad.size and bad[-1] == rel.size - k0 - 1:
        return None
    return int(bad[-1] + 1) if bad.size else 0


#: devices whose recorded streams the consistency figures re-run the observer on
CONSISTENCY_STREAMS = ("sd_standin", "sd_noisy", "sd_overload")
#: Device namespaces, in the order of :func:`device_cases` (their seeds' order).
DEVICES = tuple(device_cases(DEFAULT_DURATION_S))
#: Estimate topic of each downstream observer node.
ESTIMATES = {name: f"/{ns}/{name}/estimate" for name, (ns, _) in observer_cases().items()}


def _streams(ns: str) -> list[str]:
    return [f"/{ns}/{t}" for t in ("adc", "drive", "truth")]


#: Figure groups: label -> (topics they need, the figures' names). The oracle's group
#: (:data:`ORACLE`) needs the run record too; the re-runs take the oracle's model from it
#: (the device's own f0 and Q, :func:`exact_model`; the design values without a record).
GROUPS = {
    "observer loop (exact.*, observer.*, comparator.*, pulse.*)": (
        [
            "/sd_observer/truth",
            "/sd_observer/drive",
            "/sd_observer/loop_estimate",
            "/sd_comparator/truth",
        ],
        (
            "exact.rms_error_rel",
            "observer.amplitude",
            "comparator.amplitude",
            "comparator_observer.amplitude_ratio",
            "pulse.x_rel_mean",
            "pulse.x_rel_max",
            "pulse.center_x_rel_max",
            "pulse.count",
            "pulse.per_half_period",
            "pulse.between_samples",
            "pulse.estimate_error_rel_max",
        ),
    ),
    "observer nodes on sd_noisy (exact_noisy.error_*, identified_noisy.*, f0_error.*, "
    "adaptive.*, identified_vs_oracle.*)": (
        [
            "/sd_noisy/truth",
            ESTIMATES["identified"],
            ESTIMATES["f0_error"],
            ESTIMATES["adaptive"],
            ESTIMATES["oracle"],
        ],
        (
            "exact_noisy.error_variance_ratio",
            "exact_noisy.error_corr_x",
            "identified_noisy.error_variance_ratio",
            "f0_error.error_corr_x",
            "f0_error.error_ratio",
            "adaptive.error_ratio",
            "adaptive.f0_error",
            "identified_vs_oracle.error_ratio",
        ),
    ),
    "stand-in re-run, the oracle's model (standin.*)": (
        _streams("sd_standin"),
        ("standin.innovations_ljung_box_p", "standin.nis", "standin.nees"),
    ),
    "one-bit re-run, the oracle's model (exact_noisy.nees, .nis, .error_acf*, "
    ".*corr_estimate, .innovation_acf1)": (
        _streams("sd_noisy"),
        (
            "exact_noisy.nees",
            "exact_noisy.error_acf1",
            "exact_noisy.error_acf_max_dev",
            "exact_noisy.error_corr_estimate",
            "exact_noisy.innovation_acf1",
            "exact_noisy.nis",
        ),
    ),
    "overload re-run, the oracle's model (overload.nees)": (
        _streams("sd_overload"),
        ("overload.nees",),
    ),
    "f0 tracking (tracking.*)": (
        ["/sd_step/truth", ESTIMATES["tracking"]],
        ("tracking.settle_periods", "tracking.tail_mean_error"),
    ),
}
#: The oracle's figure group: the comparator input replayed from the devices' seeds.
ORACLE = (
    "comparator input replayed and the device as built (exact_noisy.quantizer_overload, "
    "overload.quantizer_*, device.identified_*)"
)
ORACLE_FIGURES = (
    "exact_noisy.quantizer_overload",
    "overload.quantizer_overload",
    "overload.comparator_input_std",
    "device.identified_f0_error",
    "device.identified_q_error",
)
#: Every number :func:`analyse` reports (``values``), NaN until its group is computed.
KEYS = (
    "amp_observer amp_comparator amp_ratio exact_err_rel pulses pulses_per_half_period "
    "pulse_x_rel_max pulse_x_rel_mean pulse_center_rel_max pulse_sub_sample pulse_est_err_rel "
    "consistency exact_noisy_rel standin_lb_q standin_lb_p standin_nis standin_nees "
    "one_bit_nees one_bit_nis error_acf1 error_acf1_pred error_acf_max_dev corr_err_est "
    "innov_acf1 one_bit_q_overload overload_q overload_q_std overload_nees error_corr_x "
    "f0_error_corr_x f0_error_ratio adaptive_ratio adaptive_f0_ppm settle_periods "
    "tracking_tail_ppm identified_oracle_ratio identified_f0_error identified_q_error "
    "identified_consistency"
).split()


def _stream(frames: dict, ns: str, noise: float, state: float, model: dict, **kw):
    """Consistency statistics of one recorded device stream (exact-model observer re-run,
    Anderson & Moore 1979); ``frames``: topic -> frames of the recording
    (:func:`topics_frames`)."""
    bits = frames[f"/{ns}/adc"]["data"][:, 0]
    drive = frames[f"/{ns}/drive"]["data"]
    tr = frames[f"/{ns}/truth"]["data"]
    return analyse_stream(
        bits,
        drive[:, 0],
        drive[:, 1],
        drive[:, 2],
        tr[:, 0],
        tr[:, 1],
        noise,
        state,
        skip=int(SKIP_S * FS),
        f0=model["f0_hz"],
        q=model["quality_factor"],
        **kw,
    )


def loop_figures(frames: dict) -> tuple[dict, dict]:
    """The observer loop against the comparator loop (Colinet Sec. 6): amplitudes, the
    in-loop estimate's error, the pulses' timing against the recorded truth; and the
    plot's series."""
    skip = int(SKIP_S * FS)
    x_obs = frames["/sd_observer/truth"]["data"][:, 0]
    tr_obs = frames["/sd_observer/truth"]["data"]
    drive = frames["/sd_observer/drive"]["data"]
    loop = frames["/sd_observer/loop_estimate"]["data"][:, 0]
    x_cmp = frames["/sd_comparator/truth"]["data"][:, 0]
    f: dict = {}
    a_obs = _amp(x_obs[skip:])
    f["amp_observer"], f["amp_comparator"] = a_obs, _amp(x_cmp[skip:])
    f["amp_ratio"] = f["amp_comparator"] / a_obs
    f["exact_err_rel"] = float(np.sqrt(np.mean((loop - x_obs)[skip:] ** 2)) / a_obs)
    # truth at each pulse's firing instant (start sample) and centre (sample containing it)
    k = np.flatnonzero(drive[skip:, 0]) + skip
    kc = k + np.floor((drive[k, 1] + 0.5 * drive[k, 2]) * FS).astype(int)
    k, kc = k[kc < x_obs.size], kc[kc < x_obs.size]
    x_start = np.abs(tr_obs[k, 3]) / a_obs
    x_center = np.abs(tr_obs[kc, 4]) / a_obs
    nan = math.nan
    f["pulses"] = int(k.size)
    f["pulses_per_half_period"] = float(k.size / ((x_obs.size - skip) * 2 * F0 / FS))
    f["pulse_x_rel_max"] = float(x_start.max()) if k.size else nan
    f["pulse_x_rel_mean"] = float(x_start.mean()) if k.size else nan
    f["pulse_center_rel_max"] = float(x_center.max()) if k.size else nan
    f["pulse_sub_sample"] = float(np.mean(drive[k, 1] > 0)) if k.size else nan
    f["pulse_est_err_rel"] = float(np.max(np.abs(loop - x_obs)[skip:]) / a_obs)
    fired = drive[:, 0] != 0
    series = dict(
        x_obs=x_obs,
        loop=loop,
        pulses=drive[:, 0],
        pulse_t=np.flatnonzero(drive[:, 0]) / FS + drive[fired, 1] + 0.5 * drive[fired, 2],
        x_center=tr_obs[:, 4],
        x_cmp=x_cmp,
    )
    return f, series


def noisy_figures(frames: dict) -> dict:
    """The observer nodes on ``/sd_noisy``: the exact model (the oracle node, the device's
    table: measured / predicted error variance, Kalman theory's check), the identified
    model (the same ratio; its error against the oracle's), the 5 % f0 error and the
    adaptive observer against the identified model (its f0 against the device's, the
    recorded truth)."""
    skip = int(SKIP_S * FS)
    x_noisy = frames["/sd_noisy/truth"]["data"][:, 0]
    f0_true = float(frames["/sd_noisy/truth"]["data"][-1, 2])
    est = {n: frames[ESTIMATES[n]] for n in ("identified", "f0_error", "adaptive", "oracle")}
    a_noisy = _amp(x_noisy[skip:])
    half = x_noisy.size // 2
    err = {n: est[n]["data"][:, 0] - x_noisy for n in est}

    def variance_ratio(name):
        return float(np.var(err[name][skip:]) / np.mean(est[name]["variances"][skip:, 0]))

    ident = np.std(err["identified"][half:])
    f: dict = {}
    f["consistency"] = variance_ratio("oracle")
    f["identified_consistency"] = variance_ratio("identified")
    f["exact_noisy_rel"] = float(np.std(err["oracle"][half:]) / a_noisy)
    f["error_corr_x"] = float(np.corrcoef(err["oracle"][skip:], x_noisy[skip:])[0, 1])
    f["f0_error_corr_x"] = float(np.corrcoef(err["f0_error"][skip:], x_noisy[skip:])[0, 1])
    f["f0_error_ratio"] = float(np.std(err["f0_error"][half:]) / ident)
    f["adaptive_ratio"] = float(np.std(err["adaptive"][half:]) / ident)
    f["adaptive_f0_ppm"] = float((est["adaptive"]["data"][-1, 1] / f0_true - 1) * 1e6)
    f["identified_oracle_ratio"] = float(ident / np.std(err["oracle"][half:]))
    return f


def standin_figures(frames: dict, model: dict) -> dict:
    """Stand-in quantiser: white innovations (Ljung & Box 1978, lags 1-50), NIS, NEES;
    ``model``: the re-run observer's f0_hz, quality_factor (:func:`exact_model`)."""
    st = _stream(frames, "sd_standin", NOISE_NOISY, STATE_NOISE, model, linear_output=True)
    q, p_lb, _ = ljung_box_pooled([st.innov], 50)
    return dict(standin_lb_q=q, standin_lb_p=p_lb, standin_nis=st.nis, standin_nees=st.nees)


def one_bit_figures(frames: dict, model: dict) -> dict:
    """One-bit in range: NEES, the error autocorrelation against the filter's prediction,
    corr(error, estimate), innovation autocorrelation and NIS (``model`` as above)."""
    ob = _stream(frames, "sd_noisy", NOISE_NOISY, STATE_NOISE, model)
    r_err, _ = pooled_acf([ob.err], ACF_LAGS)
    pred = predicted_error_acf(_observer_model(model), ACF_LAGS)
    r_inn, _ = pooled_acf([ob.innov], 3)
    return dict(
        one_bit_nees=ob.nees,
        one_bit_nis=ob.nis,
        error_acf1=float(r_err[0]),
        error_acf_max_dev=float(np.max(np.abs(r_err - pred))),
        corr_err_est=ob.corr_err_est,
        innov_acf1=float(r_inn[0]),
    )


def _observer_model(model: dict):
    """The steady-state observer model of ``/sd_noisy`` with ``model``'s f0 and Q."""
    return observer_model(model["f0_hz"], model["quality_factor"], FS, NOISE_NOISY, STATE_NOISE)


def device_as_built(record: dict | None) -> dict | None:
    """``/sd_noisy``'s RESONATOR_SPECS values as built, from its parameters in the run
    record, drawn as the node does (every device is the same draw); None without one."""
    try:
        params = contract.node_parameters(record, device_fqn("sd_noisy"), "")
    except contract.AnalysisError:
        return None
    return _as_built(params, record.get("fixed_parameters", {}).get(device_fqn("sd_noisy"), ()))


def exact_model(record: dict | None) -> dict:
    """The exact model the consistency re-runs test Kalman theory with (Anderson & Moore
    1979 hold for the true model only): the device's own f0 and Q as built
    (:func:`device_as_built`, the oracle's), or the design values F0, Q for a recording
    without a run record."""
    dev = device_as_built(record)
    if dev is None:
        return dict(f0_hz=F0, quality_factor=Q)
    return {k: float(dev[k]) for k in MODEL_KEYS}


def overload_figures(frames: dict, model: dict) -> dict:
    """The overloaded case (0.5 V + 0.5 V): the exact-model observer's NEES there."""
    ov = _stream(frames, "sd_overload", NOISE_OVER, STATE_NOISE_OVER, model)
    return dict(overload_nees=ov.nees)


def tracking_figures(frames: dict) -> tuple[dict, dict]:
    """The adaptive observer on ``/sd_step``: settling within 100 ppm after the +2 % f0
    step, mean error over the last 50 ms; and the plot's series."""
    f0_true = frames["/sd_step/truth"]["data"][:, 2]
    f0_est = frames[ESTIMATES["tracking"]]["data"][:, 1]
    rel = f0_est / f0_true - 1.0
    k0 = int(np.flatnonzero(np.diff(f0_true) != 0)[0]) + 1
    s = _settling(rel, k0, 100e-6)
    f = dict(
        settle_periods=None if s is None else s * f0_true[-1] / FS,
        tracking_tail_ppm=float(np.mean(rel[-int(0.05 * FS) :]) * 1e6),
    )
    return f, dict(rel=rel, k0=k0)


def oracle(record: dict | None, frames: dict) -> dict:
    """The oracle step: the modulator's comparator input q(k), replayed from each device's
    run seed (in the run record) by :func:`replay_comparator_input` (the device's noise
    layout, Colinet eqs. 10-12), on ``/sd_noisy`` and ``/sd_overload``: the fraction of
    samples with |q| > 2 V (quantiser overloaded) and the std of q [V] after the start-up.
    NaN where the replay does not reproduce the recorded bits."""
    skip = int(SKIP_S * FS)
    out = {}
    for ns, noise, keys in (
        ("sd_noisy", NOISE_NOISY, ("one_bit_q_overload", None)),
        ("sd_overload", NOISE_OVER, ("overload_q", "overload_q_std")),
    ):
        seed = contract.node_parameters(record, device_fqn(ns), "the devices' seeds")["seed"]
        position = frames[f"/{ns}/truth"]["data"][:, 0]
        bits = frames[f"/{ns}/adc"]["data"][:, 0]
        q = replay_comparator_input(seed, position, bits, noise)
        overload = math.nan if q is None else float(np.mean(np.abs(q[skip:]) > 2.0))
        out[keys[0]] = overload
        if keys[1] is not None:
            out[keys[1]] = math.nan if q is None else float(q[skip:].std())
    out.update(identification_error(record))
    return out


def identification_error(record: dict) -> dict:
    """The bench's f0 and Q against the device as built (:func:`device_as_built`): relative
    errors; NaN without the bench's result."""
    dev = device_as_built(record)
    if dev is None or "bench" not in record:
        return dict(identified_f0_error=math.nan, identified_q_error=math.nan)
    model = record["bench"]["model"]
    return dict(
        identified_f0_error=float(model["f0_hz"] / dev["f0_hz"] - 1.0),
        identified_q_error=float(model["quality_factor"] / dev["quality_factor"] - 1.0),
    )


def _needed_topics() -> list[str]:
    topics = [t for needs, _ in GROUPS.values() for t in needs]
    return list(dict.fromkeys(topics))


def figures(bag: Path) -> tuple[dict, dict, list[tuple[str, str]]]:
    """Every acceptance figure of the scenario that the recording ``bag`` allows: (numbers
    by :data:`KEYS`, plot series, (group, reason) of each group it does not allow)."""
    frames = bag_frames.topics_frames(bag, _needed_topics(), missing_ok=True)
    record = contract.read_run_info(bag)
    model = exact_model(record)
    f: dict = dict.fromkeys(KEYS, math.nan)
    f["error_acf1_pred"] = float(predicted_error_acf(_observer_model(model), ACF_LAGS)[0])
    series: dict = {}
    unavailable = []
    compute = (
        loop_figures,
        noisy_figures,
        lambda fr: standin_figures(fr, model),
        lambda fr: one_bit_figures(fr, model),
        lambda fr: overload_figures(fr, model),
        tracking_figures,
    )
    for (group, (needs, _)), fn in zip(GROUPS.items(), compute, strict=True):
        absent = [t for t in needs if t not in frames]
        if absent:
            unavailable.append((group, f"{bag}: no frames on {', '.join(absent)}"))
            continue
        got = fn(frames)
        if isinstance(got, tuple):
            got, more = got
            series.update(more)
        f.update(got)
    absent = [t for ns in ("sd_noisy", "sd_overload") for t in _streams(ns) if t not in frames]
    try:
        if absent:
            raise contract.AnalysisError(f"{ORACLE}: no frames on {', '.join(absent)}")
        f.update(oracle(record, frames))
    except contract.AnalysisError as exc:
        unavailable.append((ORACLE, str(exc)))
    return f, series, unavailable


def analyse(bag, pngs=None) -> contract.ScenarioResult:
    """The scenario's figures from its recording ``bag`` alone (:func:`figures`; the
    replayed comparator input through :func:`oracle`, from the run record); ``pngs``: the
    figure's PNG path in a 1-tuple (None: no plot)."""
    f, series, unavailable = figures(bag)
    missing = {
        name
        for group, _ in unavailable
        for name in (ORACLE_FIGURES if group == ORACLE else GROUPS[group][1])
    }
    if len(missing) == sum(len(g[1]) for g in GROUPS.values()) + len(ORACLE_FIGURES):
        raise contract.AnalysisError("; ".join(reason for _, reason in unavailable))
    paths = []
    if pngs and {"x_obs", "rel"} <= set(series):
        plot(dict(f, series=series), pngs[0])
        paths.append(Path(pngs[0]))
    return contract.ScenarioResult(
        NAME,
        [r for r in records(f) if r.name not in missing],
        table(f),
        paths,
        unavailable,
        oracle_only=[ORACLE],
        values=f,
    )


def _check_duration(duration: float) -> None:
    if duration < 0.2:
        raise base.ScenarioError(
            f"--duration = {duration!r} is too short for sd_resonator: at least "
            "0.2 s (start-up, steady state, and the f0 step at mid-run)"
        )


def run(options: base.ScenarioOptions) -> dict:
    """Run the scenario and analyse its recording (:func:`analyse`); return the table,
    figures and paths."""
    return base.run_recorded(
        options,
        name=NAME,
        default_duration_s=DEFAULT_DURATION_S,
        check_duration=_check_duration,
        run_graph=run_graph,
        analyse=analyse,
    )

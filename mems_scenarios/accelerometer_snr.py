"""Scenario ``accelerometer_snr``: force-to-rebalance accelerometer, open loop vs PI loop vs
hybrid-EKF loop (Zhang 2010, chapter 5, Tables III and IV).

Device instances run side by side in one graph, each on its own namespace, all with
the thesis's chapter-5 noise (500 ug Brownian, 0.02 g electronic, per sample at 1 MHz)
and a 10 Hz sinusoidal input:

``/acc_<mode>_<amp>``  Table III: modes ``open``, ``pi``, ``ekf`` at 0.1, 1, 5, 10 g, plus
                       the open loop at 12 and 13 g (either side of its static pull-in
                       acceleration, 12.2 g);
``/acc_qr_<case>``     Table IV: the EKF loop at 0.1 g with Q x10, Q/10, R x10, R/10 and
                       R x10 with Q/10 (same seed as ``/acc_ekf_0g1``, the "exact" case);
``/acc_t3_<mode>_<amp>``  the Table III reading of the thesis (carrier amplitude 0.675 V,
                       :data:`~mems_sim.devices.accelerometer.TABLE_III_VARIANT`): the open
                       loop at 1, 4 and 5 g, the PI and EKF loops at 10 g;
``/acc_pi_1g/hybrid_ekf``  a downstream hybrid EKF node on the PI loop's raw frames.

Every device is the same device (one draw of the batch with ``--device-seed``); the
rebalance bias is designed from the nominal values.

Identification on the bench first (:func:`bench_identification`): the same device on a
shaker, ROS-free, with the carrier only and with the bias on and the loop open, gives its
mass, spring, damping, gap and readout noise
(:mod:`mems_estimation.identification.accelerometer_identification`), written as
``<out>-seed<N>-accelerometer_params.yaml``
(:func:`mems_scenarios.accelerometer_bench.bench_paths`): the model of every in-loop EKF
(``loop_params_yaml``) and of the downstream EKF (``params_yaml``). The oracle rows run on
the same recording with the device's own table (what only the simulation knows): a
downstream EKF ``/acc_pi_1g/oracle/accelerometer_ekf`` on the same PI loop and the EKF
loops ``/acc_oracle_ekf_0g1`` and ``/acc_oracle_ekf_1g`` with the noise of ``/acc_ekf_0g1``
and ``/acc_ekf_1g``.

Output SNR (same definition for every mode, :mod:`mems_estimation.identification.signal_metrics`): the
device's output — the readout voltage in open loop, the feedback voltage v_F in the
closed loops — is fitted with a 10 Hz tone over the analysis window (one whole period
after a 20 ms start-up); SNR = tone power / residual variance, at the 1 MHz output rate
(full bandwidth, no post-filtering). Every figure is computed from the recorded MCAP
(:func:`analyse`; the covariance counters from its /diagnostics), but the device as built
(its mismatch against the nominal model, the analytic pull-in): the :func:`oracle` step on
the run record.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mems_estimation.identification.accelerometer_identification import (
    MODEL_KEYS,
)
from mems_estimation.identification.signal_metrics import coherent_snr_db, consistency
from mems_scenarios import accelerometer_bench as accel_bench
from mems_scenarios import bag_frames, base, contract, delivery
from mems_scenarios.accelerometer_bench import device_as_built
from mems_scenarios.accelerometer_snr_report import (
    AMPS,
    FS,
    MODES,
    NAME_SPREAD,
    ORACLE_LOOPS,
    PULL_IN_AMPS,
    QR_CASES,
    SKIP_S,
    SPREAD_AMPS,
    G,
    checks,
    plot,
    records,
    spread_checks,
    table,
)
from mems_sim.devices import accelerometer
from mems_sim.ros.flow import progress_of

NAME = "accelerometer_snr"
DESCRIPTION = (
    "force-rebalance accelerometer (Zhang 2010): open loop vs PI vs hybrid-EKF loop, "
    "output SNR and displacement (Table III), Q/R tuning (Table IV)"
)
DEFAULT_DURATION_S = 0.12
F_IN = 10.0
#: The Table III reading (carrier 0.675 V): (mode, amplitude label, g).
T3_CASES = (("open", "1g", 1.0), ("open", "4g", 4.0), ("open", "5g", 5.0))
T3_CASES += (("pi", "10g", 10.0), ("ekf", "10g", 10.0))


def device_cases() -> dict[str, dict]:
    """Device parameters of every instance (namespace -> ACCEL_SPECS overrides)."""
    cases = {
        f"acc_{m}_{a}": dict(mode=mode, accel_amplitude=amp * G)
        for a, amp in AMPS.items()
        for m, mode in MODES.items()
    }
    for a, amp in PULL_IN_AMPS.items():
        cases[f"acc_open_{a}"] = dict(mode="open_loop", accel_amplitude=amp * G)
    for case, (qs, rs) in QR_CASES.items():
        if case != "exact":
            cases[f"acc_qr_{case}"] = dict(
                mode="ekf_rebalance", accel_amplitude=0.1 * G, ekf_q_scale=qs, ekf_r_scale=rs
            )
    for m, a, amp in T3_CASES:
        cases[f"acc_t3_{m}_{a}"] = dict(
            accelerometer.TABLE_III_VARIANT, mode=MODES[m], accel_amplitude=amp * G
        )
    for oracle_loop, ns in ORACLE_LOOPS.items():
        cases[oracle_loop] = dict(cases[ns])
    return cases


def spread_cases() -> dict[str, dict]:
    """The PI and EKF loops at 0.1 g and 1 g only, and the oracle EKF loops (scenario
    ``accelerometer_spread``)."""
    names = {f"acc_{m}_{a}" for m in ("pi", "ekf") for a in SPREAD_AMPS} | set(ORACLE_LOOPS)
    return {ns: p for ns, p in device_cases().items() if ns in names}


def _seed(options: base.ScenarioOptions, ns: str) -> int:
    """Run seed of one device (its place among :func:`device_cases`, so a device has the
    same noise in both scenarios); the Q/R sweep shares the seed of its exact case."""
    names = list(device_cases())
    same = ORACLE_LOOPS.get(ns, ns)
    k = names.index("acc_ekf_0g1" if ns.startswith("acc_qr_") else same)
    return int(options.seed) * 100 + k


#: Fully qualified name of the downstream hybrid EKF and its output topic.
DOWNSTREAM = "/acc_pi_1g/accelerometer_ekf"
DOWNSTREAM_TOPIC = "/acc_pi_1g/hybrid_ekf/estimate"
#: The same with the device's own table as its model (the oracle row).
DOWNSTREAM_ORACLE = "/acc_pi_1g/oracle/accelerometer_ekf"
DOWNSTREAM_ORACLE_TOPIC = "/acc_pi_1g/hybrid_ekf_oracle/estimate"
ESTIMATORS = (DOWNSTREAM, DOWNSTREAM_ORACLE)


def _full(cases: dict) -> bool:
    """True for the cases of the full scenario (not :func:`spread_cases`)."""
    return "acc_pi_1g" in cases and len(cases) > len(spread_cases())


def emulator(ns: str) -> str:
    """Fully qualified name of the device node in namespace ``ns``."""
    return f"/{ns}/accelerometer"


def _entry(options: base.ScenarioOptions, ns: str, params: dict, duration_s: float):
    return contract.NodeEntry(
        "accelerometer_node",
        "accelerometer",
        ns,
        dict(params, seed=_seed(options, ns), duration_s=float(duration_s), frame_size=10000),
    )


def _bench_entry(options: base.ScenarioOptions) -> contract.NodeEntry:
    """The device the bench measures: the PI loop at 1 g (every device is the same draw)."""
    return _entry(options, "acc_pi_1g", device_cases()["acc_pi_1g"], DEFAULT_DURATION_S)


def bench_identification(options: base.ScenarioOptions, out=None, spread: bool = False) -> dict:
    """The bench (module doc) of :func:`_bench_entry`'s device
    (:func:`mems_scenarios.accelerometer_bench.bench_identification`)."""
    name = NAME_SPREAD if spread else NAME
    return accel_bench.bench_identification(options, _bench_entry(options), name, out)


def prepare(options: base.ScenarioOptions, spread: bool = False) -> dict:
    """Make the files :func:`graph` names (the bench's model YAMLs) before a runner of
    processes starts the graph (``run_scenario --write-launch``); returns what the run
    record adds (the bench's result)."""
    return contract.bench_record(bench_identification(options, spread=spread))


def graph(
    options: base.ScenarioOptions,
    duration_s: float,
    *,
    spread: bool = False,
    bench: dict | None = None,
) -> contract.GraphSpec:
    """The scenario's graph: one device per case (:func:`device_cases`, ``spread``:
    :func:`spread_cases`), each in its namespace, the EKF loops with the identified model
    (the oracle loop with the device's table), the downstream hybrid EKFs (identified and
    oracle) on the PI loop at 1 g (full scenario only), recorded with /diagnostics (the
    covariance counters). ``bench``: the model YAMLs' paths
    (:func:`~mems_scenarios.accelerometer_bench.bench_paths`, the default; the files are
    made by :func:`bench_identification`, or :func:`prepare`)."""
    if bench is None:
        bench = accel_bench.bench_paths(options, NAME_SPREAD if spread else NAME)
    cases = spread_cases() if spread else device_cases()
    nodes = []
    for ns, params in cases.items():
        if params["mode"] == "ekf_rebalance":
            model = bench["oracle_path"] if ns in ORACLE_LOOPS else bench["path"]
            params = dict(params, loop_params_yaml=str(model))
        nodes.append(_entry(options, ns, params, duration_s))
    topics = [t for ns, p in cases.items() for t in _device_topics(ns, p["mode"], every=True)]
    if _full(cases):
        for fqn, topic, path in (
            (DOWNSTREAM, DOWNSTREAM_TOPIC, bench["path"]),
            (DOWNSTREAM_ORACLE, DOWNSTREAM_ORACLE_TOPIC, bench["oracle_path"]),
        ):
            nodes.append(
                contract.NodeEntry(
                    "accelerometer_ekf_node",
                    "accelerometer_ekf",
                    fqn.rsplit("/", 1)[0].lstrip("/"),
                    dict(
                        cases["acc_pi_1g"],
                        params_yaml=str(path),
                        device_namespace="/acc_pi_1g",
                        output_topic=topic,
                    ),
                )
            )
            topics.append(topic)
    name = NAME_SPREAD if spread else NAME
    return contract.GraphSpec(
        name, tuple(nodes), (*topics, "/diagnostics", contract.RUN_INFO_TOPIC)
    )


def run_graph(
    options: base.ScenarioOptions, out: Path, duration: float, progress: base.Progress, spread=False
) -> dict:
    """Run :func:`graph` until every device published ``duration``; record it with the
    run record (and each device's ``fixed_parameters``, for :func:`oracle`) and, at the
    end, every device's final diagnostics; return counts."""
    bench = bench_identification(options, out, spread)
    spec = graph(options, duration, spread=spread, bench=bench)
    graph_ = base.graph_for(options)
    nodes = graph_.build(spec, realtime=options.realtime)
    ekfs = [nodes[fqn] for fqn in ESTIMATORS if fqn in nodes]
    devices = {n.namespace: nodes[n.fqn] for n in spec.nodes if n.fqn not in ESTIMATORS}
    regex = rf"^/acc_|^/diagnostics$|^{re.escape(contract.RUN_INFO_TOPIC)}$"
    rec = graph_.recorder(str(out), regex=regex, exclude=base.NOT_RECORDED)
    fixed = {emulator(ns): sorted(d.fixed_parameters) for ns, d in devices.items()}
    graph_.publish_run_info(
        spec,
        options,
        nodes,
        duration_s=duration,
        fixed_parameters=fixed,
        **contract.bench_record(bench),
    )
    n_topics = sum(len(_topics(d)) for d in devices.values()) + len(ekfs)

    def delivered(device) -> int | None:
        """Progress [samples] of the slower downstream EKF (the recorder counts in the
        skeleton)."""
        if ekfs and device.get_namespace() == "/acc_pi_1g":
            return min(progress_of(e) or 0 for e in ekfs)
        return None

    try:
        graph_.spin_until(
            lambda: (
                len(rec.recorded_topics()) >= n_topics
                and (
                    not ekfs
                    or (
                        all(e.pub.get_subscription_count() >= 1 for e in ekfs)
                        and devices["acc_pi_1g"].pub_adc.get_subscription_count() >= 1 + len(ekfs)
                    )
                )
            ),
            30.0,
            "the recorder and the hybrid EKF nodes to subscribe",
        )
        delivery.publish_all(
            graph_,
            list(devices.values()),
            delivered,
            progress,
            realtime=options.realtime,
            realtime_timeout_s=duration * 200 + 60,
            window=20,
        )
        if ekfs:
            graph_.spin_until(
                lambda: all(
                    rec.received(t) >= e.frames_done
                    for t, e in zip((DOWNSTREAM_TOPIC, DOWNSTREAM_ORACLE_TOPIC), ekfs)
                ),
                60.0,
                "the last estimates",
            )
        _record_final_diagnostics(graph_, rec, list(devices.values()))
        graph_.wait_run_info(rec)
        published = {ns: d.frames_published for ns, d in devices.items()}
    finally:
        rec.close()
        # /diagnostics goes out once per wall-clock second: its count is the host's, not
        # the run's (the printed counts are of the data topics)
        counts = {t: n for t, n in rec.counts().items() if t != "/diagnostics"}
        summary = rec.report(counts)
        graph_.close()
    return dict(published=published, recorder=summary)


def _record_final_diagnostics(graph_, rec, devices: list) -> None:
    """Have every device publish its diagnostics once more after its last frame (its
    final counters) and wait until the recorder holds them."""
    before = rec.received("/diagnostics")
    for d in devices:
        d.diag.publish()
    graph_.spin_until(
        lambda: rec.received("/diagnostics") >= before + len(devices),
        20.0,
        "the recorder to take the final diagnostics",
    )
    for _ in range(10):
        graph_.executor.spin_once(timeout_sec=0.01)


def _topics(device) -> list[str]:
    ns = device.get_namespace()
    names = ["adc", "drive", "truth"] + (["loop_estimate"] if device.ekf_mode else [])
    return [f"{ns}/{t}" for t in names]


#: devices whose streams one pass over the MCAP reads (bounds the memory of a pass)
DEVICES_PER_PASS = 8


def _device_topics(ns: str, mode: str, every: bool = False) -> list[str]:
    """The topics :func:`_device_figures` reads for device ``ns`` in ``mode`` (``every``:
    all the data topics the device publishes)."""
    if every:
        topics = [f"/{ns}/adc", f"/{ns}/drive", f"/{ns}/truth"]
    else:
        topics = [f"/{ns}/truth", f"/{ns}/adc" if mode == "open_loop" else f"/{ns}/drive"]
    return topics + ([f"/{ns}/loop_estimate"] if mode == "ekf_rebalance" else [])


def _device_figures(frames: dict, ns: str, mode: str) -> dict:
    """SNR, displacement, contact, saturation (and EKF errors) of one device from the MCAP;
    ``frames``: topic -> frames (:func:`topics_frames` of :func:`_device_topics`)."""
    truth = frames[f"/{ns}/truth"]["data"]
    out = frames[_device_topics(ns, mode)[1]]["data"][:, 0]
    k0 = int(SKIP_S * FS)
    t = np.arange(truth.shape[0]) / FS
    contact = truth[:, 3] > 0.5
    f = dict(
        snr=coherent_snr_db(out[k0:], t[k0:], F_IN),
        x_max=float(np.abs(truth[:, 1]).max()),
        contact=bool(contact.any()),
        saturated=bool(truth[:, 4].any()),
        # the input when the mass first reached the stop: the simulated pull-in
        contact_accel_g=float(abs(truth[int(np.argmax(contact)), 0]) / G)
        if contact.any()
        else None,
        series=dict(t=t, a=truth[:, 0], x=truth[:, 1], out=out),
    )
    if mode == "ekf_rebalance":
        est = frames[f"/{ns}/loop_estimate"]
        err = est["data"][k0:, 0] - truth[k0:, 1]
        f.update(
            accel_snr=coherent_snr_db(est["data"][k0:, 2], t[k0:], F_IN),
            err_max=float(np.abs(err).max()),
            err_std=float(err.std()),
            consistency=consistency(err, est["variances"][k0:, 0]),
        )
    return f


def oracle(record: dict, cases: dict) -> dict:
    """What only the simulation knows: the first device as built (every device is the
    same draw) from its parameters in the run record (:func:`device_as_built`), its
    mismatch against the designer's values (:func:`mismatch`), the relative error of the
    identified model (the bench's result in the record) and
    its analytic static pull-in accelerations [g] (Table I, and the Table III reading)."""
    fqn = emulator(next(iter(cases)))
    params = contract.node_parameters(record, fqn, "the device as built")
    values = device_as_built(params, record.get("fixed_parameters", {}).get(fqn, ()))
    p = accelerometer.validate_params(values["p"] | {"mode": "open_loop"})
    p3 = dict(p, **accelerometer.TABLE_III_VARIANT)
    identification = None
    if "bench" in record:  # the bench's identification, recorded with the run
        model = record["bench"]["model"]
        identification = {k: model[k] / values["p"][k] - 1.0 for k in MODEL_KEYS}
    return dict(
        mismatch=mismatch(values),
        identification_error=identification,
        pull_in_g=accelerometer.pull_in_acceleration(p)[0] / G,
        pull_in_t3_g=accelerometer.pull_in_acceleration(p3)[0] / G,
    )


def mismatch(values: dict) -> dict:
    """The device as built against the designer's values: ratios of mass, stiffness,
    damping and gap, and the relative error of the effective stiffness
    k_eff = k - eps A V1^2 / d0^3 (the carrier's softening, eq. 2-12 linearised) and of
    k_eff / m (the squared natural frequency), which the filter's model gets wrong."""
    dev, nom = values["p"], values["nominal"]

    def k_eff(p):
        return (
            p["stiffness"] - accelerometer.eps_area(p) * p["carrier_amplitude"] ** 2 / p["gap"] ** 3
        )

    out = {name: dev[name] / nom[name] for name in ("mass", "stiffness", "damping", "gap")}
    out["k_eff"] = k_eff(dev) / k_eff(nom) - 1.0
    out["omega2"] = (k_eff(dev) / dev["mass"]) / (k_eff(nom) / nom["mass"]) - 1.0
    return out


def not_pd_counters(path, cases: dict) -> dict[str, int]:
    """Samples with a covariance that was not positive definite, per device (namespace),
    from the last status of the device on the recorded /diagnostics (its
    ``covariance_not_pd_samples`` counter, absent: 0); devices without a status left out."""
    from mems_sim.bag.player import read_messages

    by_fqn = {emulator(ns): ns for ns in cases}
    out = {}
    for _, _, _, msg in read_messages(str(path), ["/diagnostics"]):
        for status in msg.status:
            ns = by_fqn.get(status.hardware_id)
            if ns is not None:
                values = {kv.key: kv.value for kv in status.values}
                out[ns] = int(values.get("covariance_not_pd_samples", 0))
    return out


#: Figure groups of :func:`oracle` (the full scenario; the spread one: ``device.*``).
ORACLE_GROUPS = (
    "device.*",
    "table_i.pull_in_analytic",
    "table_iii.pull_in_analytic",
    "check.table_i.pull_in",
)


def _drawn(record: dict | None, cases: dict) -> bool:
    """Whether the run's devices were drawn from the batch (``device_seed`` >= 0 in the run
    record; no record: judged as nominal)."""
    try:
        params = contract.node_parameters(record, emulator(next(iter(cases))), "")
    except contract.AnalysisError:
        return False
    return int(params.get("device_seed", -1)) >= 0


def figures(path: Path, record: dict | None, cases: dict) -> tuple[dict, list]:
    """Every figure of the scenario from the recorded MCAP: the devices' topics, the
    covariance counters on /diagnostics and the :func:`oracle` step on the run record.
    Returns the figures and (figure group, reason) of those the recording did not allow."""
    unavailable = []
    f: dict = {"devices": {}}
    names = list(cases)
    for i in range(0, len(names), DEVICES_PER_PASS):
        group = {ns: cases[ns]["mode"] for ns in names[i : i + DEVICES_PER_PASS]}
        frames = bag_frames.topics_frames(
            path, [t for ns, m in group.items() for t in _device_topics(ns, m)]
        )
        for ns, mode in group.items():
            f["devices"][ns] = _device_figures(frames, ns, mode)
        del frames
    counters = not_pd_counters(path, cases)
    for ns in cases:
        f["devices"][ns]["not_pd"] = counters.get(ns)
    f["full"] = _full(cases)
    if f["full"] and len(counters) < len(cases):  # Table IV's column
        unavailable.append(("*.not_pd_samples", f"{path}: no device status on /diagnostics"))
    f["drawn"] = _drawn(record, cases)
    try:
        f.update(oracle(record, cases))
    except contract.AnalysisError as exc:
        f.update(mismatch=None, identification_error=None, pull_in_g=None, pull_in_t3_g=None)
        groups = ORACLE_GROUPS if f["full"] else ORACLE_GROUPS[:1]
        unavailable.append((", ".join(groups), str(exc)))
    if f["full"]:
        k0 = int(SKIP_S * FS)
        fr = bag_frames.topics_frames(
            path, ["/acc_pi_1g/truth", DOWNSTREAM_TOPIC, DOWNSTREAM_ORACLE_TOPIC]
        )
        truth = fr["/acc_pi_1g/truth"]["data"]
        t = np.arange(truth.shape[0]) / FS
        for key, topic in (
            ("downstream", DOWNSTREAM_TOPIC),
            ("downstream_oracle", DOWNSTREAM_ORACLE_TOPIC),
        ):
            est = fr[topic]
            f[key] = consistency(est["data"][k0:, 0] - truth[k0:, 1], est["variances"][k0:, 0])
            f[key]["accel_snr"] = coherent_snr_db(est["data"][k0:, 2], t[k0:], F_IN)
        f["checks"] = checks(f)
    else:
        f["checks"] = spread_checks(f)
    return f, unavailable


def _check_duration(duration: float) -> None:
    if duration < SKIP_S + 1.0 / F_IN - 1e-9:
        raise base.ScenarioError(
            f"--duration = {duration!r} is too short for {NAME}: at least "
            f"{SKIP_S + 1.0 / F_IN:g} s (start-up and one 10 Hz period)"
        )


def analyse(bag, pngs=None, *, spread: bool = False) -> contract.ScenarioResult:
    """The scenario's figures from its recording ``bag`` alone (``spread``: scenario
    ``accelerometer_spread``): the devices' topics, their covariance counters on
    /diagnostics, and the device as built from the run record (:func:`oracle`; without
    the record its figures are listed as unavailable). ``pngs``: the PNG path (or a
    one-element sequence of it), None: no plot."""
    cases = spread_cases() if spread else device_cases()
    f, unavailable = figures(Path(bag), contract.read_run_info(bag), cases)
    paths = []
    if pngs is not None:
        paths = [Path(pngs)] if isinstance(pngs, str | Path) else [Path(q) for q in pngs]
        plot(f, paths[0])
    values = dict(
        devices={
            ns: {k: v for k, v in d.items() if k != "series"} for ns, d in f["devices"].items()
        },
        downstream=f.get("downstream"),
        downstream_oracle=f.get("downstream_oracle"),
        mismatch=f["mismatch"],
        identification_error=f["identification_error"],
        pull_in_g=f["pull_in_g"],
        pull_in_t3_g=f["pull_in_t3_g"],
        checks=f["checks"],
    )
    oracle_only = list(ORACLE_GROUPS if f["full"] else ORACLE_GROUPS[:1])
    return contract.ScenarioResult(
        NAME_SPREAD if spread else NAME,
        records(f),
        table(f),
        paths,
        unavailable,
        oracle_only,
        values,
    )


def run(options: base.ScenarioOptions, *, spread: bool = False) -> dict:
    """Run the scenario (``spread``: scenario ``accelerometer_spread``, the PI and EKF loops
    at 0.1 g and 1 g only) and analyse its recording (:func:`analyse`); return the tables,
    figures and paths."""
    return base.run_recorded(
        options,
        name=NAME_SPREAD if spread else NAME,
        default_duration_s=DEFAULT_DURATION_S,
        check_duration=_check_duration,
        run_graph=lambda o, out, d, pr: run_graph(o, out, d, pr, spread),
        analyse=lambda out, pngs: analyse(out, pngs, spread=spread),
    )

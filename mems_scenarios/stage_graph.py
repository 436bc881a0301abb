"""The node graph of the micro-stage calibration scenarios (Chen 2018 ch. 3): per instance a
``stage_node`` (stage at 625 kHz with its on-stage gyro), a ``stage_ekf_node`` loading an
identified parameter YAML (eqs. 48-53; optionally in its in-situ mode, eqs. 44-47) and a
``stage_gyro_calibration_node`` publishing ``/<ns>/gyro_scale_factor`` (eq. 27), one
recorder for every instance, driven by the scenario skeleton (fast or paced); the graph as
data (:func:`graph`, a GraphSpec) and the nodes' last /diagnostics counters of a recording
(:func:`recorded_counters`). Used by ``gyro_calibration`` and the SF(T) study."""

from __future__ import annotations

import time
from pathlib import Path

from mems_scenarios.contract import RUN_INFO_TOPIC, GraphSpec, NodeEntry

#: the topics of each instance recorded (besides its end-of-stream record and /diagnostics)
RECORDED = ("adc", "drive", "truth", "estimate", "gyro/adc", "gyro_scale_factor", "temperature")
#: stage frame size [samples] (20,000 samples = 32 ms at 625 kHz)
FRAME = 20000


def graph(options, layout: dict, name: str, run_info: bool = False) -> GraphSpec:
    """The graph of ``layout`` (namespace -> (stage node parameters, parameter YAML path
    of its EKF, further EKF parameters)): per namespace its stage node, its EKF and its
    calibration node, in that order; the recorder's topics (``run_info``: with the run
    record)."""
    nodes = []
    for ns, (stage, yaml_path, ekf_params) in layout.items():
        nodes += [
            NodeEntry(
                "stage_node",
                "stage",
                ns,
                dict(stage, frame_size=FRAME, frame_id=ns, publish_imu=bool(options.realtime)),
            ),
            NodeEntry(
                "stage_ekf_node",
                "stage_ekf",
                ns,
                dict(device_namespace=f"/{ns}", params_yaml=str(yaml_path), **ekf_params),
            ),
            NodeEntry(
                "stage_gyro_calibration_node",
                "stage_gyro_calibration",
                ns,
                dict(device_namespace=f"/{ns}", n_trials=stage["n_trials"]),
            ),
        ]
    topics = [f"/{ns}/{t}" for ns in layout for t in (*RECORDED, "end_of_stream")]
    topics.append("/diagnostics")
    return GraphSpec(name, tuple(nodes), (*topics, *([RUN_INFO_TOPIC] if run_info else ())))


def recorded_counters(bag, topic: str = "/diagnostics") -> dict[str, dict]:
    """The last diagnostics counters of every node in the recording ``bag``: hardware_id
    (the node's fully qualified name) -> counter -> value (int or float, as published)."""
    from mems_sim.bag.player import read_messages

    out: dict[str, dict] = {}
    for _, _, _, msg in read_messages(str(bag), [topic]):
        for status in msg.status:
            values = {}
            for kv in status.values:
                try:
                    values[kv.key] = int(kv.value)
                except ValueError:
                    try:
                        values[kv.key] = float(kv.value)
                    except ValueError:
                        values[kv.key] = kv.value
            out[status.hardware_id] = values
    return out


def run_stage_graph(
    options,
    layout: dict,
    out: Path,
    name: str,
    shielded: dict | None = None,
    run_info: dict | None = None,
) -> dict:
    """Run the graph of ``layout`` (namespace -> (stage node parameters, parameter YAML
    path of its EKF, further EKF parameters such as ``insitu``)), recorded to ``out``, until
    every calibration node published its result and the recorder has every frame.
    ``shielded``: namespace -> stage parameters the user's overrides must not reach.
    Returns the published results (eq. 27, with their peak-to-peak pairs) and the true
    gyro scale factor per namespace, the recorder's summary (counts, gaps, losses), frames
    published and rejected, the in-situ corrections (in-situ instances), simulated and wall
    time [s]. ``run_info``: extra keys of the run record (None: no run record); it is
    published once the graph ran, with the graph's simulated and wall time
    (``simulated_s``, ``wall_s``), after every EKF's final diagnostics."""
    from mems_scenarios.base import Progress, graph_for
    from mems_scenarios.delivery import publish_all
    from mems_sim.ros.flow import progress_of

    shielded = shielded or {}
    spec = graph(options, layout, name, run_info is not None)
    g = graph_for(options)
    rec = None
    try:
        nodes = g.build(
            spec,
            realtime=options.realtime,
            shielded={f"/{ns}/stage": v for ns, v in shielded.items()},
        )
        devs = {ns: nodes[f"/{ns}/stage"] for ns in layout}
        ekfs = {ns: nodes[f"/{ns}/stage_ekf"] for ns in layout}
        cals = {ns: nodes[f"/{ns}/stage_gyro_calibration"] for ns in layout}
        rec = g.recorder(str(out), topics=list(spec.recorded))

        def delivered(d) -> int:
            """Progress [samples] of the device's EKF (the recorder counts in the skeleton)."""
            return progress_of(ekfs[d.get_namespace().lstrip("/")]) or 0

        g.spin_until(
            lambda: (
                all(
                    d.pub_adc.get_subscription_count() >= 2
                    and d.pub_gyro.get_subscription_count() >= 2
                    # the in-situ EKF learns the sweep's end from the end-of-stream record
                    and d.pub_end_of_stream.get_subscription_count()
                    >= (2 if ekfs[ns].insitu else 1)
                    for ns, d in devs.items()
                )
                and all(e.pub.get_subscription_count() >= 2 for e in ekfs.values())
            ),
            30.0,
            "the recorder, EKF and calibration nodes to subscribe",
        )
        total = max(d.total_samples for d in devs.values()) / next(iter(devs.values())).fs
        progress = Progress(total, options.progress, name)
        wall0 = time.monotonic()
        publish_all(
            g,
            list(devs.values()),
            delivered,
            progress,
            realtime=options.realtime,
            realtime_timeout_s=total * 50 + 120,
            window=20,
            drain_timeout_s=120.0,
        )
        wall = time.monotonic() - wall0
        progress.close()
        # every estimate published (in-situ: once the sweep is processed) and taken
        g.spin_until(
            lambda: all(
                ekfs[ns].estimates_published >= ekfs[ns].frames_done
                and cals[ns].estimates_received >= ekfs[ns].estimates_published
                and cals[ns].gyro_frames_received >= rec.received(f"/{ns}/gyro/adc")
                for ns in layout
            ),
            120.0,
            "the calibration nodes to receive the last estimates and gyro frames",
        )
        for ns, c in cals.items():
            c.close()
        g.spin_until(
            lambda: all(rec.received(f"/{ns}/gyro_scale_factor") >= 1 for ns in layout),
            30.0,
            "the calibration results",
        )
        g.spin_until(
            lambda: all(rec.received(f"/{ns}/estimate") >= ekfs[ns].frames_done for ns in layout),
            60.0,
            "the last estimates",
        )
        if run_info is not None:  # the EKFs' final counters, then the run record
            before = rec.received("/diagnostics")
            for e in ekfs.values():
                e.diag.publish()
            g.spin_until(
                lambda: rec.received("/diagnostics") >= before + len(ekfs),
                20.0,
                "the recorder to take the final diagnostics",
            )
            for _ in range(10):  # and those of the other nodes' timers sent before them
                g.executor.spin_once(timeout_sec=0.01)
            g.publish_run_info(spec, options, nodes, simulated_s=total, wall_s=wall, **run_info)
            g.wait_run_info(rec)
        k_true = {ns: devs[ns].gyro.scale_factor() for ns in layout}
        results = {ns: cals[ns].results[-1] for ns in layout}
        rejected = {ns: ekfs[ns].diag.counters.get("rejected_frames", 0) for ns in layout}
        published = {ns: d.frames_published for ns, d in devs.items()}
        insitu = {
            ns: {
                k: ekfs[ns].diag.counters[k]
                for k in ("insitu_wn_ratio", "insitu_b_c_ratio", "insitu_sweeps")
            }
            for ns in layout
            if ekfs[ns].insitu
        }
    finally:
        summary = None
        if rec is not None:  # None when building the graph failed
            rec.close()
            summary = rec.report()
        g.close()
    return dict(
        k_true=k_true,
        results=results,
        recorder=summary,
        published=published,
        rejected=rejected,
        insitu=insitu,
        wall_s=wall,
        simulated_s=total,
    )

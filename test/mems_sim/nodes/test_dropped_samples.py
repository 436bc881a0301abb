"""Dropped samples of a fault schedule, end to end in one rclpy context: the IMU emulator
leaves exactly the scheduled indices out of its ADC, temperature and sensor_msgs/Imu
streams (its truth stays whole, every delivered code equals the fault-free run's), the
faults topic labels them, and the recorder, ``mcap_info`` and an estimator report a device
gap of exactly that length, not transport loss."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import params, spin_until
from sensor_msgs.msg import Imu

from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
from mems_msgs.msg import AdcFrame, FaultEvent, SignalFrame
from mems_sim.bag import info as info_mod
from mems_sim.bag.player import read_messages
from mems_sim.bag.recorder import RecorderNode
from mems_sim.nodes.imu_node import ImuNode

FRAME, FRAMES = 20, 10
# one gap inside a frame, one across a frame boundary, one of whole frames
DROPS = ((25, 7), (58, 5), (120, 40))
TOPICS = ("/imu/adc", "/imu/truth", "/imu/temperature_sensor", "/imu/data", "/imu/faults")


def _record(tmp_path, schedule: str | None, graph) -> str:
    ctx, ex, _ = graph
    path = tmp_path / ("drop.mcap" if schedule else "clean.mcap")
    extra = {}
    if schedule:
        (tmp_path / "faults.yaml").write_text(schedule)
        extra["fault_schedule"] = str(tmp_path / "faults.yaml")
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4, frame_size=FRAME, calibration_topics="on", frame_id="imu", **extra
        ),
    )
    topics = [t for t in TOPICS if schedule or t != "/imu/faults"]
    rec = RecorderNode(str(path), topics=topics, context=ctx)
    ident = ImuNoiseIdentifierNode(context=ctx, namespace="imu", parameter_overrides=params())
    ex.add_node(emu)
    ex.add_node(rec)
    ex.add_node(ident)
    try:
        assert spin_until(ex, lambda: all(rec.matched(t) for t in topics))
        assert spin_until(ex, lambda: emu.pub_adc.get_subscription_count() == 2)
        for _ in range(FRAMES):
            emu.step()
        n_imu = FRAME * FRAMES - (sum(n for _, n in DROPS) if schedule else 0)
        assert spin_until(ex, lambda: rec.received("/imu/data") == n_imu)
        assert spin_until(ex, lambda: rec.received("/imu/truth") == FRAMES)
        end = FRAME * FRAMES
        assert spin_until(ex, lambda: ident.progress == end)
        rec.close()
        return str(path), rec, dict(ident.diag.counters)
    finally:
        for node in (ident, rec, emu):
            ex.remove_node(node)
            node.destroy_node()


def _frames(path: str, topic: str, kind):
    out = [msg for _, _, _, msg in read_messages(path, topics=[topic])]
    assert all(isinstance(m, kind) for m in out)
    return out


def _indexed(frames, width):
    """(index, values (n, width)) of every sample of the frames."""
    idx = np.concatenate([np.arange(f.num_samples) + f.first_sample_index for f in frames])
    vals = np.concatenate(
        [np.asarray(getattr(f, "codes", None) or f.data).reshape(-1, width) for f in frames]
    )
    return idx, vals


def test_dropped_samples_are_a_declared_device_gap_of_exactly_their_length(tmp_path, graph):
    schedule = "faults:\n" + "".join(
        f"  - {{kind: dropped_samples, start_sample: {a}, duration_samples: {n}}}\n"
        for a, n in DROPS
    )
    clean, _, _ = _record(tmp_path, None, graph)
    path, rec, counters = _record(tmp_path, schedule, graph)
    dropped = np.concatenate([np.arange(a, a + n) for a, n in DROPS])
    kept = np.setdiff1d(np.arange(FRAME * FRAMES), dropped)
    # the device's streams jump over exactly the dropped indices, the rest bit for bit
    for topic, kind, width in (
        ("/imu/adc", AdcFrame, 6),
        ("/imu/temperature_sensor", SignalFrame, 1),
    ):
        idx, vals = _indexed(_frames(path, topic, kind), width)
        ref_idx, ref = _indexed(_frames(clean, topic, kind), width)
        np.testing.assert_array_equal(idx, kept)
        np.testing.assert_array_equal(ref_idx, np.arange(FRAME * FRAMES))
        np.testing.assert_array_equal(vals, ref[kept])
    # a frame cut in two: each piece stamped at its own first sample
    adc = _frames(path, "/imu/adc", AdcFrame)
    piece = next(f for f in adc if f.first_sample_index == 32)
    assert (piece.header.stamp.sec, piece.header.stamp.nanosec) == (0, 320_000_000)
    assert piece.num_samples == 8 and piece.header.frame_id == "imu"
    # truth stays whole
    idx, _ = _indexed(_frames(path, "/imu/truth", SignalFrame), 6)
    np.testing.assert_array_equal(idx, np.arange(FRAME * FRAMES))
    # sensor_msgs/Imu: one message per delivered sample
    imu = _frames(path, "/imu/data", Imu)
    stamps = [(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec) // 10**7 for m in imu]
    np.testing.assert_array_equal(stamps, kept)  # 100 Hz: sample k at k * 10 ms
    # labelled truth of the schedule
    events = sorted(_frames(path, "/imu/faults", FaultEvent), key=lambda m: m.number)
    labels = [(m.kind, m.channel, m.first_faulty_sample, m.faulty_samples) for m in events]
    assert labels == [("dropped_samples", "", a, n) for a, n in DROPS]
    # the recorder: device gaps of exactly that length, no loss
    d = rec.gap_details()["/imu/adc"]
    assert (d["gaps"], d["missing_samples"], d["device_gaps"], d["device_missing_samples"]) == (
        0,
        0,
        3,
        dropped.size,
    )
    assert rec.losses() == []
    assert "device gap: /imu/adc: 3 device gaps (52 samples, declared by the device)" in (
        rec.summary()
    )
    # mcap_info: the same, and no 'lost data' warning
    info = info_mod.bag_info(path)
    t = info["topics"]["/imu/adc"]
    assert (t["gaps"], t["device_gaps"], t["device_missing_samples"]) == (0, 3, 52)
    assert info["topics"]["/imu/truth"]["device_gaps"] == 0
    assert info_mod.losses(info) == []
    assert "3 device gaps (52 samples, declared by the device)" in info_mod.format_info(info)
    # an estimator of the device: the same device gaps, no loss
    got = {k: counters.get(k, 0) for k in ("gaps", "missing_samples", "device_gaps")}
    assert got == {"gaps": 0, "missing_samples": 0, "device_gaps": 3}, counters
    assert counters["device_missing_samples"] == 52


def test_undeclared_gaps_stay_transport_loss(tmp_path, graph):
    """The same gaps with the faults topic not recorded: the file cannot tell a dropped
    sample from a lost one, so mcap_info reports loss."""
    ctx, ex, _ = graph
    (tmp_path / "faults.yaml").write_text(
        "faults:\n  - {kind: dropped_samples, start_sample: 25, duration_samples: 7}\n"
    )
    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4,
            frame_size=FRAME,
            publish_imu=False,
            fault_schedule=str(tmp_path / "faults.yaml"),
        ),
    )
    path = str(tmp_path / "undeclared.mcap")
    rec = RecorderNode(path, topics=["/imu/adc"], context=ctx)
    ex.add_node(emu)
    ex.add_node(rec)
    try:
        assert spin_until(ex, lambda: rec.matched("/imu/adc"))
        for _ in range(3):
            emu.step()
        assert spin_until(ex, lambda: rec.received("/imu/adc") == 4)
        rec.close()
    finally:
        for node in (rec, emu):
            ex.remove_node(node)
            node.destroy_node()
    info = info_mod.bag_info(path)
    assert info_mod.losses(info) == ["/imu/adc: 1 frame-index gaps (7 samples)"]


def test_a_declaration_after_the_gap_moves_the_estimators_counts(graph):
    """The FaultEvent reaches the estimator after the frame that jumped: the transport gap
    it had counted becomes a device gap on /diagnostics."""
    from mems_sim.nodes.fault_topic import fault_qos
    from mems_sim.ros.frames import make_adc_frame
    from mems_sim.ros.qos import FRAME_QOS

    ctx, ex, probe = graph
    ident = ImuNoiseIdentifierNode(context=ctx, namespace="imu", parameter_overrides=params())
    ex.add_node(ident)
    try:
        pub = probe.create_publisher(AdcFrame, "/imu/adc", FRAME_QOS)
        faults = probe.create_publisher(FaultEvent, "/imu/faults", fault_qos(1))
        assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
        assert spin_until(ex, lambda: faults.get_subscription_count() == 1)
        names = [f"{k}_{a}" for k in ("gyro", "accel") for a in "xyz"]
        units = ["rad/s"] * 3 + ["m/s^2"] * 3
        for first in (0, 30):  # samples 20..29 missing
            pub.publish(
                make_adc_frame(
                    np.zeros((20, 6), np.int32),
                    first,
                    100.0,
                    bits=16,
                    channel_names=names,
                    channel_units=units,
                    lsb=[1e-4] * 6,
                    full_scale=[3.0] * 6,
                )
            )
        assert spin_until(ex, lambda: ident.progress == 50)
        assert (ident.diag.counters["gaps"], ident.diag.counters["missing_samples"]) == (1, 10)
        faults.publish(
            FaultEvent(kind="dropped_samples", first_faulty_sample=20, faulty_samples=10)
        )
        assert spin_until(ex, lambda: ident.diag.counters.get("device_gaps") == 1)
        c = ident.diag.counters
        assert (c["gaps"], c["missing_samples"], c["device_missing_samples"]) == (0, 0, 10)
    finally:
        ex.remove_node(ident)
        ident.destroy_node()


def test_dropped_samples_of_the_resonator_cut_bits_pulses_and_loop_estimate(graph, tmp_path):
    """The sigma-delta resonator offers the timing kinds: its bit stream, pulses and in-loop
    observer's estimate skip the dropped samples, its truth does not, and a sensor kind is
    refused in one line."""
    from mems_msgs.msg import StateEstimate
    from mems_sim.nodes.resonator_node import ResonatorNode
    from mems_sim.params import ParameterError
    from mems_sim.ros.qos import FRAME_QOS

    (tmp_path / "faults.yaml").write_text(
        "faults:\n  - {kind: dropped_samples, start_sample: 700, duration_samples: 600}\n"
    )
    ctx, ex, probe = graph
    dev = ResonatorNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4, frame_size=500, mode="observer", fault_schedule=str(tmp_path / "faults.yaml")
        ),
    )
    ex.add_node(dev)
    got = {"adc": [], "drive": [], "truth": [], "loop_estimate": []}
    kinds = {"adc": AdcFrame, "loop_estimate": StateEstimate}
    try:
        for name in got:
            probe.create_subscription(
                kinds.get(name, SignalFrame), f"/resonator/{name}", got[name].append, FRAME_QOS
            )
        assert spin_until(ex, lambda: dev.pub_estimate.get_subscription_count() == 1)
        assert spin_until(ex, lambda: dev.pub_adc.get_subscription_count() == 1)
        for _ in range(4):
            dev.step()
        assert spin_until(ex, lambda: all(len(v) == 4 for v in got.values()))
        for name in ("adc", "drive", "loop_estimate"):
            runs = [(m.first_sample_index, m.num_samples) for m in got[name]]
            assert runs == [(0, 500), (500, 200), (1300, 200), (1500, 500)], (name, runs)
        assert [m.first_sample_index for m in got["truth"]] == [0, 500, 1000, 1500]
        est = got["loop_estimate"][2]
        assert len(est.states) == len(est.variances) == 200
    finally:
        ex.remove_node(dev)
        dev.destroy_node()
    (tmp_path / "bad.yaml").write_text(
        "faults:\n  - {kind: bias_step, channel: sd_bit, start_sample: 1, magnitude: 1}\n"
    )
    with pytest.raises(
        ParameterError, match=r"not a fault of this device \(one of: dropped_samples\)"
    ):
        ResonatorNode(
            context=ctx,
            drive_externally=True,
            parameter_overrides=params(fault_schedule=str(tmp_path / "bad.yaml")),
        )

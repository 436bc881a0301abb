"""Micro-scanner device node (dc_transimpedance / shared_amdm) and threshold hybrid-EKF node."""

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from node_helpers import (
    diagnostics_show,
    emulator_refuses,
    one_channel_adc,
    step_frames,
    wait_matched,
)

from mems_estimation.nodes.scanner_threshold_ekf_node import (
    ScannerThresholdEkfNode,
    detections_from_rows,
)
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices.scanner import MicroScannerDevice
from mems_sim.nodes.scanner_node import ScannerNode, quantize
from mems_sim.params import ParameterError
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.qos import FRAME_QOS

# free decay from 0.1 rad: short, with threshold crossings at good SNR
DECAY = dict(initial_angle=0.1, sweep_time_s=0.0, hold_time_s=0.0, ringdown_time_s=0.03)


def _subscribe(probe, ns, names):
    got = {}
    types = {"adc": AdcFrame, "estimate": StateEstimate, "estimate_plain": StateEstimate}
    for n in names:
        got[n] = []
        probe.create_subscription(types.get(n, SignalFrame), f"{ns}/{n}", got[n].append, FRAME_QOS)
    return got


def test_device_node_publishes_core_frames(graph):
    ctx, ex, probe = graph
    dev = ScannerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=7, frame_size=1000, **DECAY),
    )
    ex.add_node(dev)
    got = _subscribe(probe, "/scanner", ("adc", "drive", "truth", "psd"))
    assert wait_matched(ex, dev.pub_adc, dev.pub_psd)
    for _ in range(5):
        dev.step()
    assert spin_until(ex, lambda: all(len(v) == 5 for v in got.values()))
    ref = MicroScannerDevice(DECAY, seed=7).step(5000)
    codes = np.concatenate([np.asarray(m.codes) for m in got["adc"]])
    exp, lsb, _ = quantize(ref.y, 16, 10.0)
    np.testing.assert_array_equal(codes, exp)
    assert got["adc"][0].lsb[0] == pytest.approx(lsb) and got["adc"][0].bits == 16
    truth = np.concatenate([np.asarray(m.data).reshape(-1, 2) for m in got["truth"]])
    np.testing.assert_array_equal(truth[:, 0], ref.theta)
    psd = np.concatenate([np.asarray(m.data) for m in got["psd"]])
    np.testing.assert_array_equal(psd, ref.psd)
    assert list(got["truth"][0].channel_units) == ["rad", "rad/s"]
    assert [m.first_sample_index for m in got["adc"]] == list(range(0, 5000, 1000))
    assert dev.diag.counters["psd_delay_s"] == pytest.approx(0.114e-3)


def test_threshold_node_tracks_through_topics(graph):
    ctx, ex, probe = graph
    dev = ScannerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=2, frame_size=1000, **DECAY),
    )
    est = ScannerThresholdEkfNode(context=ctx, parameter_overrides=params(dog_sigma=45.0))
    ex.add_node(dev)
    ex.add_node(est)
    got = _subscribe(
        probe, "/scanner", ("estimate", "estimate_plain", "threshold_detections", "truth")
    )
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() == 1
            and dev.pub_drive.get_subscription_count() == 1
            and est.pub_hyb.get_subscription_count() == 1
        ),
    )
    n_frames = 15
    step_frames(ex, dev, n_frames)
    assert spin_until(
        ex,
        lambda: (
            est.frames_done == n_frames
            and len(got["estimate"]) == n_frames
            and len(got["truth"]) == n_frames
            and len(got["threshold_detections"]) == n_frames
        ),
        timeout=30,
    )
    firsts = [m.first_sample_index for m in got["estimate"]]
    lag = est.hybrid.lag
    assert firsts[0] == 0 and firsts[1] == 1000 - lag  # final estimates lag by `lag`
    x = np.concatenate([np.asarray(m.states).reshape(-1, 2) for m in got["estimate"]])
    var = np.concatenate([np.asarray(m.variances).reshape(-1, 2) for m in got["estimate"]])
    truth = np.concatenate([np.asarray(m.data).reshape(-1, 2) for m in got["truth"]])
    n = x.shape[0]
    assert n == n_frames * 1000 - lag
    err = x[5000:, 0] - truth[5000:n, 0]
    assert np.sqrt(np.mean(err**2)) < 0.01 and np.all(var > 0)
    assert len(got["threshold_detections"]) == n_frames
    rows = np.concatenate([np.asarray(m.data).reshape(-1, 3) for m in got["threshold_detections"]])
    D = detections_from_rows(rows, 0)
    assert D.index.size > 20
    np.testing.assert_array_equal(D.arrival - D.index, est.detector.latency)
    assert est.diag.counters["detections_applied"] > 10
    assert not est.low_signal


def test_low_signal_reported_far_from_resonance(graph):
    ctx, ex, probe = graph
    dev = ScannerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=3, frame_size=1000, initial_angle=0.0, drive_frequency_hz=3000.0
        ),
    )
    est = ScannerThresholdEkfNode(context=ctx)
    ex.add_node(dev)
    ex.add_node(est)
    diags = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    assert wait_matched(ex, dev.pub_adc, dev.pub_drive)
    step_frames(ex, dev, 12)
    assert spin_until(ex, lambda: est.frames_done == 12)
    assert est.low_signal and est.snr < 0.1
    assert any("low signal" in w for w in est.diag.warnings)
    assert est.hybrid.counts["min_det"] > 0 and np.all(np.isfinite(est.hybrid.x))
    assert abs(est.hybrid.x[0]) < 0.02
    est.diag.publish()
    assert spin_until(
        ex,
        lambda: diagnostics_show(
            diags,
            "scanner_threshold",
            lambda s: s.level == DiagnosticStatus.WARN and "low signal" in s.message,
        ),
    )


def _y_frame(first, n, fs=500e3, name="y_cap"):
    codes = np.zeros(n, dtype=int)
    return one_channel_adc(first, codes, fs, bits=16, name=name, lsb=20 / 65536, full_scale=10.0)


def test_threshold_node_rejects_malformed_frames(graph):
    ctx, ex, probe = graph
    est = ScannerThresholdEkfNode(context=ctx)
    ex.add_node(est)
    pub_y = probe.create_publisher(AdcFrame, "/scanner/adc", FRAME_QOS)
    pub_v = probe.create_publisher(SignalFrame, "/scanner/drive", FRAME_QOS)
    assert wait_matched(ex, pub_y, pub_v)
    pub_y.publish(_y_frame(0, 100, fs=1e6))  # wrong rate
    pub_y.publish(_y_frame(0, 100, name="other"))  # wrong channel
    bad = make_signal_frame(
        [[0.0], [float("nan")]], 0, 500e3, channel_names=["v_drive"], channel_units=["V"]
    )
    pub_v.publish(bad)  # non-finite
    assert spin_until(ex, lambda: est.diag.counters.get("rejected_frames", 0) == 3)
    assert est.frames_done == 0


def test_invalid_parameters_refused(ros_context):
    emulator_refuses(ScannerNode, ros_context, "damping_ratio", damping_ratio=-1.0)
    emulator_refuses(ScannerNode, ros_context, "front_end", front_end="optical")
    with pytest.raises(ParameterError, match="lag"):
        ScannerThresholdEkfNode(context=ros_context, parameter_overrides=params(lag=100))
    with pytest.raises(ParameterError, match="dog_width"):
        ScannerThresholdEkfNode(context=ros_context, parameter_overrides=params(dog_sigma=200.0))


def test_shared_amdm_front_end_publishes(graph):
    ctx, ex, probe = graph
    dev = ScannerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(front_end="shared_amdm", frame_size=200),
    )
    ex.add_node(dev)
    got = _subscribe(probe, "/scanner", ("adc", "truth"))
    assert dev.pub_psd is None
    assert spin_until(ex, lambda: dev.pub_adc.get_subscription_count() == 1)
    dev.step()
    assert spin_until(ex, lambda: len(got["adc"]) == 1 and len(got["truth"]) == 1)
    assert got["adc"][0].num_samples == 200 and got["adc"][0].sample_rate_hz == dev.fs


def test_threshold_node_publishes_its_last_estimates_at_the_end_of_the_stream(graph):
    """The estimates lag the input by ``lag`` samples: once the device's end-of-stream
    record announces the end and every frame is done, the node publishes the last ``lag``
    (no shutdown, no flush call), once."""
    ctx, ex, probe = graph
    dev = ScannerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=3, frame_size=1000, duration_s=0.008, **DECAY),
    )
    est = ScannerThresholdEkfNode(context=ctx, parameter_overrides=params(dog_sigma=45.0))
    ex.add_node(dev)
    ex.add_node(est)
    got = _subscribe(probe, "/scanner", ("estimate", "estimate_plain"))
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() == 1
            and dev.pub_drive.get_subscription_count() == 1
            and est.pub_hyb.get_subscription_count() == 1
            and est.pub_plain.get_subscription_count() == 1
        ),
    )
    while dev.step():
        ex.spin_once(timeout_sec=0.0)
    assert dev.end_of_stream_sent

    def ends(name):
        return [m.first_sample_index + m.num_samples for m in got[name]]

    assert spin_until(
        ex,
        lambda: ends("estimate")[-1:] == [4000] and ends("estimate_plain")[-1:] == [4000],
        timeout=30,
    )
    for name in ("estimate", "estimate_plain"):
        firsts = [m.first_sample_index for m in got[name]]
        assert firsts == [0] + [1000 * k - est.hybrid.lag for k in range(1, 5)], name
    assert est.flushed
    est.flush()  # a second flush publishes nothing
    for _ in range(20):
        ex.spin_once(timeout_sec=0.01)
    assert len(got["estimate"]) == 5 and len(got["estimate_plain"]) == 5


def test_fault_schedule_on_the_readout_voltage(graph, tmp_path):
    """dc_transimpedance: a sign flip of y_cap over samples 1500..3499 and a stuck readout
    from 4200: the codes are the fault-free run's outside, mirrored and frozen inside, and
    the faults topic labels both; shared_amdm offers the timing kinds only."""
    from mems_msgs.msg import FaultEvent
    from mems_sim.nodes.fault_topic import fault_qos

    schedule = tmp_path / "faults.yaml"
    schedule.write_text(
        "faults:\n"
        "  - {kind: sign_flip, channel: y_cap, start_sample: 1500, duration_samples: 2000}\n"
        "  - {kind: stuck_at, channel: y_cap, start_sample: 4200}\n"
    )
    ctx, ex, probe = graph
    dev = ScannerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=7, frame_size=1000, fault_schedule=str(schedule), **DECAY),
    )
    ex.add_node(dev)
    got = _subscribe(probe, "/scanner", ("adc",))
    events = []
    probe.create_subscription(FaultEvent, "/scanner/faults", events.append, fault_qos(2))
    assert wait_matched(ex, dev.pub_adc)
    for _ in range(5):
        dev.step()
    assert spin_until(ex, lambda: len(got["adc"]) == 5 and len(events) == 2)
    codes = np.concatenate([np.asarray(m.codes) for m in got["adc"]])
    clean, _, _ = quantize(MicroScannerDevice(DECAY, seed=7).step(5000).y, 16, 10.0)
    np.testing.assert_array_equal(codes[:1500], clean[:1500])
    np.testing.assert_array_equal(codes[3500:4200], clean[3500:4200])
    assert np.all(np.abs(codes[1500:3500] + clean[1500:3500]) <= 1)
    assert np.all(codes[4200:] == clean[4200]) and np.ptp(clean[4200:]) > 0
    assert sorted((e.kind, e.first_faulty_sample, e.permanent) for e in events) == [
        ("sign_flip", 1500, False),
        ("stuck_at", 4200, True),
    ]
    emulator_refuses(
        ScannerNode,
        ctx,
        r"'sign_flip' is not a fault of this device \(one of: dropped_samples\)",
        front_end="shared_amdm",
        fault_schedule=str(schedule),
    )

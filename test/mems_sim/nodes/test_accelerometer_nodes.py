"""Force-rebalance accelerometer node and hybrid EKF node through real topics."""

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from node_helpers import emulator_refuses, one_channel_adc, wait_matched

from mems_estimation.filters.accelerometer_ekf import HybridEkf
from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices import accelerometer
from mems_sim.nodes.accelerometer_node import AccelerometerNode
from mems_sim.params import ParameterError
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.qos import FRAME_QOS

G = accelerometer.G0


def _collect(probe, ns, names):
    got = {n: [] for n in names}
    types = {
        "adc": AdcFrame,
        "drive": SignalFrame,
        "truth": SignalFrame,
        "loop_estimate": StateEstimate,
        "estimate": StateEstimate,
    }
    for n in names:
        probe.create_subscription(types[n], f"{ns}/{n}", got[n].append, FRAME_QOS)
    return got


def _cat(frames, field, width):
    return np.concatenate([np.asarray(getattr(m, field)).reshape(-1, width) for m in frames])


def test_device_publishes_readout_drive_truth_and_loop_estimate(graph):
    ctx, ex, probe = graph
    dev = AccelerometerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4, frame_size=2000, mode="ekf_rebalance", accel_amplitude=G
        ),
    )
    ex.add_node(dev)
    got = _collect(probe, "/accelerometer", ("adc", "drive", "truth", "loop_estimate"))
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() == 1
            and dev.pub_estimate.get_subscription_count() == 1
        ),
    )
    for _ in range(5):
        dev.step()
    assert spin_until(ex, lambda: all(len(v) == 5 for v in got.values()))
    ref = accelerometer.ForceRebalanceAccelerometer(
        {"mode": "ekf_rebalance", "accel_amplitude": G}, seed=4
    ).step(10_000)
    assert [m.first_sample_index for m in got["adc"]] == list(range(0, 10_000, 2000))
    m = got["adc"][0]
    assert m.bits == 16 and list(m.channel_names) == ["readout"] and m.sample_rate_hz == 1e6
    np.testing.assert_array_equal(_cat(got["adc"], "codes", 1)[:, 0], ref.code)
    drive = _cat(got["drive"], "data", 2)
    np.testing.assert_array_equal(drive[:, 0], ref.v_f)
    assert np.all(
        drive[:, 1] == pytest.approx(accelerometer.bias_voltage(accelerometer.validate_params({})))
    )
    truth = _cat(got["truth"], "data", 5)
    np.testing.assert_array_equal(truth[:, 1], ref.x)
    assert list(got["truth"][0].channel_units) == ["m/s^2", "m", "m/s", "1", "1"]
    np.testing.assert_array_equal(_cat(got["loop_estimate"], "states", 3), ref.estimate)


def test_ekf_node_on_the_device_topics_matches_the_core(graph):
    """Device (PI loop) -> adc/drive -> hybrid EKF node -> estimate equals the core filter."""
    ctx, ex, probe = graph
    over = params(seed=6, frame_size=5000, mode="pi_rebalance", accel_amplitude=0.5 * G)
    dev = AccelerometerNode(context=ctx, drive_externally=True, parameter_overrides=over)
    ekf = AccelerometerEkfNode(context=ctx, parameter_overrides=params(mode="pi_rebalance"))
    ex.add_node(dev)
    ex.add_node(ekf)
    got = _collect(probe, "/accelerometer", ("estimate",))
    assert wait_matched(ex, dev.pub_adc, ekf.pub)
    for _ in range(4):
        dev.step()
    assert spin_until(ex, lambda: len(got["estimate"]) == 4)
    d = accelerometer.ForceRebalanceAccelerometer(
        {"mode": "pi_rebalance", "accel_amplitude": 0.5 * G}, seed=6
    )
    f = d.step(20_000)
    ref = HybridEkf(d.ekf_config).run(f.code * d.lsb, f.v_f)
    np.testing.assert_allclose(
        _cat(got["estimate"], "states", 3), ref["estimate"], rtol=1e-12, atol=0
    )
    np.testing.assert_allclose(
        _cat(got["estimate"], "variances", 3), ref["variance"], rtol=1e-12, atol=0
    )


def test_ekf_node_rejects_non_finite_drive_and_keeps_running(graph):
    ctx, ex, probe = graph
    ekf = AccelerometerEkfNode(context=ctx, parameter_overrides=params(mode="pi_rebalance"))
    ex.add_node(ekf)
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "pi_rebalance"}, seed=1)
    pub_a = probe.create_publisher(AdcFrame, "/accelerometer/adc", FRAME_QOS)
    pub_d = probe.create_publisher(SignalFrame, "/accelerometer/drive", FRAME_QOS)
    got = _collect(probe, "/accelerometer", ("estimate",))
    diags = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    assert wait_matched(ex, pub_a, pub_d)
    for k in range(3):
        f = d.step(1000)
        pub_a.publish(
            one_channel_adc(
                k * 1000, f.code, 1e6, bits=16, name="readout", lsb=d.lsb, full_scale=0.5
            )
        )
        v = np.column_stack([f.v_f, np.full(1000, d.v_b)])
        if k == 1:
            v[10, 0] = np.nan
        pub_d.publish(
            make_signal_frame(
                v,
                k * 1000,
                1e6,
                channel_names=("feedback_voltage", "bias_voltage"),
                channel_units=("V", "V"),
            )
        )
    assert spin_until(
        ex, lambda: len(got["estimate"]) == 2 and ekf.diag.counters.get("rejected_frames", 0) == 1
    )
    assert [m.first_sample_index for m in got["estimate"]] == [0, 2000]
    assert np.all(np.isfinite(got["estimate"][1].states))
    assert any("non-finite" in w for w in ekf.diag.warnings)
    ekf.diag.publish()
    assert spin_until(
        ex,
        lambda: any(
            s.name.startswith("accelerometer_ekf")
            and {kv.key: kv.value for kv in s.values}.get("rejected_frames") == "1"
            for m in diags
            for s in m.status
        ),
    )


def test_over_range_input_warns_on_diagnostics(graph):
    ctx, ex, probe = graph
    dev = AccelerometerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(frame_size=20_000, mode="pi_rebalance", accel_amplitude=50 * G),
    )
    ex.add_node(dev)
    diags = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    for _ in range(3):
        dev.step()
    assert dev.diag.counters["over_range_samples"] > 0
    assert dev.diag.counters["feedback_saturated_samples"] > 0
    dev.diag.publish()
    assert spin_until(
        ex,
        lambda: any(
            s.level == DiagnosticStatus.WARN and s.name.startswith("accelerometer:")
            for m in diags
            for s in m.status
        ),
    )
    assert any("dynamic range" in w for w in dev.diag.warnings)


@pytest.mark.parametrize("name,value", [("mass", 0.0), ("gap", 0.0), ("stiffness", -3.0)])
def test_nodes_refuse_non_physical_parameters(ros_context, name, value):
    emulator_refuses(AccelerometerNode, ros_context, name, **{name: value})
    with pytest.raises(ParameterError, match=name):
        AccelerometerEkfNode(context=ros_context, parameter_overrides=params(**{name: value}))


def test_fault_schedule_acts_in_the_loop_and_is_labelled(graph, tmp_path):
    """A readout bias step inside the loop: the codes are the core device's with the same
    injector, and the faults topic carries the entry, stamped in sensor time."""
    from mems_msgs.msg import FaultEvent
    from mems_sim.hardware.fault_schedule import load_schedule
    from mems_sim.hardware.sensor_faults import SensorFaultInjector
    from mems_sim.nodes.fault_topic import fault_qos

    schedule = tmp_path / "faults.yaml"
    schedule.write_text(
        "faults:\n"
        "  - {kind: bias_step, channel: readout, start_sample: 2500, duration_s: 0.004,"
        " magnitude: 0.002}\n"
    )
    ctx, ex, probe = graph
    dev = AccelerometerNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=4, frame_size=2000, fault_schedule=str(schedule)),
    )
    ex.add_node(dev)
    got = _collect(probe, "/accelerometer", ("adc",))
    events = []
    probe.create_subscription(FaultEvent, "/accelerometer/faults", events.append, fault_qos(1))
    assert spin_until(ex, lambda: dev.pub_adc.get_subscription_count() == 1)
    for _ in range(5):
        dev.step()
    assert spin_until(ex, lambda: len(got["adc"]) == 5 and len(events) == 1)
    ref = accelerometer.ForceRebalanceAccelerometer(seed=4)
    ref.faults = SensorFaultInjector(
        load_schedule(str(schedule), ("readout",), ("V",), ref.fs), ref.fs, 4, (ref.v_noise_std,)
    )
    clean = accelerometer.ForceRebalanceAccelerometer(seed=4).step(10_000).code
    codes = _cat(got["adc"], "codes", 1)[:, 0]
    np.testing.assert_array_equal(codes, ref.step(10_000).code)
    np.testing.assert_array_equal(codes[:2500], clean[:2500])
    assert np.any(codes[2500:] != clean[2500:])
    (e,) = events
    assert (e.kind, e.channel, e.first_faulty_sample, e.faulty_samples, e.permanent) == (
        "bias_step",
        "readout",
        2500,
        4000,
        False,
    )
    assert (e.magnitude, e.magnitude_unit) == (0.002, "V")
    assert (e.start.nanosec, e.end.nanosec, e.header.stamp.nanosec) == (
        2_500_000,
        6_500_000,
        2_500_000,
    )


def test_bad_fault_schedule_is_refused(ros_context, tmp_path):
    bad = tmp_path / "faults.yaml"
    bad.write_text("faults:\n  - {kind: stuck_at, channel: gyro_x, start_s: 0.1}\n")
    emulator_refuses(
        AccelerometerNode, ros_context, "fault_schedule.*'gyro_x'", fault_schedule=str(bad)
    )

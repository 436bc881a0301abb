"""The hybrid EKF node's innovation consistency monitor through real topics: one
diagnostic_msgs/DiagnosticStatus on the device's ``health`` per completed window (OK on
fault-free data, the statistic of the core filter's NIS), the counts on /diagnostics,
windows over a gap and after a stream reset, and the refusal of bad parameter values."""

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from node_helpers import diagnostics_show, one_channel_adc, status_values, wait_matched

from mems_estimation.filters.accelerometer_ekf import (
    FAULT_FREE_NIS_DISPERSION,
    FAULT_FREE_NIS_MEAN,
    HybridEkf,
)
from mems_estimation.filters.consistency_monitor import NisMonitor
from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices import accelerometer
from mems_sim.nodes.accelerometer_node import AccelerometerNode
from mems_sim.params import ParameterError
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.qos import FRAME_QOS, HEALTH_QOS

G = accelerometer.G0


def _health(probe, ns="/accelerometer"):
    got = []
    probe.create_subscription(DiagnosticStatus, f"{ns}/health", got.append, HEALTH_QOS)
    return got


def test_one_health_message_per_window_ok_on_fault_free_data(graph):
    """Device (PI loop, 0.5 g) -> hybrid EKF node: 20 000 samples in windows of 4000 give 5
    OK verdicts whose statistics are the core filter's NIS sums; /diagnostics counts them."""
    ctx, ex, probe = graph
    over = params(seed=6, frame_size=5000, mode="pi_rebalance", accel_amplitude=0.5 * G)
    dev = AccelerometerNode(context=ctx, drive_externally=True, parameter_overrides=over)
    ekf = AccelerometerEkfNode(
        context=ctx, parameter_overrides=params(mode="pi_rebalance", health_window=4000)
    )
    ex.add_node(dev)
    ex.add_node(ekf)
    health = _health(probe)
    estimates, diags = [], []
    probe.create_subscription(StateEstimate, "/accelerometer/estimate", estimates.append, FRAME_QOS)
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    assert wait_matched(ex, dev.pub_adc, ekf.pub, ekf.pub_health)
    for _ in range(4):
        dev.step()
    assert spin_until(ex, lambda: len(estimates) == 4 and len(health) == 5)
    d = accelerometer.ForceRebalanceAccelerometer(
        {"mode": "pi_rebalance", "accel_amplitude": 0.5 * G}, seed=6
    )
    f = d.step(20_000)
    ref = HybridEkf(d.ekf_config).run(f.code * d.lsb, f.v_f)
    monitor = NisMonitor.moment_matched(4000, 1e-3, FAULT_FREE_NIS_MEAN, FAULT_FREE_NIS_DISPERSION)
    windows = monitor.update(ref["innovation"] ** 2 / ref["innovation_variance"])
    assert [m.level for m in health] == [DiagnosticStatus.OK] * 5
    assert {m.name for m in health} == {"accelerometer_ekf"}
    assert {m.message for m in health} == {"OK"}
    for m, w in zip(health, windows, strict=True):
        v = status_values(m)
        assert int(v["first_sample_index"]) == w.first and int(v["samples"]) == 4000
        assert float(v["statistic"]) == w.statistic
        assert float(v["threshold_warn"]) == monitor.thresholds[0]
        assert float(v["threshold_error"]) == monitor.thresholds[1]
        assert float(v["designed_false_alarms_per_hour"]) == pytest.approx(1e-3 * 250 * 3600)
    # the monitor only reports: the estimates are the core filter's
    states = np.concatenate([np.asarray(m.states).reshape(-1, 3) for m in estimates])
    assert states.tobytes() == ref["estimate"].tobytes()
    c = ekf.diag.counters
    assert (c["health_windows"], c["health_warn_windows"], c["health_error_windows"]) == (5, 0, 0)
    assert c["health_verdict"] == "OK"
    assert float(c["health_statistic"]) == windows[-1].statistic
    ekf.diag.publish()

    def counted(s):
        v = status_values(s)
        return (
            v.get("health_windows") == "5"
            and v.get("health_warn_windows") == "0"
            and (v.get("health_error_windows") == "0" and v.get("health_verdict") == "OK")
        )

    assert spin_until(ex, lambda: diagnostics_show(diags, "accelerometer_ekf", counted))


def test_windows_continue_over_a_gap_and_start_again_after_a_stream_reset(graph):
    """Windows of 1500 samples: frames at 0, 1000, 2500 (a gap of 500), 3500, then a jump
    beyond max_gap_samples to 100 000 (a stream reset: a new window, the 1000 samples of
    the open one dropped). The window from monitor sample 1500 starts at stream index 1500."""
    ctx, ex, probe = graph
    ekf = AccelerometerEkfNode(
        context=ctx,
        parameter_overrides=params(mode="pi_rebalance", health_window=1500, max_gap_samples=10_000),
    )
    ex.add_node(ekf)
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "pi_rebalance"}, seed=1)
    pub_a = probe.create_publisher(AdcFrame, "/accelerometer/adc", FRAME_QOS)
    pub_d = probe.create_publisher(SignalFrame, "/accelerometer/drive", FRAME_QOS)
    health = _health(probe)
    assert wait_matched(ex, pub_a, pub_d, ekf.pub_health)
    firsts = (0, 1000, 2500, 3500, 100_000, 101_000, 102_000)
    for first in firsts:
        f = d.step(1000)
        pub_a.publish(
            one_channel_adc(first, f.code, 1e6, bits=16, name="readout", lsb=d.lsb, full_scale=0.5)
        )
        pub_d.publish(
            make_signal_frame(
                np.column_stack([f.v_f, np.full(1000, d.v_b)]),
                first,
                1e6,
                channel_names=("feedback_voltage", "bias_voltage"),
                channel_units=("V", "V"),
            )
        )
    assert spin_until(ex, lambda: ekf.frames_done == len(firsts) and len(health) == 4)
    ex.spin_once(timeout_sec=0.1)
    assert [int(status_values(m)["first_sample_index"]) for m in health] == [
        0,
        1500,
        100_000,
        101_500,
    ]
    assert {status_values(m)["samples"] for m in health} == {"1500"}
    assert ekf.diag.counters["stream_resets"] == 1 and ekf.diag.counters["gaps"] == 1


@pytest.mark.parametrize(
    "name,value",
    [
        ("health_window", 0),
        ("health_window", 2.5),
        ("health_false_alarm", 0.0),
        ("health_false_alarm", 0.5),
        ("health_false_alarm", 0.9),
        ("health_false_alarm", -1e-3),
    ],
)
def test_bad_health_parameters_are_refused_in_one_line(ros_context, name, value):
    with pytest.raises(ParameterError, match=name) as exc:
        AccelerometerEkfNode(context=ros_context, parameter_overrides=params(**{name: value}))
    assert "\n" not in str(exc.value)

"""Shared-electrode scanner (AMDM) emulator node and EKF/UKF estimator node through real topics."""

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from node_helpers import (
    diagnostics_show,
    emulator_refuses,
    one_channel_adc,
    status_values,
    step_frames,
    wait_matched,
)

from mems_estimation.nodes.scanner_amdm_estimator_node import ScannerAmdmEstimatorNode
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices.scanner_amdm import AmdmScannerDevice, chain_delay, resolve_amdm
from mems_sim.nodes.scanner_amdm_node import ScannerAmdmNode
from mems_sim.params import ParameterError
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.qos import FRAME_QOS

RUN = dict(
    drive_voltage_max=150.0,
    sweep_start_hz=31.32e3,
    sweep_end_hz=31.27e3,
    sweep_time_s=0.03,
    initial_angle=0.06,
)


def _collect(probe, got, ns="/scanner_amdm"):
    for name, typ in (
        ("adc", AdcFrame),
        ("drive", SignalFrame),
        ("truth", SignalFrame),
        ("ekf/estimate", StateEstimate),
        ("ukf/estimate", StateEstimate),
        ("ekf/phase_amplitude", StateEstimate),
        ("ukf/phase_amplitude", StateEstimate),
    ):
        got[name] = []
        probe.create_subscription(typ, f"{ns}/{name}", got[name].append, FRAME_QOS)


def test_emulator_and_estimators_through_topics(graph):
    ctx, ex, probe = graph
    dev = ScannerAmdmNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=3, frame_size=1000, **RUN),
    )
    delay = chain_delay(resolve_amdm(RUN))
    est = ScannerAmdmEstimatorNode(context=ctx, parameter_overrides=params(chain_delay_s=delay))
    ex.add_node(dev)
    ex.add_node(est)
    got = {}
    _collect(probe, got)
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() == 2
            and est.pub_est["ukf"].get_subscription_count() == 1
            and est.pub_evt["ukf"].get_subscription_count() == 1
        ),
    )
    n_frames = 12
    step_frames(ex, dev, n_frames)
    assert spin_until(
        ex,
        lambda: (
            len(got["ukf/estimate"]) == n_frames
            and len(got["ekf/estimate"]) == n_frames
            and len(got["truth"]) == n_frames
        ),
    )
    # emulator output equals the core
    ref = AmdmScannerDevice(RUN, seed=3).step(1000 * n_frames)
    codes = np.concatenate([np.asarray(m.codes) for m in got["adc"]])
    np.testing.assert_array_equal(codes, ref.codes)
    assert list(got["adc"][0].channel_names) == ["y_cap"] and got["adc"][0].bits == 16
    assert list(got["drive"][0].channel_names) == ["v_drive", "f_drive"]
    # estimates: finite, tracked, per-sample
    m = got["ukf/estimate"][-1]
    assert list(m.state_names) == ["theta", "omega"] and m.num_samples == 1000
    assert [x.first_sample_index for x in got["ekf/estimate"]] == list(range(0, 12000, 1000))
    for k in ("ekf", "ukf"):
        assert est.filters[k].tracking and est.filters[k].pd_failures == 0
        ev = got[f"{k}/phase_amplitude"]
        assert ev and list(ev[0].state_names) == ["t_peak", "phase", "amplitude"]
        st = np.concatenate([np.asarray(e.states).reshape(-1, 3) for e in ev])
        assert st.shape[0] > 100  # ~31 extrema per ms
        assert np.all((st[:, 1] >= 0) & (st[:, 1] < np.pi)) and np.all(st[:, 2] > 0.03)
    th = np.concatenate([np.asarray(x.states).reshape(-1, 2)[:, 0] for x in got["ukf/estimate"]])
    truth = np.concatenate([np.asarray(x.data).reshape(-1, 2)[:, 0] for x in got["truth"]])
    assert np.max(np.abs(np.abs(th[-2000:]).max() - np.abs(truth[-2000:]).max())) < 0.01


def _adc(first, y, fs=1e6, name="y_cap"):
    lsb = 20.0 / 65536
    codes = np.round(np.asarray(y) / lsb).astype(int)
    return one_channel_adc(first, codes, fs, bits=16, name=name, lsb=lsb, full_scale=10.0)


def _drive(first, v, fs=1e6):
    return make_signal_frame(
        np.column_stack([v, np.full(len(v), 25e3)]),
        first,
        fs,
        channel_names=["v_drive", "f_drive"],
        channel_units=["V", "Hz"],
    )


def test_estimator_rejects_bad_frames_and_reports_low_signal(graph):
    ctx, ex, probe = graph
    est = ScannerAmdmEstimatorNode(context=ctx)
    ex.add_node(est)
    pub_a = probe.create_publisher(AdcFrame, "/scanner_amdm/adc", FRAME_QOS)
    pub_d = probe.create_publisher(SignalFrame, "/scanner_amdm/drive", FRAME_QOS)
    out, diags = [], []
    probe.create_subscription(StateEstimate, "/scanner_amdm/ukf/estimate", out.append, FRAME_QOS)
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    assert wait_matched(ex, pub_a, pub_d)
    rng = np.random.default_rng(0)
    y0 = -0.3574e12 * (5.71e-12 + 9.79e-12) + 6.3945  # mirror at rest
    t = np.arange(2000) / 1e6
    v = 75 * (1 - np.cos(2 * np.pi * 25e3 * t))  # far from 2 f_n = 31.1 kHz
    for i in (0, 1000):
        pub_a.publish(_adc(i, y0 + rng.standard_normal(1000) * 0.01386))
        pub_d.publish(_drive(i, v[i : i + 1000]))
    pub_a.publish(_adc(2000, np.full(1000, y0), fs=2e6))  # another sample rate
    pub_a.publish(_adc(3000, np.full(1000, y0), name="other"))  # wrong channel
    bad = _drive(4000, np.zeros(1000))
    bad.data[5] = float("nan")  # non-finite drive
    pub_d.publish(bad)
    assert spin_until(ex, lambda: len(out) == 2 and est.diag.counters.get("rejected_frames") == 3)
    assert all(np.all(np.asarray(m.states) == 0.0) for m in out)
    assert not est.filters["ukf"].tracking and est.filters["ukf"].pd_failures == 0
    assert any("low signal" in w for w in est.diag.warnings)
    est.diag.publish()
    assert spin_until(
        ex,
        lambda: diagnostics_show(
            diags,
            "scanner_amdm_estimator",
            lambda s: s.level == DiagnosticStatus.WARN and "low_signal_frames" in status_values(s),
        ),
    )


def test_invalid_parameters_refused(ros_context):
    emulator_refuses(ScannerAmdmNode, ros_context, "carrier_freq_hz", carrier_freq_hz=5e6)
    with pytest.raises(ParameterError, match="inertia"):
        ScannerAmdmEstimatorNode(context=ros_context, parameter_overrides=params(inertia=-1.0))

"""The stage EKF's innovation consistency monitor (Chen 2018 eqs. 48-53; windowed NIS test,
Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4.2): the NIS nu^T S^-1 nu of the core filter
against the textbook S = H P^- H^T + R, the estimates the same with and without it, the
false alarms of the moment-matched monitor (Satterthwaite 1946) on an evaluation seed, and
through real topics one diagnostic_msgs/DiagnosticStatus on the device's ``health`` per
window of measured samples (OK on fault-free data, the statistics of the core filter's NIS),
an ERROR on a readout noise burst, and the refusal of bad parameter values."""

from pathlib import Path

import numpy as np
import pytest
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from node_helpers import diagnostics_show, status_values, wait_matched

from mems_estimation.filters.consistency_monitor import NisMonitor, nis_moments, window_sums
from mems_estimation.filters.stage_ekf import (
    FAULT_FREE_NIS_DISPERSION,
    FAULT_FREE_NIS_MEAN,
    HEALTH_WINDOW,
    FeedthroughCanceller,
    StageEkf,
    load_model,
    output_h,
)
from mems_estimation.nodes.stage_ekf_node import StageEkfNode
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices.stage import DriveSchedule, MicroStage
from mems_sim.nodes.stage_node import StageNode
from mems_sim.params import ParameterError
from mems_sim.ros.frames import adc_physical, signal_data
from mems_sim.ros.qos import FRAME_QOS, HEALTH_QOS

REPO = Path(__file__).resolve().parents[3]
#: the reference identified model (the one the moments were measured with)
STAGE_YAML = str(REPO / "bags" / "stage_params.yaml")


def _cancelled(seed: int, trials: int, periods: int = 200):
    """Feedthrough-cancelled channels [V] (n, 4) and drive u [V] of the default stage on
    the calibration sweep 1.0-1.3 V at 1700 Hz, ``trials`` trials of ``periods`` periods."""
    st = MicroStage({}, DriveSchedule.amplitude_sweep(n_trials=trials, periods=periods), seed=seed)
    f = st.step(st.total_samples())
    return FeedthroughCanceller(4, st.fs).step(f.codes * st.lsb, f.v_bias, f.f_drive), f.u


def test_nis_is_the_textbook_one_and_changes_no_estimate():
    """Sample by sample from the carried state: nu^T (H P^- H^T + R)^-1 nu with the
    matrices of eqs. (48)-(50) equals the kernel's Woodbury form to 1e-9; NaN where no
    update; the estimates and variances with the NIS are those without it bit for bit."""
    m = load_model(STAGE_YAML)
    yc, u = _cancelled(4, 1, 20)
    plain = StageEkf(m).step(yc, u)
    x, v, nis = StageEkf(m).step(yc, u, nis=True)
    assert x.tobytes() == plain[0].tobytes() and v.tobytes() == plain[1].tobytes()
    measured = np.isfinite(yc).all(axis=1)
    assert np.array_equal(np.isfinite(nis), measured) and measured.mean() > 0.4
    ekf = StageEkf(m)
    ekf.step(yc[:3000], u[:3000])  # past the start-up transient
    h = np.empty(4)
    b = ekf.B.reshape(2)
    checked = 0
    for k in range(3000, 4000):
        xp = ekf.A @ ekf.x + b * ekf.uprev[0]
        pp = ekf.A @ ekf.P @ ekf.A.T + np.outer(b, b) * m.Q
        _, _, got = ekf.step(yc[k : k + 1], u[k : k + 1], nis=True)
        if not measured[k]:
            assert np.isnan(got[0])
            continue
        output_h(xp[0], m.eta, m.gap, m.limits, ekf.eps, h)
        hm = np.column_stack([np.zeros(4), h])
        nu = yc[k] - hm @ xp
        ref = nu @ np.linalg.solve(hm @ pp @ hm.T + m.R, nu)
        assert got[0] == pytest.approx(ref, rel=1e-9)
        checked += 1
    assert checked > 300


def test_false_alarms_of_the_moment_matched_monitor_on_an_evaluation_seed():
    """Moments measured (nis_moments, 4 degrees of freedom) on noise seeds 1 and 2 over
    windows of 500 measured samples (short, for enough windows; the node's window of 31250
    would need 3000 windows, 1.9e8 samples, for 30 designed alarms), evaluated on seed 3:
    3372 windows at alpha = 1e-2 (33.7 designed), measured alarms within [0.5, 2]x designed.
    The mean NIS per degree of freedom is the node's FAULT_FREE_NIS_MEAN (it does not depend
    on the window) within 0.5 %."""
    w, alpha = 500, 1e-2
    train = []
    for seed in (1, 2):
        yc, u = _cancelled(seed, 20)
        nis = StageEkf(load_model(STAGE_YAML)).step(yc, u, nis=True)[2]
        nis = nis[np.isfinite(nis)]
        train.append(nis[: nis.size // w * w])
    mean, disp = nis_moments(np.concatenate(train), w, dof=4)
    assert mean == pytest.approx(FAULT_FREE_NIS_MEAN, rel=5e-3)
    assert 1.3 < disp < 2.0  # not chi-square: 1.6 measured
    yc, u = _cancelled(3, 46)
    nis = StageEkf(load_model(STAGE_YAML)).step(yc, u, nis=True)[2]
    sums = window_sums(nis[np.isfinite(nis)], w)
    monitor = NisMonitor.moment_matched(w, alpha, mean, disp, dof=4)
    designed = alpha * sums.size
    assert designed >= 30
    alarms = int(np.count_nonzero(sums > monitor.thresholds[0]))
    assert 0.5 * designed <= alarms <= 2.0 * designed, (alarms, designed)
    # the plain chi-square of Kalman theory would alarm on most windows
    assert np.count_nonzero(sums > NisMonitor(w, alpha, 4).thresholds[0]) > 0.3 * sums.size


def _health(probe):
    got = []
    probe.create_subscription(DiagnosticStatus, "/stage/health", got.append, HEALTH_QOS)
    return got


def _run(graph, fault_schedule: str = ""):
    """Stage (4 trials of 200 periods, 294 118 samples; seed 6) -> stage EKF node with the
    default window: the health messages, estimates, adc and drive frames, both nodes."""
    ctx, ex, probe = graph
    over = dict(seed=6, n_trials=4, periods_per_trial=200, frame_size=20000, gyro_enabled=False)
    if fault_schedule:
        over["fault_schedule"] = fault_schedule
    dev = StageNode(context=ctx, drive_externally=True, parameter_overrides=params(**over))
    ekf = StageEkfNode(context=ctx, parameter_overrides=params(params_yaml=STAGE_YAML))
    ex.add_node(dev)
    ex.add_node(ekf)
    health = _health(probe)
    est, adc, drv = [], [], []
    probe.create_subscription(StateEstimate, "/stage/estimate", est.append, FRAME_QOS)
    probe.create_subscription(AdcFrame, "/stage/adc", adc.append, FRAME_QOS)
    probe.create_subscription(SignalFrame, "/stage/drive", drv.append, FRAME_QOS)
    assert spin_until(ex, lambda: dev.pub_adc.get_subscription_count() >= 2)
    assert wait_matched(ex, ekf.pub, ekf.pub_health)
    frames = 0
    while dev.step():
        frames += 1
        assert spin_until(ex, lambda: ekf.frames_done >= frames, timeout=30)
    assert spin_until(ex, lambda: len(est) == len(adc) == len(drv) == frames, timeout=30)
    ex.spin_once(timeout_sec=0.1)
    return health, est, adc, drv, ekf, ex


def test_one_health_message_per_window_ok_on_fault_free_data(graph):
    """146 kilo-samples with a measurement in windows of 31250: 4 OK verdicts whose
    statistics, thresholds and first stream sample indices are those of a NisMonitor on the
    core filter's NIS of the same frames; the estimates are the core filter's (without the
    NIS) bit for bit; /diagnostics counts the windows."""
    health, est, adc, drv, ekf, ex = _run(graph)
    y = np.concatenate([adc_physical(m) for m in adc])
    d = np.concatenate([signal_data(m) for m in drv])
    yc = FeedthroughCanceller(4, 625e3).step(y, d[:, 1], d[:, 2])
    m = load_model(STAGE_YAML)
    xr, vr = StageEkf(m).step(yc, d[:, 0])
    _, _, nis = StageEkf(m).step(yc, d[:, 0], nis=True)
    measured = np.flatnonzero(np.isfinite(yc).all(axis=1))
    monitor = NisMonitor.moment_matched(
        HEALTH_WINDOW, 1e-3, FAULT_FREE_NIS_MEAN, FAULT_FREE_NIS_DISPERSION, dof=4
    )
    windows = monitor.update(nis[measured])
    assert len(windows) == 4
    assert spin_until(ex, lambda: len(health) == 4)
    assert [s.level for s in health] == [DiagnosticStatus.OK] * 4
    assert {s.name for s in health} == {"stage_ekf"} and {s.message for s in health} == {"OK"}
    for s, w in zip(health, windows, strict=True):
        v = status_values(s)
        assert int(v["first_sample_index"]) == measured[w.first]
        assert int(v["samples"]) == HEALTH_WINDOW
        assert float(v["statistic"]) == w.statistic
        assert float(v["threshold_warn"]) == monitor.thresholds[0]
        assert float(v["threshold_error"]) == monitor.thresholds[1]
        # the measured samples' rate fs / 2: 1e-3 * 10 windows/s
        assert float(v["designed_false_alarms_per_hour"]) == pytest.approx(36.0)
    x = np.concatenate([np.asarray(s.states).reshape(-1, 2) for s in est])
    var = np.concatenate([np.asarray(s.variances).reshape(-1, 2) for s in est])
    assert x.tobytes() == xr.tobytes() and var.tobytes() == vr.tobytes()
    c = ekf.diag.counters
    assert (c["health_windows"], c["health_warn_windows"], c["health_error_windows"]) == (4, 0, 0)
    assert c["health_verdict"] == "OK" and float(c["health_statistic"]) == windows[-1].statistic


def test_a_readout_noise_burst_raises_error(graph, tmp_path):
    """A noise burst x3 on channel 1A from 0.2 s for 0.1 s (a readout bias step is no
    fault for this filter: the feedthrough cancellation, bias-on minus bias-off samples of
    the same drive, removes it but on the bias-on period it starts or ends in): the window
    holding it is ERROR, those before it OK; counted on /diagnostics."""
    schedule = tmp_path / "faults.yaml"
    schedule.write_text(
        "faults:\n"
        "  - {kind: noise_burst, channel: 1A, start_s: 0.2, duration_s: 0.1, magnitude: 3.0}\n"
    )
    health, _, _, _, ekf, ex = _run(graph, str(schedule))
    assert spin_until(ex, lambda: len(health) == 4)
    start, end = 125_000, 187_500
    for s in health:
        first = int(status_values(s)["first_sample_index"])
        if first + 2 * HEALTH_WINDOW < start:
            assert s.level == DiagnosticStatus.OK, first
    faulty = [s for s in health if s.level == DiagnosticStatus.ERROR]
    assert faulty and all(
        start - 2 * HEALTH_WINDOW < int(status_values(s)["first_sample_index"]) < end
        for s in faulty
    )
    assert ekf.diag.counters["health_error_windows"] == len(faulty)
    diags = []
    probe = graph[2]
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    ekf.diag.publish()
    errors = str(len(faulty))
    assert spin_until(
        ex,
        lambda: diagnostics_show(
            diags, "stage_ekf", lambda s: status_values(s).get("health_error_windows") == errors
        ),
    )


@pytest.mark.parametrize(
    "name,value",
    [("health_window", 0), ("health_false_alarm", 0.5), ("health_nis_dispersion", 0.0)],
)
def test_bad_health_parameters_are_refused_in_one_line(ros_context, name, value):
    with pytest.raises(ParameterError, match=name) as exc:
        StageEkfNode(
            context=ros_context, parameter_overrides=params(params_yaml=STAGE_YAML, **{name: value})
        )
    assert "\n" not in str(exc.value)

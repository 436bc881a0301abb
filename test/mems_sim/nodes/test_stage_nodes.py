"""Micro-stage, stage EKF and gyro calibration nodes through real topics (Chen 2018 ch. 3)."""

import numpy as np
import pytest
from conftest import params, spin_until
from node_helpers import emulator_refuses

from mems_estimation.filters.stage_ekf import FeedthroughCanceller, StageEkf, load_model, save_model
from mems_estimation.identification.stage_gyro_calibration import Plan, identify_stage
from mems_estimation.nodes.stage_ekf_node import StageEkfNode
from mems_estimation.nodes.stage_gyro_calibration_node import StageGyroCalibrationNode
from mems_msgs.msg import AdcFrame, CalibrationResult, SignalFrame, StateEstimate
from mems_sim.nodes.stage_node import StageNode
from mems_sim.params import ParameterError
from mems_sim.ros.frames import adc_physical, make_signal_frame, signal_data
from mems_sim.ros.qos import FRAME_QOS, RESULT_QOS


@pytest.fixture(scope="module")
def yaml_path(tmp_path_factory):
    model, _ = identify_stage(seed=6, plan=Plan(2.0, 200, 3, 100, 30, 3, 100))
    p = tmp_path_factory.mktemp("stage") / "stage.yaml"
    save_model(model, str(p))
    return str(p)


def _subscribe(probe) -> tuple[list, list, list]:
    """Lists filled with the stage's ``adc`` and ``drive`` frames and the EKF's estimates."""
    adc, drv, est = [], [], []
    probe.create_subscription(AdcFrame, "/stage/adc", adc.append, FRAME_QOS)
    probe.create_subscription(SignalFrame, "/stage/drive", drv.append, FRAME_QOS)
    probe.create_subscription(StateEstimate, "/stage/estimate", est.append, FRAME_QOS)
    return adc, drv, est


def _step_through(ex, dev, ekf, each=None) -> int:
    """Step the stage to its end, spinning after each frame until the EKF has taken it (and
    calling ``each()`` then); the number of frames."""
    frames = 0
    while dev.step():
        frames += 1
        spin_until(ex, lambda: ekf.frames_done >= frames, timeout=30)
        if each is not None:
            each()
    return frames


def _bad_drive_frame(data: list[float]) -> SignalFrame:
    """A two-sample drive frame without the sweep's phase/trial channels."""
    return make_signal_frame(
        np.reshape(data, (2, 3)),
        10**9,
        625e3,
        channel_names=["u", "v_bias", "f_drive"],
        channel_units=["V", "V", "Hz"],
    )


def test_graph_estimate_and_calibration(graph, yaml_path):
    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=3, n_trials=3, periods_per_trial=120, frame_size=20000),
    )
    ekf = StageEkfNode(context=ctx, parameter_overrides=params(params_yaml=yaml_path))
    cal = StageGyroCalibrationNode(context=ctx, parameter_overrides=params(n_trials=3))
    for n in (dev, ekf, cal):
        ex.add_node(n)
    adc, drv, est = _subscribe(probe)
    res = []
    probe.create_subscription(CalibrationResult, "/stage/gyro_scale_factor", res.append, RESULT_QOS)
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() >= 1
            and dev.pub_gyro.get_subscription_count() >= 1
            and ekf.pub.get_subscription_count() >= 2
        ),
    )
    frames = _step_through(ex, dev, ekf)
    assert spin_until(
        ex, lambda: len(est) == frames and len(adc) == frames and len(drv) == frames, timeout=30
    )
    assert spin_until(ex, lambda: cal.estimates_received == frames, timeout=30)
    cal.close()
    assert spin_until(ex, lambda: len(res) >= 1, timeout=10)
    r = res[-1]
    assert list(r.names) == ["scale_factor", "bias"] and r.num_points == 3
    assert abs(r.values[0] - 1.0) < 0.02 and r.standard_errors[0] > 0
    # the node's estimate equals the core EKF on the same frames (identified parameters)
    x = np.concatenate([np.asarray(m.states).reshape(-1, 2) for m in est])
    assert [m.first_sample_index for m in est] == list(range(0, x.shape[0], 20000))
    assert np.all(np.isfinite(x))
    y = np.concatenate([adc_physical(m) for m in adc])
    d = np.concatenate([signal_data(m) for m in drv])
    yc = FeedthroughCanceller(4, 625e3).step(y, d[:, 1], d[:, 2])
    xr, _ = StageEkf(load_model(yaml_path)).step(yc, d[:, 0])
    np.testing.assert_array_equal(x, xr)
    assert ekf.diag.counters.get("rejected_frames", 0) == 0


def test_insitu_mode_equals_core(graph, yaml_path):
    """insitu: the node keeps the sweep, and once the stage's end-of-stream record announced
    its end corrects wn, b_c from the sweep's channels (Chen 2018 eqs. 44-47) and publishes
    the EKF on the corrected model (alpha = 1, beta = 0) frame by frame, equal to the core on
    the same frames, with the input frames' indices and stamps."""
    from mems_estimation.identification.stage_insitu import insitu_correct

    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4, gyro_seed=9, n_trials=3, periods_per_trial=120, frame_size=20000
        ),
    )
    ekf = StageEkfNode(context=ctx, parameter_overrides=params(params_yaml=yaml_path, insitu=True))
    for n in (dev, ekf):
        ex.add_node(n)
    adc, drv, est = _subscribe(probe)
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() >= 2
            and dev.pub_end_of_stream.get_subscription_count() >= 1
            and ekf.pub.get_subscription_count() >= 1
        ),
    )

    def processed_once_complete():
        if not dev.finished:
            assert not est  # the sweep is processed only once complete

    frames = _step_through(ex, dev, ekf, processed_once_complete)
    assert spin_until(ex, lambda: len(est) == frames and len(adc) == frames, timeout=30)
    assert [m.first_sample_index for m in est] == [m.first_sample_index for m in adc]
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in est] == [
        (m.header.stamp.sec, m.header.stamp.nanosec) for m in adc
    ]
    x = np.concatenate([np.asarray(m.states).reshape(-1, 2) for m in est])
    y = np.concatenate([adc_physical(m) for m in adc])
    d = np.concatenate([signal_data(m) for m in drv])
    yc = FeedthroughCanceller(4, 625e3).step(y, d[:, 1], d[:, 2])
    m, _ = insitu_correct(load_model(yaml_path), yc, d[:, 0], d[:, 3], d[:, 4].astype(int), d[:, 2])
    xr, _ = StageEkf(m).step(yc, d[:, 0], corrected=False)
    np.testing.assert_array_equal(x, xr)
    c = ekf.diag.counters
    assert c["insitu_sweeps"] == 1 and c.get("rejected_frames", 0) == 0
    assert c["insitu_wn_ratio"] == m.extra["insitu_wn_ratio"] != 1.0
    assert c["insitu_b_c_ratio"] == m.extra["insitu_b_c_ratio"]
    # a drive frame without the sweep's phase/trial channels is rejected and counted
    bad_pub = probe.create_publisher(SignalFrame, "/stage/drive", FRAME_QOS)
    assert spin_until(ex, lambda: bad_pub.get_subscription_count() >= 1)
    bad_pub.publish(_bad_drive_frame([0.0, 1.0, 1700.0, 0.0, 1.0, 1700.0]))
    assert spin_until(ex, lambda: ekf.diag.counters.get("rejected_frames", 0) == 1)


def _insitu_chain(graph, yaml_path, ns: str, origin: str) -> tuple:
    """Stage (``stamp_origin`` ``origin``), in-situ EKF and calibration node in ``ns``, the
    sweep stepped through; (calibration node, its result after close)."""
    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        namespace=ns,
        drive_externally=True,
        parameter_overrides=params(
            seed=4,
            gyro_seed=9,
            n_trials=3,
            periods_per_trial=120,
            frame_size=20000,
            stamp_origin=origin,
        ),
    )
    ekf = StageEkfNode(
        context=ctx,
        namespace=ns,
        parameter_overrides=params(device_namespace=ns, params_yaml=yaml_path, insitu=True),
    )
    cal = StageGyroCalibrationNode(
        context=ctx, namespace=ns, parameter_overrides=params(device_namespace=ns, n_trials=3)
    )
    for n in (dev, ekf, cal):
        ex.add_node(n)
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() >= 1
            and dev.pub_gyro.get_subscription_count() >= 1
            and dev.pub_end_of_stream.get_subscription_count() >= 1
            and ekf.pub.get_subscription_count() >= 1
        ),
    )
    frames = _step_through(ex, dev, ekf)
    assert spin_until(
        ex,
        lambda: cal.estimates_received == frames and cal.gyro_frames_received == frames,
        timeout=30,
    )
    cal.close()
    for n in (dev, ekf, cal):
        ex.remove_node(n)
    return dev, cal


def test_calibration_with_stamps_from_the_wall_clock(graph, yaml_path):
    """The in-situ EKF publishes every estimate after every gyro frame: the calibration node
    takes the stage's time origin from the drive stream (live) and holds gyro frames that
    arrive before any stage frame, so stamps from the wall-clock epoch (real-time runs) place
    the gyro exactly as stamps from 0: the same pairs and eq. (27) result, bit for bit."""
    dz, zero = _insitu_chain(graph, yaml_path, "/z", "zero")
    dw, wall = _insitu_chain(graph, yaml_path, "/w", "wall")
    assert dz.t0_ns == 0 and dw.t0_ns > 10**18  # ns since the epoch (2001 on)
    assert wall.t0_ns == dw.t0_ns
    assert zero.results and wall.results
    assert wall.results[-1] == zero.results[-1]
    assert zero.results[-1]["n"] == 3 and abs(zero.results[-1]["scale_factor"] - 1) < 0.02
    assert wall.cal.pairs == zero.cal.pairs


def test_refusals(ros_context, yaml_path, tmp_path):
    with pytest.raises(ParameterError, match="params_yaml"):
        StageEkfNode(
            context=ros_context, parameter_overrides=params(params_yaml=str(tmp_path / "none.yaml"))
        )
    with pytest.raises(ParameterError, match="channels"):
        StageEkfNode(
            context=ros_context, parameter_overrides=params(params_yaml=yaml_path, channels="1A,3C")
        )
    emulator_refuses(StageNode, ros_context, "safe_tilt_rad", amp_hi_v=4.0)
    emulator_refuses(StageNode, ros_context, "sample_rate_hz", sample_rate_hz=0.0)
    bad = tmp_path / "faults.yaml"
    bad.write_text("faults:\n  - {kind: stuck_at, channel: 3C, start_s: 0.1}\n")
    emulator_refuses(StageNode, ros_context, "fault_schedule.*'3C'", fault_schedule=str(bad))


def test_nonfinite_frames_rejected_and_counted(graph, yaml_path):
    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=1, n_trials=1, periods_per_trial=20, frame_size=2000, gyro_enabled=False
        ),
    )
    ekf = StageEkfNode(context=ctx, parameter_overrides=params(params_yaml=yaml_path))
    ex.add_node(dev)
    ex.add_node(ekf)
    bad_pub = probe.create_publisher(SignalFrame, "/stage/drive", FRAME_QOS)
    assert spin_until(
        ex,
        lambda: dev.pub_adc.get_subscription_count() >= 1 and bad_pub.get_subscription_count() >= 1,
    )
    bad_pub.publish(_bad_drive_frame([0.0, float("nan"), 0.0, 0.0, 1.0, 1700.0]))
    assert spin_until(ex, lambda: ekf.diag.counters.get("rejected_frames", 0) == 1)
    for _ in range(3):
        dev.step()
    assert spin_until(ex, lambda: ekf.frames_done == 3)
    assert ekf.diag.counters["rejected_frames"] == 1


def test_imu_messages_match_gyro_frames(graph):
    """publish_imu: one sensor_msgs/Imu per gyro sample, same rate value as the gyro ADC frame
    and stamps in integer ns of the stage time base (reused message, rewritten fields)."""
    from sensor_msgs.msg import Imu

    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=2, n_trials=1, periods_per_trial=20, frame_size=5000, publish_imu=True
        ),
    )
    ex.add_node(dev)
    imu, gy = [], []
    probe.create_subscription(Imu, "/stage/gyro/imu", imu.append, FRAME_QOS)
    probe.create_subscription(AdcFrame, "/stage/gyro/adc", gy.append, FRAME_QOS)
    assert spin_until(
        ex,
        lambda: (
            dev.pub_imu.get_subscription_count() >= 1 and dev.pub_gyro.get_subscription_count() >= 1
        ),
    )
    for _ in range(2):
        dev.step()
    n = sum(m.num_samples for m in gy) if gy else -1
    assert spin_until(
        ex, lambda: len(gy) == 2 and len(imu) == sum(m.num_samples for m in gy), timeout=20
    ), (len(imu), n)
    v = np.concatenate([adc_physical(m)[:, 0] for m in gy])
    np.testing.assert_array_equal([m.angular_velocity.y for m in imu], v)
    ns = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imu])
    assert np.all(np.diff(ns) > 0)
    assert np.allclose(np.diff(ns), 1e9 / dev.gyro.rate, atol=1.0)
    assert all(
        m.angular_velocity_covariance[0] > 0 and m.orientation_covariance[0] == -1.0 for m in imu
    )

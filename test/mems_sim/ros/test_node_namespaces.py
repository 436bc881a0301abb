"""Relative topic names: an estimator node started in a device's namespace (and given no
``device_namespace``) finds that device, and only that one."""

import importlib

import numpy as np
import pytest
from conftest import params, spin_until

from mems_estimation.nodes.accelerometer_ekf_node import AccelerometerEkfNode
from mems_msgs.msg import SignalFrame, StateEstimate
from mems_sim.devices import accelerometer
from mems_sim.nodes.accelerometer_node import AccelerometerNode
from mems_sim.ros.qos import FRAME_QOS

G = accelerometer.G0
AMPLITUDES = {"a": 1.0 * G, "b": 0.2 * G}  # input acceleration of the device in /a, /b
FRAMES, FRAME = 4, 5000


def _cat(frames, field, width):
    frames = sorted(frames, key=lambda m: m.first_sample_index)
    return np.concatenate([np.asarray(getattr(m, field)).reshape(-1, width) for m in frames])


def test_estimators_in_device_namespaces_follow_their_own_device(graph):
    ctx, ex, probe = graph
    devices, ekfs, got = {}, {}, {}
    for k, (ns, amp) in enumerate(AMPLITUDES.items()):
        devices[ns] = AccelerometerNode(
            context=ctx,
            namespace=ns,
            drive_externally=True,
            parameter_overrides=params(
                seed=10 + k, frame_size=FRAME, mode="pi_rebalance", accel_amplitude=amp
            ),
        )
        # only the namespace: no device_namespace parameter
        ekfs[ns] = AccelerometerEkfNode(
            context=ctx, namespace=ns, parameter_overrides=params(mode="pi_rebalance")
        )
        assert ekfs[ns].p["device_namespace"] == ""
        assert ekfs[ns].pub.topic_name == f"/{ns}/estimate"
        got[ns] = {"estimate": [], "truth": []}
        probe.create_subscription(
            StateEstimate, f"/{ns}/estimate", got[ns]["estimate"].append, FRAME_QOS
        )
        probe.create_subscription(SignalFrame, f"/{ns}/truth", got[ns]["truth"].append, FRAME_QOS)
        ex.add_node(devices[ns])
        ex.add_node(ekfs[ns])
    # each device's adc and drive have exactly one subscriber: the estimator of its namespace
    assert spin_until(
        ex,
        lambda: all(
            d.pub_adc.get_subscription_count() == 1
            and d.pub_drive.get_subscription_count() == 1
            and d.pub_truth.get_subscription_count() == 1
            and ekfs[ns].pub.get_subscription_count() == 1
            for ns, d in devices.items()
        ),
    )
    for _ in range(FRAMES):
        for d in devices.values():
            d.step()
    assert spin_until(
        ex,
        lambda: all(len(v) == FRAMES for g in got.values() for v in g.values()),
        timeout=60.0,
    )
    assert all(e.frames_done == FRAMES for e in ekfs.values())
    accel = {ns: _cat(g["estimate"], "states", 3)[:, 2] for ns, g in got.items()}
    truth = {ns: _cat(g["truth"], "data", 5)[:, 0] for ns, g in got.items()}
    settled = slice(FRAMES * FRAME // 2, None)  # after the filter's transient
    for ns, other in (("a", "b"), ("b", "a")):
        amp = AMPLITUDES[ns]
        # the device's own input: a quarter period of a 10 Hz sinusoid of amplitude amp
        assert 0.9 * amp < np.max(truth[ns]) <= amp
        own = np.sqrt(np.mean((accel[ns][settled] - truth[ns][settled]) ** 2))
        cross = np.sqrt(np.mean((accel[ns][settled] - truth[other][settled]) ** 2))
        assert own < 0.03 * G, (ns, own)  # ~0.011 g for either amplitude
        assert cross > 10 * own, (ns, own, cross)


@pytest.mark.parametrize(
    "module, cls, namespace, topics",
    [
        ("accelerometer_ekf_node", "AccelerometerEkfNode", "/accelerometer", ("adc", "drive")),
        ("scanner_threshold_ekf_node", "ScannerThresholdEkfNode", "/scanner", ("adc", "drive")),
        ("scanner_amdm_estimator_node", "ScannerAmdmEstimatorNode", "/scanner_amdm", ("adc",)),
        ("resonator_observer_node", "ResonatorObserverNode", "/resonator", ("adc", "drive")),
        (
            "stage_gyro_calibration_node",
            "StageGyroCalibrationNode",
            "/stage",
            ("estimate", "gyro/adc"),
        ),
        ("imu_noise_identifier_node", "ImuNoiseIdentifierNode", "/imu", ("adc",)),
    ],
)
def test_estimator_defaults_to_its_device_namespace(ros_context, module, cls, namespace, topics):
    """Started without a namespace the node is in its device's usual one and reads it there;
    a non-empty device_namespace still overrides."""
    node_class = getattr(importlib.import_module(f"mems_estimation.nodes.{module}"), cls)
    node = node_class(context=ros_context)
    try:
        assert node.get_namespace() == namespace
        subscribed = {s.topic_name for s in node.subscriptions}
        assert {f"{namespace}/{t}" for t in topics} <= subscribed
    finally:
        node.destroy_node()
    if cls == "ImuNoiseIdentifierNode":
        return
    node = node_class(context=ros_context, parameter_overrides=params(device_namespace="/x/"))
    try:
        subscribed = {s.topic_name for s in node.subscriptions}
        assert {f"/x/{t}" for t in topics} <= subscribed
    finally:
        node.destroy_node()

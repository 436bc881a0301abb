"""The stage node with its real-part terms on (ADC static errors, the gyro's DLPF): its
frames through real topics equal the ROS-free core's with the same parameters and seed."""

import numpy as np
from conftest import params, spin_until
from node_helpers import emulator_refuses

from mems_msgs.msg import AdcFrame
from mems_sim.devices.stage import MicroStage
from mems_sim.devices.stage_gyro import MemsGyro
from mems_sim.nodes.stage_node import StageNode, make_schedule
from mems_sim.ros.frames import adc_physical
from mems_sim.ros.qos import FRAME_QOS

STAGE = {"adc_offset_lsb": -1.5, "adc_inl_lsb": 3.0, "adc_dnl_lsb": 0.2, "adc_missing_codes": 9}
GYRO = {"gyro_dlpf_cfg": 0}


def test_node_frames_equal_the_core_with_adc_errors_and_dlpf(graph):
    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=4, n_trials=1, periods_per_trial=40, frame_size=5000, **STAGE, **GYRO
        ),
    )
    ex.add_node(dev)
    adc, gyro = [], []
    probe.create_subscription(AdcFrame, "/stage/adc", adc.append, FRAME_QOS)
    probe.create_subscription(AdcFrame, "/stage/gyro/adc", gyro.append, FRAME_QOS)
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() >= 1 and dev.pub_gyro.get_subscription_count() >= 1
        ),
    )
    for _ in range(3):
        dev.step()
    assert spin_until(ex, lambda: len(adc) == 3 and len(gyro) == 3, timeout=20)
    assert dev.device.converters is not None and dev.gyro.dlpf is not None

    core = MicroStage(STAGE, make_schedule(dev.p), seed=4)
    g = MemsGyro(GYRO, seed=4)
    codes, values = [], []
    for m in adc:
        k0 = core.next_index
        f = core.step(m.num_samples)
        codes.append(f.codes)
        values.append(
            g.step(
                k0,
                core.fs,
                f.theta[:, 0],
                f.omega[:, 0],
                core.last_applied,
                core.wn,
                core.zeta,
                core.b_c,
            ).value
        )
    np.testing.assert_array_equal(
        np.concatenate([adc_physical(m) for m in adc]), np.concatenate(codes) * core.lsb
    )
    np.testing.assert_array_equal(
        np.concatenate([adc_physical(m)[:, 0] for m in gyro]), np.concatenate(values)
    )
    assert np.any(codes[-1] != np.rint(f.y / core.lsb))  # not the ideal quantiser's codes


def test_dlpf_row_at_another_rate_refused(ros_context):
    emulator_refuses(StageNode, ros_context, "gyro_nominal_rate_hz", gyro_dlpf_cfg=3)

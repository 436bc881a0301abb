"""Sigma-delta resonator device node and observer node through real topics."""

import numpy as np
from conftest import params, spin_until
from diagnostic_msgs.msg import DiagnosticArray
from node_helpers import (
    diagnostics_show,
    emulator_refuses,
    one_channel_adc,
    status_values,
    wait_matched,
)

from mems_estimation.nodes.resonator_observer_node import ResonatorObserverNode
from mems_msgs.msg import AdcFrame, SignalFrame, StateEstimate
from mems_sim.devices.resonator import SdResonatorDevice
from mems_sim.kernels.resonator_observer import KalmanObserver
from mems_sim.nodes.resonator_node import ResonatorNode
from mems_sim.ros.frames import make_signal_frame
from mems_sim.ros.qos import FRAME_QOS


def test_device_publishes_bits_pulses_truth_and_loop_estimate(graph):
    ctx, ex, probe = graph
    dev = ResonatorNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(seed=4, frame_size=500, output_noise_std=0.5),
    )
    ex.add_node(dev)
    got = {"adc": [], "drive": [], "truth": [], "loop_estimate": []}
    for name, typ in (
        ("adc", AdcFrame),
        ("drive", SignalFrame),
        ("truth", SignalFrame),
        ("loop_estimate", StateEstimate),
    ):
        probe.create_subscription(typ, f"/resonator/{name}", got[name].append, FRAME_QOS)
    assert wait_matched(ex, dev.pub_adc, dev.pub_estimate)
    for _ in range(6):
        dev.step()
    assert spin_until(ex, lambda: all(len(v) == 6 for v in got.values()))
    assert [m.first_sample_index for m in got["adc"]] == list(range(0, 3000, 500))
    m = got["adc"][0]
    assert m.bits == 1 and list(m.channel_names) == ["sd_bit"] and m.sample_rate_hz == 1e6
    bits = np.concatenate([np.asarray(x.codes) for x in got["adc"]])
    assert set(np.unique(bits)) <= {-1, 1}
    ref = SdResonatorDevice({"output_noise_std": 0.5}, seed=4).step(3000)
    np.testing.assert_array_equal(bits, ref.bits)
    drive = np.concatenate([np.asarray(x.data).reshape(-1, 3) for x in got["drive"]])
    np.testing.assert_array_equal(drive[:, 0], ref.pulses)
    np.testing.assert_array_equal(drive[:, 1], ref.pulse_start)
    np.testing.assert_array_equal(drive[:, 2], ref.pulse_width)
    assert list(got["drive"][0].channel_names) == ["pulse", "pulse_start", "pulse_width"]
    assert list(got["drive"][0].channel_units) == ["V", "s", "s"]
    assert np.count_nonzero(drive[:, 1]) > 0  # sub-sample pulses (default)
    truth = np.concatenate([np.asarray(x.data).reshape(-1, 5) for x in got["truth"]])
    np.testing.assert_array_equal(truth[:, 0], ref.position)
    np.testing.assert_array_equal(truth[:, 3], ref.x_pulse_start)
    np.testing.assert_array_equal(truth[:, 4], ref.x_pulse_center)
    assert list(got["truth"][0].channel_units) == ["V", "V/s", "Hz", "V", "V"]


def test_device_refuses_f0_above_nyquist_and_bad_q(ros_context):
    emulator_refuses(ResonatorNode, ros_context, "f0_hz", f0_hz=6e5)
    emulator_refuses(ResonatorNode, ros_context, "quality_factor", quality_factor=0.0)


def _bit_frame(first, codes, fs=1e6):
    return one_channel_adc(first, codes, fs, bits=1, name="sd_bit", lsb=1.0, full_scale=1.0)


def _pulse_frame(first, n, fs=1e6):
    return make_signal_frame(
        np.zeros((n, 1)), first, fs, channel_names=["pulse"], channel_units=["V"]
    )


def test_observer_node_rejects_bad_bit_streams_on_diagnostics(graph):
    ctx, ex, probe = graph
    obs = ResonatorObserverNode(context=ctx, parameter_overrides=params(output_noise_std=0.5))
    ex.add_node(obs)
    pub_b = probe.create_publisher(AdcFrame, "/resonator/adc", FRAME_QOS)
    pub_p = probe.create_publisher(SignalFrame, "/resonator/drive", FRAME_QOS)
    estimates, diags = [], []
    probe.create_subscription(StateEstimate, "/resonator/estimate", estimates.append, FRAME_QOS)
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    assert wait_matched(ex, pub_b, pub_p)
    rng = np.random.default_rng(0)
    good = rng.choice([-1, 1], size=100)
    pub_b.publish(_bit_frame(0, good))
    pub_p.publish(_pulse_frame(0, 100))
    pub_b.publish(_bit_frame(100, [0, 2] + [1] * 98))  # values other than -1/+1
    pub_b.publish(_bit_frame(200, good, fs=2e6))  # another sample rate
    assert spin_until(
        ex, lambda: len(estimates) == 1 and obs.diag.counters.get("rejected_frames", 0) == 2
    )
    assert estimates[0].num_samples == 100 and np.all(np.isfinite(estimates[0].states))
    assert any("-1/+1" in w for w in obs.diag.warnings)
    obs.diag.publish()
    assert spin_until(
        ex,
        lambda: diagnostics_show(
            diags,
            "resonator_observer",
            lambda s: status_values(s).get("rejected_frames") == "2",
        ),
    )


def _drive_frame(first, pulses, starts, widths, fs=1e6):
    return make_signal_frame(
        np.column_stack([pulses, starts, widths]),
        first,
        fs,
        channel_names=["pulse", "pulse_start", "pulse_width"],
        channel_units=["V", "s", "s"],
    )


def test_observer_node_uses_sub_sample_pulse_timing(graph):
    """The downstream observer takes the pulses' firing offsets and widths from the drive
    frame (its estimate equals the core observer's given them); a drive frame with an
    offset outside [0, T) is rejected and counted."""
    ctx, ex, probe = graph
    obs = ResonatorObserverNode(context=ctx, parameter_overrides=params(output_noise_std=0.5))
    ex.add_node(obs)
    pub_b = probe.create_publisher(AdcFrame, "/resonator/adc", FRAME_QOS)
    pub_p = probe.create_publisher(SignalFrame, "/resonator/drive", FRAME_QOS)
    estimates = []
    probe.create_subscription(StateEstimate, "/resonator/estimate", estimates.append, FRAME_QOS)
    assert wait_matched(ex, pub_b, pub_p)
    fr = SdResonatorDevice({"output_noise_std": 0.5}, seed=5).step(4000)
    assert np.count_nonzero(fr.pulse_start) > 100
    for first in range(0, 4000, 1000):
        sl = slice(first, first + 1000)
        pub_b.publish(_bit_frame(first, fr.bits[sl]))
        pub_p.publish(_drive_frame(first, fr.pulses[sl], fr.pulse_start[sl], fr.pulse_width[sl]))
    assert spin_until(ex, lambda: len(estimates) == 4)
    est = np.concatenate([np.asarray(m.states) for m in estimates])
    ref, _ = KalmanObserver(5e4, 100.0, 1e6, 0.5, 0.0).step(
        fr.bits, fr.pulses, fr.pulse_start, fr.pulse_width
    )
    np.testing.assert_allclose(est, ref, rtol=0, atol=1e-12)
    naive, _ = KalmanObserver(5e4, 100.0, 1e6, 0.5, 0.0).step(fr.bits, fr.pulses)
    gap = np.abs(naive - ref)[2000:].max()
    print(f"\nnode = core observer; ignoring the timing would change the estimate by {gap:.1e} V")
    assert gap > 1e-3
    bad = np.zeros(1000)
    bad[3] = 1.0
    pub_b.publish(_bit_frame(4000, np.ones(1000)))
    pub_p.publish(_drive_frame(4000, bad, np.where(bad != 0, 1.5e-6, 0.0), bad * 5e-8))
    assert spin_until(ex, lambda: obs.diag.counters.get("rejected_frames", 0) == 1)
    assert any("pulse start" in w for w in obs.diag.warnings)

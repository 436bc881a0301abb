"""Plotting views: the ROS-free core on analytic signals, and view_node through real topics."""

import math

import numpy as np
import pytest
from conftest import params, spin_until
from geometry_msgs.msg import Vector3Stamped

from mems_msgs.msg import SignalFrame
from mems_sim import views
from mems_sim.ros.frames import index_to_ns, make_signal_frame, time_to_ns
from mems_sim.ros.qos import FRAME_QOS


def _pushed(obj, x, block):
    out = []
    for k in range(0, x.shape[0], block):
        out.append(obj.push(x[k : k + block]))
    return out


@pytest.mark.parametrize("frequency", [1000.0, 0.0])
def test_period_fit_of_a_sine_is_exact(frequency):
    """A sine of known amplitude, phase and offset: every period gives them to 1e-6 (known
    frequency; the estimated one is exact to the zero-crossing interpolation)."""
    fs, f, amp, phi, c = 48_000.0, 1000.0, 0.37, 0.8, -0.05
    n = np.arange(24_000)
    x = amp * np.cos(2 * math.pi * f * n / fs + phi) + c
    fitter = views.PeriodFitter(fs, frequency, periods=1)
    fits = [r for r in _pushed(fitter, x, 1000) if r.index.size]
    index = np.concatenate([r.index for r in fits])
    a = np.concatenate([r.amplitude for r in fits])
    p = np.concatenate([r.phase for r in fits])
    o = np.concatenate([r.offset for r in fits])
    tol = 1e-6 if frequency else 1e-4
    assert index.size >= 400
    assert np.max(np.abs(a - amp)) < tol * amp
    assert np.max(np.abs(np.angle(np.exp(1j * (p - phi))))) < tol * 10
    assert np.max(np.abs(o - c)) < tol
    # one point per period, centred in it
    np.testing.assert_allclose(np.diff(index), fs / f, atol=1)


def test_period_fit_from_a_later_start_uses_absolute_time():
    fs, f, amp, phi = 10_000.0, 123.4, 2.0, -2.5
    start = 1_234_567
    n = start + np.arange(5000)
    x = amp * np.cos(2 * math.pi * f * n / fs + phi)
    fit = views.PeriodFitter(fs, f, periods=2, start_index=start).push(x)
    assert fit.index.size == int(5000 * f / fs / 2) - 1 or fit.index.size == int(5000 * f / fs / 2)
    np.testing.assert_allclose(fit.amplitude, amp, rtol=1e-6)
    np.testing.assert_allclose(np.angle(np.exp(1j * (fit.phase - phi))), 0, atol=1e-6)
    assert fit.index[0] >= start


def test_decimation_attenuates_a_tone_above_the_new_nyquist_by_40_db():
    """A slow sine plus a tone above the output Nyquist frequency: the decimated output is
    the slow sine, the tone attenuated by > 40 dB (no alias), aligned in time (the FIR delay
    is taken out)."""
    fs, q = 1000.0, 100  # output 10 Hz, Nyquist 5 Hz
    n = np.arange(40_000)
    t = n / fs
    slow = np.sin(2 * math.pi * 0.3 * t)
    tone = np.sin(2 * math.pi * 27.3 * t)  # aliases to 2.7 Hz without the filter
    d = views.Decimator(q, 2)
    outs = _pushed(d, np.column_stack([slow + tone, tone]), 777)
    idx = np.concatenate([o[0] for o in outs])
    val = np.concatenate([o[1] for o in outs])
    lo = np.concatenate([o[2] for o in outs])
    hi = np.concatenate([o[3] for o in outs])
    assert idx.size > 350 and np.all(np.diff(idx) == q) and idx[0] >= 0
    steady = idx > 2 * d.offset  # after the filters' start-up
    ref = np.sin(2 * math.pi * 0.3 * idx / fs)
    err_db = 20 * np.log10(np.max(np.abs(val[steady, 0] - ref[steady])))
    tone_db = 20 * np.log10(np.max(np.abs(val[steady, 1])))
    assert tone_db < -40 and err_db < -40, (tone_db, err_db)
    # the envelope still shows the tone's band around the filtered value
    assert np.all(hi[steady, 1] > 0.9) and np.all(lo[steady, 1] < -0.9)
    # the same output in one block or in pieces (streaming state carried)
    whole = views.Decimator(q, 2).push(np.column_stack([slow + tone, tone]))
    np.testing.assert_array_equal(whole[0], idx)
    np.testing.assert_allclose(whole[1], val, atol=1e-12)


def test_stage_factors():
    assert views.stage_factors(100) == [5, 5, 4]
    assert views.stage_factors(6250) == [5, 5, 5, 5, 5, 2]
    assert views.stage_factors(13) == [13]
    assert views.stage_factors(1) == []


def test_view_node_through_topics(graph):
    """view_node in a resonator-like namespace: the carrier channel comes out per period
    (amplitude, phase in sensor time) and the slow channel decimated, stamped epoch + k/fs."""
    from mems_sim.nodes.view_node import ViewNode

    ctx, ex, probe = graph
    node = ViewNode(
        context=ctx,
        namespace="resonator",
        parameter_overrides=params(inputs="truth", carrier_hz=500.0, output_rate_hz=50.0),
    )
    ex.add_node(node)
    got = {"position": [], "f0": []}
    for name in got:
        probe.create_subscription(
            Vector3Stamped, f"/resonator/view/truth/{name}", got[name].append, FRAME_QOS
        )
    pub = probe.create_publisher(SignalFrame, "/resonator/truth", FRAME_QOS)
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    fs, epoch = 20_000.0, 5_000_000_000
    n = np.arange(20_000)
    position = 0.8 * np.cos(2 * math.pi * 500.0 * n / fs + 0.3)
    f0 = 500.0 + 0.001 * n / fs
    data = np.column_stack([position, f0])

    def send(k):
        pub.publish(
            make_signal_frame(
                data[k : k + 2000],
                k,
                fs,
                channel_names=["position", "f0"],
                channel_units=["V", "Hz"],
                t0_ns=epoch,
            )
        )

    # the view publishers appear with the first frame (its channel names): match them first
    send(0)
    assert spin_until(
        ex,
        lambda: (
            node.frames_received == 1
            and len(node._view_pubs) == 2
            and all(p.get_subscription_count() == 1 for p in node._view_pubs.values())
        ),
    )
    for name in got:
        got[name].clear()
    for k in range(2000, n.size, 2000):
        send(k)
        ex.spin_once(timeout_sec=0.01)
    # 18,000 samples: 450 periods of 40 samples; at 50 Hz one point per 400 samples, less
    # the anti-alias filters' lag (their delay: the points wait for their filter to fill)
    lag = node.views["truth"].decimator.offset
    slow_points = (n.size - 2000 - lag) // 400 - 1
    assert spin_until(ex, lambda: len(got["position"]) >= 449 and len(got["f0"]) >= slow_points)
    pos = got["position"]
    amp = np.array([m.vector.x for m in pos])
    ph = np.array([m.vector.y for m in pos])
    np.testing.assert_allclose(amp, 0.8, rtol=1e-6)
    np.testing.assert_allclose(np.angle(np.exp(1j * (ph - 0.3))), 0, atol=1e-6)
    stamps = np.array([time_to_ns(m.header.stamp) for m in pos])
    np.testing.assert_allclose(np.diff(stamps), 2_000_000, atol=1)  # one per 2 ms period
    # the carrier's window centre in sensor time: epoch + (40 k + 19.5) / fs
    k = (stamps[0] - epoch - index_to_ns(19, fs)) // 2_000_000
    assert abs(stamps[0] - (epoch + (40 * k + 19.5) / fs * 1e9)) <= 1
    slow = got["f0"]
    s = np.array([time_to_ns(m.header.stamp) for m in slow])
    assert np.all(np.diff(s) == 20_000_000)  # 50 Hz
    v = np.array([m.vector.x for m in slow])
    ref = 500.0 + 0.001 * (s - epoch) * 1e-9
    assert np.max(np.abs(v - ref)) < 1e-6
    assert all(m.vector.y <= m.vector.x <= m.vector.z for m in slow)

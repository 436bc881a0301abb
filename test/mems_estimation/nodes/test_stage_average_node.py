"""Synchronous-average node of the stage (Chen 2018 sec. 3.5.2) through real topics: its
effect on the readout noise measured against sqrt(n_avg), a periodic signal passing with
the documented attenuation, and the averaged stream recorded to MCAP.

Statistics of the noise ratio. The averaged noise at one drive phase is a moving average
over N periods of independent samples, so the samples of one phase stream in consecutive
averaged periods share N - 1 of N terms (correlation 1 - |l|/N at lag l periods); the
phases of one period are independent. The variance of the sample variance of M such
samples is then about (2 sigma^4 / M) sum_l rho_l^2 = (2 sigma^4 / M)(2N/3), so the
measured std (and the ratio raw/averaged: the raw std has M N independent samples and
negligible error) has a relative standard deviation sqrt(N / (3 M)). The tests allow five
of those (12 comparisons: a false failure about once in 10^5 runs).
"""

import numpy as np
import pytest
from conftest import params, spin_until

from mems_estimation.filters.stage_ekf import FeedthroughCanceller
from mems_estimation.filters.synchronous_average import SynchronousAverager
from mems_estimation.nodes.stage_average_node import (
    OUTPUT_CHANNELS,
    StageAverageNode,
    averaged_channels,
)
from mems_msgs.msg import AdcFrame, SignalFrame
from mems_sim.bag.player import read_messages
from mems_sim.bag.recorder import RecorderNode
from mems_sim.nodes.stage_node import StageNode
from mems_sim.params import ParameterError
from mems_sim.ros.frames import adc_physical, signal_data
from mems_sim.ros.qos import FRAME_QOS

FS = 625e3
FRAME = 25000


def averager(ctx, n: int, device: str = "/stage", **kw) -> StageAverageNode:
    """An averaging node over ``n`` periods reading ``device``, publishing
    ``/avg<n><device>/adc_averaged`` (remapped, so that several run side by side)."""
    tag = f"avg{n}{device.replace('/', '_')}"
    return StageAverageNode(
        context=ctx,
        namespace=f"/{tag}",
        cli_args=["--ros-args", "-r", f"{device}/adc_averaged:=/{tag}/adc_averaged"],
        parameter_overrides=params(device_namespace=device, n_periods=n, **kw),
    ), f"/{tag}/adc_averaged"


def collect(probe, topic, msg_type=SignalFrame):
    got = []
    probe.create_subscription(msg_type, topic, got.append, FRAME_QOS)
    return got


def run(ex, devices, nodes, outputs):
    """Step the devices frame by frame until their schedules end, each frame waiting for
    every node; return the number of frames."""
    frames = 0
    while all([d.step() for d in devices]):
        frames += 1
        spin_until(ex, lambda: all(n.frames_done >= frames for n in nodes), timeout=15)
    assert spin_until(ex, lambda: all(len(o) == frames for o in outputs), timeout=15)
    return frames


def cancelled(adc, drv):
    """The feedthrough-cancelled channels (n, 4) [V] and the drive (n, 5) of the frames."""
    y = np.concatenate([adc_physical(m) for m in adc])
    d = np.concatenate([signal_data(m) for m in drv])
    return FeedthroughCanceller(4, FS).step(y, d[:, 1], d[:, 2]), d


def test_zero_drive_noise_falls_as_sqrt_n_and_is_recorded(graph, tmp_path):
    """Zero drive (schedule 'zero', 0 V at 1700 Hz): the cancelled channels are readout
    noise; std(raw cancelled) / std(averaged, n_avg = N) is sqrt(N) within its statistical
    tolerance; the node equals the core averager; /stage/adc_averaged recorded to MCAP
    reads back as published."""
    ctx, ex, probe = graph
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=5, schedule="zero", periods_per_trial=1600, frame_size=FRAME, gyro_enabled=False
        ),
    )
    ns = (4, 16, 64)
    made = [averager(ctx, n) for n in ns]
    nodes = [m[0] for m in made]
    # the node at its default topic, recorded
    plain = StageAverageNode(context=ctx, parameter_overrides=params(n_periods=16))
    out = str(tmp_path / "averaged.mcap")
    rec = RecorderNode(out, topics=["/stage/adc_averaged"], context=ctx)
    for n in (dev, *nodes, plain, rec):
        ex.add_node(n)
    outs = [collect(probe, m[1]) for m in made]
    plain_out = collect(probe, "/stage/adc_averaged")
    adc = collect(probe, "/stage/adc", AdcFrame)
    drv = collect(probe, "/stage/drive")
    assert spin_until(
        ex,
        lambda: (
            dev.pub_adc.get_subscription_count() >= 5
            and all(n.pub.get_subscription_count() >= 1 for n in nodes)
            and plain.pub.get_subscription_count() >= 2
        ),
    )
    frames = run(ex, [dev], [*nodes, plain], [*outs, plain_out, adc, drv])
    assert spin_until(ex, lambda: rec.received("/stage/adc_averaged") == frames, timeout=15)
    rec.close()

    yc, d = cancelled(adc, drv)
    raw = np.nanstd(yc, axis=0)
    ratios = {}
    for n, node, got in zip(ns, nodes, outs):
        assert [m.first_sample_index for m in got] == [m.first_sample_index for m in adc]
        assert [m.header.stamp for m in got] == [m.header.stamp for m in adc]
        assert all(list(m.channel_names) == list(OUTPUT_CHANNELS) for m in got)
        x, count = map(np.concatenate, zip(*[averaged_channels(m) for m in got]))
        # the node is the core averager on the same frames (no value: n_avg = 0)
        ref, rc = SynchronousAverager(4, FS, n, 2).step(yc, d[:, 2], d[:, 4])
        np.testing.assert_array_equal(x, ref)
        np.testing.assert_array_equal(count, np.where(np.isfinite(ref[:, 0]), rc, 0))
        full = count == n
        m = int(full.sum())
        ratio = raw / np.std(x[full], axis=0)
        tol = 5 * np.sqrt(n / (3 * m))
        ratios[n] = ratio
        assert np.all(np.abs(ratio / np.sqrt(n) - 1) < tol), (n, ratio, np.sqrt(n), tol)
        assert node.diag.counters.get("rejected_frames", 0) == 0
    print("zero drive, std(raw)/std(averaged):", {n: np.round(r, 3) for n, r in ratios.items()})

    recorded = [msg for _, _, _, msg in read_messages(out, ["/stage/adc_averaged"])]
    assert recorded == plain_out and len(recorded) == frames


def test_driven_signal_passes_and_noise_averages(graph):
    """Calibration drive (1 V, 1700 Hz), 600 periods, averages over N = 16 after skipping
    the 200-period settling (6 time constants): a twin stage with the same seed and no
    readout noise gives the noise-free channels s. The twin's average passes s with gain
    1 - (2 pi f/fs)^2/24 (within 1e-4: harmonics, the residual transient and the drive
    noise); the noisy average deviates from s by the averaged noise sigma_raw/sqrt(N)."""
    ctx, ex, probe = graph
    common = dict(
        seed=4,
        schedule="calibration",
        n_trials=1,
        amp_lo_v=1.0,
        amp_hi_v=1.0,
        periods_per_trial=600,
        frame_size=FRAME,
        gyro_enabled=False,
    )
    noisy = StageNode(context=ctx, drive_externally=True, parameter_overrides=params(**common))
    clean = StageNode(
        context=ctx,
        drive_externally=True,
        namespace="/clean",
        parameter_overrides=params(readout_noise_scale=0.0, **common),
    )
    n = 16
    (a_noisy, t_noisy), (a_clean, t_clean) = (
        averager(ctx, n, dev, skip_periods=200) for dev in ("/stage", "/clean")
    )
    for node in (noisy, clean, a_noisy, a_clean):
        ex.add_node(node)
    streams = {
        k: collect(probe, topic, AdcFrame if topic.endswith("/adc") else SignalFrame)
        for k, topic in {
            "avg": t_noisy,
            "avg_clean": t_clean,
            "adc": "/stage/adc",
            "drive": "/stage/drive",
            "adc_clean": "/clean/adc",
            "truth": "/stage/truth",
            "truth_clean": "/clean/truth",
        }.items()
    }
    assert spin_until(
        ex,
        lambda: (
            noisy.pub_adc.get_subscription_count() >= 2
            and clean.pub_adc.get_subscription_count() >= 2
            and a_noisy.pub.get_subscription_count() >= 1
            and a_clean.pub.get_subscription_count() >= 1
        ),
    )
    run(ex, [noisy, clean], [a_noisy, a_clean], list(streams.values()))
    # the twin is the same stage (same motion), only without readout noise
    th = [np.concatenate([signal_data(m) for m in streams[k]]) for k in ("truth", "truth_clean")]
    np.testing.assert_array_equal(th[0], th[1])
    yc, d = cancelled(streams["adc"], streams["drive"])
    s, _ = cancelled(streams["adc_clean"], streams["drive"])
    x, count = map(np.concatenate, zip(*[averaged_channels(m) for m in streams["avg"]]))
    xs, count_s = map(np.concatenate, zip(*[averaged_channels(m) for m in streams["avg_clean"]]))
    np.testing.assert_array_equal(count, count_s)
    full = count == n
    m = int(full.sum())
    assert m > 60_000
    # the periodic signal passes: gain of the noise-free average on s
    gain = np.sum(xs[full] * s[full], axis=0) / np.sum(s[full] ** 2, axis=0)
    attenuation = (2 * np.pi * 1700.0 / FS) ** 2 / 24
    assert np.all(np.abs(gain - (1 - attenuation)) < 1e-4), gain - 1
    lsb = 0.02 / 2**15
    assert np.all(np.sqrt(np.mean((xs[full] - s[full]) ** 2, axis=0)) < 2 * lsb)
    # the noisy average's deviation from the noise-free signal: the averaged noise
    sigma_raw = np.nanstd(yc - s, axis=0)
    dev = np.sqrt(np.mean((x[full] - s[full]) ** 2, axis=0))
    tol = 5 * np.sqrt(n / (3 * m))
    assert np.all(np.abs(dev * np.sqrt(n) / sigma_raw - 1) < tol), (dev, sigma_raw / np.sqrt(n))
    print(
        "driven, N = 16: gain - 1",
        gain - 1,
        "rms(avg - s)",
        dev,
        "sigma_raw/sqrt(N)",
        sigma_raw / np.sqrt(n),
        "rms(s)",
        np.sqrt(np.mean(s[full] ** 2, axis=0)),
    )


def test_refusals_and_gap(graph):
    ctx, ex, probe = graph
    with pytest.raises(ParameterError, match="n_periods"):
        StageAverageNode(context=ctx, parameter_overrides=params(n_periods=0))
    with pytest.raises(ParameterError, match="period_step"):
        StageAverageNode(context=ctx, parameter_overrides=params(period_step=0))
    # a gap starts the average again: n_avg counts up from 1 after it
    dev = StageNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=2, schedule="zero", periods_per_trial=80, frame_size=3000, gyro_enabled=False
        ),
    )
    ex.add_node(dev)
    adc, drv = collect(probe, "/stage/adc", AdcFrame), collect(probe, "/stage/drive")
    assert spin_until(ex, lambda: dev.pub_adc.get_subscription_count() >= 1)
    frames = 0
    while dev.step():
        frames += 1
    assert spin_until(ex, lambda: len(adc) == len(drv) == frames) and frames >= 8
    # replay the device's frames to the node with frame 4 missing
    node = StageAverageNode(context=ctx, parameter_overrides=params(n_periods=8))
    ex.add_node(node)
    got = collect(probe, "/stage/adc_averaged")
    adc_pub = probe.create_publisher(AdcFrame, "/stage/adc", FRAME_QOS)
    drv_pub = probe.create_publisher(SignalFrame, "/stage/drive", FRAME_QOS)
    assert spin_until(
        ex,
        lambda: (
            node.pub.get_subscription_count() >= 1
            and adc_pub.get_subscription_count() >= 2
            and drv_pub.get_subscription_count() >= 2
        ),
    )
    sent = [k for k in range(frames) if k != 4]
    for k in sent:
        adc_pub.publish(adc[k])
        drv_pub.publish(drv[k])
    assert spin_until(ex, lambda: len(got) == len(sent))
    assert node.diag.counters["gaps"] == 1 and node.frames_done == len(sent)
    counts = [averaged_channels(m)[1] for m in got]
    assert counts[3].max() == 8  # 16 periods (5,900 samples) after the start
    after = counts[4]  # the frame after the gap: the average starts again
    assert after.max() < 8 and after[after > 0].min() == 1

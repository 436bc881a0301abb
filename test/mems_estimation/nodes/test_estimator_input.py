"""The estimators' input path and filter resets, ROS-free: sequence accounting, bounded
pairing, the stream format, the ADC decode checks, the divergence test and the ``reset()``
of every filter class (after a divergence the filter is a fresh one again)."""

from __future__ import annotations

import array
import math

import numpy as np
import pytest

from mems_estimation.filters.accelerometer_ekf import HybridEkf
from mems_estimation.filters.resonator_adaptive_observer import AdaptiveObserver
from mems_estimation.filters.scanner_amdm_model import ESTIMATOR_SPECS
from mems_estimation.filters.scanner_amdm_tracking import ScannerFilter
from mems_estimation.filters.scanner_threshold_ekf import StreamingScannerEkf
from mems_estimation.filters.stage_ekf import FeedthroughCanceller, StageEkf, load_model
from mems_estimation.nodes.frame_input import FormatPin, FramePairer, StreamIndex, input_specs
from mems_msgs.msg import AdcFrame
from mems_sim.devices import accelerometer
from mems_sim.kernels.divergence import covariance_ok, state_ok
from mems_sim.kernels.resonator_observer import KalmanObserver
from mems_sim.ros.frames import FrameError, adc_codes, adc_physical, code_range, frame_format

# ---------------------------------------------------------------------- sequence


def test_stream_index_classifies_every_kind_of_index():
    s = StreamIndex(max_gap=1000)
    assert s.update(0, 10) == ("first", 0)
    assert s.update(10, 10) == ("next", 0)
    assert s.update(10, 10) == ("repeat", 0)  # taken before: dropped
    assert s.update(520, 10) == ("gap", 500)
    assert s.update(500, 10) == ("out_of_order", 0)  # behind, never taken
    assert s.expected == 530
    assert s.update(530 + 1001, 10) == ("reset", 1001)  # beyond max_gap
    assert s.update(2**62, 10) == ("reset", 2**62 - 1541)
    assert s.update(0, 10) == ("reset", 0)  # back by more than max_gap
    # a stream that starts again inside max_gap: three behind frames in a row, each after
    # the previous (frames taken recently are repeats instead)
    s = StreamIndex(max_gap=10**6)
    for k in range(100):
        s.update(1000 + 10 * k, 10)
    assert [s.update(10 * k, 10)[0] for k in range(3)] == ["out_of_order"] * 2 + ["reset"]
    assert s.update(30, 10) == ("next", 0)
    assert s.update(1990, 10) == ("gap", 1950)  # the old stream's frames are not recent


def test_pairer_pairs_in_index_order_and_bounds_the_waiting_frames():
    p = FramePairer(("adc", "drive"), max_samples=25, max_frames=4)
    assert p.add("adc", 10, "a10", 10) == []
    assert p.add("adc", 0, "a0", 10) == []
    assert p.add("drive", 0, "d0", 10) == [(0, "a0", "d0")]
    assert p.samples == {"adc": 10, "drive": 0}
    # beyond 25 samples the oldest waiting frames are dropped (reported in overflow)
    p.add("adc", 20, "a20", 10)
    p.add("adc", 30, "a30", 10)
    assert p.overflow == [("adc", 10, 10)] and p.samples["adc"] == 20
    assert not p.holds("adc", 10) and p.holds("adc", 30)
    # frames left behind by the stream are dropped
    assert p.drop_before(25) == [("adc", 20, 10)]
    assert p.add("drive", 30, "d30", 10) == [(30, "a30", "d30")]
    assert p.samples == {"adc": 0, "drive": 0}
    # the frame count bound
    q = FramePairer(("adc", "drive"), max_samples=None, max_frames=4)
    for k in range(10):
        q.add("drive", 10 * k, k, 10)
    assert len(q.frames["drive"]) == 4 and q.overflow == [("drive", 50, 10)]


def test_format_pin_rejects_a_stray_frame_and_adopts_a_lasting_change():
    pin = FormatPin()
    a, b = ("A",), ("B",)
    assert pin.check(a) == "new"
    pin.adopt(a)
    assert pin.check(b) == "foreign" and pin.check(a) == "same"  # one stray frame
    assert [pin.check(b) for _ in range(3)] == ["foreign", "foreign", "adopt"]
    pin.adopt(b)
    assert pin.check(b) == "same"
    # a stray frame first: replaced by the stream after ADOPT_FRAMES frames
    pin = FormatPin()
    pin.adopt(b)
    assert [pin.check(a) for _ in range(FormatPin.ADOPT_FRAMES)][-1] == "adopt"


def test_input_specs_defaults_per_node():
    specs = {s.name: s for s in input_specs(max_frame_samples=100)}
    assert specs["max_frame_samples"].default == 100
    assert specs["max_gap_samples"].default == 2**32
    assert "max_unpaired_samples" not in {s.name for s in input_specs(paired=False)}
    with pytest.raises(KeyError):
        input_specs(frame_size=1)


# ---------------------------------------------------------------------- decode


def _adc(codes, bits=16, lsb=1e-3, offset=0.0, n=None):
    m = AdcFrame(
        first_sample_index=7,
        sample_rate_hz=1e3,
        num_samples=len(codes) if n is None else n,
        bits=bits,
        channel_names=["x"],
        channel_units=["V"],
    )
    m.lsb, m.offset, m.full_scale = (array.array("d", [v]) for v in (lsb, offset, 1.0))
    m.codes = array.array("i", codes)
    return m


def test_adc_codes_outside_the_declared_bit_range_are_rejected():
    assert code_range(16) == (-32768, 32767) and code_range(1) == (-1, 1)
    np.testing.assert_array_equal(adc_codes(_adc([-32768, 0, 32767])).ravel(), [-32768, 0, 32767])
    for codes, bits in (([32768], 16), ([-32769], 16), ([2], 1), ([0, 8], 4)):
        with pytest.raises(FrameError) as err:
            adc_physical(_adc(codes, bits))
        assert err.value.reason == "out_of_range"
    with pytest.raises(FrameError, match="-1/\\+1"):
        adc_codes(_adc([3], 1))
    for bits in (0, 33):
        with pytest.raises(FrameError) as err:
            adc_codes(_adc([0], bits))
        assert err.value.reason == "malformed"


def test_adc_conversion_that_overflows_is_rejected_as_non_finite():
    with pytest.raises(FrameError) as err:
        adc_physical(_adc([30000], lsb=1e305))
    assert err.value.reason == "non_finite"
    with pytest.raises(FrameError) as err:
        adc_physical(_adc([1, 2], n=3))  # 2 codes for 3 samples
    assert err.value.reason == "malformed"
    assert adc_physical(_adc([2], lsb=0.5, offset=1.0))[0, 0] == 2.0


def test_frame_format_names_what_a_stream_shares():
    a, b = _adc([1]), _adc([1], lsb=2e-3)
    assert frame_format(a) == frame_format(_adc([5, 6]))  # data and size are not format
    assert frame_format(a) != frame_format(b)


# ---------------------------------------------------------------------- divergence


def test_divergence_test():
    assert covariance_ok(np.diag([1.0, 1e-12])) and state_ok(np.zeros(3), [1.0])
    assert not covariance_ok(np.array([[1.0, 2.0], [2.0, 1.0]]))  # indefinite
    assert not covariance_ok(np.diag([1.0, 0.0]))
    assert not covariance_ok(np.diag([1.0, np.nan]))
    assert not state_ok(np.array([0.0, np.inf]))
    # round-off below the tolerance is not a divergence
    P = np.array([[1.0, 1.0], [1.0, 1.0 + 1e-15]])
    assert covariance_ok(P)


def _same_state(a, b):
    for name in ("x", "P", "s", "pm", "uprev", "_spill"):
        if hasattr(a, name):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_hybrid_ekf_reset_after_an_absurd_frame():
    d = accelerometer.ForceRebalanceAccelerometer({"mode": "pi_rebalance"}, seed=1)
    f = d.step(2000)
    y, v = f.code * d.lsb, f.v_f
    ekf = HybridEkf(d.ekf_config)
    ekf.run(y[:1000], v[:1000])
    assert not ekf.diverged()
    ekf.run(y[:1000], v[:1000] * 1e150)  # finite, absurd feedback voltage
    assert ekf.diverged()
    ekf.reset()
    fresh = HybridEkf(d.ekf_config)
    _same_state(ekf, fresh)
    a, b = ekf.run(y[1000:], v[1000:]), fresh.run(y[1000:], v[1000:])
    np.testing.assert_array_equal(a["estimate"], b["estimate"])
    assert not ekf.diverged() and ekf.resets == 1


def test_stage_ekf_and_canceller_reset(tmp_path):
    from pathlib import Path

    model = load_model(str(Path(__file__).resolve().parents[3] / "bags" / "stage_params.yaml"))
    nch = len(model.channels)
    rng = np.random.default_rng(0)
    y, u = rng.normal(0, 1e-3, (2000, nch)), rng.normal(0, 0.5, 2000)
    ekf = StageEkf(model)
    ekf.step(y, u)
    assert not ekf.diverged()
    ekf.step(y[:10], u[:10] * 1e150)
    assert ekf.diverged()
    ekf.reset()
    _same_state(ekf, StageEkf(model))
    np.testing.assert_array_equal(ekf.step(y, u)[0], StageEkf(model).step(y, u)[0])
    # bridging a gap in bounded chunks equals one block of time updates
    a, b = StageEkf(model), StageEkf(model)
    a.step(y, u)
    b.step(y, u)
    a.time_update(100_000, chunk=4096)
    b.step(np.full((100_000, nch), np.nan), np.zeros(100_000))
    _same_state(a, b)
    can = FeedthroughCanceller(nch, model.fs)
    can.step(y, np.zeros(2000), np.full(2000, 1700.0))
    can.reset()
    _same_state(can, FeedthroughCanceller(nch, model.fs))
    np.testing.assert_array_equal(can.hy, FeedthroughCanceller(nch, model.fs).hy)


def test_scanner_amdm_filter_reset():
    p = {s.name: s.default for s in ESTIMATOR_SPECS}
    y = 6.0 + np.random.default_rng(1).normal(0, 0.01, 500)
    for kind in ("ekf", "ukf"):
        f = ScannerFilter(kind, p)
        f.step(y, np.full(500, 100.0))
        f.x[:] = (np.nan, 0.0)  # as after a non-finite step
        assert f.diverged()
        f.reset()
        fresh = ScannerFilter(kind, p)
        _same_state(f, fresh)
        assert not f.diverged() and not f.tracking
        np.testing.assert_array_equal(
            f.step(y, np.full(500, 100.0))["x"], fresh.step(y, np.full(500, 100.0))["x"]
        )


def test_threshold_ekf_reset_keeps_the_sample_count():
    rng = np.random.default_rng(2)
    y, v = rng.normal(0, 0.01, 3000), np.full(3000, 10.0)
    f = StreamingScannerEkf()
    f.process(y[:1000], v[:1000])
    f.process(y[1000:2000], v[1000:2000] * 1e150)
    assert f.diverged()
    f.reset()
    assert not f.diverged() and f.next_index == 2000 and f.valid_from == 2000
    first, x, P, _ = f.process(y[2000:], v[2000:])
    assert first == 2000 - f.lag and np.all(np.isfinite(x)) and np.all(np.isfinite(P))
    # the pending rows are the prior
    np.testing.assert_array_equal(x[: f.lag], np.tile(f.x0, (f.lag, 1)))


@pytest.mark.parametrize("steady", [False, True])
def test_kalman_observer_reset(steady):
    rng = np.random.default_rng(3)
    bits, pulses = rng.choice([-1.0, 1.0], 2000), np.zeros(2000)
    obs = KalmanObserver(5e4, 100.0, 1e6, 0.5, 1e-4, steady_state=steady)
    obs.step(bits[:1000], pulses[:1000])
    assert not obs.diverged()
    kick = pulses[:1000].copy()
    kick[10] = 1e150
    obs.step(bits[:1000], kick)
    assert obs.diverged()
    obs.reset()
    fresh = KalmanObserver(5e4, 100.0, 1e6, 0.5, 1e-4, steady_state=steady)
    _same_state(obs, fresh)
    np.testing.assert_array_equal(
        obs.step(bits[1000:], pulses[1000:])[0], fresh.step(bits[1000:], pulses[1000:])[0]
    )


def test_adaptive_observer_reset_repeats_the_warm_up():
    rng = np.random.default_rng(4)
    bits, pulses = rng.choice([-1.0, 1.0], 3000), np.zeros(3000)
    obs = AdaptiveObserver(5e4, 100.0, 1e6, 0.5, 1e-4)
    obs.step(bits[:2000], pulses[:2000])
    assert not obs.diverged()
    obs.x[6] = -2.0  # f0 < 0
    assert obs.diverged()
    obs.reset()
    fresh = AdaptiveObserver(5e4, 100.0, 1e6, 0.5, 1e-4)
    _same_state(obs, fresh)
    a, b = obs.step(bits[2000:], pulses[2000:]), fresh.step(bits[2000:], pulses[2000:])
    for u, w in zip(a, b):
        np.testing.assert_array_equal(u, w)
    assert math.isclose(obs.f0, fresh.f0)

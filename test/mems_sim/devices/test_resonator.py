"""Core tests of the pulse-actuated sigma-delta resonator (Colinet et al.).

Acceptance figures: the comparator loop fails and the observer loop sustains under output
noise equal to the amplitude (figure 3), parameter validation (figure 5) and frame-size
independence (figure 6), plus the exactness of the modulator's linearised model
(eqs. (11)-(12)) and of the sub-sample pulse term.  Seeded; measured figures are printed.
"""

import math

import numpy as np
import pytest
from scipy import signal

from mems_sim.devices.resonator import (
    RESONATOR_SPECS,
    SdResonatorDevice,
    default_pulse_amplitude,
    validate_params,
)
from mems_sim.kernels.resonator_models import (
    NTF_NUM,
    SD_DEN,
    interval_input,
    modulate,
    next_crossing,
    next_spill,
    resonator_zoh_dt,
    resonator_zoh_np,
    stf_num,
)
from mems_sim.params import ParameterError

FS = 1e6
N = 200_000
HALF = N // 2


def _amp(y):
    return math.sqrt(2.0) * float(np.std(y))


@pytest.mark.parametrize("c", [0.5, 0.0])
def test_linearised_modulator_reproduces_bits_exactly(c):
    """v = STF x + NTF e with e = v - q (eqs. (11)-(12)) reproduces the real bit stream."""
    rng = np.random.default_rng(1)
    k = np.arange(50_000)
    x = 0.5 * np.sin(2 * np.pi * 0.05 * k) + 0.3 * rng.standard_normal(k.size)
    bits, q = modulate(x, c)
    e = bits - q
    v = signal.lfilter(stf_num(c), SD_DEN, x) + signal.lfilter(NTF_NUM, SD_DEN, e)
    dev = np.max(np.abs(v - bits))
    print(f"\nc={c}: max |STF x + NTF e - bits| = {dev:.2e}; var(e) = {e.var():.3f} V^2")
    assert set(np.unique(bits)) <= {-1, 1}
    assert dev < 1e-9


def test_default_amplitude_and_observer_loop_without_noise():
    d = SdResonatorDevice(seed=0)
    fr = d.step(N)
    a = _amp(fr.position[HALF:])
    npulse = np.count_nonzero(fr.pulses[HALF:])
    print(
        f"\nsteady amplitude {a:.4f} V, {npulse} pulses in {HALF} samples "
        f"(2 per period -> {2 * 0.05 * HALF:.0f})"
    )
    assert 0.4 < a < 0.6
    assert abs(npulse - 2 * 0.05 * HALF) <= 0.005 * 2 * 0.05 * HALF
    assert fr.bits.dtype == np.int8 and set(np.unique(fr.bits)) <= {-1, 1}


def _pulse_positions(fr, a):
    """|x| / A at the firing instants and at the centres of the pulses after HALF."""
    k = np.flatnonzero(fr.pulses)
    k = k[k > HALF]
    kc = k + np.floor((fr.pulse_start[k] + 0.5 * fr.pulse_width[k]) * FS).astype(int)
    keep = kc < fr.pulses.size
    return (np.abs(fr.x_pulse_start[k]) / a, np.abs(fr.x_pulse_center[kc[keep]]) / a, k)


def test_fig3_comparator_loop_fails_observer_loop_sustains():
    """Figure 3: output noise std = amplitude: Fig. 1 loop never builds up; Fig. 4 loop does,
    with its (sub-sample, default) pulses fired at |x| <= 2 % of the amplitude."""
    for seed in (11, 12, 13):
        obs = SdResonatorDevice({"mode": "observer", "output_noise_std": 0.5}, seed=seed)
        fo = obs.step(N)
        cmp_ = SdResonatorDevice({"mode": "comparator", "output_noise_std": 0.5}, seed=seed)
        fc = cmp_.step(N)
        cmp_bits = SdResonatorDevice(
            {"mode": "comparator", "comparator_input": "bitstream", "output_noise_std": 0.5},
            seed=seed,
        ).step(N)
        cmp_clean = SdResonatorDevice({"mode": "comparator"}, seed=seed).step(N)
        a_o, a_c = _amp(fo.position[HALF:]), _amp(fc.position[HALF:])
        a_b, a_0 = _amp(cmp_bits.position[HALF:]), _amp(cmp_clean.position[HALF:])
        rel_s, rel_c, k = _pulse_positions(fo, a_o)
        rel_e = np.abs(fo.estimate - fo.position)[HALF:].max() / a_o
        print(
            f"\nseed {seed}: amplitude observer loop {a_o:.4f} V, comparator loop (y+b) "
            f"{a_c:.4f} V = {a_c / a_o:.1%}, comparator on decoded bits {a_b:.4f} V, "
            f"noise-free comparator loop {a_0:.4f} V"
        )
        print(
            f"  observer-loop pulses ({k.size}, expected {0.1 * HALF:.0f}): |x| / A at the "
            f"firing instant mean {rel_s.mean():.4f} max {rel_s.max():.4f}, at the pulse "
            f"centre mean {rel_c.mean():.1e} max {rel_c.max():.1e}; "
            f"max |x_hat - x| / A {rel_e:.1e}"
        )
        assert a_c < 0.10 * a_o
        assert a_b < 0.10 * a_o
        assert a_0 > 0.9 * a_o  # the comparator loop works without noise
        assert a_o > 0.4
        assert abs(k.size - 0.1 * HALF) <= 2  # one pulse per crossing, no spurious ones
        assert rel_e <= 1e-9
        assert rel_s.max() <= 0.02 and rel_c.max() <= 0.02


def test_on_sample_timing_limit():
    """pulse_timing = on_sample (the pulse at the first sample after the estimate's crossing):
    |x| at the pulse reaches sin(2 pi f0/fs) = 31 % of A at 20 samples per period, however
    exact the estimate; with one-sample pulses (width 1/fs) it is the original loop."""
    for width in (0.05, 1.0):
        p = {
            "output_noise_std": 0.5,
            "pulse_timing": "on_sample",
            "pulse_width_s": width / FS,
            "pulse_amplitude": default_pulse_amplitude(width=width, timing="on_sample"),
        }
        fo = SdResonatorDevice(p, seed=11).step(N)
        a = _amp(fo.position[HALF:])
        rel_s, rel_c, k = _pulse_positions(fo, a)
        x = fo.position
        first = np.mean(np.sign(x[k]) != np.sign(x[k - 1]))
        print(
            f"\non-sample, width {width} T: A = {a:.4f} V, |x| / A at firing mean "
            f"{rel_s.mean():.3f} max {rel_s.max():.3f}; at the centre max {rel_c.max():.3f}; "
            f"{first:.2%} of the pulses on the first sample after a true crossing"
        )
        assert np.all(fo.pulse_start == 0)
        assert first >= 0.99
        assert 0.4 < a < 0.6
        assert 0.05 < rel_s.max() <= 1.02 * math.sin(2 * math.pi * 0.05)


def test_sub_sample_pulse_term_is_exact():
    """interval_input (used by the device and the observers) equals the numerically
    integrated impulse response of eq. (7) for a pulse inside and across an interval."""
    from scipy.linalg import expm

    f0, Q, fs = 5e4, 100.0, 1e6
    w0 = 2 * np.pi * f0
    Ac = np.array([[0.0, 1.0], [-(w0**2), -w0 / Q]])
    Bc = np.array([0.0, fs * w0])

    def numeric(a, b):
        r = np.linspace(a, b, 4001) / fs
        vals = np.array([expm(Ac * (1 / fs - ri)) @ Bc for ri in r])
        return np.sum((vals[1:] + vals[:-1]) / 2 * np.diff(r)[:, None], axis=0)

    _, gam = resonator_zoh_np(f0, Q, fs)
    out, z, spill, tail = np.empty(2), np.empty(6), np.zeros(2), np.empty(2)
    for s0, w in ((0.3, 0.05), (0.0, 1.0), (0.97, 0.05), (0.6, 0.7)):
        interval_input(f0, Q, fs, gam, 0.0, 0.0, 2.0, s0, w, out, z, np.full(3, -1.0))
        ref = 2.0 * numeric(s0, min(s0 + w, 1.0))
        next_spill(2.0, s0, w, spill)
        interval_input(f0, Q, fs, gam, spill[0], spill[1], 0.0, 0.0, 1.0, tail, z, np.full(3, -1.0))
        ref_tail = 2.0 * numeric(0.0, max(s0 + w - 1.0, 0.0))
        print(
            f"\ns={s0}, w={w}: rel. error {np.abs(out / ref - 1).max():.1e}, "
            f"tail {tail} vs {ref_tail}"
        )
        np.testing.assert_allclose(out, ref, rtol=1e-6)
        np.testing.assert_allclose(tail, ref_tail, rtol=1e-6, atol=1e-12 * np.abs(ref).max())
    # a one-sample pulse is Gam(T) exactly; the crossing time is a root of the free response
    interval_input(f0, Q, fs, gam, 0.0, 0.0, 1.0, 0.0, 1.0, out, z, np.full(3, -1.0))
    assert np.array_equal(out, gam)
    y, yd = 0.3, -2e5
    t = next_crossing(f0, Q, fs, y, yd, 0.0, 3.0)
    resonator_zoh_dt(f0, Q, fs, t / fs, z)
    assert 0 < t < 3 and abs(z[0] * y + z[1] * yd) < 1e-12
    assert next_crossing(f0, Q, fs, y, yd, t, t + 1.0) == -1.0


@pytest.mark.parametrize(
    "name,value",
    [
        ("sample_rate_hz", 0.0),
        ("sample_rate_hz", -1.0),
        ("quality_factor", 0.0),
        ("quality_factor", -5.0),
        ("mode", "pll"),
        ("output_noise_std", -0.1),
    ],
)
def test_bad_parameters_refused(name, value):
    with pytest.raises(ParameterError, match=name):
        SdResonatorDevice({name: value})


def test_f0_at_or_above_nyquist_refused():
    for f0 in (5e5, 6e5):
        with pytest.raises(ParameterError, match="f0_hz") as ei:
            SdResonatorDevice({"f0_hz": f0})
        print("\n", ei.value)
    with pytest.raises(ParameterError, match="f0_step_fraction"):
        SdResonatorDevice({"f0_hz": 4.9e5, "f0_step_fraction": 0.05})
    with pytest.raises(ParameterError, match="comparator_window"):
        SdResonatorDevice({"comparator_window": 4})
    with pytest.raises(ParameterError, match="pulse_width_s"):
        SdResonatorDevice({"pulse_width_s": 2e-6})
    with pytest.raises(ParameterError, match="pulse_timing"):
        SdResonatorDevice({"pulse_timing": "early"})


def test_specs_complete():
    names = {s.name for s in RESONATOR_SPECS}
    for n in (
        "sample_rate_hz",
        "f0_hz",
        "quality_factor",
        "pulse_amplitude",
        "output_noise_std",
        "state_noise_std",
        "mode",
        "f0_drift_ppm_per_s",
        "f0_step_fraction",
        "f0_step_time_s",
        "observer_f0_error",
        "observer_state_noise_std",
        "fast",
    ):
        assert n in names
    for s in RESONATOR_SPECS:
        assert s.unit and s.source and s.description
    validate_params({s.name: s.default for s in RESONATOR_SPECS})


@pytest.mark.parametrize(
    "params",
    [
        {
            "mode": "observer",
            "output_noise_std": 0.5,
            "state_noise_std": 1e-3,
            "observer_state_noise_std": 1e-3,
            "fast": False,
        },
        {
            "mode": "observer",
            "output_noise_std": 0.5,
            "fast": True,
            "f0_drift_ppm_per_s": 50.0,
            "f0_step_fraction": 0.02,
            "f0_step_time_s": 0.003,
        },
        {
            "mode": "observer",
            "output_noise_std": 0.2,
            "fast": False,
            "pulse_width_s": 0.9e-6,
            "state_noise_std": 1e-3,
        },
        {"mode": "observer", "output_noise_std": 0.2, "pulse_timing": "on_sample"},
        {"mode": "comparator", "comparator_input": "bitstream", "output_noise_std": 0.3},
        {"mode": "comparator", "output_noise_std": 0.1, "state_noise_std": 1e-3},
    ],
)
def test_frame_size_independence(params):
    """Figure 6: any framing gives bit-identical output."""
    n = 20_000
    whole = SdResonatorDevice(params, seed=7).step(n)
    d = SdResonatorDevice(params, seed=7)
    sizes = [1, 2, 999, 0, 4096, 3, 5000]
    parts, total = [], 0
    for s in sizes:
        parts.append(d.step(s))
        total += s
    parts.append(d.step(n - total))
    assert d.next_index == n
    for field in whole._fields:
        a = getattr(whole, field)
        b = np.concatenate([getattr(p, field) for p in parts])
        assert a.dtype == b.dtype
        assert np.array_equal(a, b, equal_nan=True), field


def test_f0_step_and_drift_in_truth():
    d = SdResonatorDevice(
        {"f0_step_fraction": 0.02, "f0_step_time_s": 1e-3, "f0_drift_ppm_per_s": 100.0}, seed=0
    )
    fr = d.step(2000)
    assert fr.f0[999] == pytest.approx(5e4 * (1 + 100e-6 * 999e-6))
    assert fr.f0[1000] == pytest.approx(5e4 * (1 + 100e-6 * 1e-3) * 1.02)


def test_standin_quantizer_is_linear_gaussian():
    """The ``quantizer: gaussian`` stand-in (v = q + w, Colinet eqs. 10-13 with the one-bit
    comparator replaced by additive Gaussian noise of the model's variance): real-valued
    output, v = STF x + NTF w exactly; the default stays the one-bit stream."""
    from mems_sim.devices.resonator import SdResonatorDevice
    from mems_sim.kernels.resonator_models import sd_step_standin

    p = {"output_noise_std": 0.25, "state_noise_std": 5e-4, "observer_state_noise_std": 5e-4}
    one = SdResonatorDevice(p, seed=2).step(20_000)
    explicit = SdResonatorDevice(dict(p, quantizer="one_bit"), seed=2).step(20_000)
    assert one.bits.dtype == np.int8 and np.array_equal(one.bits, explicit.bits)
    fr = SdResonatorDevice(dict(p, quantizer="gaussian"), seed=2).step(20_000)
    assert fr.bits.dtype == np.float64 and np.unique(fr.bits).size > 1000
    # the stand-in step alone: v - q is exactly the injected noise
    s = np.zeros(2)
    w = np.random.default_rng(0).standard_normal(1000) / np.sqrt(3.0)
    e = np.array([np.subtract(*sd_step_standin(0.3, s, 0.5, wi)) for wi in w])
    assert np.allclose(e, w, atol=1e-12)
    print(f"\nstand-in output std {fr.bits[5000:].std():.3f} V")

"""Core tests of the pulse-actuated sigma-delta resonator (issue 6, Colinet et al.).

Acceptance figures 3, 5 (parameters) and 6, plus the exactness of the
modulator's linearised model (eqs. (11)-(12)).  Seeded; measured figures are printed.
"""
import math

import numpy as np
import pytest
from scipy import signal

from mems_sim.params import ParameterError
from mems_sim.sd_models import NTF_NUM, SD_DEN, modulate, stf_num
from mems_sim.sd_resonator import RESONATOR_SPECS, SdResonatorDevice, validate_params

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
    print(f"\nsteady amplitude {a:.4f} V, {npulse} pulses in {HALF} samples "
          f"(2 per period -> {2 * 0.05 * HALF:.0f})")
    assert 0.4 < a < 0.6
    assert abs(npulse - 2 * 0.05 * HALF) <= 0.005 * 2 * 0.05 * HALF
    assert fr.bits.dtype == np.int8 and set(np.unique(fr.bits)) <= {-1, 1}


def test_fig3_comparator_loop_fails_observer_loop_sustains():
    """Figure 3: output noise std = amplitude: Fig. 1 loop never builds up; Fig. 4 loop does."""
    amp_obs = []
    for seed in (11, 12, 13):
        obs = SdResonatorDevice({"mode": "observer", "output_noise_std": 0.5}, seed=seed)
        fo = obs.step(N)
        cmp_ = SdResonatorDevice({"mode": "comparator", "output_noise_std": 0.5}, seed=seed)
        fc = cmp_.step(N)
        cmp_bits = SdResonatorDevice({"mode": "comparator", "comparator_input": "bitstream",
                                      "output_noise_std": 0.5}, seed=seed).step(N)
        cmp_clean = SdResonatorDevice({"mode": "comparator"}, seed=seed).step(N)
        a_o, a_c = _amp(fo.position[HALF:]), _amp(fc.position[HALF:])
        a_b, a_0 = _amp(cmp_bits.position[HALF:]), _amp(cmp_clean.position[HALF:])
        amp_obs.append(a_o)
        # pulse timing of the observer loop
        k = np.flatnonzero(fo.pulses)[1:]
        k = k[k > HALF]
        x = fo.position
        ideal = np.sign(x[k]) != np.sign(x[k - 1])          # true crossing in (k-1, k]
        rel_x = np.abs(x[k]) / a_o
        rel_e = np.abs(fo.estimate[k] - x[k]) / a_o
        print(f"\nseed {seed}: amplitude observer loop {a_o:.4f} V, comparator loop (y+b) "
              f"{a_c:.4f} V = {a_c / a_o:.1%}, comparator on decoded bits {a_b:.4f} V, "
              f"noise-free comparator loop {a_0:.4f} V")
        print(f"  observer-loop pulses: {ideal.mean():.4%} at the first sample after a true "
              f"crossing; |x| at pulse / A: mean {rel_x.mean():.3f}, max {rel_x.max():.3f} "
              f"(sampling limit sin(2 pi f0/fs) = {math.sin(2 * math.pi * 0.05):.3f}); "
              f"|x_hat - x| at pulse / A: max {rel_e.max():.1e}")
        assert a_c < 0.10 * a_o
        assert a_b < 0.10 * a_o
        assert a_0 > 0.9 * a_o           # the comparator loop works without noise
        assert a_o > 0.4
        assert ideal.mean() >= 0.99
        assert rel_e.max() <= 0.02
        assert rel_x.max() <= 1.02 * math.sin(2 * math.pi * 0.05)


@pytest.mark.xfail(strict=True, reason="one-sample pulses on a 20-samples-per-period grid: "
                   "|x| at the first sample after a crossing is up to sin(2 pi f0/fs) = 31 % "
                   "of the amplitude (mean ~15 %), whatever the observer")
def test_fig3_literal_pulse_position_within_2_percent():
    fo = SdResonatorDevice({"mode": "observer", "output_noise_std": 0.5}, seed=11).step(N)
    a = _amp(fo.position[HALF:])
    k = np.flatnonzero(fo.pulses)
    k = k[k > HALF]
    print(f"\nmax |x| at pulses / A = {np.max(np.abs(fo.position[k])) / a:.3f}")
    assert np.max(np.abs(fo.position[k])) <= 0.02 * a


@pytest.mark.parametrize("name,value", [("sample_rate_hz", 0.0), ("sample_rate_hz", -1.0),
                                        ("quality_factor", 0.0), ("quality_factor", -5.0),
                                        ("mode", "pll"), ("output_noise_std", -0.1)])
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


def test_specs_complete():
    names = {s.name for s in RESONATOR_SPECS}
    for n in ("sample_rate_hz", "f0_hz", "quality_factor", "pulse_amplitude", "output_noise_std",
              "state_noise_std", "mode", "f0_drift_ppm_per_s", "f0_step_fraction",
              "f0_step_time_s", "observer_f0_error", "observer_state_noise_std", "fast"):
        assert n in names
    for s in RESONATOR_SPECS:
        assert s.unit and s.source and s.description
    validate_params({s.name: s.default for s in RESONATOR_SPECS})


@pytest.mark.parametrize("params", [
    {"mode": "observer", "output_noise_std": 0.5, "state_noise_std": 1e-3,
     "observer_state_noise_std": 1e-3, "fast": False},
    {"mode": "observer", "output_noise_std": 0.5, "fast": True, "f0_drift_ppm_per_s": 50.0,
     "f0_step_fraction": 0.02, "f0_step_time_s": 0.003},
    {"mode": "comparator", "comparator_input": "bitstream", "output_noise_std": 0.3},
    {"mode": "comparator", "output_noise_std": 0.1, "state_noise_std": 1e-3},
])
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
    d = SdResonatorDevice({"f0_step_fraction": 0.02, "f0_step_time_s": 1e-3,
                           "f0_drift_ppm_per_s": 100.0}, seed=0)
    fr = d.step(2000)
    assert fr.f0[999] == pytest.approx(5e4 * (1 + 100e-6 * 999e-6))
    assert fr.f0[1000] == pytest.approx(5e4 * (1 + 100e-6 * 1e-3) * 1.02)

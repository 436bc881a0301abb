"""Manufacturing spread and temperature coefficients of parameter tables (draw_device)."""

import numpy as np
import pytest

from mems_sim.params import ParamSpec, Spread, TempCo, draw_device

K = ParamSpec("k", 3.0, "N/m", "stiffness", min=0.0, spread=Spread("uniform", 0.1))
D = ParamSpec("d", 1e-6, "m", "gap", min=0.0, spread=Spread("normal", 0.05))
F = ParamSpec("f", 1e3, "Hz", "resonance", min=1.0, tempco=TempCo(-30e-6))
B = ParamSpec("b", 0.5, "V", "bias", tempco=TempCo(2e-3, relative=False))
SPECS = (K, D, F, B)
NOMINAL = {s.name: s.default for s in SPECS}


def test_nominal_device_and_reference_temperature_change_nothing():
    assert draw_device(SPECS, NOMINAL) == NOMINAL
    assert draw_device(SPECS, NOMINAL, device_seed=-1) == NOMINAL


def test_draws_are_per_name_reproducible_and_within_the_spread():
    ks = np.array([draw_device(SPECS, NOMINAL, seed)["k"] for seed in range(2000)])
    assert ks.min() >= 2.7 and ks.max() <= 3.3  # uniform +-10 %
    assert ks.std() == pytest.approx(0.3 / np.sqrt(3), rel=0.05)  # uniform std w / sqrt(3)
    ds = np.array([draw_device(SPECS, NOMINAL, seed)["d"] for seed in range(2000)])
    assert ds.std() / 1e-6 == pytest.approx(0.05, rel=0.08)
    # the same seed draws the same device, whatever the table's order or other entries
    a = draw_device(SPECS, NOMINAL, 7)
    assert draw_device((D, K), {"k": 3.0, "d": 1e-6}, 7) == {"k": a["k"], "d": a["d"]}
    assert draw_device(SPECS, NOMINAL, 8)["k"] != a["k"]
    assert draw_device(SPECS, NOMINAL, 7, fixed=("k",))["k"] == 3.0  # a user's value stays


def test_temperature_coefficients_are_linear_around_the_reference():
    hot = draw_device(SPECS, NOMINAL, delta_k=12.8)
    assert hot["f"] == pytest.approx(1e3 * (1 - 30e-6 * 12.8), rel=1e-12)
    assert hot["b"] == pytest.approx(0.5 + 2e-3 * 12.8, rel=1e-12)
    assert hot["k"] == 3.0  # no coefficient: no drift

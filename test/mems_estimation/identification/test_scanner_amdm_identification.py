"""Ring-down fit, carrier stiffness and the parameter YAML of
mems_estimation.identification.scanner_amdm_identification."""

import math

import numpy as np
import pytest

from mems_estimation.identification import scanner_amdm_identification as sai
from mems_sim.devices import scanner_amdm as sa


def _line(wn, zeta, n=8000, fs=1.0e6, noise=0.0, seed=0):
    t = np.arange(n) / fs
    wd = wn * math.sqrt(1 - zeta * zeta)
    s = zeta * wn
    y = 0.3 + np.exp(-2 * s * t) * (0.05 * np.cos(2 * wd * t + 0.4) + 0.02)
    return y + np.random.default_rng(seed).standard_normal(n) * noise


def test_ringdown_fit_recovers_wn_and_zeta_of_the_2wd_line():
    wn, zeta = 2 * math.pi * 15.6e3, 0.0026
    fit = sai.ringdown_fit(_line(wn, zeta, noise=2e-3), 1.0e6, 31.1e3)
    assert fit["omega_n"] == pytest.approx(wn, rel=2e-5)
    assert fit["zeta"] == pytest.approx(zeta, rel=0.02)


def test_ringdown_fit_rejects_a_short_record():
    with pytest.raises(ValueError, match="too short"):
        sai.ringdown_fit(np.zeros(10), 1.0e6, 31e3)


def test_carrier_stiffness_is_kc_at_small_swing_and_falls_with_it():
    d = sa.resolve_amdm()
    kc = d["carrier_amplitude"] ** 2 * d["cap_c0"] / (2 * d["cap_theta0"] ** 2)
    assert float(sai.carrier_stiffness(1e-6, d)) == pytest.approx(kc, rel=1e-9)
    big = sai.carrier_stiffness(np.array([0.1, 0.3]), d)
    assert kc > big[0] > big[1] > 0


def test_identify_on_the_emulated_nominal_device():
    """Two ring-downs of the nominal core: w_n within 1e-5 and zeta within 5 %."""
    from mems_estimation.studies import scanner_amdm_bench as b

    p = sa.resolve_amdm()
    ys, fs, _ = b.ringdown(p, b.RELEASE_ANGLES[0], 3)
    yl, _, a = b.ringdown(p, b.RELEASE_ANGLES[1], 4)
    m = sai.identify(ys, yl, fs, b.design(), (26e3, 36e3), a)
    wn = math.sqrt(p["spring_constant"] / p["inertia"])
    zeta = p["damping"] / (2 * math.sqrt(p["inertia"] * p["spring_constant"]))
    assert m["omega_n"] == pytest.approx(wn, rel=1e-5)
    assert m["zeta"] == pytest.approx(zeta, rel=0.05)
    assert m["spring_constant"] == pytest.approx(p["inertia"] * m["omega_n"] ** 2)


def test_yaml_round_trip_and_rejections(tmp_path):
    model = dict(inertia=1.15e-14, spring_constant=1.1e-4, damping=5.9e-12, omega_n=9.78e4)
    path = tmp_path / "m.yaml"
    sai.save_identification(model, str(path))
    assert sai.load_identification(str(path)) == {k: model[k] for k in sai.MODEL_KEYS}
    path.write_text("inertia: 1.0e-14\n")
    with pytest.raises(ValueError, match="lacks"):
        sai.load_identification(str(path))
    path.write_text("inertia: 1.0e-14\nspring_constant: -1.0\ndamping: 1.0e-12\n")
    with pytest.raises(ValueError, match="not > 0"):
        sai.load_identification(str(path))

"""In-situ correction of the stage model from the capacitive channels (stage_insitu)."""

import copy
import math

import numpy as np
import pytest

from mems_estimation.filters.stage_ekf import StageModel, oracle_model
from mems_estimation.identification.stage_identification import cancelled
from mems_estimation.identification.stage_insitu import (
    correct_model,
    insitu_correct,
    model_response,
)
from mems_sim.devices.stage import DriveSchedule, MicroStage, record


def test_correct_model_round_trip():
    """The model whose response at f equals G has the wn and b_c that produced G."""
    fs, f = 625e3, 1700.0
    wn, zeta, bc = 2 * math.pi * 1714.5, 0.005, 3782.5
    G = model_response(wn * (1 - 4e-4), zeta, bc * 1.0128, f, fs)
    m0 = StageModel(wn, zeta, bc, fs, np.ones(4), np.ones(4), np.ones((4, 4)), np.eye(4), 1.0)
    m = correct_model(m0, G, f)
    assert m.wn / (wn * (1 - 4e-4)) - 1 == pytest.approx(0, abs=1e-9)
    assert m.b_c / (bc * 1.0128) - 1 == pytest.approx(0, abs=1e-9)


def test_insitu_recovers_drifted_stage_noise_free():
    """Noise-free drifting stage at 35.7 C, model of 22.9 C with the true sensor
    parameters: the channels alone give the response at the drive frequency within 2e-5
    and the corrected model's wn within 1e-6, b_c within 1e-4."""
    p = {"readout_noise_scale": 0.0, "drive_noise_density": 0.0}
    cold = MicroStage(dict(p, temperature_c=22.9))
    stage = MicroStage(
        dict(p, temperature_c=35.7), DriveSchedule.amplitude_sweep(n_trials=3, periods=600), seed=3
    )
    rec = record(stage)
    model = oracle_model(cold, 1e-8)
    model.gap = np.full(4, stage.gap)  # sensor parameters of the temperature of use
    model.eta = stage.eta_true.copy()
    m, rep = insitu_correct(
        model, cancelled(rec), rec["u"], rec["phase"], rec["segment"], rec["f_drive"]
    )
    G_true = model_response(stage.wn, stage.zeta, stage.b_c, 1700.0, stage.fs)
    assert abs(rep["G"] / G_true - 1) < 2e-5
    assert np.max(np.abs(rep["scatter"])) < 1e-4
    # zeta is kept (the cold model's = the drifting stage's here): wn and b_c recovered
    assert m.wn / stage.wn - 1 == pytest.approx(0, abs=1e-6)
    assert m.b_c / stage.b_c - 1 == pytest.approx(0, abs=1e-4)
    # the uncorrected model is off by the drift (> 1 %)
    assert abs(model_response(cold.wn, cold.zeta, cold.b_c, 1700.0, stage.fs) / G_true - 1) > 1e-2
    c = copy.deepcopy(model)
    assert c.wn == cold.wn  # the input model is not modified


# --- scale-factor curve SF(T) (stage_sf_curve) ---------------------------------------


def test_sensor_bootstrap_table_matches_identification():
    """The tabulated re-identification (eq. 55) equals identify_sensor on the full trials and
    on a resample within 5e-5 (D_n) / 1e-4 (eta)."""
    from mems_estimation.identification.stage_identification import identify_sensor, trial_fits
    from mems_estimation.studies.stage_sf_curve import SensorBootstrap

    stage = MicroStage(
        {"temperature_c": 30.0}, DriveSchedule.amplitude_sweep(n_trials=4, periods=120), seed=11
    )
    rec = record(stage)
    fits = trial_fits(cancelled(rec), rec["ldv"], rec["phase"], rec["segment"], rec["f_drive"], 0.0)
    limits = stage.design_limits
    gaps, etas, _ = identify_sensor(fits, limits)
    sb = SensorBootstrap(fits, limits, gaps)
    for counts in (np.ones(4), np.array([2, 0, 1, 1])):
        g, e = sb.identify(counts)
        sub = [f for f, c in zip(fits, counts) for _ in range(int(c))]
        g0, e0, _ = identify_sensor(sub, limits)
        assert np.max(np.abs(g / g0 - 1)) < 5e-5
        assert np.max(np.abs(e / e0 - 1)) < 1e-4


def test_sf_curve_fit_band_covers_on_synthetic_points():
    """Linear SF(T) through 6 points with known scatter, bootstrap replicates of that
    scatter: the 95 % band holds the truth at ~95 % of temperatures over 300 draws."""
    from mems_estimation.studies.stage_sf_curve import fit_sf_curve

    rng = np.random.default_rng(0)
    T = np.arange(20.0, 46.0, 5.0)
    truth = 1.0 * (1 - 0.0543 / 12.8 * (T - 22.9))
    tg = np.linspace(20, 45, 26)
    tg_true = 1.0 * (1 - 0.0543 / 12.8 * (tg - 22.9))
    inside = []
    for _ in range(300):
        sd = 2e-4
        y = truth + rng.normal(0, sd, T.size)
        boot = y + rng.normal(0, sd, (100, T.size))
        c = fit_sf_curve(T, y, boot)
        lo, hi = c.band(tg)
        inside.append((tg_true >= lo) & (tg_true <= hi))
        assert c.birge >= 1.0
    cover = float(np.mean(inside))
    assert 0.93 <= cover <= 0.995
    assert c.sf_tempco == pytest.approx(c.coef[1] / c.coef[0])


def test_sf_curve_yaml_round_trip(tmp_path):
    """The calibration YAML (format mems_emulator/gyro_sf_curve) loads back to the same curve,
    band and correction; a file of another format is refused."""
    from mems_estimation.studies.stage_sf_curve import fit_sf_curve, load_yaml, save_yaml

    T = np.arange(20.0, 46.0, 5.0)
    y = 1 - 4e-3 * (T - 22.9)
    boot = y + np.random.default_rng(1).normal(0, 1e-4, (50, T.size))
    c = fit_sf_curve(T, y, boot)
    p = tmp_path / "sf.yaml"
    save_yaml(c, p, info={"seed": 3})
    d = load_yaml(p)
    tg = np.array([21.0, 33.3, 44.0])
    assert np.allclose(d(tg), c(tg), rtol=0, atol=1e-15)
    assert np.allclose(d.band(tg), c.band(tg), rtol=1e-12)
    assert d.correct(2.0, 30.0) == pytest.approx(2.0 / c(30.0))
    assert d.valid_range_c == (20.0, 45.0)
    (tmp_path / "bad.yaml").write_text("format: other\n")
    with pytest.raises(ValueError, match="format"):
        load_yaml(tmp_path / "bad.yaml")

"""In-situ correction of the stage model from the capacitive channels (stage_insitu)."""

import copy
import math

import numpy as np
import pytest

from mems_estimation.filters.stage_ekf import StageModel
from mems_estimation.identification.stage_identification import cancelled
from mems_estimation.identification.stage_insitu import (
    correct_model,
    insitu_correct,
    model_response,
)
from mems_sim.devices.stage import DriveSchedule, MicroStage, record


def _true_model(stage: MicroStage) -> StageModel:
    return StageModel(
        stage.wn,
        stage.zeta,
        stage.b_c,
        stage.fs,
        stage.eta_true.copy(),
        np.full(4, stage.gap),
        stage.limits.copy(),
        np.eye(4) * 1e-8,
        1e-6,
    )


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
    model = _true_model(cold)
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

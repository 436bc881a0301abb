"""``identify_noise --model``: the default (and ``--model gm``) prints exactly what it
printed before the option existed; ``auto`` and ``flicker`` add the model-choice table and a
``model_choice`` JSON list, nothing else changes (bags/imu.mcap, in-process runs)."""

from __future__ import annotations

import json
import math

from identify_noise_helpers import IMU_BAG, run_identify_noise

BAG = IMU_BAG


_run = run_identify_noise


def test_default_gm_and_auto_outputs():
    code, default_json, default_table = _run([BAG, "--json"])
    assert code == 0
    assert _run([BAG, "--json", "--model", "gm"])[1:] == (default_json, default_table)
    code, auto_json, auto_table = _run([BAG, "--json", "--model", "auto"])
    assert code == 0
    assert auto_table.startswith(default_table) and "noise model choice by BIC" in auto_table
    assert "noise model choice" not in default_table
    auto = json.loads(auto_json)
    choices = auto.pop("model_choice")
    assert auto == json.loads(default_json)
    assert [c["axis"] for c in choices] == [a["axis"] for a in auto["axes"]]
    for c in choices:
        bic = c["bic"]
        assert c["model"] == c["chosen_by_criterion"] == min(bic, key=lambda m: (bic[m], m))
        assert set(c["parameters"]) == ({"N", "B", "K"} | ({"T"} if c["model"] == "gm" else set()))
        lo, hi = c["parameters"]["N"]["ci95"]
        assert lo <= c["parameters"]["N"]["value"] <= hi and math.isfinite(hi)


def test_forced_flicker_reports_flicker_everywhere():
    code, out, _ = _run([BAG, "--json", "--model", "flicker"])
    assert code == 0
    choices = json.loads(out)["model_choice"]
    assert {c["model"] for c in choices} == {"flicker"}
    assert all("T" not in c["parameters"] for c in choices)

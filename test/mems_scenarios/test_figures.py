"""Figure records (ROS-free): the JSON form of ``run_scenario --json`` (design: a list of
``{"name", "value", "unit", "target", "pass", "source", "role"}``), values that are not
finite, where a target comes from, table flags."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mems_scenarios.figures import (
    NOT_FINITE,
    Figure,
    cell,
    figure_table,
    met_cell,
    project_criterion,
    to_json,
    valid_source,
)

KEYS = {"name", "value", "unit", "target", "pass", "source", "role"}
#: A source for the targets of these tests.
OURS = project_criterion("a test's")


def test_json_form_is_a_list_of_seven_key_records():
    figs = [
        Figure("ukf.phase_rmse", 0.132, "deg", "<= 0.18 deg", True, "Chen 2018 eqs. 78-79"),
        Figure("ekf.nees", 74.66, "1", "0.8-1.2", False, OURS),
        Figure("pulse.count", 35000, ""),
        Figure("check.qr_sweep_direction", "yes", "", "yes", True, "Zhang 2010 Table IV"),
    ]
    out = json.loads(to_json(figs))
    assert isinstance(out, list) and len(out) == 4
    assert all(set(r) == KEYS for r in out)
    assert out[0] == {
        "name": "ukf.phase_rmse",
        "value": 0.132,
        "unit": "deg",
        "target": "<= 0.18 deg",
        "pass": True,
        "source": "Chen 2018 eqs. 78-79",
        "role": "headline",
    }
    assert out[1]["pass"] is False and out[1]["source"] == OURS
    assert out[2]["target"] is None and out[2]["pass"] is None and out[2]["value"] == 35000
    assert out[2]["source"] is None and out[2]["role"] == "context"
    assert out[3]["value"] == "yes"


def test_numpy_scalars_become_plain_json_numbers():
    figs = [
        Figure("a", np.float64(1.5), "m"),
        Figure("b", np.int64(7), ""),
        Figure("c", np.float32(0.25), "1", "< 1", bool(np.float32(0.25) < 1), OURS),
        Figure("d", True, ""),
    ]
    out = json.loads(to_json(figs))
    assert [r["value"] for r in out] == [1.5, 7, 0.25, True]
    assert isinstance(out[1]["value"], int)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, np.float64("nan"), None])
def test_value_not_finite_is_null_and_fails_a_target(bad):
    with_target = Figure("x", bad, "m", "<= 1 m", True, OURS)  # passed claimed, value unusable
    without = Figure("y", bad, "m")
    text = to_json([with_target, without])
    assert "nan" not in text.lower() and "infinity" not in text.lower()
    out = json.loads(text)
    assert out[0]["value"] is None and out[0]["pass"] is False
    assert out[1]["value"] is None and out[1]["pass"] is None
    assert with_target.met is False and without.met is None


def test_target_and_verdict_go_together_and_names_are_unique():
    with pytest.raises(ValueError, match="target"):
        Figure("x", 1.0, "m", "<= 1 m", source=OURS)  # a target without a verdict
    with pytest.raises(ValueError, match="target"):
        Figure("x", 1.0, "m", None, True)  # a verdict without a target
    with pytest.raises(ValueError, match="more than once: a"):
        to_json([Figure("a", 1, ""), Figure("a", 2, "")])


def test_a_target_names_its_source():
    with pytest.raises(ValueError, match="needs a source"):
        Figure("x", 1.0, "m", "<= 1 m", True)
    with pytest.raises(ValueError, match="a source a target"):
        Figure("x", 1.0, "m", source=OURS)
    for bad in ("", "the thesis", "Chen 2018", "Chen 2018 somewhere", "this project's criterion: "):
        assert not valid_source(bad), bad
        with pytest.raises(ValueError, match="neither a paper"):
            Figure("x", 1.0, "m", "<= 1 m", True, bad)
    for good in (
        "Chen 2018 Table 5.3: 0.63 deg",
        "Zhang 2010 Table III",
        "Colinet et al. Sec. 6: exact model",
        "Petkov & Slavov eq. 9",
        project_criterion("why"),
    ):
        assert valid_source(good), good
    judged = Figure("x", 1.0, "m", "<= 1 m", True, OURS)
    assert judged.role == "headline" and Figure("y", 1.0, "m").role == "context"


def test_cells_never_print_nan():
    assert cell(0.12345, ".3f") == "0.123"
    assert cell(12.5, ".1f", " %") == "12.5 %"
    for bad in (math.nan, math.inf, None, np.float64("nan")):
        assert cell(bad, ".3f") == NOT_FINITE
    assert cell("text") == "text" and cell(True) == "True"


def test_met_cell_flags_every_miss():
    ok = Figure("a", 1.0, "1", "<= 2", True, OURS)
    missed = Figure("b", 3.0, "1", "<= 2", False, OURS)
    not_finite = Figure("c", math.nan, "1", "<= 2", True, OURS)
    plain = Figure("d", 5.0, "1")
    assert met_cell(ok) == "yes"
    assert met_cell(missed) == "NO"
    assert met_cell(not_finite) == "NO"
    assert met_cell(plain) == "-"  # "-" only where no target applies
    assert met_cell(ok, plain) == "yes"
    assert met_cell(ok, missed) == "NO"


def test_figure_table_rows():
    text = figure_table(
        [
            Figure("ekf.nees", 74.66, "1", "0.8-1.2", False, "Zhang 2010 Table II"),
            Figure("ekf.theta_rmse", 0.035, "deg"),
            Figure("pulse.x_rel_max", math.nan, "1", "<= 0.02", True, "Zhang 2010 Table I"),
        ]
    )
    lines = text.splitlines()
    assert lines[0].split() == ["figure", "value", "unit", "target", "source", "met"]
    assert lines[2].split() == [
        "ekf.nees",
        "74.66",
        "1",
        "0.8-1.2",
        *"Zhang 2010 Table II NO".split(),
    ]
    assert lines[3].split() == ["ekf.theta_rmse", "0.035", "deg", "-", "-", "-"]
    assert lines[4].split()[-1] == "NO" and NOT_FINITE in lines[4]
    assert "nan" not in text


def test_result_json_carries_its_schema():
    from mems_scenarios.figures import JSON_SCHEMA_VERSION, figures_of, result_json

    figs = [Figure("a.b", 1.5, "m", "<= 2 m", True, OURS)]
    doc = json.loads(result_json("imu_noise", figs, [("c.*", "no /c")], ["d.*"]))
    assert doc["schema_version"] == JSON_SCHEMA_VERSION == 2 and doc["scenario"] == "imu_noise"
    assert figures_of(doc) == json.loads(to_json(figs)) == figures_of(doc["figures"])
    assert doc["unavailable"] == [{"figures": "c.*", "reason": "no /c"}]
    assert doc["oracle_only"] == ["d.*"]
    with pytest.raises(ValueError, match="schema"):
        figures_of(dict(doc, schema_version=1))  # the records of schema 1 had no source

"""End-to-end: scenario scanner_threshold through the node graph, figures from its MCAP (Chen 2018,
chapter 4)."""

import math

import pytest
from figure_checks import assert_figures

from mems_scenarios import scanner_threshold
from mems_scenarios.base import ScenarioError, ScenarioOptions


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    from conftest import next_domain_id

    out = tmp_path_factory.mktemp("scanner") / "scanner_threshold-0.mcap"
    return scanner_threshold.run(
        ScenarioOptions(seed=0, out=out, domain_id=next_domain_id(), progress=False)
    )


def test_recording_complete(result):
    counts = result["recorder"]["counts"]
    for topic in ("adc", "drive", "truth", "psd", "threshold_detections"):
        assert counts[f"/scanner/{topic}"] == result["published"]
    assert counts["/scanner/estimate"] == result["published"] + 1  # + the final flush
    assert all(g == 0 for g in result["recorder"]["gaps"].values())
    for png in result["figure_paths"]:
        assert png.stat().st_size > 20_000


def test_table_4_3_hybrid_better_everywhere(result):
    f = result["values"]
    print("\n" + result["table"])
    snrs = [s for _, _, s in f["segments"]]
    assert 60 < snrs[0] < 120 and 15 < snrs[1] < 35 and 3 < snrs[2] < 8 and 0.5 < snrs[3] < 2
    assert all(h < p for h, p in zip(f["rmse_hyb"], f["rmse_ekf"]))
    assert f["reduction"][-1] >= 0.10  # paper 15.1 %
    # RMSE over the 50 samples after each detection (Table 4.3 lower half), overall
    assert f["rmse_th_hyb"][-1] < f["rmse_th_ekf"][-1]


def test_detection_study(result):
    f = result["values"]
    assert f["online_offline_same"] and f["latency"] == 300
    assert all(k[3] > 0.05 for k in f["ks"])  # normal at every tested SNR
    sw = f["sigma_sweep"]
    for i in (2, 3):  # SNR ~5 and ~1
        assert sw[45.0]["var"][i] < sw[15.0]["var"][i]
    rates = sorted({fs for (_, fs) in f["fs_study"]})
    assert all(not math.isnan(f["fs_study"][(1.0, r)][0]) for r in rates)


def test_filters_positive_definite(result):
    f = result["values"]
    assert f["min_var_hyb"] > 0 and f["min_var_ekf"] > 0
    assert f["max_var_theta_hyb"] <= 0.04 + 1e-12 and f["max_var_theta_ekf"] <= 0.04 + 1e-12


def test_bad_duration_refused():
    with pytest.raises(ScenarioError, match="duration"):
        scanner_threshold.run(ScenarioOptions(duration_s=0.1))


def test_figures_as_data(result):
    figs = assert_figures(result)
    assert all(r["pass"] is None for r in figs.values())  # beside the paper, not judged
    f = result["values"]
    assert figs["overall.hyb.theta_rmse"]["value"] == f["rmse_hyb"][-1]
    assert figs["seg1.snr"]["value"] == f["segments"][0][2]
    assert figs["detector.latency"]["value"] == f["latency"]

"""End-to-end: scenario scanner_shared_electrodes through the node graph, figures from its MCAP
(Chen 2018 ch. 5: Table 5.3 form, consistency, off-resonance low signal)."""

import pytest
from figure_checks import assert_figures, met_of, verdict

from mems_scenarios import scanner_amdm_shared_electrodes as sse
from mems_scenarios.base import ScenarioOptions


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    from conftest import next_domain_id

    out = tmp_path_factory.mktemp("sse") / "scanner_shared_electrodes-2.mcap"
    return sse.run(ScenarioOptions(seed=2, out=out, domain_id=next_domain_id(), progress=False))


def test_recording_complete_and_figures(result):
    counts = result["recorder"]["counts"]
    for ns, n in result["published"].items():
        for topic in ("adc", "drive", "truth", "ekf/estimate", "ukf/estimate"):
            assert counts[f"/{ns}/{topic}"] == n
    assert all(g == 0 for g in result["recorder"]["gaps"].values())
    for p in result["figure_paths"]:
        assert p.stat().st_size > 20_000


def test_table_5_3_ukf_phase_and_amplitude(result):
    f = result["values"]
    print("\n" + result["table"])
    assert f["ukf_pairs"] > 500
    assert f["ukf_phase_deg"] <= 0.39  # Table 5.3 (paper's UKF)
    assert f["ukf_phase_deg"] <= 0.18  # target of eq. (79)
    assert f["ukf_amp_deg"] <= 0.63  # Table 5.3 (paper's UKF)


def test_filters_keep_a_positive_definite_bounded_covariance(result):
    f = result["values"]
    for k in ("ekf", "ukf"):
        assert f[f"{k}_pd_failures"] == 0 and f[f"{k}_min_var"] > 0
        assert f[f"{k}_max_var_theta_eval"] < 1e-4  # no blow-up after acquisition
        assert f[f"{k}_acquisitions"] == 1


def test_off_resonance_reports_low_signal(result):
    f = result["values"]
    assert f["off_final_amplitude"] < 1e-3
    assert f["off_low_signal_warned"] and not f["off_tracking"]
    assert f["off_events"] == 0 and f["off_finite"] and f["off_pd_failures"] == 0


@pytest.mark.xfail(
    strict=True,
    reason=(
        "target: the UKF beats the EKF on amplitude and phase RMSE (Chen 2018 Table 5.3); measured (seed 2) "
        "UKF/EKF = 1.000 on both (~0.05 deg amplitude, ~0.13 deg phase): at R = 1.92e-4 V^2 and "
        "1 MHz the posterior std of theta (~1e-4 rad) is tiny against the 0.2 rad scale of the "
        "Gaussian C_s, so linearisation costs the EKF nothing; both are limited by the AMDM "
        "chain's unmodelled distortion (phase bias ~-0.13 deg)"
    ),
)
def test_ukf_beats_ekf(result):
    assert result["values"]["ukf_beats_ekf"]


def test_figures_as_data_and_every_miss_flagged(result):
    figs = assert_figures(result)
    table = result["table"]
    for k in ("EKF", "UKF"):
        nees = figs[f"{k.lower()}.nees"]
        assert nees["target"] == "0.5-2" and nees["unit"] == "1"
        assert met_of(table, f"{k} theta RMSE") == verdict(nees)  # never "-" for a miss
        assert met_of(table, f"{k} RMSE amplitude") == verdict(figs[f"{k.lower()}.amplitude_rmse"])
    assert figs["ukf.phase_rmse_target"]["target"] == "<= 0.18 deg"

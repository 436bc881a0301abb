"""End-to-end: scenario scanner_shared_electrodes through the node graph, figures from its MCAP
(Chen 2018 ch. 5: Table 5.3 form, consistency, off-resonance low signal, acquisition from a
wrong start).  One seeded run (seed 2) is the quick check of the restated criteria; the
campaign over seeds runs in the acceptance tier."""

import pytest
from figure_checks import assert_figures, met_of, verdict

from mems_scenarios import scanner_shared_electrodes as sse
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


def test_table_5_3_phase_and_amplitude_of_both_filters(result):
    f = result["values"]
    print("\n" + result["table"])
    for k in ("ekf", "ukf"):
        assert f[f"{k}_pairs"] > 500
        assert f[f"{k}_phase_deg"] <= 0.18  # target of eq. (79)
        assert f[f"{k}_amp_deg"] <= 0.63  # Table 5.3 (the thesis's UKF)


def test_both_filters_consistent_on_the_full_chain(result):
    """NEES of theta within 0.5-2 (Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4) with the
    chain's identified square-law curve in h and the calibrated process-noise inflation."""
    f = result["values"]
    for k in ("ekf", "ukf"):
        assert 0.5 <= f[f"{k}_nees"] <= 2.0, (k, f[f"{k}_nees"])
        assert abs(f[f"{k}_phase_bias_deg"]) < 0.03  # was -0.13 deg with eq. (104) alone


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


def test_ukf_and_ekf_agree_within_one_percent(result):
    """Restated criterion (the thesis's Table 5.3 has the UKF 3-8x better): UKF/EKF RMSE ratio
    within +-1 % on the nominal device.  Measured over seeds 1-10: 1.0002 on amplitude,
    1.0000 on phase.  At R = 1.92e-4 V^2 and 1 MHz the posterior std of theta is ~8e-5 rad,
    tiny against the 0.2 rad scale of the Gaussian C_s: the unscented transform (Julier &
    Uhlmann 2004) and the linearisation see the same h, so the thesis's gap is not a
    linearisation effect.  They differ only while acquiring from a wrong start
    (:func:`test_stress_acquisition_reported_for_both_filters`)."""
    f = result["values"]
    assert f["ukf_ekf_within_1pct"]
    for q in ("amp", "phase"):
        assert abs(f[f"ukf_{q}_deg"] / f[f"ekf_{q}_deg"] - 1.0) <= 0.01


def test_stress_acquisition_reported_for_both_filters(result):
    """Started 0.25 theta_0 (0.05 rad) and 0.1 rad off at four phases, too large and too small:
    both filters acquire within a few motion periods; times reported as figures."""
    figs = {r.name: r for r in result["figures"]}
    for case in ("stress", "acquire_0p1rad"):
        for k in ("ekf", "ukf"):
            assert figs[f"{case}.{k}.initial_error"].value >= 0.25 * 0.2
            assert figs[f"{case}.{k}.acquired"].met
            assert 0 <= figs[f"{case}.{k}.acquire_time_max"].value < 500.0  # us


def test_figures_as_data_and_every_miss_flagged(result):
    figs = assert_figures(result)
    table = result["table"]
    for k in ("EKF", "UKF"):
        nees = figs[f"{k.lower()}.nees"]
        assert nees["target"] == "0.5-2" and nees["unit"] == "1"
        assert met_of(table, f"{k} theta RMSE") == verdict(nees)  # never "-" for a miss
        assert met_of(table, f"{k} RMSE amplitude") == verdict(figs[f"{k.lower()}.amplitude_rmse"])
    for k in ("ekf", "ukf"):
        assert figs[f"{k}.phase_rmse"]["target"] == "<= 0.18 deg"
        assert figs[f"{k}.amplitude_rmse"]["target"] == "<= 0.63 deg"
    assert figs["ukf_ekf.amplitude_rmse_ratio"]["target"] == "0.99-1.01"
    assert figs["stress.ukf.acquired"]["target"] == "== 1"


def test_oracle_delay_is_the_one_the_estimators_ran_with(result):
    """The oracle step (the AMDM chain's delay of each device as built, from the run
    record) gives the delay the run handed its estimators (their recorded
    ``chain_delay_s``, taken from the built devices), and the end state of the estimators
    comes from the recorded /diagnostics."""
    from mems_scenarios.contract import read_run_info

    record = read_run_info(result["mcap"])
    delays = sse.oracle(record)
    estimators = {
        fqn: n["parameters"]
        for fqn, n in record["nodes"].items()
        if n["executable"] == "scanner_amdm_estimator_node"
    }
    assert set(delays) == {p["device_namespace"].lstrip("/") for p in estimators.values()}
    assert len(estimators) == 3  # the device's, the off device's and the oracle filters
    for p in estimators.values():
        assert p["chain_delay_s"] == delays[p["device_namespace"].lstrip("/")] > 0
    assert result["result"].oracle_only == [sse.ORACLE] and not result["result"].unavailable


def test_filters_run_the_bench_model_and_the_oracle_the_device_table(result):
    """The estimators load the bench's YAML (the ring-downs' w_n and zeta, the comb's map),
    the oracle filters the device's own table; the bench's errors against the device as
    built are small, and the identified filters' NEES holds with their inflation."""
    import yaml

    from mems_scenarios.contract import read_run_info

    record = read_run_info(result["mcap"])
    est = record["nodes"]["/scanner_amdm/estimator/scanner_amdm_estimator"]["parameters"]
    orc = record["nodes"]["/scanner_amdm/oracle/scanner_amdm_estimator"]["parameters"]
    bench = yaml.safe_load(open(est["params_yaml"]))
    table = yaml.safe_load(open(orc["params_yaml"]))
    for k in ("spring_constant", "damping", "cap_c0", "cap_theta0"):
        assert est[k] == bench[k] and orc[k] == table[k]
    assert est["process_noise_inflation"] > orc["process_noise_inflation"]
    figs = {r.name: r for r in result["figures"]}
    assert abs(figs["device.identified_omega_n_error"].value) < 1e-5
    assert abs(figs["device.identified_zeta_error"].value) < 2e-3
    for k in ("cap_c0", "cap_theta0"):
        assert abs(figs[f"device.identified_{k}_error"].value) < 5e-3
    for k in ("ekf", "ukf"):
        assert figs[f"{k}.nees"].met
        assert figs[f"oracle.{k}.phase_rmse"].value > 0
        ratio = figs[f"identified_vs_oracle.{k}.phase_rmse_ratio"]
        assert ratio.target is None and ratio.value > 0  # context (docs/scanner.md)

"""End-to-end: scenario accelerometer_snr through the node graph, figures from its MCAP
(Zhang 2010, Tables III and IV)."""

import pytest
from figure_checks import assert_figures

from mems_scenarios import accelerometer_snr as sc
from mems_scenarios.base import ScenarioOptions


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    from conftest import next_domain_id

    out = tmp_path_factory.mktemp("acc") / "accelerometer_snr-2.mcap"
    return sc.run(ScenarioOptions(seed=2, out=out, domain_id=next_domain_id(), progress=False))


def _check(result, prefix):
    found = [c for c in result["values"]["checks"] if c[0].startswith(prefix)]
    assert found, prefix
    return found


def test_recording_complete(result):
    counts = result["recorder"]["counts"]
    for ns, n in result["published"].items():
        for topic in ("adc", "drive", "truth"):
            assert counts[f"/{ns}/{topic}"] == n == 12
    assert counts["/acc_pi_1g/hybrid_ekf/estimate"] == 12
    assert all(g == 0 for g in result["recorder"]["gaps"].values())
    assert result["figure"].stat().st_size > 20_000


def test_table_iii(result):
    print("\n" + result["table"])
    dev = result["values"]["devices"]
    assert not dev["acc_open_0g1"]["contact"] and not dev["acc_open_1g"]["contact"]
    assert dev["acc_open_15g"]["contact"]  # above the open loop's pull-in
    for m in ("pi", "ekf"):
        assert not dev[f"acc_{m}_10g"]["contact"] and not dev[f"acc_{m}_10g"]["saturated"]
        for a in ("0g1", "1g", "10g"):
            assert dev[f"acc_{m}_{a}"]["x_max"] * 10 <= dev[f"acc_open_{a}"]["x_max"]
    for a in ("0g1", "1g"):
        assert dev[f"acc_ekf_{a}"]["snr"] >= dev[f"acc_pi_{a}"]["snr"] + 6.0
        assert dev[f"acc_ekf_{a}"]["x_max"] <= 1.1 * dev[f"acc_pi_{a}"]["x_max"]


def test_table_iv_and_consistency(result):
    for item in (
        "Q/R sweep",
        "covariance positive definite",
        "in-loop EKF, 1 g",
        "downstream EKF on the PI loop",
    ):
        for c in _check(result, item):
            assert c[4], c


@pytest.mark.xfail(
    strict=True,
    reason=(
        "target: the open loop fails at 5 g (Zhang 2010 Table III); with Table I and the "
        "carrier force (2-12) the static pull-in is at 12.2 g and the 10 Hz, 5 g input is tracked "
        "(max |x| 1.8e-7 m, no contact); the thesis' 7e-8 m at 1 g implies a softer loop"
    ),
)
def test_open_loop_fails_at_5g(result):
    assert result["values"]["devices"]["acc_open_5g"]["contact"]


def test_figures_as_data_and_every_miss_flagged(result):
    figs = assert_figures(result)
    checks = [r for name, r in figs.items() if name.startswith("check.")]
    items = result["values"]["checks"]
    assert len(checks) == len(items)
    assert [r["pass"] for r in checks] == [bool(c[4]) for c in items]
    assert figs["acc_open_1g.output_snr"]["unit"] == "dB"
    assert figs["acc_qr_qx10.not_pd_samples"]["target"] == "== 0"

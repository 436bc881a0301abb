"""``run_scenario --faults``: a fault schedule on the scenario's emulators, recorded."""

import json

import pytest

from mems_scenarios.cli import main as run_scenario
from mems_sim.bag.player import read_messages

SCHEDULE = """\
faults:
  - kind: bias_step
    channel: gyro_z
    start_s: 1.0
    magnitude: 0.01
"""


@pytest.fixture
def schedule(tmp_path):
    path = tmp_path / "faults.yaml"
    path.write_text(SCHEDULE)
    return path


def test_faults_reach_the_launch_file_with_the_other_overrides(tmp_path, schedule):
    launch = tmp_path / "g.yaml"
    argv = ["imu_noise", "--duration", "3", "--faults", str(schedule), "--set", "imu.seed=5"]
    assert run_scenario(argv + ["--device-seed", "3", "--write-launch", str(launch)]) == 0
    text = launch.read_text()
    header = text.splitlines()[1]
    assert header.startswith("# Recorded topics:") and header.endswith(", /imu/faults"), header
    import yaml

    nodes = {e["node"]["exec"]: e["node"] for e in yaml.safe_load(text)["launch"]}
    params = {p["name"]: p["value"] for p in nodes["imu_node"]["param"]}
    # the launch file runs what the run record says: --set, --device-seed and --faults
    assert params["seed"] == 5 and params["device_seed"] == 3
    assert params["fault_schedule"] == str(schedule.resolve())
    assert "fault_schedule" not in {p["name"] for p in nodes["imu_noise_identifier_node"]["param"]}
    record = json.loads((tmp_path / "g.run_record.json").read_text())
    assert record["nodes"]["/imu/imu"]["parameters"]["fault_schedule"] == str(schedule.resolve())
    assert (
        f"/imu/imu.fault_schedule='{schedule.resolve()}' (--faults)"
        in (record["options"]["overrides"])
    )


@pytest.mark.parametrize(
    "faults, expected",
    [
        ("{missing}", "is not a file"),
        ("imu_noise_identifier={schedule}", "no emulator of scenario imu_noise takes it"),
        ("={schedule}", "expected [NODE=]FILE"),
        ("imu=", "expected [NODE=]FILE"),
    ],
)
def test_a_bad_faults_option_is_one_line(tmp_path, schedule, capsys, faults, expected):
    text = faults.format(missing=tmp_path / "none.yaml", schedule=schedule)
    argv = ["imu_noise", "--faults", text, "--write-launch", str(tmp_path / "g.yaml")]
    assert run_scenario(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("run_scenario: error: --faults") and expected in err, err
    assert err.count("\n") == 1 and not (tmp_path / "g.yaml").exists()


def test_a_kind_the_scenarios_emulators_lack_is_refused_in_one_line(tmp_path, schedule, capsys):
    """The sigma-delta resonators take the timing kinds only: a bias step is refused before
    anything is recorded."""
    argv = ["sd_resonator", "--faults", str(schedule), "--out", str(tmp_path / "r.mcap")]
    assert run_scenario(argv) == 2
    err = capsys.readouterr().err
    assert "'bias_step' is not a fault of this device (one of: dropped_samples)" in err, err
    assert err.count("\n") == 1 and not (tmp_path / "r.mcap").exists()


def test_dropped_samples_are_device_gaps_and_the_analysis_says_why_it_stops(
    tmp_path, domain_id, capsys
):
    """Dropped samples on every resonator of sd_resonator: the run succeeds, the recording
    is complete (device gaps, no loss, also on the estimates under each device), and the
    figures are refused in one line because the analysis aligns whole streams; --analyse of
    that recording exits 2 with the same line."""
    from mems_sim.bag import info as info_mod

    drop = tmp_path / "drop.yaml"
    drop.write_text(
        "faults:\n  - {kind: dropped_samples, start_sample: 20000, duration_samples: 5000}\n"
    )
    out = tmp_path / "run.mcap"
    argv = ["sd_resonator", "--duration", "0.2", "--faults", str(drop), "--out", str(out)]
    assert run_scenario(argv + ["--domain-id", str(domain_id), "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "device gap: /sd_step/tracking/estimate: 1 device gaps (5000 samples" in text
    assert "figures not computed:" in text and "frame-index gaps: none" in text
    info = info_mod.bag_info(str(out))
    assert info_mod.losses(info) == []
    assert info["topics"]["/sd_noisy/identified/estimate"]["device_missing_samples"] == 5000
    assert info["topics"]["/sd_noisy/truth"]["total_samples"] == 200000
    assert run_scenario(["sd_resonator", "--analyse", str(out)]) == 2
    err = capsys.readouterr().err
    assert "jumps from sample 20000 to 25000" in err and err.count("\n") == 1, err


def test_a_run_with_faults_records_their_labels(tmp_path, schedule, domain_id):
    out = tmp_path / "run.mcap"
    argv = ["imu_noise", "--duration", "61", "--faults", f"imu={schedule}", "--out", str(out)]
    assert run_scenario(argv + ["--domain-id", str(domain_id), "--no-plots"]) == 0
    events = [m for _, _, _, m in read_messages(str(out), ["/imu/faults"])]
    assert [(e.kind, e.channel, e.first_faulty_sample) for e in events] == [
        ("bias_step", "gyro_z", 100)
    ]
    assert events[0].magnitude == pytest.approx(0.01) and events[0].permanent

"""The scenario contract: a run's figures equal ``run_scenario NAME --analyse`` of its
recording, directly, after a replay into another recorder, and a recording that lacks
what a figure needs gives the other figures, one line per missing one, and exit 2."""

from __future__ import annotations

import contextlib
import io
import json

import pytest
from conftest import next_domain_id
from mcap.reader import make_reader
from mcap.writer import Writer

from mems_scenarios import SCENARIOS, load
from mems_scenarios.cli import main as run_scenario
from mems_scenarios.contract import RUN_INFO_TOPIC
from mems_scenarios.figures import figures_of

#: Short runs of each scenario for ``make test`` (the defaults run in ``make acceptance``).
SHORT = {
    "imu_noise": ["--duration", "300"],
    "sd_resonator": ["--duration", "0.2"],  # the shortest it allows (f0 step at mid-run)
    "scanner_shared_electrodes": ["--duration", "0.05"],
    "scanner_threshold": ["--duration", "0.38"],
    "accelerometer_snr": ["--duration", "0.12"],
    "accelerometer_spread": ["--duration", "0.12"],
    "accelerometer_faults": ["--duration", "0.3"],
    "gyro_calibration": ["--set", "stage.idealised=true"],  # drift-free stage (~30 s)
    "imu_calibration": [],
    "imu_thermal_calibration": [],
}


def cli(argv: list[str]) -> tuple[int, str, str]:
    """``run_scenario argv`` in this process: (status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = run_scenario(argv)
    return status, out.getvalue(), err.getvalue()


def ran(name: str, bag, seed: int = 1) -> list[dict]:
    """The figures (``--json``) of a seeded short run of ``name`` recorded to ``bag``."""
    argv = [name, "--seed", str(seed), "--out", str(bag), "--json", "--no-plots"]
    argv += ["--no-progress", "--domain-id", str(next_domain_id())]
    status, out, err = cli(argv + SHORT[name])
    assert status == 0, err[-2000:]
    return figures_of(json.loads(out))


def analysed(name: str, bag, expect: int = 0) -> tuple[list[dict], str]:
    """The figures and stderr of ``run_scenario name --analyse bag --json``."""
    status, out, err = cli([name, "--analyse", str(bag), "--json", "--no-plots"])
    assert status == expect, err[-2000:]
    return figures_of(json.loads(out)), err


def without(src, dst, topics: set[str]) -> None:
    """Copy the MCAP file ``src`` to ``dst`` without the messages of ``topics``."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        reader, writer = make_reader(f), Writer(g)
        writer.start()
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages():
            if channel.topic in topics:
                continue
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        writer.finish()


def contract_scenarios() -> list[str]:
    """The scenarios that follow the contract (an ``analyse`` of a recording)."""
    return [n for n in SCENARIOS if hasattr(load(n), "analyse")]


@pytest.mark.parametrize("name", contract_scenarios())
def test_analyse_equals_run(name, tmp_path):
    bag = tmp_path / f"{name}.mcap"
    figures = ran(name, bag)
    assert figures, "a run reports figures"
    again, _ = analysed(name, bag)
    assert again == figures


def test_imu_noise_without_run_record(tmp_path):
    """A recording without the run record (a user's own): the identified terms, one line
    for the configured ones and their errors, exit 2."""
    bag = tmp_path / "imu_noise.mcap"
    figures = ran("imu_noise", bag)
    bare = tmp_path / "bare.mcap"
    without(bag, bare, {RUN_INFO_TOPIC})
    partial, err = analysed("imu_noise", bare, expect=2)
    assert partial == [
        f for f in figures if f["name"].endswith(("identified", "ci_low", "ci_high"))
    ]
    assert len(partial) == 6 * 4 * 3  # six axes, four terms
    assert "not computed: *.configured, *.rel_error" in err and RUN_INFO_TOPIC in err
    status, out, err = cli(["imu_noise", "--analyse", str(tmp_path / "missing.mcap")])
    assert status == 2 and "no such file" in err and err.count("\n") == 1
    empty = tmp_path / "empty.mcap"
    without(bag, empty, {"/imu/noise_model"})
    assert analysed("imu_noise", empty, expect=2)[0] == []


#: Scenarios whose generated launch file runs as processes: realtime factor, seconds the
#: graph runs (its estimators do not end by themselves); imu_noise in ``make test``, three
#: device families in ``make acceptance``.
PROCESSES = {
    "imu_noise": (100.0, 30),
    "accelerometer_spread": (0.1, 30),
    "scanner_threshold": (0.02, 45),
}


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(n, marks=[] if n == "imu_noise" else [pytest.mark.slow])
        for n in sorted(PROCESSES)
    ],
)
def test_analyse_a_process_graph(name, tmp_path):
    """The scenario's graph written as a launch file and run by ``run_graph`` as processes
    (emulators that start when their consumers and the recorder are matched): the figures
    of its recording equal those of the in-process run."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    figures = ran(name, tmp_path / "in_process.mcap")
    launch = tmp_path / f"{name}.launch.yaml"
    argv = [name, "--seed", "1", "--write-launch", str(launch)]
    factor, seconds = PROCESSES[name]
    status, _, err = cli(argv + ["--realtime-factor", str(factor)] + SHORT[name])
    assert status == 0, err
    assert (tmp_path / f"{name}.run_record.json").is_file()
    bag = tmp_path / "processes.mcap"
    run_graph = Path(sys.executable).parent / "run_graph"
    cmd = [str(run_graph), str(launch), "--record", str(bag), "--kill-timeout", "60"]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env["ROS_DOMAIN_ID"] = str(next_domain_id())
    done = subprocess.run(
        cmd + ["--duration", str(seconds)], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode in (0, 1), done.stderr[-3000:]
    assert "gaps: 0 (0 samples missing)" in done.stdout + done.stderr
    again, _ = analysed(name, bag)
    assert again == figures


def test_analyse_a_replay(tmp_path):
    """``mcap_play`` of a run into another process's ``mcap_record`` (flow-controlled by its
    progress): the re-recorded bag gives the run's figures, run record included."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    figures = ran("imu_noise", tmp_path / "run.mcap")
    binary = Path(sys.executable).parent
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env["ROS_DOMAIN_ID"] = str(next_domain_id())
    copy = tmp_path / "replayed.mcap"
    record = [str(binary / "mcap_record"), "-o", str(copy), "-a", "--report-progress", "/imu/adc"]
    recorder = subprocess.Popen(record, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        play = [str(binary / "mcap_play"), str(tmp_path / "run.mcap"), "--as-fast-as-possible"]
        play += ["--wait-for-consumer", "/mcap_recorder:/imu/adc", "--wait-timeout", "60"]
        done = subprocess.run(play, env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stdout + done.stderr
        time.sleep(1.0)  # the last messages after the last acknowledged frame
    finally:
        recorder.send_signal(signal.SIGINT)
        log = recorder.communicate(timeout=60)[0].decode()
    assert recorder.returncode in (0, 130), log
    again, _ = analysed("imu_noise", copy)
    assert again == figures

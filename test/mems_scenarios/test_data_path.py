"""The data path of a scenario run: no loss under load, every loss named, isolated runs.

* A fast run under a one-core CPU hog records every message of every topic (frames and
  not), and the file says so: no frame-index or sequence gaps, no missing tail against the
  emulator's end-of-stream record.
* A run whose truth topic is cut short (fault injected with the hidden ``--cut``) exits
  non-zero with one line naming the topic and the missing samples; ``mcap_info`` on its
  file reports the missing tail.
* Two graphs on one ROS domain: the second is refused with one line (domain lease), a
  publisher of another graph on the scenario's topics makes the run fail naming it, and
  runs without a domain get distinct ones; a refused run leaves the first one's recording
  identical to a solo run.

The long campaign (every scenario at its default duration, 5 loaded runs each) is the slow
test ``test/acceptance/test_loaded_runs.py``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mems_scenarios import imu_noise
from mems_scenarios.base import (
    DEFAULT_DOMAINS,
    DomainBusy,
    DomainLease,
    Graph,
    ScenarioError,
    ScenarioOptions,
    default_domain_id,
    holder,
    lease_default_domain,
    lease_domain,
)
from mems_scenarios.cli import main as run_scenario
from mems_scenarios.domain import free_domains
from mems_scenarios.figures import figures_of
from mems_sim.bag import info as info_mod
from mems_sim.bag.player import read_messages

DATA_TOPICS = ("/imu/adc", "/imu/truth", "/imu/noise_model")


def assert_lossless(path: Path) -> dict:
    """Every recorded topic complete in the file: no gaps, no missing tail; the
    end-of-stream record present. Returns bag_info's dict."""
    info = info_mod.bag_info(str(path))
    assert info_mod.losses(info) == [], info_mod.losses(info)
    announced = [t for t, v in info["topics"].items() if "end_of_stream" in v]
    assert announced, "no end-of-stream record in the file"
    for topic in announced:
        t = info["topics"][topic]
        assert t["count"] == t["end_of_stream"]["messages"], topic
        if "end_sample_index" in t["end_of_stream"]:
            assert t["total_samples"] == t["end_of_stream"]["samples"], topic
    return info


def test_loaded_short_run_loses_nothing(cpu_hog, tmp_path, domain_id):
    out = tmp_path / "imu.mcap"
    r = imu_noise.run(
        ScenarioOptions(
            duration_s=1200.0, seed=3, out=out, domain_id=domain_id, progress=False, plots=False
        )
    )
    counts = r["recorder"]["counts"]
    for topic, n in r["published"].items():
        assert counts[topic] == n, topic
    assert r["recorder"]["losses"] == []
    info = assert_lossless(out)
    # the non-frame result carries its publisher's sequence numbers from 1
    assert info["topics"]["/imu/noise_model"]["sequence_gaps"] == 0
    assert info["topics"]["/imu/truth"]["end_of_stream"] == {
        "messages": 1200,
        "end_sample_index": 120000,
        "samples": 120000,
    }


def test_cut_topic_fails_naming_it_and_mcap_info_reports_the_tail(tmp_path, domain_id, capsys):
    out = tmp_path / "cut.mcap"
    argv = ["imu_noise", "--duration", "300", "--seed", "4", "--out", str(out)]
    argv += ["--domain-id", str(domain_id), "--no-plots", "--no-progress"]
    code = run_scenario(argv + ["--cut", "/imu/truth:200"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    assert len(err) == 1 and "/imu/truth" in err[0], err
    assert "100 of 300 messages missing (10000 samples; the tail from sample 20000)" in err[0]
    assert "/imu/adc" not in err[0]

    assert info_mod.main([str(out)]) == 0
    captured = capsys.readouterr()
    truth = [line for line in captured.out.splitlines() if "/imu/truth " in line][0]
    assert "missing tail of 100 of 300 messages (10000 samples from sample 20000)" in truth
    assert "lost data: /imu/truth: missing tail" in captured.err
    info = info_mod.bag_info(str(out))
    assert info["topics"]["/imu/truth"]["gaps"] == 0  # no gap: only the tail tells
    assert info["topics"]["/imu/adc"]["tail"] == {"messages": 0, "samples": 0, "from_index": 30000}


def test_second_graph_on_a_domain_is_refused_and_the_first_is_unchanged(
    tmp_path, domain_id, subprocess_env
):
    """A run in another process holds the domain: a second run on it is refused with one
    line; the first run's recording equals a solo run of the same seed. The first run prints
    its figures with ``--json``: stdout is the JSON list alone, the table goes to stderr."""
    first = tmp_path / "first.mcap"
    cmd = [str(Path(sys.executable).parent / "run_scenario"), "imu_noise", "--duration", "600"]
    cmd += ["--seed", "6", "--out", str(first), "--no-plots", "--no-progress", "--json"]
    cmd += ["--domain-id", str(domain_id)]
    proc = subprocess.Popen(
        cmd, env=subprocess_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 30
        while not holder(domain_id).startswith(f"pid {proc.pid}:"):
            assert time.monotonic() < deadline and proc.poll() is None, "no lease taken"
            time.sleep(0.02)
        with pytest.raises(ScenarioError) as exc:
            Graph(domain_id)  # refused before it joins the domain
        refused = str(exc.value)
        assert f"ROS domain {domain_id} is in use by another scenario graph" in refused
        assert "imu_noise" in refused and "\n" not in refused
    finally:
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    figures = figures_of(json.loads(out))  # nothing but the JSON on stdout
    assert isinstance(figures, list) and figures
    keys = {"name", "value", "unit", "target", "pass", "source", "role"}
    assert all(set(f) == keys for f in figures)
    assert len({f["name"] for f in figures}) == len(figures)
    assert all(f["pass"] in (True, False, None) for f in figures)
    assert all((f["target"] is None) == (f["pass"] is None) for f in figures)
    assert {f["name"] for f in figures} >= {"gyro_x.N.identified", "accel_z.T.rel_error"}
    assert "rel. error" in err  # the table went to stderr
    solo = tmp_path / "solo.mcap"
    imu_noise.run(
        ScenarioOptions(
            duration_s=600.0, seed=6, out=solo, domain_id=domain_id, progress=False, plots=False
        )
    )
    a = {t: [m for tt, _, _, m in read_messages(str(first), [t])] for t in DATA_TOPICS}
    b = {t: [m for tt, _, _, m in read_messages(str(solo), [t])] for t in DATA_TOPICS}
    for topic in DATA_TOPICS:
        assert a[topic] and a[topic] == b[topic], topic


def test_cli_refusal_is_one_line(tmp_path, domain_id, capsys):
    held = Graph(domain_id)
    try:
        argv = ["imu_noise", "--duration", "300", "--out", str(tmp_path / "x.mcap")]
        code = run_scenario(argv + ["--domain-id", str(domain_id), "--no-plots", "--no-progress"])
    finally:
        held.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f"ROS domain {domain_id} is in use by another scenario graph" in err[0]


def test_another_graphs_publisher_is_never_mixed_in(ros_context, domain_id, tmp_path):
    """A plain rclpy publisher (no lease) on /imu/adc of the run's domain, publishing: the
    run is refused at start (publisher already discovered) or fails at the end naming the
    topic (messages of a publisher outside the run recorded); never a silent mix."""
    import rclpy

    from mems_msgs.msg import AdcFrame
    from mems_sim.ros.qos import FRAME_QOS

    node = rclpy.create_node("intruder", context=ros_context)
    pub = node.create_publisher(AdcFrame, "/imu/adc", FRAME_QOS)
    stop = threading.Event()

    def publish():
        k = 0
        while not stop.is_set():
            pub.publish(AdcFrame(first_sample_index=10**9 + k, num_samples=1))
            k += 1
            time.sleep(0.02)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        with pytest.raises(ScenarioError) as exc:
            imu_noise.run(
                ScenarioOptions(
                    duration_s=600.0,
                    seed=7,
                    out=tmp_path / "mixed.mcap",
                    domain_id=domain_id,
                    progress=False,
                    plots=False,
                )
            )
    finally:
        stop.set()
        thread.join()
        node.destroy_node()
    text = str(exc.value)
    assert "/imu/adc" in text and "outside this run" in text and "\n" not in text, text


def test_default_domains_are_leased_distinct(tmp_path, monkeypatch):
    monkeypatch.setenv("MEMS_DOMAIN_LEASE_DIR", str(tmp_path))
    assert all(0 <= d <= 101 and not 61 <= d <= 65 for d in DEFAULT_DOMAINS)
    assert DEFAULT_DOMAINS[-1] == 0 and len(set(DEFAULT_DOMAINS)) == 97
    a = lease_default_domain()
    b = lease_default_domain()
    assert a != b
    lease_a = lease_domain(a)  # the graph takes over the pending lease
    with pytest.raises(RuntimeError, match=f"ROS domain {a} is in use"):
        lease_domain(a)
    assert DomainLease.try_acquire(a) is None
    lease_a.release()
    again = DomainLease.try_acquire(a)
    assert again is not None and again.held
    again.release()
    lease_domain(b).release()


def test_free_domains_confine_the_default_lease(tmp_path, monkeypatch):
    monkeypatch.setenv("MEMS_DOMAIN_LEASE_DIR", str(tmp_path))
    monkeypatch.setenv("MEMS_FREE_DOMAINS", "70-71, 75")
    assert free_domains() == (70, 71, 75)
    taken = [lease_default_domain() for _ in range(3)]
    assert sorted(taken) == [70, 71, 75]
    with pytest.raises(DomainBusy, match=r"MEMS_FREE_DOMAINS \(70-71, 75\)"):
        lease_default_domain()
    for d in taken:
        lease_domain(d).release()
    monkeypatch.delenv("MEMS_FREE_DOMAINS")
    assert free_domains() == DEFAULT_DOMAINS


@pytest.mark.parametrize("value", ["66-", "a-b", "90-80", "233", "-3", "5,,6"])
def test_malformed_free_domains_is_one_line(monkeypatch, value):
    monkeypatch.setenv("MEMS_FREE_DOMAINS", value)
    with pytest.raises(ValueError) as exc:
        free_domains()
    text = str(exc.value)
    assert text.startswith(f"MEMS_FREE_DOMAINS = {value!r} is invalid") and "\n" not in text
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    with pytest.raises(ScenarioError, match="MEMS_FREE_DOMAINS"):
        default_domain_id()

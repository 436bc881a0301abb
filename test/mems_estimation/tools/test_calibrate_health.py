"""``calibrate_health BAG``: the moments of a recording's fault-free ``health`` window sums
(as the accelerometer EKF node publishes them) equal those of the filter's own NIS, a
drawn device's differ from the table's, the parameter file sets them, and a recording it
cannot use is one line and exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.serialization import serialize_message

from mems_estimation.filters.accelerometer_ekf import FAULT_FREE_NIS_MEAN
from mems_estimation.filters.consistency_monitor import NisMonitor, nis_moments
from mems_estimation.studies.accelerometer_fault_detection import fault_free_nis
from mems_msgs.msg import FaultEvent
from mems_sim.bag.schema import schema_text
from mems_sim.bag.writer import McapBagWriter
from mems_sim.ros.qos import HEALTH_QOS
from mems_sim.ros.qos_yaml import profiles_yaml as qos_profiles_yaml

WINDOW = 1000
NODE = "/acc/accelerometer_ekf"
TOPIC = "/acc/health"
HEALTH = "diagnostic_msgs/msg/DiagnosticStatus"


def health_bag(path, nis, window=WINDOW, faults=0, windows=None, dof=None):
    """The ``health`` messages a node publishes for per-sample ``nis`` (the monitor's
    windows, values as the node writes them), in an MCAP file; ``faults`` FaultEvents on
    /acc/faults; ``windows``: per-window sample counts instead (mixed lengths)."""
    mon = NisMonitor(window, 1e-3)
    verdicts = mon.update(nis)
    w = McapBagWriter(str(path))
    w.add_topic(TOPIC, HEALTH, schema_text(HEALTH), qos_profiles_yaml([HEALTH_QOS]))
    for k, v in enumerate(verdicts):
        n = v.n if windows is None else windows[k]
        msg = DiagnosticStatus(
            name="accelerometer_ekf",
            hardware_id=NODE,
            values=[
                KeyValue(key="samples", value=str(n // (dof or 1))),
                KeyValue(key="statistic", value=repr(v.statistic)),
            ]
            + ([] if dof is None else [KeyValue(key="dof", value=str(dof))]),
        )
        t = (k + 1) * window * 1000
        w.write(TOPIC, serialize_message(msg), t, t)
    if faults:
        ft = "mems_msgs/msg/FaultEvent"
        w.add_topic("/acc/faults", ft, schema_text(ft), qos_profiles_yaml([HEALTH_QOS]))
        for k in range(faults):
            w.write("/acc/faults", serialize_message(FaultEvent(kind="bias_step")), k, k)
    w.close()
    return path


def run(args, env):
    return subprocess.run(
        [sys.executable, "-m", "mems_estimation.tools.calibrate_health", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )


@pytest.fixture(scope="module")
def nis_nominal():
    return fault_free_nis(3, None, 220_000)


def test_moments_of_the_recorded_windows_equal_the_filters(tmp_path, nis_nominal, subprocess_env):
    bag = health_bag(tmp_path / "h.mcap", nis_nominal)
    out = tmp_path / "params.yaml"
    r = run([bag, "--out", out, "--json"], subprocess_env)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)[TOPIC]
    mean, disp = nis_moments(nis_nominal, WINDOW)
    c = res["calibration"]
    assert res["node"] == NODE and c["window"] == WINDOW and c["windows"] == 200
    assert (c["nis_mean"], c["dispersion"]) == (mean, disp)
    assert c["nis_mean_interval"][0] < mean < c["nis_mean_interval"][1]
    assert c["dispersion_interval"][0] < disp < c["dispersion_interval"][1]
    params = yaml.safe_load(out.read_text())[NODE]["ros__parameters"]
    assert params == dict(health_window=WINDOW, health_nis_mean=mean, health_nis_dispersion=disp)
    assert "nis_mean [95 %]" in r.stderr and f"parameters: {out}" in r.stderr


def test_moments_are_per_degree_of_freedom(tmp_path, nis_nominal, subprocess_env):
    """Windows of 250 samples of 4 measurements (as the stage EKF's) holding the same sums
    as windows of 1000 scalar samples: the same moments per degree of freedom."""
    bag = health_bag(tmp_path / "d4.mcap", nis_nominal, dof=4)
    r = run([bag, "--json"], subprocess_env)
    assert r.returncode == 0, r.stderr
    c = json.loads(r.stdout)[TOPIC]["calibration"]
    assert (c["window"], c["dof"]) == (250, 4)
    mean, disp = nis_moments(nis_nominal, WINDOW)
    assert c["nis_mean"] == pytest.approx(mean, rel=1e-12)
    assert c["dispersion"] == pytest.approx(disp, rel=1e-12)


def test_a_drawn_device_calibrates_away_from_the_table(tmp_path, subprocess_env):
    """Device 13 of the batch: its fault-free mean NIS is about 1.16, far outside the
    interval of a bench calibration around the table's 0.99 (the nominal device's)."""
    bag = health_bag(tmp_path / "d13.mcap", fault_free_nis(3, 13, 220_000))
    r = run([bag, "--json"], subprocess_env)
    assert r.returncode == 0, r.stderr
    c = json.loads(r.stdout)[TOPIC]["calibration"]
    assert c["nis_mean_interval"][0] > FAULT_FREE_NIS_MEAN * 1.05, c


def test_refusals_are_one_line_and_exit_2(tmp_path, nis_nominal, subprocess_env):
    cases = {
        "faults": (health_bag(tmp_path / "f.mcap", nis_nominal, faults=2), "fault-free"),
        "short": (health_bag(tmp_path / "s.mcap", nis_nominal[:20_000]), "at least 30"),
        "mixed": (
            health_bag(tmp_path / "m.mcap", nis_nominal, windows=[1000] * 100 + [500] * 100),
            "one health_window",
        ),
    }
    for name, (bag, words) in cases.items():
        r = run([bag], subprocess_env)
        assert r.returncode == 2 and words in r.stderr, (name, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, (name, r.stderr)
    r = run([tmp_path / "none.mcap"], subprocess_env)
    assert r.returncode == 2 and "no such file" in r.stderr
    r = run([cases["short"][0], "--topic", "/other/health"], subprocess_env)
    assert r.returncode == 2 and "no health topic" in r.stderr
    good = health_bag(tmp_path / "g.mcap", nis_nominal)
    r = run([good, "--false-alarm", "0.7"], subprocess_env)
    assert r.returncode == 2 and "--false-alarm" in r.stderr

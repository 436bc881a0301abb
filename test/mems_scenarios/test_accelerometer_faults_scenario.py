"""Scenario ``accelerometer_faults``: on a short seeded run every scheduled kind is found
by the EKF's monitor with no false alarm, the estimates stay finite, a drawn device needs
the calibration on the run's fault-free start, a user's schedule (``--faults``) replaces
the default one, and a recording without labelled faults still gives the false alarms
with the detection figures listed as unavailable."""

from __future__ import annotations

import contextlib
import io
import json

from conftest import next_domain_id
from test_analyse import without

from mems_scenarios.cli import main as run_scenario
from mems_scenarios.figures import figures_of


def cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = run_scenario(argv)
    return status, out.getvalue(), err.getvalue()


def run(tmp_path, *extra, seed=2):
    bag = tmp_path / "acc.mcap"
    argv = ["accelerometer_faults", "--seed", str(seed), "--duration", "0.35", "--out", str(bag)]
    argv += ["--json", "--no-plots", "--no-progress", "--domain-id", str(next_domain_id())]
    status, out, err = cli(argv + list(extra))
    assert status == 0, err[-2000:]
    return {f["name"]: f for f in figures_of(json.loads(out))}, bag


def test_every_scheduled_kind_is_found_without_false_alarms(tmp_path):
    f, bag = run(tmp_path)
    kinds = [
        n.removesuffix(".detected")
        for n in f
        if n.endswith(".detected") and not n.startswith("bench.")
    ]
    assert set(kinds) == {"bias_step", "stuck_at", "saturation", "noise_burst", "spikes"}
    for k in kinds:
        assert f[f"{k}.detected"]["pass"] is True, f[f"{k}.detected"]
        assert 0 < f[f"{k}.median_delay_ms"]["value"] <= 2.0
    assert f["false_alarm.episodes"]["pass"] is True
    assert f["bench.windows"]["value"] == 200  # the fault-free first 200 ms
    assert all(g["pass"] is not False for n, g in f.items() if n.startswith("bench."))
    assert f["estimates.finite"]["value"] is True
    assert f["error.rms_in_faults"]["value"] > 3 * f["error.rms_outside_faults"]["value"]
    # without the labelled truth: no detection figures, the rest still computed
    bare = tmp_path / "bare.mcap"
    without(bag, bare, {"/acc/faults"})
    status, out, err = cli(["accelerometer_faults", "--analyse", str(bare), "--json"])
    assert status == 2 and "no labelled fault" in err
    names = {g["name"] for g in figures_of(json.loads(out))}
    assert "false_alarm.episodes" in names and not any(n.endswith(".detected") for n in names)


def test_a_drawn_device_with_the_bench_model(tmp_path):
    """Device 13 of the batch (mean NIS 1.16 with the nominal model, whose table thresholds
    then raised false alarms beyond the bound): with the model identified on the bench its
    NIS is the nominal device's, so the node's table thresholds and those calibrated on the
    run's fault-free start both hold, and both find every fault."""
    f, _ = run(tmp_path, "--device-seed", "13")
    assert abs(f["bench.nis_mean"]["value"] - 0.99) < 0.05, f["bench.nis_mean"]
    assert f["false_alarm.episodes"]["pass"] is True, f["false_alarm.episodes"]
    assert f["bench.false_alarm.episodes"]["pass"] is True
    assert all(g["pass"] for n, g in f.items() if n.endswith(".detected"))


def test_a_users_schedule_replaces_the_default(tmp_path):
    sched = tmp_path / "one.yaml"
    sched.write_text(
        "faults:\n  - {kind: bias_step, channel: readout, start_sample: 50500,"
        " duration_samples: 20000, magnitude: 2.0e-3}\n"
    )
    f, _ = run(tmp_path, "--faults", str(sched))
    assert f["bias_step.faults"]["value"] == 1
    assert f["bias_step.detected"]["value"] == 1.0
    assert not any(n.startswith(("stuck_at", "spikes")) for n in f)

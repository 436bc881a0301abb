"""The ``hardware`` parameter of every emulator node: ``ideal`` is today's device, bit for
bit; ``realistic`` starts the real-part terms at their table values; a parameter set
explicitly wins; ``run_scenario --hardware`` sets it on every emulator."""

import json

import numpy as np
import pytest
import yaml
from conftest import params, spin_until

from mems_msgs.msg import SignalFrame
from mems_scenarios.cli import main as run_scenario
from mems_sim.params import spec_table
from mems_sim.ros.qos import FRAME_QOS


def _emulators():
    from mems_sim.nodes.accelerometer_node import AccelerometerNode
    from mems_sim.nodes.imu_node import ImuNode
    from mems_sim.nodes.resonator_node import ResonatorNode
    from mems_sim.nodes.scanner_amdm_node import ScannerAmdmNode
    from mems_sim.nodes.scanner_node import ScannerNode
    from mems_sim.nodes.stage_node import StageNode

    return (AccelerometerNode, ImuNode, ResonatorNode, ScannerAmdmNode, ScannerNode, StageNode)


@pytest.mark.parametrize("cls", _emulators(), ids=lambda c: c.NODE_NAME)
def test_every_emulator_has_the_profile_and_ideal_is_its_default(ros_context, cls):
    spec = spec_table(cls.SPECS)["hardware"]
    assert spec.default == "ideal" and spec.choices == ("ideal", "realistic")
    plain = cls(context=ros_context, drive_externally=True)
    ideal = cls(
        context=ros_context, drive_externally=True, parameter_overrides=params(hardware="ideal")
    )
    try:
        assert plain.profile_changed == ideal.profile_changed == frozenset()
        assert {k: v for k, v in ideal.p.items() if k != "hardware"} == {
            k: v for k, v in plain.p.items() if k != "hardware"
        }
    finally:
        plain.destroy_node()
        ideal.destroy_node()


def _reading(ctx, ex, probe, **kw):
    from mems_sim.nodes.imu_node import ImuNode

    emu = ImuNode(
        context=ctx,
        drive_externally=True,
        parameter_overrides=params(
            seed=1, frame_size=50, publish_imu=False, calibration_topics="on", **kw
        ),
    )
    ex.add_node(emu)
    got = []
    sub = probe.create_subscription(SignalFrame, "/imu/temperature_sensor", got.append, FRAME_QOS)
    assert spin_until(ex, lambda: emu.pub_temperature.get_subscription_count() == 1)
    for _ in range(4):
        emu.step()
    assert spin_until(ex, lambda: len(got) == 4)
    probe.destroy_subscription(sub)
    ex.remove_node(emu)
    values = dict(emu.p)
    emu.destroy_node()
    return np.concatenate([np.asarray(m.data) for m in got]), values


def test_the_realistic_imu_reads_its_temperature_through_its_sensor(graph):
    """Ideal: the reading is the device temperature (25 C) exactly. Realistic: the sensor
    table's noise (0.01 K) and resolution (1/256 K), so the readings scatter on the code
    grid; an explicit noise of 0 wins over the profile's (codes only)."""
    ctx, ex, probe = graph
    ideal, p_ideal = _reading(ctx, ex, probe)
    assert np.all(ideal == 25.0) and p_ideal["temp_sensor_noise_k"] == 0.0
    real, p_real = _reading(ctx, ex, probe, hardware="realistic")
    assert p_real["temp_sensor_noise_k"] == 0.01
    assert p_real["temp_sensor_resolution_k"] == 1.0 / 256.0
    assert p_real["temp_sensor_time_constant_s"] == 1.0
    codes = (real - 25.0) * 256.0
    assert np.array_equal(codes, np.round(codes)) and np.unique(codes).size >= 3
    assert 0.005 < np.std(real) < 0.02
    quiet, p_quiet = _reading(ctx, ex, probe, hardware="realistic", temp_sensor_noise_k=0.0)
    assert p_quiet["temp_sensor_noise_k"] == 0.0 and np.all(quiet == 25.0)


def test_run_scenario_hardware_reaches_every_emulator(tmp_path):
    launch = tmp_path / "g.launch.yaml"
    argv = ["imu_noise", "--hardware", "realistic", "--write-launch", str(launch)]
    assert run_scenario(argv) == 0
    nodes = {e["node"]["exec"]: e["node"] for e in yaml.safe_load(launch.read_text())["launch"]}
    imu = {p["name"]: p["value"] for p in nodes["imu_node"]["param"]}
    assert imu["hardware"] == "realistic"
    assert "hardware" not in {p["name"] for p in nodes["imu_noise_identifier_node"]["param"]}
    record = json.loads((tmp_path / "g.run_record.json").read_text())
    full = record["nodes"]["/imu/imu"]["parameters"]
    assert full["hardware"] == "realistic" and full["temp_sensor_noise_k"] == 0.01
    assert record["options"]["hardware"] == "realistic"


def test_a_set_of_hardware_wins_over_the_option(tmp_path):
    launch = tmp_path / "g.launch.yaml"
    argv = ["imu_noise", "--hardware", "realistic", "--set", "imu.hardware=ideal"]
    assert run_scenario(argv + ["--write-launch", str(launch)]) == 0
    record = json.loads((tmp_path / "g.run_record.json").read_text())
    full = record["nodes"]["/imu/imu"]["parameters"]
    assert full["hardware"] == "ideal" and full["temp_sensor_noise_k"] == 0.0

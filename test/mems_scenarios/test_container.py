"""component_container: several nodes in one process. Its command line (node sections of
their own), its one-line refusals (exit 2), and a device and its estimator composed in one
process, through real topics: the estimator's results arrive, and SIGINT closes both nodes
(the identifier's final model is published) with exit status 0."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import spin_until

from mems_scenarios.component_container import (
    ContainerError,
    node_label,
    resolve_plugin,
    split_command_line,
)

CONTAINER = str(Path(sys.executable).parent / "component_container")


# --------------------------------------------------------------------------- command line


def test_each_node_gets_its_own_ros_args_section():
    own, nodes = split_command_line(
        ["--ros-args", "--log-level", "warn"]
        + ["--node", "imu_node", "--ros-args", "-r", "__ns:=/a", "-p", "seed:=3"]
        + ["--node=imu_noise_identifier_node", "--ros-args", "-r", "__node:=idf"]
        + ["--node", "pkg.mod:Cls"]
    )
    assert own == ["--ros-args", "--log-level", "warn"]
    assert nodes == [
        ("imu_node", ["--ros-args", "-r", "__ns:=/a", "-p", "seed:=3"]),
        ("imu_noise_identifier_node", ["--ros-args", "-r", "__node:=idf"]),
        ("pkg.mod:Cls", []),
    ]


@pytest.mark.parametrize(
    "argv, text",
    [
        ([], "no --node PLUGIN given"),
        (["--node"], "--node needs a PLUGIN"),
        (["--node", "--ros-args"], "--node needs a PLUGIN, got '--ros-args'"),
        (["--node", "imu_node", "seed:=3"], "'seed:=3' is not a --ros-args section"),
        (["extra", "--node", "imu_node"], "unrecognised argument 'extra'"),
    ],
)
def test_malformed_command_lines_are_refused(argv, text):
    with pytest.raises(ContainerError, match=text.replace("(", r"\(")):
        split_command_line(argv)


def test_plugin_names_a_node_executable_or_a_node_class():
    from mems_estimation.nodes.imu_noise_identifier_node import ImuNoiseIdentifierNode
    from mems_sim.nodes.imu_node import ImuNode

    assert resolve_plugin("imu_node") is ImuNode
    assert resolve_plugin("imu_noise_identifier_node") is ImuNoiseIdentifierNode
    assert resolve_plugin("mems_sim.nodes.imu_node:ImuNode") is ImuNode
    for plugin, text in [
        ("imu_nod", "not an executable of mems_emulator"),
        ("mcap_record", "does not run a node"),
        ("os:path", "is not a node class"),
        ("no_such_module_xyz:Node", "cannot import"),
    ]:
        with pytest.raises(ContainerError, match=text):
            resolve_plugin(plugin)


def test_error_lines_name_the_node_by_its_remappings_or_class_defaults():
    from mems_sim.nodes.imu_node import ImuNode

    args = ["--ros-args", "-r", "__ns:=/a/b", "-r", "__node:=x"]
    assert node_label("imu_node", args, ImuNode) == "node /a/b/x (imu_node)"
    assert node_label("imu_node", [], ImuNode) == "node /imu/imu (imu_node)"


def _run(args, env) -> subprocess.CompletedProcess:
    return subprocess.run([CONTAINER, *args], env=env, capture_output=True, text=True, timeout=120)


def test_refusals_are_one_line_and_exit_2(subprocess_env):
    for args, text in [
        (["--node", "imu_nod"], "plugin 'imu_nod': not an executable of mems_emulator"),
        (["--node", "mcap_record"], "does not run a node"),
        # an invalid parameter of the second node: named with the node, nothing started
        (
            ["--node", "imu_node", "--node", "resonator_observer_node"]
            + ["--ros-args", "-r", "__ns:=/r/x", "-p", "f0_hz:=-1.0"],
            "node /r/x/resonator_observer (resonator_observer_node): parameter 'f0_hz' = -1.0",
        ),
    ]:
        run = _run(args, subprocess_env)
        assert run.returncode == 2, (args, run.stderr)
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and text in lines[0], (args, run.stderr)


# --------------------------------------------------------------------------- composed graph


def test_device_and_identifier_in_one_process_publish_and_close_on_sigint(
    graph, subprocess_env, tmp_path
):
    from mems_msgs.msg import NoiseModel
    from mems_sim.ros.qos import RESULT_QOS

    _, ex, probe = graph
    models = []
    probe.create_subscription(NoiseModel, "/cimu/noise_model", models.append, RESULT_QOS)
    node = ["--ros-args", "-r", "__ns:=/cimu"]
    cmd = (
        ["--ros-args", "--log-level", "warn"]
        + ["--node", "imu_node", *node, "-p", "realtime_factor:=100.0", "-p", "frame_size:=500"]
        + ["--node", "imu_noise_identifier_node", *node]
        + ["-p", "min_duration_s:=5.0", "-p", "publish_period_s:=5.0"]
    )
    err = open(tmp_path / "stderr", "w+")
    proc = subprocess.Popen(
        [CONTAINER, *cmd], env=subprocess_env, stderr=err, start_new_session=True
    )
    try:
        assert spin_until(ex, lambda: len(models) >= 2 or proc.poll() is not None, timeout=60)
        assert proc.poll() is None
        periodic = len(models)
        os.kill(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=60)
        # the identifier's close(): its final model, after the periodic ones
        spin_until(ex, lambda: any(m.final for m in models), timeout=10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err.seek(0)
    stderr = err.read()
    assert code == 0, stderr[-3000:]
    assert not any(m.final for m in models[:periodic])
    assert [m.final for m in models].count(True) == 1, stderr[-3000:]
    # both nodes were in the one process: the device's data reached the identifier
    assert models[-1].num_samples >= 5.0 * models[-1].sample_rate_hz
    assert "Traceback" not in stderr, stderr[-3000:]

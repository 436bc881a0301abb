"""`ros2 run` compatibility: colcon builds both packages, and an executable resolved the way
`ros2 run` resolves it (ament index package prefix + lib/<pkg>/<exe>) starts and publishes."""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.executors import SingleThreadedExecutor

from mems_msgs.msg import AdcFrame
from mems_sim.ros.qos import FRAME_QOS

REPO = Path(__file__).resolve().parents[3]
VENV_BIN = Path(sys.executable).parent
PREFIX = Path(sys.prefix)

RESOLVE = """
import os, sys
from ament_index_python.packages import get_package_prefix
exe = os.path.join(get_package_prefix('mems_emulator'), 'lib', 'mems_emulator', sys.argv[1])
os.execv(exe, [exe] + sys.argv[2:])
"""


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory):
    """colcon build --paths . msg_defs into a temporary workspace (the README's command)."""
    if shutil.which("colcon", path=str(VENV_BIN)) is None:
        pytest.fail("colcon is not installed in the venv (requirements.lock pins it)")
    ws = tmp_path_factory.mktemp("colcon_ws")
    env = dict(
        os.environ,
        PATH=f"{VENV_BIN}:{os.environ['PATH']}",
        CMAKE_PREFIX_PATH=str(PREFIX),
        AMENT_PREFIX_PATH=str(PREFIX),
    )
    build = subprocess.run(
        [
            str(VENV_BIN / "colcon"),
            "build",
            "--paths",
            str(REPO),
            str(REPO / "msg_defs"),
            "--build-base",
            str(ws / "build"),
            "--install-base",
            str(ws / "install"),
            "--cmake-args",
            "-DBUILD_TESTING=OFF",
            f"-DPython3_EXECUTABLE={sys.executable}",
        ],
        cwd=ws,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    return ws / "install"


def _sourced(install: Path, command: str, env: dict) -> list[str]:
    """bash -c: the venv as underlay (like /opt/ros/<distro>), then source the overlay."""
    script = f"source {install}/setup.bash && {command}"
    return ["bash", "-c", script]


def test_colcon_layout_has_executables_in_lib_pkg(colcon_install):
    lib = colcon_install / "mems_emulator" / "lib" / "mems_emulator"
    for exe in (
        "run_scenario",
        "imu_node",
        "imu_noise_identifier_node",
        "mcap_record",
        "mcap_play",
        "mcap_info",
        "identify_noise",
        "resonator_node",
        "resonator_observer_node",
    ):
        assert (lib / exe).is_file(), exe
    assert (
        colcon_install
        / "mems_emulator"
        / "share"
        / "ament_index"
        / "resource_index"
        / "packages"
        / "mems_emulator"
    ).is_file()


def test_executable_resolved_like_ros2_run_starts_and_publishes(
    colcon_install, ros_context, subprocess_env
):
    import rclpy

    env = dict(subprocess_env, AMENT_PREFIX_PATH=str(PREFIX), PATH=f"{VENV_BIN}:/usr/bin:/bin")
    env.pop("PYTHONPATH", None)
    cmd = _sourced(
        colcon_install,
        f'exec python -c "{RESOLVE}" imu_node --ros-args -p frame_size:=10 -p realtime_factor:=5.0',
        env,
    )
    proc = subprocess.Popen(
        cmd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        node = rclpy.create_node("probe", context=ros_context)
        got = []
        node.create_subscription(AdcFrame, "/imu/adc", got.append, FRAME_QOS)
        ex = SingleThreadedExecutor(context=ros_context)
        ex.add_node(node)
        deadline = time.monotonic() + 60
        while len(got) < 3 and time.monotonic() < deadline and proc.poll() is None:
            ex.spin_once(timeout_sec=0.1)
        assert len(got) >= 3, proc.poll() and proc.communicate()
        indices = [m.first_sample_index for m in got]
        assert all(b - a == 10 for a, b in zip(indices, indices[1:]))
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err[-2000:]


def test_run_scenario_list_through_ros2_run_lookup(colcon_install, subprocess_env):
    env = dict(subprocess_env, AMENT_PREFIX_PATH=str(PREFIX), PATH=f"{VENV_BIN}:/usr/bin:/bin")
    env.pop("PYTHONPATH", None)
    run = subprocess.run(
        _sourced(colcon_install, f'python -c "{RESOLVE}" run_scenario --list', env),
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("imu_noise")

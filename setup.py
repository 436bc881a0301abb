"""ament_python package of the MEMS hardware emulator (mems_sim + mems_estimation)."""

import sys
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "mems_emulator"

# `ros2 run` looks for executables in <prefix>/lib/<package>. colcon builds an
# ament_python package with `setup.py ... install` (or `develop` with
# --symlink-install): for those commands the scripts go there, as a setup.cfg
# [install]/[develop] section would do. pip's editable/wheel installs (make
# setup) keep console scripts in the venv's bin/, so no setup.cfg is used.
SCRIPT_DIR = f"$base/lib/{PACKAGE}"
HERE = Path(__file__).resolve().parent

#: Python distributions the package imports at run time, and those its tests and benchmarks
#: add; versions come from requirements.lock (the exact environment `make setup` builds), so
#: the metadata cannot drift from the lock. ROS packages (rclpy, message packages) come from
#: the ROS 2 installation and are declared in package.xml.
RUNTIME = (
    "numpy",
    "scipy",
    "numba",
    "matplotlib",
    "PyYAML",
    "tqdm",
    "mcap",
    "mcap-ros2-support",
    "rosbags",
    "zstandard",
    "lz4",
    "foxglove-sdk",
    "websockets",
    "dask",
    "distributed",
    "pandas",
    "pyarrow",
)
TEST = ("pytest", "ruff", "xmlschema", "AllanTools", "filterpy")


def locked(names):
    """``name==version`` of each name as pinned in requirements.lock."""
    pins = {}
    for line in (HERE / "requirements.lock").read_text().splitlines():
        if "==" in line and not line.startswith("#"):
            name, version = line.strip().split("==")
            pins[name.lower()] = f"{name}=={version}"
    return [pins[n.lower()] for n in names]


OPTIONS = {}
if {"install", "develop"} & set(sys.argv[1:]):
    OPTIONS = {"install": {"install_scripts": SCRIPT_DIR}, "develop": {"script_dir": SCRIPT_DIR}}

setup(
    name=PACKAGE,
    version="0.2.0",
    packages=find_packages(
        include=[
            "mems_sim",
            "mems_sim.*",
            "mems_estimation",
            "mems_estimation.*",
            "mems_scenarios",
            "mems_scenarios.*",
        ]
    ),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml", "LICENSE", "CHANGELOG.rst"]),
        (
            f"share/{PACKAGE}/launch",
            sorted(str(p.relative_to(HERE)) for p in (HERE / "launch").glob("*.launch.yaml")),
        ),
        (
            f"share/{PACKAGE}/config",
            sorted(str(p.relative_to(HERE)) for p in (HERE / "config").glob("*") if p.is_file()),
        ),
        (
            f"share/{PACKAGE}/config/foxglove",
            sorted(str(p.relative_to(HERE)) for p in (HERE / "config" / "foxglove").glob("*.json")),
        ),
        (
            f"share/{PACKAGE}/config/imu",
            sorted(str(p.relative_to(HERE)) for p in (HERE / "config" / "imu").glob("*.csv")),
        ),
    ],
    install_requires=locked(RUNTIME),
    extras_require={"test": locked(TEST)},
    zip_safe=True,
    options=OPTIONS,
    maintainer="MEMS emulator maintainers",
    maintainer_email="maintainers@mems-emulator.org",
    description="Emulated MEMS sensor hardware with estimators and calibration, on ROS 2.",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "run_scenario = mems_scenarios.cli:main",
            "run_graph = mems_scenarios.run_graph:main",
            "run_campaign = mems_scenarios.campaign:main",
            "imu_node = mems_sim.nodes.imu_node:main",
            "imu_noise_identifier_node = mems_estimation.nodes.imu_noise_identifier_node:main",
            "resonator_node = mems_sim.nodes.resonator_node:main",
            "resonator_observer_node = mems_estimation.nodes.resonator_observer_node:main",
            "accelerometer_node = mems_sim.nodes.accelerometer_node:main",
            "accelerometer_ekf_node = mems_estimation.nodes.accelerometer_ekf_node:main",
            "stage_node = mems_sim.nodes.stage_node:main",
            "stage_ekf_node = mems_estimation.nodes.stage_ekf_node:main",
            "stage_average_node = mems_estimation.nodes.stage_average_node:main",
            "stage_gyro_calibration_node = mems_estimation.nodes.stage_gyro_calibration_node:main",
            "scanner_node = mems_sim.nodes.scanner_node:main",
            "scanner_threshold_ekf_node = mems_estimation.nodes.scanner_threshold_ekf_node:main",
            "scanner_amdm_node = mems_sim.nodes.scanner_amdm_node:main",
            "view_node = mems_sim.nodes.view_node:main",
            "scanner_amdm_estimator_node = mems_estimation.nodes.scanner_amdm_estimator_node:main",
            "identify_noise = mems_estimation.tools.identify_noise:main",
            "calibrate_imu = mems_estimation.tools.calibrate_imu:main",
            "calibrate_health = mems_estimation.tools.calibrate_health:main",
            "imu_calibration_node = mems_estimation.nodes.imu_calibration_node:main",
            "imu_corrector_node = mems_estimation.nodes.imu_corrector_node:main",
            "mcap_record = mems_sim.bag.record_cli:main",
            "mcap_play = mems_sim.bag.play_cli:main",
            "mcap_info = mems_sim.bag.info:main",
            "live_view = mems_sim.nodes.live_view:main",
            "component_container = mems_scenarios.component_container:main",
            "scenario_run_record = mems_scenarios.run_record_node:main",
        ],
        # scenarios of run_scenario (another package adds its own to the same group)
        "mems_emulator.scenarios": [
            "imu_noise = mems_scenarios.imu_noise",
            "sd_resonator = mems_scenarios.sd_resonator",
            "scanner_shared_electrodes = mems_scenarios.scanner_shared_electrodes",
            "scanner_threshold = mems_scenarios.scanner_threshold",
            "accelerometer_snr = mems_scenarios.accelerometer_snr",
            "accelerometer_spread = mems_scenarios.accelerometer_spread",
            "accelerometer_faults = mems_scenarios.accelerometer_faults",
            "gyro_calibration = mems_scenarios.gyro_calibration",
            "imu_calibration = mems_scenarios.imu_calibration",
            "imu_thermal_calibration = mems_scenarios.imu_thermal_calibration",
        ],
    },
)

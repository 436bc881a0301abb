"""ament_python package of the MEMS hardware emulator (mems_sim + mems_estimation)."""
import sys

from setuptools import find_packages, setup

PACKAGE = "mems_emulator"

# `ros2 run` looks for executables in <prefix>/lib/<package>. colcon builds an
# ament_python package with `setup.py ... install` (or `develop` with
# --symlink-install): for those commands the scripts go there, as a setup.cfg
# [install]/[develop] section would do. pip's editable/wheel installs (make
# setup) keep console scripts in the venv's bin/, so no setup.cfg is used.
SCRIPT_DIR = f"$base/lib/{PACKAGE}"
OPTIONS = {}
if {"install", "develop"} & set(sys.argv[1:]):
    OPTIONS = {"install": {"install_scripts": SCRIPT_DIR}, "develop": {"script_dir": SCRIPT_DIR}}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["mems_sim", "mems_sim.*", "mems_estimation", "mems_estimation.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    options=OPTIONS,
    maintainer="MEMS emulator maintainers",
    maintainer_email="maintainers@mems-emulator.org",
    description="Emulated MEMS sensor hardware with estimators and calibration, on ROS 2.",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "run_scenario = mems_sim.scenarios.cli:main",
            "imu_noise_node = mems_sim.imu_noise_node:main",
            "noise_identifier_node = mems_estimation.noise_identifier_node:main",
            "sd_resonator_node = mems_sim.sd_resonator_node:main",
            "sd_observer_node = mems_estimation.sd_observer_node:main",
            "fr_accelerometer_node = mems_sim.fr_accelerometer_node:main",
            "hybrid_ekf_node = mems_estimation.hybrid_ekf_node:main",
            "micro_stage_node = mems_sim.micro_stage_node:main",
            "stage_ekf_node = mems_estimation.stage_ekf_node:main",
            "gyro_calibration_node = mems_estimation.gyro_calibration_node:main",
            "micro_scanner_node = mems_sim.micro_scanner_node:main",
            "scanner_threshold_node = mems_estimation.scanner_threshold_node:main",
            "scanner_amdm_node = mems_sim.scanner_amdm_node:main",
            "scanner_amdm_estimator_node = mems_estimation.scanner_amdm_estimator_node:main",
            "identify_noise = mems_estimation.identify_noise_cli:main",
            "mcap_record = mems_sim.bag.recorder:main",
            "mcap_play = mems_sim.bag.player:main",
            "mcap_info = mems_sim.bag.info:main",
        ],
    },
)

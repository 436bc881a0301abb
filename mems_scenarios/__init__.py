"""Scenarios runnable with ``run_scenario NAME``: name -> module with NAME, DESCRIPTION,
DEFAULT_DURATION_S and ``run(ScenarioOptions) -> dict``."""

import importlib

import mems_sim  # noqa: F401  (pins numpy's and OpenBLAS's kernels before numpy loads)

#: Registered scenarios, in the order ``run_scenario --list`` shows them.
SCENARIOS = {
    "imu_noise": "mems_scenarios.imu_noise",
    "sd_resonator": "mems_scenarios.resonator_sigma_delta",
    "scanner_shared_electrodes": "mems_scenarios.scanner_amdm_shared_electrodes",
    "scanner_threshold": "mems_scenarios.scanner_threshold",
    "accelerometer_snr": "mems_scenarios.accelerometer_snr",
    "accelerometer_spread": "mems_scenarios.accelerometer_spread",
    "gyro_calibration": "mems_scenarios.stage_gyro_calibration",
    "imu_calibration": "mems_scenarios.imu_calibration",
    "imu_thermal_calibration": "mems_scenarios.imu_thermal_calibration",
}


def load(name: str):
    """The module of scenario ``name`` (KeyError if unknown)."""
    return importlib.import_module(SCENARIOS[name])

"""Scenarios runnable with ``run_scenario NAME``: name -> module with NAME, DESCRIPTION,
DEFAULT_DURATION_S and ``run(ScenarioOptions) -> dict``."""
import importlib

#: Registered scenarios, in the order ``run_scenario --list`` shows them.
SCENARIOS = {
    "imu_noise": "mems_sim.scenarios.imu_noise",
    "sd_resonator": "mems_sim.scenarios.sd_resonator",
    "scanner_shared_electrodes": "mems_sim.scenarios.scanner_shared_electrodes",
    "scanner_threshold": "mems_sim.scenarios.scanner_threshold",
    "accelerometer_snr": "mems_sim.scenarios.accelerometer_snr",
    "gyro_calibration": "mems_sim.scenarios.gyro_calibration",
}


def load(name: str):
    """The module of scenario ``name`` (KeyError if unknown)."""
    return importlib.import_module(SCENARIOS[name])

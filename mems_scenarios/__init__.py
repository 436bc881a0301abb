"""Scenarios runnable with ``run_scenario NAME``: name -> module with NAME, DESCRIPTION,
DEFAULT_DURATION_S, ``run(ScenarioOptions) -> dict`` and, on the scenario contract
(:mod:`mems_scenarios.contract`), ``graph`` and ``analyse``.

Scenarios are found through the entry-point group :data:`ENTRY_POINT_GROUP` (name = module),
so another installed package can add its own; this package's come first, in the order below.
"""

import importlib

import mems_sim  # noqa: F401  (pins numpy's and OpenBLAS's kernels before numpy loads)

#: Entry-point group of scenarios (setup.py registers this package's).
ENTRY_POINT_GROUP = "mems_emulator.scenarios"

#: This package's scenarios, in the order ``run_scenario --list`` shows them.
BUILTIN = {
    "imu_noise": "mems_scenarios.imu_noise",
    "sd_resonator": "mems_scenarios.sd_resonator",
    "scanner_shared_electrodes": "mems_scenarios.scanner_shared_electrodes",
    "scanner_threshold": "mems_scenarios.scanner_threshold",
    "accelerometer_snr": "mems_scenarios.accelerometer_snr",
    "accelerometer_spread": "mems_scenarios.accelerometer_spread",
    "accelerometer_faults": "mems_scenarios.accelerometer_faults",
    "gyro_calibration": "mems_scenarios.gyro_calibration",
    "imu_calibration": "mems_scenarios.imu_calibration",
    "imu_thermal_calibration": "mems_scenarios.imu_thermal_calibration",
}


def _registered() -> dict[str, str]:
    """:data:`BUILTIN`, then the scenarios other installed packages register in
    :data:`ENTRY_POINT_GROUP` (by name; a name of this package's stays this package's)."""
    from importlib.metadata import entry_points

    out = dict(BUILTIN)
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        out.setdefault(ep.name, ep.value)
    return out


#: Every scenario ``run_scenario`` knows: name -> module.
SCENARIOS = _registered()


def load(name: str):
    """The module of scenario ``name`` (KeyError if unknown)."""
    return importlib.import_module(SCENARIOS[name])

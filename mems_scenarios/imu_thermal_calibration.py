"""Scenario ``imu_thermal_calibration``: thermal calibration of the ADIS16350-like IMU on the
thermal_ramp profile (z up, 20 -> 60 degC at 1 K/min, the rate table alternating +-100 deg/s
about z every 60 s, 2400 s), the graph of :mod:`mems_scenarios.imu_calibration`.

Observable in this profile (and judged): the temperature coefficients of every gyro bias, of
the gyro z scale factor and of the accelerometer x and y biases; the accelerometer z bias
tempco carries b_T,z + g C_zz sf_T,z and the x/y scale-factor tempcos are not observable
(listed, not judged). Figures: the relative error of each judged tempco and their RMS
(target <= 10 %), coverage of the 95 % intervals.
"""

from __future__ import annotations

from mems_scenarios import imu_calibration
from mems_scenarios.base import ScenarioOptions
from mems_scenarios.imu_calibration import analyse_profile, run_profile

NAME = "imu_thermal_calibration"
DESCRIPTION = (
    "ADIS16350-like IMU on a 20-60 degC ramp at 1 K/min with +-100 deg/s rate table -> "
    "bias and scale-factor temperature coefficients vs the emulator's truth -> MCAP"
)
PROFILE = "thermal_ramp"
DEFAULT_DURATION_S = 2400.0


def graph(options: ScenarioOptions, duration_s: float | None = None):
    """The scenario's graph (:func:`mems_scenarios.imu_calibration.graph` on thermal_ramp)."""
    return imu_calibration.graph(options, duration_s, profile=PROFILE, name=NAME)


def run(options: ScenarioOptions) -> dict:
    """Run the scenario (thermal_ramp profile)."""
    return run_profile(options, NAME, PROFILE, thermal=True)


def analyse(bag, pngs=None):
    """The figures of the scenario from its recording
    (:func:`~mems_scenarios.imu_calibration.analyse_profile`)."""
    return analyse_profile(bag, NAME, thermal=True, pngs=pngs)

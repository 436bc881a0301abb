"""Parameter table of the IMU's motion environment (:mod:`mems_sim.devices.imu_motion`): the
Earth rate and gravity model, and the vibration of the specific force, with unit, range and
source (:class:`~mems_sim.params.ParamSpec`); part of the IMU's table
(:data:`mems_sim.devices.imu_specs.IMU_SPECS`); docs/imu.md.
"""

from __future__ import annotations

from mems_sim.params import ParamSpec

__all__ = ["AXES", "ENVIRONMENT_SPECS", "VIBRATION_SPECS"]

AXES = ("x", "y", "z")  # body axes

#: Earth rate and gravity model (mems_sim.devices.imu_motion).
ENVIRONMENT_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "earth_rate",
        False,
        "-",
        "add the Earth's rotation (7.292115e-5 rad/s) projected into the body frame by the "
        "attitude to the true angular rate",
        "WGS-84 (NIMA TR8350.2, Table 3.1); off by default (the references have no Earth rate)",
    ),
    ParamSpec(
        "gravity_model",
        "standard",
        "-",
        "magnitude of gravity: 'standard' g0 = 9.80665 m/s^2 everywhere, or 'wgs84' normal "
        "gravity at latitude_deg and height_m (Somigliana with the second-order height term)",
        "standard gravity (CGPM 1901); WGS-84 normal gravity, NIMA TR8350.2 eqs. (4-1), (4-3)",
        choices=("standard", "wgs84"),
    ),
    ParamSpec(
        "latitude_deg",
        45.0,
        "deg",
        "geodetic latitude of the IMU (Earth rate components and normal gravity)",
        "parameter of the site",
        min=-90.0,
        max=90.0,
    ),
    ParamSpec(
        "height_m",
        0.0,
        "m",
        "ellipsoidal height of the IMU (normal gravity)",
        "parameter of the site; the height series of NIMA TR8350.2 eq. (4-3) holds to 20 km",
        min=-1.0e4,
        max=2.0e4,
    ),
)

#: Vibration of the specific force (mems_sim.devices.imu_motion.Vibration).
VIBRATION_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "vibration",
        "none",
        "-",
        "vibration added to the true specific force: 'none', 'sinusoid' (peak amplitude "
        "vibration_amplitude_{a} at vibration_frequency_hz) or 'random' (band-limited, PSD "
        "vibration_psd_{a} over [vibration_band_low_hz, vibration_band_high_hz])",
        "gnss-ins-sim vibration definitions (sinusoidal, PSD); MATLAB imuSensor with a "
        "vibrating trajectory",
        choices=("none", "sinusoid", "random"),
    ),
)
VIBRATION_SPECS += (
    tuple(
        ParamSpec(
            f"vibration_amplitude_{a}",
            0.0,
            "m/s^2",
            f"peak amplitude of the sinusoidal vibration along body {a}",
            "parameter of the test (0: none)",
            min=0.0,
            max=1.0e4,
        )
        for a in AXES
    )
    + tuple(
        ParamSpec(
            f"vibration_psd_{a}",
            0.0,
            "(m/s^2)^2/Hz",
            f"one-sided PSD of the random vibration along body {a} (1 g^2/Hz = 96.17 (m/s^2)^2/Hz)",
            "parameter of the test (0: none)",
            min=0.0,
            max=1.0e6,
        )
        for a in AXES
    )
    + (
        ParamSpec(
            "vibration_frequency_hz",
            10.0,
            "Hz",
            "frequency of the sinusoidal vibration (below fs/2)",
            "parameter of the test",
            min=0.0,
            max=1.0e5,
        ),
        ParamSpec(
            "vibration_phase_rad",
            0.0,
            "rad",
            "phase of the sinusoidal vibration at t = 0",
            "parameter of the test",
            min=-10.0,
            max=10.0,
        ),
        ParamSpec(
            "vibration_band_low_hz",
            1.0,
            "Hz",
            "lower edge of the random vibration's band",
            "parameter of the test",
            min=0.0,
            max=1.0e5,
        ),
        ParamSpec(
            "vibration_band_high_hz",
            40.0,
            "Hz",
            "upper edge of the random vibration's band (below fs/2)",
            "parameter of the test",
            min=0.0,
            max=1.0e5,
            min_exclusive=True,
        ),
        ParamSpec(
            "vibration_resolution_hz",
            0.1,
            "Hz",
            "line spacing of the random vibration (a sum of sinusoids of random phase, one per "
            "line; the record repeats after 2 / spacing)",
            "Shinozuka & Deodatis, Appl. Mech. Rev. 44(4), 1991 (spectral representation)",
            min=1.0e-4,
            max=1.0e3,
        ),
    )
)

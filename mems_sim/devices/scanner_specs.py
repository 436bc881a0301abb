"""Parameter table of the chapter-4 micro-scanner model (:mod:`mems_sim.devices.scanner`).

Every parameter of the mechanics, the comb drive and sensing, the DC transimpedance front end
and the drive programme with unit, range and source (:class:`~mems_sim.params.ParamSpec`;
Chen 2018, chapter 4); docs/scanner.md.
"""

from __future__ import annotations

from mems_sim.params import (
    AIR_DAMPING_TEMPCO,
    SILICON_EXPANSION_TEMPCO,
    SILICON_RESONANCE_TEMPCO,
    ParamSpec,
    batch_spread,
)

__all__ = ["SCANNER_SPECS"]

_WN_HZ = 624.6
_ZETA = 0.0066
# Inertia: not given in chapter 4. Chosen so that the 0-60 V drive of the comb below can
# sustain ~0.15 rad against zeta = 0.0066 (energy lost per period 2 pi zeta k A^2 ~ 4.7e-9 J
# vs. at most C_dr0 V_max^2 ~ 1.1e-8 J pumped by two comb engagements per period).
_J = 3.25e-13

SCANNER_SPECS: tuple[ParamSpec, ...] = (
    # --- mechanics, eqs. (66)-(68)
    ParamSpec(
        "natural_freq_hz",
        _WN_HZ,
        "Hz",
        "natural frequency wn/2pi of the tilting mode",
        "Chen 2018 Sec. 4.4.2 (identified 624.6 Hz)",
        min=1.0,
        max=1.0e6,
        spread=batch_spread(0.05, "+-5 % (torsion bar stiffness +-10 %, f ~ sqrt(k))"),
        tempco=SILICON_RESONANCE_TEMPCO,
    ),
    ParamSpec(
        "damping_ratio",
        _ZETA,
        "-",
        "damping ratio zeta = b/(2 sqrt(J k))",
        "Chen 2018 Sec. 4.4.2 (identified 0.0066)",
        min=0.0,
        max=1.0,
        min_exclusive=True,
        spread=batch_spread(0.20, "+-20 % damping (gap tolerance of the air films)"),
        tempco=AIR_DAMPING_TEMPCO,
    ),
    ParamSpec(
        "inertia",
        _J,
        "kg m^2",
        "moment of inertia J of the mirror",
        "not in chapter 4; chosen (module doc) so 0-60 V sustains ~0.15 rad",
        min=0.0,
        max=1.0e-6,
        min_exclusive=True,
        spread=batch_spread(0.02, "+-2 % mirror inertia (thickness tolerance)"),
    ),
    ParamSpec(
        "threshold_angle",
        0.0037,
        "rad",
        "theta_th, angle of maximum comb overlap",
        "Chen 2018 Sec. 4.4.2 (calibrated 0.0037 rad)",
        min=-0.1,
        max=0.1,
    ),
    # --- capacitance, eq. (105) with offset theta_th
    ParamSpec(
        "sense_c0",
        1.0e-12,
        "F",
        "Gaussian amplitude C0 of the sensing comb",
        "chosen: SNR ~85 -> 1 over the ring-down at sigma_n = 0.0435 V (Sec. 4.6)",
        min=0.0,
        max=1.0e-9,
        min_exclusive=True,
        spread=batch_spread(
            0.20,
            "+-20 % sensing comb gain (finger gap and overlap tolerance; Chen 2018 Sec. "
            "4.2.1 names the comb's gain drift, no value)",
        ),
        tempco=SILICON_EXPANSION_TEMPCO,
    ),
    ParamSpec(
        "sense_theta0",
        0.05,
        "rad",
        "Gaussian width theta0 of the sensing comb",
        "chosen (eq. (105) form; Table 5.2 has 0.2 rad for the chapter-5 device)",
        min=1.0e-4,
        max=1.0,
        spread=batch_spread(0.10, "+-10 % sensing comb width (finger length tolerance)"),
    ),
    ParamSpec(
        "sense_cb",
        2.0e-12,
        "F",
        "constant (parasitic/base) part C_b of the sensing comb",
        "chosen (eq. (105) form); does not enter dC/dt",
        min=0.0,
        max=1.0e-9,
    ),
    ParamSpec(
        "drive_c0",
        3.0e-12,
        "F",
        "Gaussian amplitude C0 of the driving comb",
        "chosen: sweep 1600->1250 Hz + 50 ms hold at 0-60 V ends near 0.155 rad (Table 4.2: 0.15)",
        min=0.0,
        max=1.0e-9,
    ),
    ParamSpec(
        "drive_theta0",
        0.05,
        "rad",
        "Gaussian width theta0 of the driving comb",
        "chosen, same comb geometry as the sensing comb",
        min=1.0e-4,
        max=1.0,
    ),
    ParamSpec(
        "drive_cb",
        2.0e-12,
        "F",
        "constant part C_b of the driving comb",
        "chosen; no torque",
        min=0.0,
        max=1.0e-9,
    ),
    ParamSpec(
        "torque_noise_std",
        2.0e-12,
        "N m",
        "std of the white process torque held per sample",
        "chosen (small unmodelled disturbance; gives the EKF a non-zero Q)",
        min=0.0,
        max=1.0e-3,
    ),
    ParamSpec(
        "initial_angle",
        1.0e-4,
        "rad",
        "theta at t = 0 (seed of the parametric growth)",
        "chosen",
        min=-0.5,
        max=0.5,
    ),
    # --- drive programme, Sec. 4.4.1
    ParamSpec(
        "drive_voltage_max",
        60.0,
        "V",
        "peak of the unipolar drive 0..V_max",
        "Chen 2018 Sec. 4.4.1 (0 to 60 V)",
        min=0.0,
        max=200.0,
    ),
    ParamSpec(
        "sweep_start_hz",
        1600.0,
        "Hz",
        "drive frequency at the start of the sweep",
        "Chen 2018 Sec. 4.4.1 (1600 Hz)",
        min=1.0,
        max=1.0e6,
    ),
    ParamSpec(
        "sweep_end_hz",
        1250.0,
        "Hz",
        "drive frequency at the end of the sweep and during "
        "the hold (2x the 625 Hz motion of Table 4.2)",
        "Chen 2018 Sec. 4.4.1 sweeps to 1220 Hz; Table 4.2 f_m = 625 Hz",
        min=1.0,
        max=1.0e6,
    ),
    ParamSpec(
        "sweep_time_s",
        0.25,
        "s",
        "duration of the linear frequency sweep",
        "chosen",
        min=0.0,
        max=1.0e4,
    ),
    ParamSpec(
        "hold_time_s",
        0.05,
        "s",
        "duration of the hold at sweep_end_hz",
        "chosen",
        min=0.0,
        max=1.0e4,
    ),
    ParamSpec(
        "ringdown_time_s",
        0.1,
        "s",
        "free decay after the drive cut-off (V = 0)",
        "Sec. 4.4.1 used 80 ms (~50 periods); 100 ms here reaches SNR < 1 with the chosen comb",
        min=0.0,
        max=1.0e4,
    ),
    # --- dc_transimpedance readout, eq. (64), Table 4.2
    ParamSpec(
        "sample_rate_hz",
        500.0e3,
        "Hz",
        "readout sample rate fs",
        "Table 4.2 (500 kHz)",
        min=1.0e3,
        max=1.0e9,
    ),
    ParamSpec(
        "sense_resistance",
        10.0e6,
        "Ohm",
        "transimpedance feedback resistance R_s",
        "Table 4.2 (10 MOhm)",
        min=0.0,
        max=1.0e12,
        min_exclusive=True,
    ),
    ParamSpec(
        "bias_voltage",
        10.0,
        "V",
        "sensing bias V_bias",
        "Table 4.2 (10 V)",
        min=0.0,
        max=1.0e3,
        min_exclusive=True,
    ),
    ParamSpec(
        "noise_std",
        0.0435,
        "V",
        "std sigma_n of the white readout noise",
        "Table 4.2 (0.0435 V)",
        min=0.0,
        max=100.0,
    ),
    ParamSpec(
        "psd_delay_s",
        0.114e-3,
        "s",
        "delay of the PSD angle reference",
        "Chen 2018 Sec. 4.4.1 (0.114 ms)",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "psd_noise_std",
        0.0,
        "rad",
        "white noise of the PSD reference",
        "chosen (none)",
        min=0.0,
        max=1.0,
    ),
    ParamSpec("substeps", 1, "-", "RK4 steps per sample interval", "numerics", min=1, max=1000),
    # --- drift of the sensing comb away from its identified analog map (Sec. 4.2.1)
    ParamSpec(
        "sense_gain_drift",
        0.0,
        "-",
        "relative drift of the sensing comb's gain: C0 x (1 + drift)",
        "Chen 2018 Sec. 4.2.1 (temperature drift of the analog map); grid +-0.2",
        min=-0.9,
        max=10.0,
    ),
    ParamSpec(
        "sense_width_drift",
        0.0,
        "-",
        "relative drift of the sensing comb's width: theta0 x (1 + drift)",
        "Chen 2018 Sec. 4.2.1 (temperature drift of the analog map); grid +-0.1",
        min=-0.9,
        max=10.0,
    ),
)

"""Bench programme of the shared-electrode scanner (Chen 2018 ch. 5), ROS-free: on one
device (its parameters as built, driven directly through the core
:class:`~mems_sim.devices.scanner_amdm.AmdmScannerDevice`, own noise seeds):

1. ring-downs: drive off, mirror released from :data:`RELEASE_ANGLE`, :data:`RELEASES`
   times, recorded with the AMDM output and an optical reference angle (the thesis' laser
   and PSD, Fig. 5.5: the angle with :data:`REFERENCE_NOISE_RAD` of white noise, at the
   instants the AMDM output describes, the chain's design delay earlier); the swings against
   the reference map the comb, C_0 and theta_0
   (:func:`~mems_estimation.identification.scanner_amdm_identification.comb_fit`, Sec.
   5.5.1), the reference's decay gives zeta w_n and the AMDM output's 2 w_d line w_n
   (:func:`~mems_estimation.identification.scanner_amdm_identification.identify_with_reference`);
   the inertia is the design's, as the thesis computes it from the design dimensions;
2. resonance search: the study's sweep rate, downward from :data:`SEARCH_ABOVE_HZ` above
   the identified 2 f_n, watching the AMDM output's envelope (peak-to-peak per
   :data:`BLOCK_S`) for the parametric onset;
3. the sweep window of the run: :data:`LEAD_HZ` above the found onset, as long as the
   study's (60 Hz over 60 ms); when neither the search nor the slower one finds an onset,
   both again with the drive raised by :data:`DRIVE_STEP`, the run's drive too.

Scenario ``scanner_shared_electrodes`` runs it before its graph.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import CubicSpline

from mems_estimation.filters import scanner_amdm_model as sam
from mems_estimation.identification import scanner_amdm_identification as sai
from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import resolve

RELEASE_ANGLE = 0.3  # rad: a large swing (the comb's map, w_n and zeta)
RINGDOWN_S = 0.012
RELEASES = 8  # ring-downs (w_n and zeta averaged: the process noise's share falls)
FIT_SKIP_S = 2.0e-4  # the chain's filters settle after the release [s]
#: White noise of the optical reference angle [rad] (assumption: a laser on a position
#: sensing detector resolves ~0.1 mrad over the bench's lever arm).
REFERENCE_NOISE_RAD = 1.0e-4
SEARCH_ABOVE_HZ = 450.0
SWEEP_RATE = (sa.SWEEP_STUDY["sweep_start_hz"] - sa.SWEEP_STUDY["sweep_end_hz"]) / sa.SWEEP_STUDY[
    "sweep_time_s"
]  # Hz/s, the study's
BLOCK_S = 1.0e-4
ONSET_FACTOR = 4.0  # envelope above this many times the quiet level: motion
#: Window start above the found onset: the study's 31.32 kHz start over the nominal design
#: device's bench onset (design choice, rounded to 5 Hz).
LEAD_HZ = 20.0
SLOW_FACTOR = 4.0  # the second, slower search (and run window) [-]
SLOW_RANGE_HZ = (300.0, 60.0)  # its range above 2 f_n [Hz] (the drive's DC stiffening: +0.55 %)
#: The drive's rise [-] when neither search finds an onset (a part whose parametric threshold
#: is near or above the drive: +20 % covers the +-10 % k, +-20 % b, +-20 % C_0 batch).
DRIVE_STEP = 1.2
SPAN_HZ = sa.SWEEP_STUDY["sweep_start_hz"] - sa.SWEEP_STUDY["sweep_end_hz"]


def design() -> dict:
    """The Table 5.2 design values (the table's defaults, no device drawn)."""
    return sa.resolve_amdm()


def _adc_volts(fr: sa.AmdmFrame, dev: sa.AmdmScannerDevice) -> np.ndarray:
    return fr.codes * dev.lsb


def ringdown(p: dict, angle: float, seed: int) -> tuple[np.ndarray, float, np.ndarray]:
    """A ring-down record (drive off, released from ``angle`` [rad]) from FIT_SKIP_S on:
    the ADC output [V], its rate [Hz] and the optical reference angle [rad] at the instants
    the output describes (module doc; its noise seeded from ``seed``)."""
    q = dict(p, drive_voltage_max=0.0, initial_angle=angle)
    dev = sa.AmdmScannerDevice(q, seed=seed)
    fr = dev.step(int(RINGDOWN_S * dev.fs))
    y = _adc_volts(fr, dev)
    t = np.arange(y.size) / dev.fs
    tau = sa.design_chain(design()).delay  # the electronics' design, not the part's
    noise = np.random.default_rng([seed, 1]).standard_normal(y.size)
    ref = CubicSpline(t, fr.theta)(np.maximum(t - tau, 0.0)) + REFERENCE_NOISE_RAD * noise
    k0 = int(FIT_SKIP_S * dev.fs)
    return y[k0:], dev.fs, ref[k0:]


def search(p: dict, f_top: float, f_bottom: float, seed: int, slow: float = 1.0) -> float | None:
    """Downward sweep f_top -> f_bottom [Hz] at the study's rate / ``slow``; the drive
    frequency [Hz] at which the AMDM output's envelope first exceeds ONSET_FACTOR x its
    quiet level (None: no onset)."""
    tw = (f_top - f_bottom) / SWEEP_RATE * slow
    q = dict(p, sweep_start_hz=f_top, sweep_end_hz=f_bottom, sweep_start_s=0.0, sweep_time_s=tw)
    dev = sa.AmdmScannerDevice(q, seed=seed)
    fr = dev.step(int(tw * dev.fs))
    y = _adc_volts(fr, dev)
    nb = int(BLOCK_S * dev.fs)
    m = y.size // nb
    blocks = y[: m * nb].reshape(m, nb)
    env = blocks.max(axis=1) - blocks.min(axis=1)
    # quiet: the blocks after the release transient (the initial angle decayed)
    quiet = float(np.median(env[m // 20 : m // 10])) if m >= 20 else float(np.median(env))
    hit = np.nonzero(env[m // 10 :] > ONSET_FACTOR * max(quiet, dev.lsb))[0]
    if hit.size == 0:
        return None
    return float(fr.drive_freq[(hit[0] + m // 10) * nb])


def run_bench(p: dict, seed: int) -> dict:
    """Ring-down identification, resonance search and the run's sweep window of device
    ``p`` (module doc), noise seed ``seed``. Raises ValueError when no onset is found."""
    d = design()
    fn_design = math.sqrt(d["spring_constant"] / d["inertia"]) / (2 * math.pi)
    band = (2 * fn_design * 0.85, 2 * fn_design * 1.15)
    records = [ringdown(p, RELEASE_ANGLE, seed + 10 * r) for r in range(RELEASES)]
    comb = sai.comb_fit(
        np.concatenate([ref for _, _, ref in records]),
        np.concatenate([y for y, _, _ in records]),
        resolve(sam.ESTIMATOR_SPECS, {}),
    )
    mapped = dict(d, cap_c0=comb["cap_c0"], cap_theta0=comb["cap_theta0"])
    fits = [sai.identify_with_reference(y, ref, fs, mapped, band) for y, fs, ref in records]
    model = dict(
        sai.average(fits),
        cap_c0=comb["cap_c0"],
        cap_theta0=comb["cap_theta0"],
        comb_rms_residual=comb["rms_residual"],
    )
    f2 = model["omega_n"] / math.pi  # 2 f_n [Hz]
    # a device near its threshold has a narrow tongue with slow growth: the search is
    # repeated SLOW_FACTOR times slower around the tongue's expected centre (the run's
    # window is then swept as much slower), then with the drive raised by DRIVE_STEP (the
    # run's drive too), as a lab raises the drive of a part that does not start
    for drive in (p["drive_voltage_max"], DRIVE_STEP * p["drive_voltage_max"]):
        q = dict(p, drive_voltage_max=drive)
        for slow, (top, bottom) in ((1.0, (SEARCH_ABOVE_HZ, 0.0)), (SLOW_FACTOR, SLOW_RANGE_HZ)):
            onset = search(q, f2 + top, f2 + bottom, seed + 1, slow)
            if onset is not None:
                start = onset + LEAD_HZ / slow
                return dict(
                    model=model,
                    onset_hz=onset,
                    sweep_start_hz=start,
                    sweep_end_hz=start - SPAN_HZ / slow,
                    drive_voltage_max=float(drive),
                )
    raise ValueError(
        f"no parametric onset between {f2 + SEARCH_ABOVE_HZ:.0f} and {f2:.0f} Hz at "
        f"{p['drive_voltage_max']:g} V or {DRIVE_STEP * p['drive_voltage_max']:g} V"
    )

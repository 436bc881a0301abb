"""Bench programme of the shared-electrode scanner (Chen 2018 ch. 5), ROS-free: on one
device (its parameters as built, driven directly through the core
:class:`~mems_sim.devices.scanner_amdm.AmdmScannerDevice`, own noise seeds):

1. ring-downs: drive off, mirror released from :data:`RELEASE_ANGLES` (a small swing for
   zeta, a large one for w_n), :data:`RELEASES` times each; the AMDM output's 2 w_d line
   gives w_n and zeta
   (:func:`mems_estimation.identification.scanner_amdm_identification.identify`);
2. resonance search: the study's sweep rate, downward from :data:`SEARCH_ABOVE_HZ` above
   the identified 2 f_n, watching the AMDM output's envelope (peak-to-peak per
   :data:`BLOCK_S`) for the parametric onset;
3. the sweep window of the run: :data:`LEAD_HZ` above the found onset, as long as the
   study's (60 Hz over 60 ms).

Scenario ``scanner_shared_electrodes`` runs it before its graph.
"""

from __future__ import annotations

import math

import numpy as np

from mems_estimation.identification import scanner_amdm_identification as sai
from mems_sim.devices import scanner_amdm as sa

RELEASE_ANGLES = (0.05, 0.3)  # rad: small swing (zeta), large swing (w_n)
RINGDOWN_S = 0.012
RELEASES = 4  # ring-downs of each swing (w_n and zeta averaged)
FIT_SKIP_S = 2.0e-4  # the chain's filters settle after the release [s]
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
SPAN_HZ = sa.SWEEP_STUDY["sweep_start_hz"] - sa.SWEEP_STUDY["sweep_end_hz"]


def design() -> dict:
    """The Table 5.2 design values (the table's defaults, no device drawn)."""
    return sa.resolve_amdm()


def _adc_volts(fr: sa.AmdmFrame, dev: sa.AmdmScannerDevice) -> np.ndarray:
    return fr.codes * dev.lsb


def ringdown(p: dict, angle: float, seed: int) -> tuple[np.ndarray, float, float]:
    """A ring-down record (drive off, released from ``angle`` [rad]): ADC output [V] from
    FIT_SKIP_S on, its rate [Hz] and the swing amplitude there [rad] (the release angle's
    decay by the design damping over FIT_SKIP_S)."""
    q = dict(p, drive_voltage_max=0.0, initial_angle=angle)
    dev = sa.AmdmScannerDevice(q, seed=seed)
    y = _adc_volts(dev.step(int(RINGDOWN_S * dev.fs)), dev)
    d = design()
    a = angle * math.exp(-0.5 * d["damping"] / d["inertia"] * FIT_SKIP_S)
    return y[int(FIT_SKIP_S * dev.fs) :], dev.fs, a


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
    fits = []
    for r in range(RELEASES):  # w_n averaged over repeated releases (noise seeds apart)
        y_small, fs, _ = ringdown(p, RELEASE_ANGLES[0], seed + 10 * r)
        y_large, _, a_large = ringdown(p, RELEASE_ANGLES[1], seed + 10 * r + 2)
        fits.append(sai.identify(y_small, y_large, fs, d, band, a_large))
    model = sai.average(fits)
    f2 = model["omega_n"] / math.pi  # 2 f_n [Hz]
    # a device near its threshold has a narrow tongue with slow growth: the search is
    # repeated SLOW_FACTOR times slower around the tongue's expected centre, and the run's
    # window is then swept as much slower
    for slow, (top, bottom) in ((1.0, (SEARCH_ABOVE_HZ, 0.0)), (SLOW_FACTOR, SLOW_RANGE_HZ)):
        onset = search(p, f2 + top, f2 + bottom, seed + 1, slow)
        if onset is not None:
            break
    else:
        raise ValueError(f"no parametric onset between {f2 + SEARCH_ABOVE_HZ:.0f} and {f2:.0f} Hz")
    start = onset + LEAD_HZ / slow
    return dict(
        model=model, onset_hz=onset, sweep_start_hz=start, sweep_end_hz=start - SPAN_HZ / slow
    )

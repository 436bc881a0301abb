"""The bench of the shared-electrode scanner (mems_estimation.studies.scanner_amdm_bench):
the resonance search places the sweep window so that a drawn device's parametric
resonance is acquired."""

import numpy as np
import pytest

from mems_estimation.studies import scanner_amdm_bench as b
from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import draw_device


def _device(device_seed: int) -> dict:
    """The scenario's /scanner_amdm device (the study's drive, Table 5.2 process noise)
    drawn for ``device_seed``."""
    p = dict(sa.SWEEP_STUDY, torque_noise_std=1.15e-14 * np.sqrt(1.0e11 * 10))
    return sa.resolve_amdm(draw_device(sa.AMDM_SPECS, sa.resolve_amdm(p), device_seed, 0.0))


def _acquired(device_seed: int) -> bool:
    """Motion (|theta| > 0.05 rad, 250 x the missed sweep's 2e-4 rad, after 20 ms of the
    60 ms run) with the bench's window."""
    p = _device(device_seed)
    r = b.run_bench(p, 8000 + device_seed)
    assert r["sweep_start_hz"] - r["sweep_end_hz"] in (pytest.approx(60.0), pytest.approx(15.0))
    run = dict(p, **{k: r[k] for k in ("sweep_start_hz", "sweep_end_hz", "drive_voltage_max")})
    th = sa.AmdmScannerDevice(run, seed=10 + device_seed).step(60000).theta
    return bool(np.abs(th[20000:]).max() > 0.05)


def test_the_fixed_sweep_misses_device_seed_5():
    """The premise: the study's fixed 31.32 -> 31.26 kHz sweep finds no motion on it."""
    th = sa.AmdmScannerDevice(_device(5), seed=15).step(60000).theta
    assert np.abs(th[20000:]).max() < 0.01


@pytest.mark.parametrize("device_seed", [5, 101])
def test_bench_window_acquires_motion(device_seed):
    assert _acquired(device_seed)


@pytest.mark.slow
def test_bench_window_acquires_motion_on_19_of_20_drawn_devices():
    """Draws 101-120: with the drive raised 20 % for a part that does not start (device
    115's parametric threshold is 164 V, above the 150 V drive; 102, 116 and 120, at
    142-145 V, grew too slowly within the 60 ms run at 150 V)."""
    acquired = [s for s in range(101, 121) if _acquired(s)]
    print(
        f"acquired: {len(acquired)} of 20, missing {sorted(set(range(101, 121)) - set(acquired))}"
    )
    assert len(acquired) >= 19

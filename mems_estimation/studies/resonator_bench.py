"""The sigma-delta resonator's bench (Colinet et al., Sec. 6): the device as built in its
comparator loop, ROS-free, with the pulse driver switched off again and again, and its f0
and Q identified from the ring-downs of the one-bit stream
(:mod:`mems_estimation.identification.resonator_identification`).

The lab measures the part (its f0 and Q as built) on a quiet bench: a low output noise
(0.02 V), no added thermomechanical noise and the design pulse height, not at a scenario's
noise levels: the ring-downs must show the resonator, not the noise.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mems_estimation.identification.resonator_identification import identify
from mems_sim.devices.resonator import SdResonatorDevice

__all__ = ["BENCH_NOISE_STD", "bench_ringdowns", "bench_identification"]

#: Output noise of the bench's comparator loop [V].
BENCH_NOISE_STD = 0.02
#: A pulse height that leaves the resonator free [V] (the driver off; 0 is not a valid one).
DRIVER_OFF = 1e-12
#: Ring-downs per bench record. Measured on the nominal device and device seed 5, noise
#: seeds 19/29/39: f0 errors -15..+77 ppm with 40, +25..+55 ppm with 160 (the one-bit
#: quantiser biases f0 high by ~40 ppm); the observer's error grows ~1.5x at 200 ppm.
RINGDOWNS = 160


def bench_ringdowns(
    device: Mapping[str, Any], seed: int, n: int = RINGDOWNS, on: int = 1000, off: int = 2000
) -> list:
    """The comparator loop of ``device`` (RESONATOR_SPECS values as built) at
    :data:`BENCH_NOISE_STD` output noise (noise seed ``seed``), ``n`` times driven for
    ``on`` samples, then the driver off for a ring-down of ``off`` samples; the
    ring-downs' bits (-1/+1)."""
    p = dict(device, mode="comparator", output_noise_std=BENCH_NOISE_STD)
    dev = SdResonatorDevice(p, seed=seed)
    out = []
    for _ in range(n):
        dev.retune(p)
        dev.step(on)
        dev.retune(dict(p, pulse_amplitude=DRIVER_OFF))
        out.append(dev.step(off).bits)
    return out


def bench_identification(
    device: Mapping[str, Any], design_f0_hz: float, design_q: float, seed: int
) -> dict:
    """:func:`bench_ringdowns` of ``device`` fitted from the design values ``design_f0_hz``
    [Hz] and ``design_q`` [-] (the start of the fit). Returns ``model`` (f0_hz [Hz],
    quality_factor [-]) and ``fit`` (the ring-down fit as a plain mapping). ValueError
    when the fit fails."""
    fs = float(device["sample_rate_hz"])
    out = identify(bench_ringdowns(device, seed), fs, design_f0_hz, design_q)
    return dict(model=out["model"], fit=out["fit"]._asdict())

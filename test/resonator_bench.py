"""The resonator bench of mems_scenarios.sd_resonator for tests: ring-downs of a device."""

from mems_sim.devices.resonator import SdResonatorDevice


def bench_ringdowns(dp: dict, seed: int, n: int = 40, on: int = 1000, off: int = 2000):
    """The comparator loop of the device ``dp`` at 0.02 V output noise (noise seed
    ``seed``), n times driven for ``on`` samples, then the driver off (pulse height
    1e-12 V) for a ring-down of ``off`` samples; the ring-downs' bits."""
    p = dict(dp, mode="comparator", output_noise_std=0.02)
    dev = SdResonatorDevice(p, seed=seed)
    out = []
    for _ in range(n):
        dev.retune(p)
        dev.step(on)
        dev.retune(dict(p, pulse_amplitude=1e-12))
        out.append(dev.step(off).bits)
    return out

"""Figures of identified noise models: Allan deviation with the fitted terms."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mems_estimation.identification.imu_noise_fit import avar_gm
from mems_sim.bag.output_paths import write_output
from mems_sim.table import significant


def term_labels(n: float, k: float, b: float, t: float) -> tuple[str, str, str]:
    """Legend labels of the white-noise, random-walk and Gauss-Markov terms, every value
    with its three significant digits (:func:`mems_sim.table.significant`): N [unit/sqrt(Hz)],
    K [unit*sqrt(Hz)], B [unit], T [s]."""
    return (
        f"N/√τ, N={significant(n)}",
        f"K√(τ/3), K={significant(k)}",
        f"Gauss-Markov B={significant(b)}, T={significant(t)} s",
    )


def plot_allan(model, path: Path, overwrite: bool = True) -> None:
    """Allan deviation per axis with confidence bars, the fitted model and its terms, written
    to ``path`` whole and never through a symbolic link (an existing file only with
    ``overwrite``; :func:`~mems_sim.bag.output_paths.write_output`, BagWriteError)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, panels = plt.subplots(1, 2, figsize=(13, 5.2))
    for panel, prefix, unit in ((panels[0], "gyro", "rad/s"), (panels[1], "accel", "m/s²")):
        axes = [a for a in model.axes if a.axis.startswith(prefix)]
        for k, axis in enumerate(axes):
            tau, adev = np.asarray(axis.tau), np.asarray(axis.adev)
            err = [adev - np.asarray(axis.adev_ci_low), np.asarray(axis.adev_ci_high) - adev]
            line = panel.errorbar(
                tau, adev, yerr=err, fmt="o", ms=3, capsize=2, label=f"{axis.axis} measured"
            )[0]
            n, b, kk, t, q = (
                axis.white_noise_density.value,
                axis.bias_instability.value,
                axis.random_walk.value,
                axis.correlation_time.value,
                axis.quantization.value,
            )
            gm = avar_gm(tau, b, t) if b > 0 and math.isfinite(t) else 0 * tau
            total = n**2 / tau + kk**2 * tau / 3 + gm + 3 * q**2 / tau**2
            panel.loglog(
                tau, np.sqrt(total), "-", color=line.get_color(), lw=1, label=f"{axis.axis} fit"
            )
            if k == 0:
                white, walk, markov = term_labels(n, kk, b, t)
                panel.loglog(tau, n / np.sqrt(tau), "k--", lw=0.8, label=white)
                panel.loglog(tau, kk * np.sqrt(tau / 3), "k-.", lw=0.8, label=walk)
                panel.loglog(tau, np.sqrt(np.maximum(gm, 1e-300)), "k:", lw=1, label=markov)
        panel.set_xscale("log")
        panel.set_yscale("log")
        lo = min(np.min(np.asarray(a.adev)) for a in axes)
        panel.set_ylim(lo / 3, None)
        panel.set_xlabel("averaging time τ [s]")
        panel.set_ylabel(f"Allan deviation [{unit}]")
        panel.set_title(f"{prefix}: overlapping Allan deviation ({model.tau_grid} τ)")
        panel.grid(True, which="both", alpha=0.3)
        panel.legend(fontsize=7)
    fig.suptitle(
        f"{model.num_samples} samples at {model.sample_rate_hz:g} Hz, identified noise model"
    )
    fig.tight_layout()
    write_output(path, lambda tmp: fig.savefig(tmp, dpi=110), overwrite)
    plt.close(fig)

"""The accelerometer's bench (Zhang 2010, ch. 2 model): the device as built on a shaker,
run ROS-free in the two configurations of the electronics that the identification needs,
and identified (:mod:`mems_estimation.identification.accelerometer_identification`).

The lab knows its electronics' settings (carrier V1, charge-amplifier C4, bias V_B, ADC
step) and the electrode's area and dielectric (lithography): those are the designer's
values; mass, spring, damping, gap and the readout noise are what the bench finds.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mems_estimation.identification.accelerometer_identification import (
    SQUARE_HALF_PERIOD_S,
    identify,
    square_wave_rows,
)
from mems_sim.devices import accelerometer

__all__ = ["BENCH_DURATION_S", "BENCH_AMPLITUDE", "bench_records", "bench_identification"]

#: Length of each bench record [s] (1e5 samples at 1 MHz: ~200 transitions of the square
#: wave; standard errors of the fit ~0.2-0.5 % on Table I's device with ch. 5's noise).
BENCH_DURATION_S = 0.1
#: Amplitude of the shaker's square wave [m/s^2] (1 g: a displacement of ~1.5 % of the
#: gap, where the parallel-plate nonlinearity is ~0.1 %).
BENCH_AMPLITUDE = accelerometer.G0


def _configurations() -> dict[str, dict]:
    """The electronics of the two records: carrier only; carrier and bias, no feedback."""
    return dict(open=dict(mode="open_loop"), bias=dict(mode="pi_rebalance", kp=0.0, ki=0.0))


def bench_records(
    device: Mapping[str, Any],
    nominal: Mapping[str, Any],
    seed: int,
    duration_s: float = BENCH_DURATION_S,
    amplitude: float = BENCH_AMPLITUDE,
) -> dict:
    """The bench's records of ``device`` (ACCEL_SPECS values as built) whose electronics
    are designed from ``nominal``: for ``open`` and ``bias`` (:func:`_configurations`;
    noise seeds ``seed`` and ``seed + 1``) the shaker's input [m/s^2] at the sample
    instants and the readout [V] the ADC delivers, plus ``fs`` [Hz] and the ``design``
    values the identification takes (eps A [F m], V1 [V], C4 [F], V_B [V], ADC step [V])."""
    fs = float(device["sample_rate_hz"])
    n = int(round(duration_s * fs))
    t, a = square_wave_rows(duration_s, fs, amplitude, SQUARE_HALF_PERIOD_S)
    out: dict[str, Any] = dict(fs=fs)
    with tempfile.TemporaryDirectory(prefix="mems-accel-bench-") as tmp:
        shaker = Path(tmp) / "square_wave.txt"
        np.savetxt(shaker, np.column_stack([t, a]))
        profile = dict(profile="file", profile_file=str(shaker))
        for k, (name, config) in enumerate(_configurations().items()):
            dev = accelerometer.ForceRebalanceAccelerometer(
                dict(device, **profile, **config),
                seed=seed + k,
                nominal=dict(nominal, **profile, **config),
            )
            frame = dev.step(n)
            out[name] = (frame.accel, frame.code * dev.lsb)
            if name == "bias":
                v_b = dev.v_b
    nom = accelerometer.validate_params(nominal)
    out["design"] = dict(
        eps_area=accelerometer.eps_area(nom),
        carrier_amplitude=nom["carrier_amplitude"],
        feedback_capacitor=nom["feedback_capacitor"],
        bias_voltage=v_b,
        adc_lsb=accelerometer.adc_lsb(nom),
    )
    return out


def _guess(nominal: Mapping[str, Any], v_b: float) -> dict[str, float]:
    """Start values of the fit: the designer's b0/m, w^2 of both records and H."""
    p = accelerometer.validate_params(nominal)
    ea, d0, m = accelerometer.eps_area(p), p["gap"], p["mass"]

    def w2(vb):
        return (p["stiffness"] - ea * (p["carrier_amplitude"] ** 2 + 2 * vb * vb) / d0**3) / m

    return dict(
        damping_per_mass=p["damping"] / m,
        omega2_open=w2(0.0),
        omega2_bias=w2(v_b),
        readout_gain=accelerometer.readout_gain(p),
    )


def bench_identification(
    device: Mapping[str, Any], nominal: Mapping[str, Any], seed: int, **record_args
) -> dict:
    """:func:`bench_records` of ``device`` and their identification. Returns ``model``
    (:data:`~mems_estimation.identification.accelerometer_identification.MODEL_KEYS`, SI)
    and ``fit`` (its ResponseFit as a plain mapping). ValueError when the fit fails."""
    rec = bench_records(device, nominal, seed, **record_args)
    out = identify(
        {k: rec[k] for k in ("open", "bias")},
        rec["fs"],
        rec["design"],
        _guess(nominal, rec["design"]["bias_voltage"]),
    )
    fit = out["fit"]._asdict()
    fit["std_errors"] = list(fit["std_errors"])
    fit["residual_std"] = list(fit["residual_std"])
    return dict(model=out["model"], fit=fit)

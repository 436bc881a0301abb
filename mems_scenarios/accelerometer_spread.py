"""Scenario ``accelerometer_spread``: the force-rebalance accelerometer's EKF loop against
its PI loop on one device of a manufacturing batch (Zhang 2010, chapter 5, Table III).

The PI and hybrid-EKF loops at 0.1 g and 1 g (10 Hz, chapter-5 noise) of
``accelerometer_snr``, with the same seeds per device, on the device that
``--device-seed`` draws (spread of mass, stiffness, damping and gap: the parameter table);
the rebalance bias (eq. 2-18) is designed from the nominal values, as a batch's electronics
are, the in-loop EKF's model identified on the bench for the drawn device, and the oracle
EKF loops run beside with the device's own table. Figures: the EKF-over-PI output SNR gain
at 0.1 g and 1 g (target >= +6 dB), the identified loops against the oracle's, the
identification's errors and the device's mismatch against the nominal model (ratios of m,
k, b, d0 and the relative errors of the effective stiffness and of k_eff/m). Meant for
``run_campaign`` over noise seeds x device seeds.
"""

from __future__ import annotations

from mems_scenarios import accelerometer_snr as _snr
from mems_scenarios.base import ScenarioOptions
from mems_scenarios.contract import GraphSpec, ScenarioResult

NAME = _snr.NAME_SPREAD
DESCRIPTION = (
    "force-rebalance accelerometer (Zhang 2010): EKF loop vs PI loop at 0.1 g and 1 g on one "
    "drawn device, filter on the bench's model (for campaigns over --device-seeds)"
)
DEFAULT_DURATION_S = _snr.DEFAULT_DURATION_S


def graph(options: ScenarioOptions, duration_s: float) -> GraphSpec:
    """The scenario's graph: the devices of :func:`~accelerometer_snr.spread_cases`."""
    return _snr.graph(options, duration_s, spread=True)


def prepare(options: ScenarioOptions) -> dict:
    """The bench's model YAMLs the graph names (:func:`accelerometer_snr.prepare`)."""
    return _snr.prepare(options, spread=True)


def analyse(bag, pngs=None) -> ScenarioResult:
    """The scenario's figures from its recording alone (:func:`accelerometer_snr.analyse`)."""
    return _snr.analyse(bag, pngs, spread=True)


def run(options: ScenarioOptions) -> dict:
    """Run the scenario; return the tables, figures and paths."""
    return _snr.run(options, spread=True)

"""The accelerometer's bench in a scenario: the device an emulator node of the scenario
builds, identified on the bench before the graph runs
(:func:`mems_estimation.studies.accelerometer_bench.bench_identification`), its model
written beside the recording for the filters to load (``params_yaml``,
``loop_params_yaml``), and the device's own table beside it for the oracle rows. Shared by
``accelerometer_snr``, ``accelerometer_spread`` and ``accelerometer_faults``.
"""

from __future__ import annotations

from mems_estimation.identification.accelerometer_identification import (
    MODEL_KEYS,
    save_identification,
)
from mems_estimation.studies import accelerometer_bench
from mems_scenarios import base, contract
from mems_sim.devices import accelerometer
from mems_sim.nodes.accelerometer_node import REFERENCE_TEMPERATURE_C
from mems_sim.params import draw_device

__all__ = [
    "BENCH_SEED_OFFSET",
    "device_as_built",
    "bench_device",
    "bench_paths",
    "bench_identification",
]

#: Noise seed of the bench's first record (the run seed x 100 plus this; the second: + 1),
#: apart from every device's of the scenarios (the run seed x 100 plus its place, < 90).
BENCH_SEED_OFFSET = 90


def device_as_built(params: dict, fixed=()) -> dict:
    """The device an accelerometer node builds from its parameter values ``params``: its
    :data:`~mems_sim.devices.accelerometer.ACCEL_SPECS` values drawn for ``device_seed``
    and moved to ``temperature_c`` (:func:`~mems_sim.params.draw_device`, as
    :meth:`~mems_sim.ros.node_base.EmulatorNode.device_values` does; ``fixed``: the values
    the user set, left as given) as ``p``, and as designed (``nominal``), validated."""
    nominal = {s.name: params[s.name] for s in accelerometer.ACCEL_SPECS}
    delta_k = params["temperature_c"] - REFERENCE_TEMPERATURE_C
    drawn = draw_device(
        accelerometer.ACCEL_SPECS, nominal, params["device_seed"], delta_k, fixed=fixed
    )
    return dict(
        p=accelerometer.validate_params(drawn), nominal=accelerometer.validate_params(nominal)
    )


def bench_device(options: base.ScenarioOptions, entry: contract.NodeEntry) -> dict:
    """The device the emulator node ``entry`` builds (:func:`device_as_built` of its
    parameters with the user's ``--set``, ``--device-seed`` and ``--temperature``)."""
    from mems_sim.ros.params_file import node_matches

    variation = dict(device_seed=options.device_seed, temperature_c=options.temperature_c)
    values = contract.full_parameters(entry, options.overrides, variation)
    fixed = {o.name for o in options.overrides if node_matches(o.node, entry.fqn)}
    return device_as_built(values, fixed)


def bench_paths(options: base.ScenarioOptions, name: str, out=None) -> dict:
    """Where the bench's results of scenario ``name`` go, beside the MCAP file ``out``
    (None: the options' ``out``, else ``runs/``): ``path``
    ``<stem>-seed<N>-accelerometer_params.yaml`` (the identified model) and
    ``oracle_path`` ``...-accelerometer_oracle_params.yaml`` (the device's own table's)."""
    return base.bench_paths(options, name, "accelerometer", out)


def bench_identification(
    options: base.ScenarioOptions, entry: contract.NodeEntry, name: str, out=None
) -> dict:
    """:func:`bench_device` of ``entry`` identified
    (:func:`~mems_estimation.studies.accelerometer_bench.bench_identification`, noise seeds
    from :data:`BENCH_SEED_OFFSET`), written to :func:`bench_paths`. Returns ``model``,
    ``fit``, ``path`` and ``oracle_path``. ScenarioError when the fit fails."""
    built = bench_device(options, entry)
    try:
        bench = accelerometer_bench.bench_identification(
            built["p"], built["nominal"], int(options.seed) * 100 + BENCH_SEED_OFFSET
        )
    except ValueError as exc:
        raise base.ScenarioError(f"{name}: bench identification failed: {exc}") from None
    paths = bench_paths(options, name, out)
    paths["path"].parent.mkdir(parents=True, exist_ok=True)
    save_identification(dict(bench["model"], fit=bench["fit"]), str(paths["path"]))
    save_identification({k: built["p"][k] for k in MODEL_KEYS}, str(paths["oracle_path"]))
    return dict(bench, **paths)

"""The shared-electrode scanner's bench in a scenario: the device the emulator node of
``scanner_shared_electrodes`` builds, identified on the bench before the graph runs
(:func:`mems_estimation.studies.scanner_amdm_bench.run_bench`: ring-downs against an optical
reference, the comb's map, the resonance search), its model written beside the recording for
the filters to load (``params_yaml``) and the device's own table beside it for the oracle
filters. The resonance search decides the run's sweep window, a parameter of the device
node, so the graph is made from the bench's result.
"""

from __future__ import annotations

from mems_estimation.identification.scanner_amdm_identification import (
    MODEL_KEYS,
    save_identification,
)
from mems_estimation.studies import scanner_amdm_bench
from mems_scenarios import base, contract
from mems_sim.devices import scanner_amdm as sa
from mems_sim.params import draw_device, spec_table

__all__ = ["BENCH_SEED_OFFSET", "device_as_built", "bench_paths", "bench_identification"]

#: Noise seed of the bench's records: the run seed x 100 plus this (the bench's releases
#: take up to +32 more), apart from the scenario's devices' (the run seed x 10 plus 0, 1).
BENCH_SEED_OFFSET = 50
#: The fit's results kept in the YAML and the run record beside the model.
FIT_KEYS = ("omega_n", "zeta", "comb_rms_residual", "rms_residual")


def device_as_built(params: dict, fixed=()) -> dict:
    """The device a ``scanner_amdm_node`` builds from its parameter values ``params``: its
    :data:`~mems_sim.devices.scanner_amdm.AMDM_SPECS` values drawn for ``device_seed`` and
    moved to ``temperature_c`` (:func:`~mems_sim.params.draw_device`, as the emulator node
    draws them; ``fixed``: the values the user set, left as given), resolved."""
    from mems_scenarios.contract import node_class

    specs = sa.AMDM_SPECS
    t_ref = float(spec_table(node_class("scanner_amdm_node").SPECS)["temperature_c"].default)
    drawn = draw_device(
        specs,
        {s.name: params[s.name] for s in specs},
        params["device_seed"],
        params["temperature_c"] - t_ref,
        fixed=fixed,
    )
    return sa.resolve_amdm(drawn)


def bench_paths(options: base.ScenarioOptions, name: str, out=None) -> dict:
    """Where the bench's results go, beside the MCAP file ``out`` (None: the options' ``out``,
    else ``runs/``): ``path`` ``<stem>-seed<N>-scanner_amdm_params.yaml`` (the identified
    model) and ``oracle_path`` ``...-scanner_amdm_oracle_params.yaml`` (the device's own
    table's)."""
    return base.bench_paths(options, name, "scanner_amdm", out)


def bench_identification(
    options: base.ScenarioOptions, entry: contract.NodeEntry, name: str, out=None
) -> dict:
    """The device of the emulator node ``entry`` (with the user's ``--set``,
    ``--device-seed`` and ``--temperature``) on the bench
    (:func:`~mems_estimation.studies.scanner_amdm_bench.run_bench`, noise seeds from
    :data:`BENCH_SEED_OFFSET`), written to :func:`bench_paths`. Returns ``model``, ``fit``
    (the fit's figures, the found onset and the sweep window [Hz], the drive's peak [V]),
    ``path`` and
    ``oracle_path``. ScenarioError when the bench finds no parametric onset or a fit fails."""
    from mems_sim.ros.params_file import node_matches

    variation = dict(device_seed=options.device_seed, temperature_c=options.temperature_c)
    values = contract.full_parameters(entry, options.overrides, variation)
    fixed = {o.name for o in options.overrides if node_matches(o.node, entry.fqn)}
    device = device_as_built(values, fixed)
    try:
        bench = scanner_amdm_bench.run_bench(device, int(options.seed) * 100 + BENCH_SEED_OFFSET)
    except ValueError as exc:
        raise base.ScenarioError(f"{name}: bench identification failed: {exc}") from None
    model = {k: float(bench["model"][k]) for k in MODEL_KEYS}
    fit = {k: float(bench["model"][k]) for k in FIT_KEYS}
    window = ("onset_hz", "sweep_start_hz", "sweep_end_hz", "drive_voltage_max")
    fit.update({k: float(bench[k]) for k in window})
    paths = bench_paths(options, name, out)
    paths["path"].parent.mkdir(parents=True, exist_ok=True)
    save_identification(dict(model, fit=fit), str(paths["path"]))
    save_identification({k: float(device[k]) for k in MODEL_KEYS}, str(paths["oracle_path"]))
    return dict(model=model, fit=fit, **paths)

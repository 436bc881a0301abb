"""The bench of ``scanner_shared_electrodes`` (:mod:`mems_estimation.studies.scanner_amdm_bench`)
on the device the emulator node builds (the scenario's values, ``--device-seed``,
``--temperature``, the user's ``--set``), before the run; its model written as the
estimators' ``params_yaml``."""

from __future__ import annotations

from pathlib import Path

from mems_estimation.identification import scanner_amdm_identification as sai
from mems_estimation.studies import scanner_amdm_bench as bench_study
from mems_scenarios import base, contract
from mems_sim.devices import scanner_amdm as sa

#: Noise seeds of the bench: the run seed + this (the run's devices use seed*10 + k).
BENCH_SEED_OFFSET = 7919


def bench_device(options: base.ScenarioOptions, params: dict, ns: str) -> dict:
    """The device as the emulator node in ``ns`` builds it from the scenario's ``params``
    (drawn for ``--device-seed``, at ``--temperature``, the user's ``--set`` left as given)."""
    from mems_sim.params import draw_device, spec_table
    from mems_sim.ros.params_file import node_matches

    entry = contract.NodeEntry("scanner_amdm_node", "scanner_amdm", ns, dict(params))
    variation = dict(device_seed=options.device_seed, temperature_c=options.temperature_c)
    values = contract.full_parameters(entry, options.overrides, variation)
    fixed = {o.name for o in options.overrides if node_matches(o.node, entry.fqn)}
    t_ref = float(
        spec_table(contract.node_class("scanner_amdm_node").SPECS)["temperature_c"].default
    )
    drawn = draw_device(
        sa.AMDM_SPECS,
        {s.name: values[s.name] for s in sa.AMDM_SPECS},
        values["device_seed"],
        values["temperature_c"] - t_ref,
        fixed=fixed,
    )
    return sa.resolve_amdm(drawn)


def identified(options: base.ScenarioOptions, params: dict, ns: str, name: str) -> dict:
    """:func:`~mems_estimation.studies.scanner_amdm_bench.run_bench` on the device of
    ``ns``; the model written beside the MCAP file as
    ``<stem>-seed<N>-scanner_amdm_params.yaml``; the result with the YAML's ``path``."""
    try:
        bench = bench_study.run_bench(
            bench_device(options, params, ns), int(options.seed) + BENCH_SEED_OFFSET
        )
    except ValueError as exc:
        raise base.ScenarioError(f"{name}: bench failed: {exc}") from None
    out = Path(options.out or Path("runs") / f"{name}-{options.seed}.mcap")
    path = base.output_path(out, options.seed, "-scanner_amdm_params.yaml")
    path.parent.mkdir(parents=True, exist_ok=True)
    sai.save_identification(bench["model"], str(path))
    return dict(bench, path=path.resolve())

"""An identified model's parameter file: one flat YAML mapping of named numbers (what a
bench identification writes and a node loads through a ``params_yaml``-style parameter),
read bounded and checked, here where both the emulators and the estimators can use it."""

from __future__ import annotations

import math
from collections.abc import Iterable

__all__ = ["load_model"]


def load_model(
    path: str, keys: Iterable[str], what: str, positive: bool = False, specs=None
) -> dict[str, float]:
    """The numbers ``keys`` of the model YAML ``path`` (read bounded,
    :func:`mems_sim.bounded_yaml.load_mapping`); ``what`` names the file in the messages.
    ``positive``: every value must be > 0; ``specs``: a parameter table
    (:class:`~mems_sim.params.ParamSpec` tuple) whose entries of these names check unit
    range. FileNotFoundError, or ValueError for a key missing, a value that is not a finite
    number or out of its range (:class:`~mems_sim.params.ParameterError`)."""
    from mems_sim import bounded_yaml
    from mems_sim.params import resolve, spec_table

    keys = tuple(keys)
    d = bounded_yaml.load_mapping(path, what)
    missing = [k for k in keys if k not in d]
    if missing:
        raise ValueError(f"{what} {path!r} lacks {', '.join(missing)}")
    out = {}
    for k in keys:
        x = d[k]
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
            raise ValueError(f"{what} {path!r}: {k} = {x!r} is not a finite number")
        if positive and x <= 0:
            raise ValueError(f"{what} {path!r}: {k} = {x!r} is not > 0")
        out[k] = float(x)
    if specs is not None:
        table = spec_table(specs)
        checked = resolve(
            tuple(table[k] for k in keys if k in table),
            {k: v for k, v in out.items() if k in table},
        )
        out.update({k: float(v) for k, v in checked.items()})
    return out

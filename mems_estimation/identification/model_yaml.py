"""The parameter YAML of an identified model: what a bench identification writes and the
estimator node loads through its ``params_yaml`` parameter (one flat mapping of named
numbers, in the units the identification module states)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["save_model", "load_model"]


def save_model(model: Mapping[str, Any], path: str) -> None:
    """Write ``model`` (name -> number, numbers as floats; a nested mapping of plain values,
    such as a record of the identification, as it is) as YAML in its order, whole and never
    through a symbolic link (:func:`mems_sim.bag.output_paths.write_output`; BagWriteError)."""
    import yaml

    from mems_sim.bag.output_paths import write_output

    plain = {k: v if isinstance(v, Mapping) else float(v) for k, v in model.items()}
    text = yaml.safe_dump(plain, sort_keys=False)
    write_output(path, lambda tmp: Path(tmp).write_text(text), overwrite=True)


def load_model(
    path: str, keys: Iterable[str], what: str, positive: bool = False
) -> dict[str, float]:
    """The numbers ``keys`` of the model YAML ``path`` (read bounded); ``what`` names the
    file in the messages. FileNotFoundError, or ValueError for a key missing, a value that
    is not a finite number, or (``positive``) one that is not > 0."""
    from mems_sim import bounded_yaml

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
    return out

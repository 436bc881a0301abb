"""The parameter YAML of an identified model: what a bench identification writes and the
estimator node loads through its ``params_yaml`` parameter (one flat mapping of named
numbers, in the units the identification module states)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mems_sim.model_file import load_model

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

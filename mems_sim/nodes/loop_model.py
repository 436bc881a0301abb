"""The ``loop_params_yaml`` parameter of an emulator whose controller runs an estimator in
its loop: the controller's firmware given the bench's identified model instead of the
designer's values (the plant stays the device as built)."""

from __future__ import annotations

from collections.abc import Sequence

from mems_sim.model_file import load_model
from mems_sim.params import ParameterError, ParamSpec

__all__ = ["LOOP_PARAMS_YAML", "loop_params_spec", "loop_model"]

LOOP_PARAMS_YAML = "loop_params_yaml"


def loop_params_spec(keys: Sequence[str], what: str) -> ParamSpec:
    """The parameter: an identified model's YAML whose ``keys`` replace the designer's values
    in the model of the in-loop estimator ``what`` (e.g. ``"hybrid EKF (ekf_rebalance)"``)."""
    return ParamSpec(
        LOOP_PARAMS_YAML,
        "",
        "-",
        f"identified model YAML of the in-loop {what}: its {', '.join(keys)} replace the "
        "designer's values in its model; empty: the designer's",
        "the device identified on the bench, as the controller's firmware would be given it",
    )


def loop_model(node, keys: Sequence[str], specs, what: str) -> dict[str, float] | None:
    """The ``keys`` of the node's ``loop_params_yaml`` (None when empty), each checked
    against its entry of ``specs``; a missing or broken file is the parameter's invalid
    value (ParameterError naming it). ``what`` names the file in the message."""
    path = node.p[LOOP_PARAMS_YAML]
    if not path:
        return None
    try:
        return load_model(path, keys, what, specs=specs)
    except (FileNotFoundError, ValueError) as exc:
        raise ParameterError(
            f"parameter {LOOP_PARAMS_YAML!r} = {path!r} is invalid: {exc}"
        ) from None

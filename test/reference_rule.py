"""The comparison rule for reference bags and tables (docs/testing.md, "Comparing with a
reference"), one implementation for every test that holds results against a reference.

* Integers (codes, indices, counts), stamps, booleans and strings: exact.
* Floats that numba kernels and closed forms compute (device outputs, truth, drive, filter
  states and variances): exact, since those kernels fix the order of every operation.
* Floats that a fit or an optimiser produced (identified noise terms, identified stage
  parameters, the estimates of a filter built from them, a scenario's figures): within
  max(:data:`REL` x the reference's magnitude, :data:`HALF_WIDTH_SHARE` x the reference's
  95 % half-width where it has one). An optimiser stops within its tolerance, so an input
  that moves by one ulp may move its result by that much; the bound stays three decades
  below any figure's interval. A field computed from fitted terms (the discrete noise model
  from B and T) takes its half-width from theirs (:data:`DERIVED_FROM`); the bounds of a
  log-scale interval (value x exp(+-z), positive and finite) are compared on the log scale
  with the interval's log half-width z (a bound far out, such as 1e274 s for a correlation
  time a short record cannot determine, moves by z times the change of z). The magnitude
  of an element of an array is the largest magnitude in that array, and an array with a
  band of its own (an Allan deviation and its ``adev_ci_low``/``adev_ci_high``) takes each
  element's half-width from the band (a signal crossing zero is compared at its scale).
* NaN equals NaN.
"""

from __future__ import annotations

import math

import numpy as np

#: Relative tolerance of a fitted float, -.
REL = 1e-9
#: Share of a fitted figure's 95 % half-width allowed as its difference, -.
HALF_WIDTH_SHARE = 1e-3


def float_close(new: float, ref: float, scale: float | None = None, half_width=None) -> bool:
    """A fitted float within the rule: |new - ref| <= max(REL scale, share x half-width)
    (``scale`` defaults to |ref|); NaN equals NaN, infinities only themselves."""
    if new == ref or (math.isnan(new) and math.isnan(ref)):
        return True
    if not (math.isfinite(new) and math.isfinite(ref)):
        return False
    scale = abs(ref) if scale is None else scale
    tol = REL * scale
    if half_width is not None and math.isfinite(half_width):
        tol = max(tol, HALF_WIDTH_SHARE * abs(half_width))
    return abs(new - ref) <= tol


def arrays_close(new, ref, half_width=None) -> bool:
    """Fitted float arrays within the rule, at the scale of the reference's largest element,
    or of each element's own half-width (an array, e.g. an Allan deviation's band) if given."""
    x, y = np.asarray(new, dtype=float), np.asarray(ref, dtype=float)
    if x.shape != y.shape or not np.array_equal(np.isnan(x), np.isnan(y)):
        return False
    finite = np.isfinite(y)
    if not np.array_equal(x[~finite & ~np.isnan(y)], y[~finite & ~np.isnan(y)]):
        return False
    if not finite.any():
        return True
    scale = float(np.max(np.abs(y[finite])))
    tol = np.full(y.shape, REL * scale)
    if half_width is not None:
        band = HALF_WIDTH_SHARE * np.abs(np.asarray(half_width, dtype=float))
        tol = np.maximum(tol, np.where(np.isfinite(band), band, 0.0))
    return bool(np.all(np.abs(x[finite] - y[finite]) <= tol[finite]))


#: Fields of a fitted message that are functions of its fitted terms (AxisNoiseModel: the
#: discrete model of Petkov eqs. 4-9 from B, T, N and K): their half-width relative to their
#: value is taken as the sum of their sources' relative half-widths.
DERIVED_FROM = {
    "a_d": ("correlation_time",),
    "b_d": ("bias_instability", "correlation_time"),
    "sigma_eta": ("bias_instability", "correlation_time"),
    "white_std_per_sample": ("white_noise_density",),
    "random_walk_increment_std": ("random_walk",),
}


def _relative_half_width(term) -> float:
    """(ci_high - ci_low) / 2 / |value| of a NoiseTerm-like field (0 where not finite)."""
    width = _half_width(term)
    value = getattr(term, "value", float("nan"))
    if width is None or not math.isfinite(width) or not math.isfinite(value) or value == 0:
        return 0.0
    return abs(width / value)


def _derived_half_width(msg, name: str) -> float | None:
    """Half-width of a derived field ``name`` of ``msg`` (reference values), or None."""
    sources = DERIVED_FROM.get(name)
    if not sources or not all(hasattr(msg, s) for s in sources):
        return None
    value = getattr(msg, name)
    return abs(value) * sum(_relative_half_width(getattr(msg, s)) for s in sources)


def _array_half_width(msg, name: str):
    """Per-element half-width of an array field ``X`` or ``X_ci_low``/``X_ci_high`` of a
    message that carries the band ``X_ci_low``, ``X_ci_high`` (reference values), or None."""
    stem = name.removesuffix("_ci_low").removesuffix("_ci_high")
    lo, hi = getattr(msg, f"{stem}_ci_low", None), getattr(msg, f"{stem}_ci_high", None)
    if lo is None or hi is None or isinstance(lo, float) or len(lo) != len(getattr(msg, name)):
        return None
    return 0.5 * (np.asarray(hi, dtype=float) - np.asarray(lo, dtype=float))


def _log_half_width(msg) -> float | None:
    """Half-width on the log scale, ln(ci_high / ci_low) / 2, of an interval with positive
    finite bounds (the identified noise terms' intervals are log-scale, value x exp(+-z)), or
    None."""
    lo, hi = getattr(msg, "ci_low", None), getattr(msg, "ci_high", None)
    if not (isinstance(lo, float) and isinstance(hi, float)):
        return None
    if not (0 < lo < hi < math.inf):
        return None
    return 0.5 * (math.log(hi) - math.log(lo))


def _half_width(msg) -> float | None:
    """The 95 % half-width of a message that carries its interval (NoiseTerm), else None."""
    lo, hi = getattr(msg, "ci_low", None), getattr(msg, "ci_high", None)
    if isinstance(lo, float) and isinstance(hi, float):
        return 0.5 * (hi - lo)
    return None


def difference(a, b, fitted: bool = False, path: str = "", half_width=None) -> str | None:
    """Where two deserialised messages differ under the rule, field by field (None: equal).

    ``fitted``: the message is the output of a fit or of a filter built from one (its floats
    by the fitted rule); otherwise every float must be equal.
    """
    if hasattr(a, "get_fields_and_field_types"):
        if type(a) is not type(b):
            return f"{path}: {type(a).__name__} vs {type(b).__name__}"
        width = _half_width(b) if fitted else None
        log_width = _log_half_width(b) if fitted else None
        for name in a.get_fields_and_field_types():
            if log_width is not None and name in ("ci_low", "ci_high"):
                x, y = getattr(a, name), getattr(b, name)
                if x == y or (x > 0 and float_close(math.log(x), math.log(y), 0.0, log_width)):
                    continue
                return f"{path}.{name}: {x!r} vs {y!r} (log-scale interval)"
            band = _array_half_width(b, name) if fitted else None
            if band is not None:
                x, y = getattr(a, name), getattr(b, name)
                if arrays_close(x, y, band):
                    continue
                return f"{path}.{name}: arrays differ beyond the rule (per-element band)"
            own = _derived_half_width(b, name) if fitted else None
            found = difference(
                getattr(a, name), getattr(b, name), fitted, f"{path}.{name}", own or width
            )
            if found:
                return found
        return None
    if isinstance(a, float) and isinstance(b, float):
        same = float_close(a, b, half_width=half_width) if fitted else a == b
        same = same or (math.isnan(a) and math.isnan(b))
        return None if same else f"{path}: {a!r} vs {b!r}"
    if isinstance(a, (str, bytes, bool, int, float)):
        return None if a == b else f"{path}: {a!r} vs {b!r}"
    if len(a) != len(b):
        return f"{path}: {len(a)} vs {len(b)} elements"
    if len(a) and hasattr(a[0], "get_fields_and_field_types"):
        for k, (x, y) in enumerate(zip(a, b)):
            found = difference(x, y, fitted, f"{path}[{k}]")
            if found:
                return found
        return None
    x, y = np.asarray(a), np.asarray(b)
    numeric = x.dtype.kind == "f" and y.dtype.kind == "f"
    if numeric and fitted:
        return None if arrays_close(x, y) else f"{path}: arrays differ beyond the rule"
    same = np.array_equal(x, y, equal_nan=numeric)
    return None if same else f"{path}: arrays differ"


def data_difference(new, ref, path: str = "") -> str | None:
    """Where two plain data trees (parsed YAML or JSON: dicts, lists, numbers, strings)
    differ, every float by the fitted rule (None: equal)."""
    if isinstance(ref, dict):
        if not isinstance(new, dict) or sorted(new) != sorted(ref):
            return (
                f"{path}: keys {sorted(new) if isinstance(new, dict) else new!r} vs {sorted(ref)}"
            )
        for key in ref:
            found = data_difference(new[key], ref[key], f"{path}.{key}")
            if found:
                return found
        return None
    if isinstance(ref, list):
        if not isinstance(new, list) or len(new) != len(ref):
            return f"{path}: {new!r} vs {ref!r}"
        for k, (x, y) in enumerate(zip(new, ref)):
            found = data_difference(x, y, f"{path}[{k}]")
            if found:
                return found
        return None
    if isinstance(ref, float) and isinstance(new, (int, float)) and not isinstance(new, bool):
        return None if float_close(float(new), ref) else f"{path}: {new!r} vs {ref!r}"
    if type(new) is not type(ref) or new != ref:
        return f"{path}: {new!r} vs {ref!r}"
    return None


#: Figures that measure the host, not the run (wall-clock seconds): their values are not
#: compared, only their presence, unit and place.
HOST_FIGURES = ("wall_time",)


def is_host_figure(name: str) -> bool:
    """True for a figure of :data:`HOST_FIGURES` (its last dotted part)."""
    return name.rsplit(".", 1)[-1] in HOST_FIGURES


def figures_difference(new: list[dict], ref: list[dict]) -> str | None:
    """Where two ``--json`` figure lists differ under the rule (None: equal): the same names
    in the same order; name, unit, target and verdict exact; values by the fitted rule (a
    record's own ``ci_low``/``ci_high`` give its half-width where it has them), except the
    values of :data:`HOST_FIGURES`."""
    names = [r.get("name") for r in new], [r.get("name") for r in ref]
    if names[0] != names[1]:
        return f"figure names: {names[0]} vs {names[1]}"
    for a, b in zip(new, ref):
        where = f"figure {b['name']!r}"
        for key in sorted(set(a) | set(b)):
            x, y = a.get(key), b.get(key)
            if key == "value" and is_host_figure(b["name"]):
                continue
            if key == "value" and isinstance(y, float) and isinstance(x, (int, float)):
                lo, hi = b.get("ci_low"), b.get("ci_high")
                width = 0.5 * (hi - lo) if isinstance(lo, float) and isinstance(hi, float) else None
                if not float_close(float(x), y, half_width=width):
                    return f"{where}: value {x!r} vs {y!r}"
            elif key == "value":
                found = data_difference(x, y, f"{where}: value")
                if found:
                    return found
            elif x != y:
                return f"{where}: {key} {x!r} vs {y!r}"
    return None

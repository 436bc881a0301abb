"""The model-choice report of ``identify_noise --model auto|flicker``: per axis, the flicker
floor and the Gauss-Markov model fitted to the same Allan points, both information criteria,
and the reported model's parameters with 95 % intervals
(:mod:`mems_estimation.identification.imu_noise_choice`)."""

from __future__ import annotations

from mems_estimation.identification.imu_noise_choice import MODELS, choose_model

#: ``--model`` values: "gm" the default identification alone, "auto" the criterion's
#: choice, "flicker" the flicker model whatever the criterion says.
MODEL_OPTIONS = ("gm", "auto", "flicker")
CRITERION = "bic"


def axis_choices(acc) -> list:
    """NoiseModelChoice of each channel of a NoiseAccumulator (its Gauss-Markov fits reused)."""
    results, _ = acc.results()
    return [choose_model(allan, CRITERION, gm_fit=fit) for fit, allan in results]


def reported(choice, option: str) -> tuple[str, object]:
    """(model name, NoiseModelFit) that ``--model option`` reports for one axis."""
    name = choice.model if option == "auto" else option
    return name, choice.fits[name]


def _params(name: str) -> tuple[str, ...]:
    return ("N", "B", "K") if name == "flicker" else ("N", "B", "K", "T")


def choices_to_dicts(choices, channels, option: str) -> list[dict]:
    """JSON records: axis, reported and chosen model, AIC/BIC/NLL of both models, and the
    reported model's parameters (SI; B of "flicker" the flicker coefficient, u)."""
    out = []
    for axis, c in zip(channels, choices):
        name, fit = reported(c, option)
        out.append(
            {
                "axis": axis,
                "model": name,
                "chosen_by_criterion": c.model,
                "criterion": c.criterion,
                "aic": {m: c.aic[m] for m in MODELS},
                "bic": {m: c.bic[m] for m in MODELS},
                "nll": {m: c.nll[m] for m in MODELS},
                "parameters": {
                    p: {
                        "value": getattr(fit, p),
                        "standard_error": fit.se[p],
                        "ci95": list(fit.ci95[p]),
                    }
                    for p in _params(name)
                },
            }
        )
    return out


def format_choices(choices, channels, units, option: str) -> str:
    """Table: axis, model reported, BIC and AIC of both models, parameters with 95 % CI."""
    from mems_sim.table import format_table

    rows = []
    for axis, unit, c in zip(channels, units, choices):
        name, fit = reported(c, option)
        crit = (
            f"BIC {c.bic['flicker']:.1f} / {c.bic['gm']:.1f}, "
            f"AIC {c.aic['flicker']:.1f} / {c.aic['gm']:.1f}"
        )
        units_of = {"N": f"{unit}/sqrt(Hz)", "B": unit, "K": f"{unit}/sqrt(s)", "T": "s"}
        for i, p in enumerate(_params(name)):
            lo, hi = fit.ci95[p]
            rows.append(
                [
                    axis,
                    name,
                    crit if i == 0 else "",
                    p,
                    units_of[p],
                    f"{getattr(fit, p):.4g}",
                    f"[{lo:.3g}, {hi:.3g}]",
                ]
            )
    head = f"noise model choice by {CRITERION.upper()} (flicker / gm; lower wins)"
    table = format_table(
        ["axis", "model", "criteria (flicker / gm)", "param", "unit", "identified", "95 % CI"],
        rows,
    )
    return head + "\n" + table

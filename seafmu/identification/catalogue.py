"""The effect catalogue: named one- or two-parameter extensions of a trial's baseline model.

The names are an interface (reports, JSON, tests): keep them spelled exactly so. Each effect says
which parameters it adds and their "effect absent" value; its object (``effects/<name>.py``) says
where it can be observed at all (a steady table cannot show a lag; a decay alone cannot separate
added mass from damping) and how to say the finding in words a naval architect would use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seafmu.identification import effects
from seafmu.identification.effects.base import is_rpm, quantity_unit
from seafmu.identification.trial import Trial


@dataclass(frozen=True)
class Effect:
    name: str
    meaning: str
    params: tuple[str, ...]
    observable_in: str


def _build() -> dict[str, Effect]:
    """The catalogue from the registered effect objects, in their declared order."""
    objs = sorted(effects.all_effects(), key=lambda o: (o.position, o.name))
    return {o.name: Effect(o.name, o.meaning, tuple(o.params), o.observable_in) for o in objs}


# name -> entry, in the catalogue's order (the effects' ``position``): reports, JSON and tests use it.
CATALOGUE: dict[str, Effect] = _build()

NAMES = tuple(CATALOGUE)

# Effects with a maneuver-level extension (their objects in effects/ say how; output error on the
# whole log), in catalogue order.
MANEUVER_EFFECTS = effects.maneuver_effects(NAMES)


def not_applicable(name: str, trial: Trial) -> str | None:
    """None if the effect can be observed in this trial, else the reason it cannot."""
    if trial.kind == "maneuver":
        if name in MANEUVER_EFFECTS:
            return effects.get(name).maneuver_applies(trial)  # type: ignore[union-attr]
        return (f"a maneuver log is fitted as a whole model; of the catalogue only "
                f"{', '.join(MANEUVER_EFFECTS[:-1])} and {MANEUVER_EFFECTS[-1]} are maneuver-level "
                "extensions so far")
    if trial.dof == "sway_yaw":
        return None if name == "coupling" else "a sway_yaw trial tests the coupling only"
    obj = effects.get(name)
    if obj is None:
        return f"unknown effect '{name}'"
    return obj.applies(trial)  # the effect's own rule (effects/<name>.py)


def applicable(trial: Trial) -> list[str]:
    return [n for n in NAMES if not_applicable(n, trial) is None]


def input_scale(trial: Trial) -> float:
    """Largest |command| of the fitting data (the 'cap inactive' value of saturation)."""
    if trial.kind == "static":
        x = np.concatenate([np.abs(np.asarray(r.u, dtype=float)) for r in trial.runs])
    else:
        x = np.concatenate([np.abs(np.asarray(r.u, dtype=float)).ravel() for r in trial.runs
                            if r.u is not None] or [np.zeros(1)])
    return float(np.max(x)) if x.size else 0.0


def effect_params(name: str, names: list[str]) -> list[str]:
    """The fit parameters that belong to effect `name`: its catalogue names, or their per-DOF /
    per-axis forms of a maneuver fit (F_0[X], v_c_north, ...)."""
    own = CATALOGUE[name].params
    return [p for p in names if p in own or any(p.startswith((f"{q}[", f"{q}_")) for q in own)]


def null_value(param: str, trial: Trial) -> float:
    """Value of an effect parameter at which the effect vanishes (significance is tested against it)."""
    obj = effects.owner(param)
    return obj.absent_values(trial).get(param, obj.absent) if obj is not None else 0.0


# -- units and words ------------------------------------------------------------------------------

# Units of the baseline models' own parameters (an effect's parameters: its object's ``unit``).
_PENDULUM_UNITS = {"alpha": "1/s²", "beta": "1/s", "gamma": "1/rad"}
_SWAY_YAW_UNITS = {"Y_v": "N/(m/s)", "N_r": "N·m/(rad/s)"}
_BASELINE_UNITS = {"M": ("inertia", False), "c": ("stiffness", True)}


def param_unit(name: str, trial: Trial) -> str:
    """The unit of a fitted parameter in this trial ("" where it has none to state)."""
    if trial.kind == "pendulum" and name in _PENDULUM_UNITS:
        return _PENDULUM_UNITS[name]
    if trial.dof == "sway_yaw" and name in _SWAY_YAW_UNITS:
        return _SWAY_YAW_UNITS[name]
    if name == "k":
        quadratic = trial.thrust_law == "quadratic" and is_rpm(trial)
        return quantity_unit("thrust_n2" if quadratic else "thrust_n", trial, True)
    if name in _BASELINE_UNITS:
        quantity, per_inertia = _BASELINE_UNITS[name]
        return quantity_unit(quantity, trial, per_inertia)
    obj = effects.owner(name)
    return obj.unit(name, trial) if obj is not None else ""


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def finding(name: str, params: dict[str, float], trial: Trial) -> str:
    """The effect's finding in words (its object's), without the numbers of the gain."""
    obj = effects.get(name)
    assert obj is not None, name
    if trial.kind == "maneuver":
        assert obj.maneuver
        return obj.maneuver_evidence(params)
    return obj.evidence(params, trial)


def fit_bounds(trial: Trial) -> dict[str, tuple[float, float]]:
    """The effects' parameter bounds in the fit of this trial's model family."""
    return effects.bounds("static" if trial.kind == "static" else "timeseries")


def held_out_words(base_val: float, ext_val: float) -> str:
    """The held-out NRMSE before and after, and their ratio; a baseline that diverges said so (as the
    report and the JSON say it: not "inf", "ratio inf")."""
    def shown(x: float) -> str:
        return f"{x:.3g}" if math.isfinite(x) else ("diverges" if x > 0 else "none")

    if math.isfinite(base_val) and math.isfinite(ext_val) and ext_val > 0:
        return f"held-out NRMSE {base_val:.3g} -> {ext_val:.3g}, ratio {base_val / ext_val:.2f}"
    if math.isinf(base_val) and math.isfinite(ext_val):
        return f"held-out NRMSE: the baseline diverges -> {ext_val:.3g}"
    return f"held-out NRMSE {shown(base_val)} -> {shown(ext_val)}"


def evidence(name: str, params: dict[str, float], trial: Trial, base_val: float, ext_val: float,
             delta_aic: float, runner_up: str | None = None, form: str | None = None) -> str:
    """One sentence naming the cause in a naval architect's words, with the numbers that back it
    (``form``: the physical form it was fitted in, where it has several)."""
    text = finding(name, params, trial) + (f", fitted with {form}" if form else "")
    gain = f" ({held_out_words(base_val, ext_val)}, dAIC {delta_aic:.1f})" if ext_val > 0 else ""
    alias = f"; '{runner_up}' explains the data almost as well" if runner_up else ""
    return text[0].upper() + text[1:] + gain + alias + "."

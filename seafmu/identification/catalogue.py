"""The effect catalogue: named one- or two-parameter extensions of a trial's baseline model.

The names are an interface (reports, JSON, tests): keep them spelled exactly so. Each effect says
which parameters it adds and their "effect absent" value; its object (``effects/<name>.py``) says
where it can be observed at all (a steady table cannot show a lag; a decay alone cannot separate
added mass from damping) and how to say the finding in words a naval architect would use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seafmu.identification import effects
from seafmu.identification.trial import ROTATIONAL, Trial


@dataclass(frozen=True)
class Effect:
    name: str
    meaning: str
    params: tuple[str, ...]
    observable_in: str


CATALOGUE: dict[str, Effect] = {e.name: e for e in (
    Effect("linear_damping", "drag term proportional to v missing", ("d_L",),
           "static force-speed, decay, step, 2nd-order decay whose baseline lacks the linear term"),
    Effect("quadratic_damping", "drag term proportional to v|v| missing", ("d_Q",),
           "static force-speed, decay, step, 2nd-order decay whose baseline lacks the quadratic term"),
    Effect("coulomb_friction", "constant-magnitude force opposing motion (bearing, ground, seal)", ("f_c",),
           "static force-speed, decay, step, 2nd-order decay, pendulum"),
    Effect("current", "the water moves: damping acts on v - v_c", ("v_c",),
           "static force-speed, decay, step with quadratic damping and motion ahead and astern (to tell "
           "it from a constant force); maneuver (NED current v_c_north, v_c_east)"),
    Effect("constant_force", "constant external force/moment or offset (wind, tether, trim)", ("F_0",),
           "every kind except sway_yaw (maneuver: one per DOF, F_0[X] ...)"),
    Effect("added_mass", "inertia differs from the rigid-body value", ("m_a",),
           "step with known force (force input or known thrust coefficient) and known mass; "
           "2nd-order decay with known stiffness and mass"),
    Effect("thrust_quadratic", "thrust proportional to n|n| rather than n", ("k_q",),
           "thrust-rpm table, step with shaft-speed command, linear thrust law"),
    Effect("thrust_asymmetry", "reverse thrust efficiency differs from forward", ("eta_rev",),
           "thrust-rpm table, step with shaft-speed command, commands of both signs"),
    Effect("deadband", "no thrust below a threshold speed", ("n_0",),
           "thrust-rpm table, step with shaft-speed command"),
    Effect("actuator_lag", "first-order lag between command and thrust", ("T_lag",), "step"),
    Effect("time_delay", "pure transport delay between command and response", ("t_d",), "step"),
    Effect("saturation", "thrust or speed capped", ("u_sat",), "thrust-rpm table, step"),
    Effect("nonlinear_restoring", "restoring not proportional to the angle (sin or cubic term)", ("c3",),
           "2nd-order decay with a linear restoring baseline"),
    Effect("coupling", "cross-coupling between DOFs (sway-yaw Y_r, N_v)", ("Y_r", "N_v"),
           "sway_yaw step or decay with v and r measured"),
)}

NAMES = tuple(CATALOGUE)

# Effects with a maneuver-level extension (their objects in effects/ say how; output error on the
# whole log), in catalogue order.
MANEUVER_EFFECTS = effects.maneuver_effects(NAMES)


def not_applicable(name: str, trial: Trial) -> str | None:
    """None if the effect can be observed in this trial, else the reason it cannot."""
    if trial.kind == "maneuver":
        if name in MANEUVER_EFFECTS:
            return None
        return (f"a maneuver log is fitted as a whole model; of the catalogue only "
                f"{' and '.join(MANEUVER_EFFECTS)} are maneuver-level extensions so far")
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

def param_unit(name: str, trial: Trial) -> str:
    rot = trial.dof in ROTATIONAL
    F = "N·m" if rot else "N"
    V = "rad/s" if rot else "m/s"
    X = "rad" if rot else "m"
    per_unit = trial.kind in ("decay", "step", "decay2") and "mass" not in trial.constants
    if trial.kind == "pendulum":
        units = {"alpha": "1/s²", "beta": "1/s", "gamma": "1/rad", "f_c": "rad/s²", "F_0": "rad/s²"}
        return units.get(name, "")
    if trial.dof == "sway_yaw":
        return {"Y_v": "N/(m/s)", "Y_r": "N/(rad/s)", "N_v": "N·m/(m/s)", "N_r": "N·m/(rad/s)"}.get(name, "")
    rpm = (trial.kind == "static" and trial.table == "thrust_rpm") or trial.input_kind == "rpm"
    table = {
        "M": "kg·m²" if rot else "kg", "m_a": "kg·m²" if rot else "kg",
        "d_L": f"{F}/({V})", "d_Q": f"{F}/({V})²", "f_c": F, "F_0": F, "v_c": V,
        "c": f"{F}/{X}", "c3": f"{F}/{X}³",
        "k": "N/rps²" if trial.thrust_law == "quadratic" and rpm else "N/rps",
        "k_q": "N/rps²", "eta_rev": "1", "n_0": "rev/s" if rpm else F, "u_sat": "rev/s" if rpm else F,
        "T_lag": "s", "t_d": "s",
    }
    if trial.kind == "static" and trial.table == "thrust_rpm":
        table["F_0"] = "N"
    unit = table.get(name, "")
    if per_unit and name in ("d_L", "d_Q", "f_c", "F_0", "c", "c3", "k", "k_q", "m_a", "u_sat", "n_0") and (
            name not in ("n_0", "u_sat") or not rpm):
        unit = f"{unit} per unit inertia"
    return unit


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def evidence(name: str, params: dict[str, float], trial: Trial, base_val: float, ext_val: float,
             delta_aic: float, runner_up: str | None = None) -> str:
    """One sentence naming the cause in a naval architect's words, with the numbers that back it."""
    if trial.kind == "maneuver":
        obj = effects.get(name)
        assert obj is not None and obj.maneuver
        text = obj.maneuver_evidence(params)
    else:
        obj = effects.get(name)
        assert obj is not None, name
        text = obj.evidence(params, trial)
    gain = (f" (held-out NRMSE {base_val:.3g} -> {ext_val:.3g}, ratio {base_val / ext_val:.2f}, "
            f"dAIC {delta_aic:.1f})") if ext_val > 0 else ""
    alias = f"; '{runner_up}' explains the data almost as well" if runner_up else ""
    return text[0].upper() + text[1:] + gain + alias + "."

"""The interface of a catalogue effect object and the registry."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial

REGISTRY: dict[str, CatalogueEffect] = {}


def register(cls: type[CatalogueEffect]) -> type[CatalogueEffect]:
    """Class decorator: one instance per effect, under its catalogue name."""
    if cls.name in REGISTRY:
        raise ValueError(f"effect '{cls.name}' registered twice")
    REGISTRY[cls.name] = cls()
    return cls


class EffectNotSupported(TypeError):
    """A capability this effect does not have (e.g. a maneuver-level term of a static-only effect)."""


class CatalogueEffect(ABC):
    """One catalogue effect. A model family the effect extends is a group of methods below.

    Every effect (1-2-DOF trials): ``absent_values(trial)``, ``static_bounds`` and
    ``timeseries_bounds`` (its parameters), ``applies(trial)`` — None where the effect can be observed,
    else the reason it cannot (maneuver and sway_yaw trials are decided by ``catalogue``) — and
    ``evidence(params, trial)``, the finding in a naval architect's words.

    Maneuver model (``seafmu.identification.maneuver``, output error on the whole log): set
    ``maneuver = True`` and give

    - ``maneuver_params(d)``: the parameter names it adds to a d-DOF fit (their "absent" value is
      ``absent``, where output error starts them);
    - ``maneuver_scales(tau)``: one optimiser scale per parameter, from the logged forces (n, d);
    - ``maneuver_terms(P)``: the simulator's keyword arguments (``F0`` a force added to tau,
      ``vc`` a NED current; ``maneuver.simulation._Simulator.run``) from the parameter values
      P (K, n_params) of K parameter sets;
    - ``maneuver_evidence(params)``: the finding in words, from the fitted parameters.
    """

    name: ClassVar[str]
    absent: ClassVar[float] = 0.0
    maneuver: ClassVar[bool] = False
    # Bounds of the effect's parameters in the fits of the 1-2-DOF families (unbounded if absent).
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {}
    # False when the fit must not start at the "absent" value (no gradient there: a cap that is
    # never reached); the extension then starts with the effect absent but from its start grid only.
    start_at_absent: ClassVar[bool] = True

    def absent_values(self, trial: Trial) -> dict[str, float]:
        """The parameter values at which the effect vanishes (its significance is tested against
        them; the extended fit may start there)."""
        from seafmu.identification.catalogue import CATALOGUE  # the catalogue imports this package

        return dict.fromkeys(CATALOGUE[self.name].params, self.absent)

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        """Start values to try in a time-series fit, from the data's scales ``s`` (V speed, U
        command, F force, M inertia, Tv time constant, h sample step, dur record length), the
        baseline's values, the model (``timeseries.TSModel``) and the prepared runs."""
        raise EffectNotSupported(f"effect '{self.name}' has no time-series start grid")

    def static_start_grid(self, xmax: float) -> dict[str, list[float]]:
        """Start values of the parameters a static table is nonlinear in (none: solved linearly)."""
        return {}

    @abstractmethod
    def applies(self, trial: Trial) -> str | None:
        """Why the effect does not apply to ``trial`` (None: it applies)."""

    @abstractmethod
    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        """The sentence that names the effect with its fitted parameters."""

    def maneuver_params(self, d: int) -> list[str]:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_scales(self, tau: np.ndarray) -> list[float]:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")


def fmt(x: float) -> str:
    """A number in a finding's sentence."""
    return f"{x:.4g}"


# -- what a trial is (the questions applies() asks) ----------------------------------------------

def static_force_speed(trial: Trial) -> bool:
    return trial.kind == "static" and trial.table == "force_speed"


def static_thrust(trial: Trial) -> bool:
    return trial.kind == "static" and trial.table == "thrust_rpm"


def rpm_step(trial: Trial) -> bool:
    """A step trial commanded by shaft speed (not sway_yaw)."""
    return trial.kind == "step" and trial.input_kind == "rpm" and trial.dof != "sway_yaw"


def has_both_signs(trial: Trial) -> bool:
    """Commands of both signs."""
    us = [np.asarray(r.u, dtype=float).ravel() for r in trial.runs if r.u is not None]
    u = np.concatenate(us) if us else np.zeros(0)
    return bool(u.size and np.any(u > 0) and np.any(u < 0))


def moves_both_ways(trial: Trial) -> bool:
    """Speeds (table input or measured output) of both signs, each above 20 % of the largest."""
    if trial.kind == "static":
        v = np.concatenate([np.asarray(r.u, dtype=float).ravel() for r in trial.runs])
    else:
        v = np.concatenate([np.asarray(r.y, dtype=float).ravel() for r in trial.runs])
    peak = float(np.max(np.abs(v))) if v.size else 0.0
    return bool(peak > 0 and np.max(v) > 0.2 * peak and np.min(v) < -0.2 * peak)


# -- words ------------------------------------------------------------------------------------------

def words(trial: Trial) -> tuple[str, str, bool]:
    """(the DOF as a word, "force" or "moment", rotational) for a finding's sentence."""
    from seafmu.identification.trial import ROTATIONAL

    rot = trial.dof in ROTATIONAL
    what = {"surge": "surge", "sway": "sway", "heave": "heave", "roll": "roll", "pitch": "pitch",
            "yaw": "yaw", "sway_yaw": "sway-yaw"}.get(trial.dof or "", "the")
    return what, "moment" if rot else "force", rot


def unit(param: str, trial: Trial) -> str:
    """The unit of a parameter in this trial (``catalogue.param_unit``)."""
    from seafmu.identification.catalogue import param_unit  # the catalogue imports this package

    return param_unit(param, trial)

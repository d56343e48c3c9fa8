"""The interface of a catalogue effect object and the registry."""

from __future__ import annotations

import dataclasses
import itertools
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
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


@dataclass(frozen=True)
class Hiding:
    """What hiding an effect changes in a synthetic trial (None/empty: the clean trial's own).

    ``synthetic.demo_trial`` uses ``truth`` (the simulated model's values), ``restoring``,
    ``thrust_law`` and ``input_kind`` (of the simulated model); ``plant_trials.plant_trial`` uses
    ``vessel`` (the vessel file carrying the effect) and ``plant`` (the plant's parameters). Both
    use ``baseline`` (the trial's stated baseline: a damping term left out of it is the effect),
    ``constants`` (merged into the trial's), ``starts`` (initial speeds/angles, times the amplitude)
    and ``levels`` (the command staircases of a step trial, times the amplitude).
    """

    truth: dict[str, float] = field(default_factory=dict)
    baseline: str | None = None
    constants: dict[str, float] = field(default_factory=dict)
    starts: tuple[float, ...] | None = None
    levels: tuple[tuple[float, ...], ...] | None = None
    restoring: str | None = None
    thrust_law: str | None = None
    input_kind: str | None = None
    trial_restoring: str | None = None
    vessel: Callable[[Any], Any] | None = None
    plant: dict[str, float] = field(default_factory=dict)


class CatalogueEffect(ABC):
    """One catalogue effect. A model family the effect extends is a group of methods below.

    Every effect: its catalogue entry (``name``, ``meaning``, ``params``, ``observable_in`` and
    ``position``, its place in the catalogue's order), ``absent_values(trial)``, ``static_bounds``
    and ``timeseries_bounds`` (its parameters), ``units`` (each parameter's quantity; ``unit``),
    ``applies(trial)`` — None where the effect can be observed, else the reason it cannot
    (maneuver and sway_yaw trials are decided by ``catalogue``) — and ``evidence(params, trial)``,
    the finding in a naval architect's words.

    Static tables (``static.StaticModel.predict``): the input passes every effect's
    ``static_input`` (in ``input_stage`` order), the thrust law is the baseline's unless an effect
    gives ``thrust_law``, multiplied by every ``thrust_gain``, and every ``static_term`` is added.

    Time series (``timeseries``): the command passes every effect's ``command`` (in
    ``input_stage`` order), then the same thrust law, gains and ``thrust_term``; the state terms
    of the RK4 loops read the effect's parameters by name (their neutral values ``neutral``, in
    ``timeseries.DEFAULTS``); ``regressors`` give the equation-error start guess its columns.

    Synthetic data: ``demo_kinds`` (the first is the default) and ``hide(kind, A)`` for
    ``synthetic.demo_trial``; ``plant`` (kind, how the plant carries it) or ``plant_missing`` (why
    the plant cannot) and ``hide_in_plant(kind, A)`` for ``plant_trials.plant_trial``.

    Maneuver model (``seafmu.identification.maneuver``, output error on the whole log): set
    ``maneuver = True`` and give

    - ``maneuver_params(d)``: the parameter names it adds to a d-DOF fit (their "absent" value is
      ``absent``, where output error starts them);
    - ``maneuver_scales(tau, nu)``: one optimiser scale per parameter, from the logged forces and
      velocities (n, d each; ``nu`` may be None);
    - ``maneuver_terms(P)``: the simulator's keyword arguments (``F0`` a force added to tau,
      ``vc`` a NED current, ``thrust_gain`` per thruster, ``sway_yaw`` coupling derivatives,
      ``added_mass`` on M's diagonal;
      ``maneuver.simulation._Simulator.run``) from the parameter values
      P (K, n_params) of K parameter sets;
    - ``maneuver_evidence(params)``: the finding in words, from the fitted parameters.
    """

    name: ClassVar[str]
    # The catalogue entry (catalogue.CATALOGUE is built from these, ordered by position).
    meaning: ClassVar[str] = ""
    params: ClassVar[tuple[str, ...]] = ()
    observable_in: ClassVar[str] = ""
    position: ClassVar[float] = 1000.0
    absent: ClassVar[float] = 0.0
    maneuver: ClassVar[bool] = False
    # Each parameter's quantity (see ``quantity_unit``) and whether it is stated per unit inertia
    # when the trial does not give the mass.
    units: ClassVar[dict[str, tuple[str, bool]]] = {}
    # Bounds of the effect's parameters in the fits of the 1-2-DOF families (unbounded if absent).
    static_bounds: ClassVar[dict[str, tuple[float, float]]] = {}
    timeseries_bounds: ClassVar[dict[str, tuple[float, float]]] = {}
    # False when the fit must not start at the "absent" value (no gradient there: a cap that is
    # never reached); the extension then starts with the effect absent but from its start grid only.
    start_at_absent: ClassVar[bool] = True
    # Time-series model families ("first", "second", "pendulum", "sway_yaw") whose simulator has
    # the effect's parameters, and their values where the term vanishes (default: ``absent``).
    families: ClassVar[tuple[str, ...]] = ()
    neutral: ClassVar[dict[str, float]] = {}
    # Where the effect acts on the input chain (None: not at all); lower acts first.
    input_stage: ClassVar[float | None] = None
    # A family containing other effects' shapes (a power law): the cause only where it beats every
    # accepted specific effect by the acceptance rule's margins (diagnosis.choose).
    general: ClassVar[bool] = False
    # Effects modelling the same thing another way: never fitted together (e.g. two thrust laws).
    excludes: ClassVar[tuple[str, ...]] = ()
    # Maneuver effects located by variants (``maneuver_variants``: which thruster): True when two
    # of its variants can act at once (two thrusters lost), so the combination search pairs them.
    variants_combine: ClassVar[bool] = False
    # The smallest departure from ``absent`` the effect's model is known to (a thrust law's
    # accuracy): a fitted value closer to absent is not reported, however narrow its interval.
    min_effect: ClassVar[float] = 0.0
    # (parameter, width) of a regularised law a time-series fit sharpens by continuation.
    regularised: ClassVar[tuple[str, str] | None] = None
    # Synthetic trials: the demo kinds it is hidden in (first: default), the plant trial kind and
    # how the plant carries it, or why the plant cannot.
    demo_kinds: ClassVar[tuple[str, ...]] = ()
    plant: ClassVar[tuple[str, str] | None] = None
    plant_missing: ClassVar[str | None] = None

    def absent_values(self, trial: Trial) -> dict[str, float]:
        """The parameter values at which the effect vanishes (its significance is tested against
        them; the extended fit may start there)."""
        return dict.fromkeys(self.params, self.absent)

    def neutral_values(self) -> dict[str, float]:
        """The parameters' values in a simulator where the effect is not part of the model."""
        return {p: self.neutral.get(p, self.absent) for p in self.params}

    def unit(self, param: str, trial: Trial) -> str:
        """The unit of one of its parameters in this trial."""
        q = self.units.get(param)
        return quantity_unit(q[0], trial, q[1]) if q else ""

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

    def contradiction(self, params: dict[str, float], trial: Trial, fit: Any, noise: float) -> str | None:
        """What in the measured data contradicts the fitted effect's claim beyond the noise (None:
        nothing), e.g. thrust measured inside a claimed deadband. ``fit`` is the extended fit
        (``fitting.FitResult``), ``noise`` the measurement noise (the best candidate's residual RMS)."""
        return None

    # -- the model terms (each returns None or its input unchanged where the effect is absent) --

    def static_input(self, x: np.ndarray, v: dict[str, float]) -> np.ndarray:
        """A table's input (speed or shaft speed) as the model sees it."""
        return x

    def command(self, t: np.ndarray, x: np.ndarray, v: dict[str, float], uniform: bool,
                before: float | None = None) -> tuple[np.ndarray, bool]:
        """A time series' command as the thruster sees it, and whether it now varies continuously
        between samples (after a lag). ``before``: the command before the first sample (0.0 when
        the run starts at rest with the command just switched on), None = the first sample's, held
        (the run starts in steady state)."""
        return x, False

    def thrust_law(self, n: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        """The shape g(n) of thrust k g(n), replacing the baseline's n or n|n|."""
        return None

    def thrust_gain(self, n: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        """A factor on the thrust k g(n)."""
        return None

    def thrust_term(self, n: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        """A thrust added to k g(n) (tables and time series)."""
        return None

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> np.ndarray | float | None:
        """A force added to a table's law (x the table's input, w after ``static_input``)."""
        return None

    def state_force(self, v: dict[str, float]) -> Callable[[float, float], float] | None:
        """An extra force f(x, w) of the time-series state (x the position of a 2nd-order model,
        0 in a 1st-order one; w the speed, through the water where there is a current), on the
        side of the damping (it opposes the motion when positive for w > 0). None where absent.
        The RK4 loops then take their general path (a Python call per stage)."""
        return None

    def fixed_values(self, trial: Trial) -> dict[str, float]:
        """Values the extended model fixes (not fitted) when it adds this effect."""
        return {}

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        """Equation-error columns of its parameters that enter the equation linearly (force per
        unit parameter, on the side of M x_dd)."""
        return {}

    # -- synthetic data --

    def hide(self, kind: str, amplitude: float) -> Hiding:
        """How ``synthetic.demo_trial`` hides the effect in a trial of ``kind``."""
        raise EffectNotSupported(f"effect '{self.name}' is not hidden in a '{kind}' demo trial")

    def hide_in_plant(self, kind: str, amplitude: float) -> Hiding:
        """How ``plant_trials.plant_trial`` hides the effect in a plant-made trial of ``kind``."""
        raise EffectNotSupported(f"effect '{self.name}' is not hidden in a '{kind}' plant trial")

    # -- maneuver model --

    def maneuver_applies(self, trial: Trial) -> str | None:
        """None where the maneuver extension is tried on this log, else the reason it is not."""
        return None

    def maneuver_params(self, d: int) -> list[str]:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        raise EffectNotSupported(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_forms(self, vessel: Any) -> list[CatalogueEffect]:
        """The physical forms of the extension the fit tries, keeping the one that fits the log best
        (same parameters; ``effects.current``: the inertia on the current's rate); itself alone."""
        return [self]

    def maneuver_form(self) -> str | None:
        """Which form this object simulates, in words (None: the only one, or the vessel file's)."""
        return None


class Combined(CatalogueEffect):
    """Several maneuver effects (or located variants of one) fitted together: their parameters side
    by side, their simulator terms merged (forces, currents and damping add, thrust gains multiply). Not
    registered: the diagnosis's combination search builds it from the parts."""

    maneuver = True

    def __init__(self, parts: tuple[CatalogueEffect, ...] | list[CatalogueEffect], d: int) -> None:
        if not parts or not all(p.maneuver for p in parts):
            raise ValueError("a combination needs one or more maneuver effects")
        self.parts = tuple(parts)
        self.name = "+".join(p.name for p in self.parts)  # type: ignore[misc]
        # one "absent" value for every parameter: only the fit's vessel-file start uses it (the
        # combination search always gives each parameter a start of its own)
        self.absent = self.parts[0].absent  # type: ignore[misc]
        self._sizes = [len(p.maneuver_params(d)) for p in self.parts]
        self._d = d

    def applies(self, trial: Trial) -> str | None:
        return None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return self.maneuver_evidence(params)

    def maneuver_params(self, d: int) -> list[str]:
        return [q for p in self.parts for q in p.maneuver_params(d)]

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        return [x for p in self.parts for x in p.maneuver_scales(tau, nu)]

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        k = 0
        for p, n in zip(self.parts, self._sizes, strict=True):
            for key, v in p.maneuver_terms(P[:, k : k + n]).items():
                if key not in out:
                    out[key] = np.array(v, dtype=float)
                elif key == "thrust_gain":
                    out[key] = out[key] * v
                else:
                    out[key] = out[key] + v
            k += n
        return out

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        return "; ".join(p.maneuver_evidence({q: params[q] for q in p.maneuver_params(self._d)
                                              if q in params}) for p in self.parts)

    def maneuver_forms(self, vessel: Any) -> list[CatalogueEffect]:
        """Every choice of its parts' forms (``CatalogueEffect.maneuver_forms``)."""
        choices = list(itertools.product(*(p.maneuver_forms(vessel) for p in self.parts)))
        if len(choices) == 1:
            return [self]
        return [Combined(c, self._d) for c in choices]

    def maneuver_form(self) -> str | None:
        forms = [f for p in self.parts if (f := p.maneuver_form()) is not None]
        return "; ".join(forms) if forms else None


def vessel_dof(trial: Trial) -> int | None:
    """The DOF count of the trial's vessel file, None where it names none or the file does not read
    (the fit itself then reports that)."""
    from seafmu.components.vessel_spec import VesselFileError, load_vessel

    try:
        return load_vessel(trial.vessel).dof if trial.vessel else None
    except (VesselFileError, OSError, ValueError):
        return None

def fmt(x: float) -> str:
    """A number in a finding's sentence."""
    return f"{x:.4g}"


# -- what a trial is (the questions applies() asks) ----------------------------------------------

def static_force_speed(trial: Trial) -> bool:
    return trial.kind == "static" and trial.table == "force_speed"


def not_a_damping_trial(trial: Trial, pendulum: str) -> str | None:
    """Why a damping-term effect does not apply (None: a force-speed table, a decay or a step,
    whose baseline is a damping law); ``pendulum`` says why the pendulum's own law excludes it."""
    if static_force_speed(trial) or trial.kind in ("decay", "step", "decay2"):
        return None
    return pendulum if trial.kind == "pendulum" else "not a damping trial"


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


def is_rpm(trial: Trial) -> bool:
    """The trial's input is a shaft speed (a bollard-pull table or an rpm-commanded step)."""
    return (trial.kind == "static" and trial.table == "thrust_rpm") or trial.input_kind == "rpm"


def quantity_unit(quantity: str, trial: Trial, per_inertia: bool = False) -> str:
    """The unit of a quantity in this trial: "force", "speed", "inertia", "damping_L" (force per
    speed), "damping_Q", "stiffness", "stiffness3", "thrust_n" (N/rps), "thrust_n2" (N/rps²),
    "command" (rev/s or a force), "time", "ratio".

    ``per_inertia``: a time-series trial that does not state the mass fits force per unit inertia
    (a shaft-speed command stays in rev/s). A pendulum's forces are angular accelerations; a
    sway_yaw trial has units for its own coefficients only (``coupling``).
    """
    if trial.kind == "pendulum":
        return "rad/s²" if quantity == "force" else ""
    if trial.dof == "sway_yaw":
        return ""
    from seafmu.identification.trial import ROTATIONAL

    rot = trial.dof in ROTATIONAL
    F = "N·m" if rot else "N"
    V = "rad/s" if rot else "m/s"
    X = "rad" if rot else "m"
    rpm = is_rpm(trial)
    table = {"force": F, "speed": V, "inertia": "kg·m²" if rot else "kg", "damping_L": f"{F}/({V})",
             "damping_Q": f"{F}/({V})²", "stiffness": f"{F}/{X}", "stiffness3": f"{F}/{X}³",
             "thrust_n": "N/rps", "thrust_n2": "N/rps²", "command": "rev/s" if rpm else F,
             "time": "s", "ratio": "1"}
    if trial.kind == "static" and trial.table == "thrust_rpm" and quantity == "force":
        table["force"] = "N"
    text = table.get(quantity, "")
    per_unit = trial.kind in ("decay", "step", "decay2") and "mass" not in trial.constants
    if per_unit and per_inertia and not (quantity == "command" and rpm):
        text = f"{text} per unit inertia"
    return text


# -- plant trials: vessel-file edits an effect's hiding uses ------------------------------------

def replace_matrix(m: np.ndarray, entries: dict[tuple[int, int], float]) -> np.ndarray:
    """A copy of a vessel matrix with some entries set."""
    out = np.array(m, dtype=float)
    for (i, j), v in entries.items():
        out[i, j] = v
    return out


def with_thrusters(spec: Any, **changes: float | str) -> Any:
    """The vessel spec with every thruster's field(s) set (numbers broadcast over the thrusters)."""
    th = spec.thrusters
    kw: dict[str, object] = {}
    for name, value in changes.items():
        kw[name] = value if isinstance(value, str) else np.full(th.count, float(value))
    return dataclasses.replace(spec, thrusters=dataclasses.replace(th, **kw))

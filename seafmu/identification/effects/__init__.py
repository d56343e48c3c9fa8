"""Catalogue effects as objects: one class per effect, one file per class, found by name.

Each module of this package defines one subclass of ``base.CatalogueEffect`` decorated with
``@register``; the package imports every module on first use, so an effect's behaviour is its
file (plus its tests) and its name one line in ``catalogue.CATALOGUE``, the ordered list of names
that reports and JSON use.

Owned by the objects so far: for every effect, when it applies to a 1-2-DOF trial
(``applies``), the finding in words (``evidence``), the "absent" values, the parameters' bounds
and start grids; for the **maneuver** model family (multi-DOF output error,
``seafmu.identification.maneuver``), the parameter names per DOF, scales, simulator term and
sentence. Still name switches elsewhere: the parameters' units, the force/thrust terms of the
``static`` and ``timeseries`` models, and the hiding in ``synthetic``/``plant_trials``;
docs/architecture.md, "Identification: where changes go", has the plan.
"""

from __future__ import annotations

import importlib
import pkgutil

from seafmu.identification.effects.base import REGISTRY, CatalogueEffect, register

__all__ = ["REGISTRY", "CatalogueEffect", "bounds", "get", "maneuver_effects", "owner", "register",
           "static_grids"]

_loaded = False


def _load() -> None:
    """Import every effect module once (each registers its class)."""
    global _loaded
    if _loaded:
        return
    for info in pkgutil.iter_modules(__path__):
        if info.name != "base":
            importlib.import_module(f"{__name__}.{info.name}")
    _loaded = True


def get(name: str) -> CatalogueEffect | None:
    """The effect object registered under a catalogue name, or None."""
    _load()
    return REGISTRY.get(name)


def maneuver_effects(order: tuple[str, ...]) -> tuple[str, ...]:
    """The effects with a maneuver-level extension, in the given (catalogue) order."""
    _load()
    return tuple(n for n in order if n in REGISTRY and REGISTRY[n].maneuver)


def owner(param: str) -> CatalogueEffect | None:
    """The effect whose parameter ``param`` is (catalogue names, or a maneuver fit's per-DOF names)."""
    from seafmu.identification.catalogue import CATALOGUE, effect_params

    _load()
    for name, obj in REGISTRY.items():
        if name in CATALOGUE and effect_params(name, [param]):
            return obj
    return None


def bounds(family: str) -> dict[str, tuple[float, float]]:
    """Parameter bounds of every effect in one model family's fits ("static" or "timeseries")."""
    _load()
    out: dict[str, tuple[float, float]] = {}
    for obj in REGISTRY.values():
        out.update(obj.static_bounds if family == "static" else obj.timeseries_bounds)
    return out


def static_grids(xmax: float) -> dict[str, list[float]]:
    """Start grids of every parameter a static table model is nonlinear in (largest |input| xmax)."""
    _load()
    out: dict[str, list[float]] = {}
    for obj in REGISTRY.values():
        out.update(obj.static_start_grid(xmax))
    return out

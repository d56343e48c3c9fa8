"""Catalogue effects as objects: one class per effect, one file per class, found by name.

Each module of this package defines one subclass of ``base.CatalogueEffect`` decorated with
``@register``; the package imports every module on first use, so adding an effect is one file
(plus its tests). The catalogue's names (``catalogue.CATALOGUE``) stay the interface of reports
and JSON.

Owned by the objects so far: for every effect, when it applies to a 1-2-DOF trial (``applies``)
and the finding in words (``evidence``); for the **maneuver** model family (multi-DOF output
error, ``seafmu.identification.maneuver``), the parameter names per DOF, "absent" value, scales,
simulator term and sentence. Still name switches elsewhere: the parameters' bounds, units and
start grids and the force/thrust terms of the ``static`` and ``timeseries`` models, and the hiding
in ``synthetic``/``plant_trials``; docs/architecture.md, "Identification: where changes go", has
the plan.
"""

from __future__ import annotations

import importlib
import pkgutil

from seafmu.identification.effects.base import REGISTRY, CatalogueEffect, register

__all__ = ["REGISTRY", "CatalogueEffect", "get", "maneuver_effects", "register"]

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

"""Catalogue effects as objects: one class per effect, one file per class, found by name.

Each module of this package defines one subclass of ``base.CatalogueEffect`` decorated with
``@register``; the package imports every module on first use, so an effect's behaviour is its
file (plus its tests). The object owns its catalogue entry (``catalogue.CATALOGUE`` is built
from the registry in ``position`` order), units, "absent" values, bounds, start grids, when it
applies and its finding in words, its terms in the static, time-series and maneuver models
(the fitters sum them), and how synthetic and plant-made trials hide it. docs/architecture.md,
"Identification: where changes go", has the table of hooks and a worked example.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

from seafmu.identification.effects.base import REGISTRY, CatalogueEffect, register

__all__ = ["REGISTRY", "CatalogueEffect", "all_effects", "bounds", "get", "maneuver_effects", "owner",
           "register", "static_grids"]

_loaded = False
_ordered: list[Any] = [None, []]


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


def all_effects() -> list[CatalogueEffect]:
    """Every registered effect object, in catalogue order (``position``, then name)."""
    _load()
    key = tuple(REGISTRY)  # the sorted list is reused until an effect is (un)registered
    if _ordered[0] != key:
        _ordered[0] = key
        _ordered[1] = sorted(REGISTRY.values(), key=lambda o: (o.position, o.name))
    return _ordered[1]


def owner(param: str) -> CatalogueEffect | None:
    """The effect whose parameter ``param`` is (its own names, or a maneuver fit's per-DOF names
    F_0[X], v_c_north, ...)."""
    _load()
    for obj in REGISTRY.values():
        if any(param == q or param.startswith((f"{q}[", f"{q}_")) for q in obj.params):
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

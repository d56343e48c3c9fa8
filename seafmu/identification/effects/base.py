"""The interface of a catalogue effect object and the registry."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

REGISTRY: dict[str, CatalogueEffect] = {}


def register(cls: type[CatalogueEffect]) -> type[CatalogueEffect]:
    """Class decorator: one instance per effect, under its catalogue name."""
    if cls.name in REGISTRY:
        raise ValueError(f"effect '{cls.name}' registered twice")
    REGISTRY[cls.name] = cls()
    return cls


class CatalogueEffect:
    """One catalogue effect. A model family the effect extends is a group of methods below.

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

    def maneuver_params(self, d: int) -> list[str]:
        raise NotImplementedError(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_scales(self, tau: np.ndarray) -> list[float]:
        raise NotImplementedError(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        raise NotImplementedError(f"effect '{self.name}' has no maneuver-level extension")

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        raise NotImplementedError(f"effect '{self.name}' has no maneuver-level extension")


def fmt(x: float) -> str:
    """A number in a finding's sentence."""
    return f"{x:.4g}"

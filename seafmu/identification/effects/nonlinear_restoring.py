"""Nonlinear restoring: restoring not proportional to the angle (sin or cubic term)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from seafmu.identification.effects.base import CatalogueEffect, fmt, register, unit, words

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial


@register
class NonlinearRestoring(CatalogueEffect):
    name = "nonlinear_restoring"

    def applies(self, trial: Trial) -> str | None:
        if trial.kind == "decay2" and trial.restoring == "linear":
            return None
        return "needs a 2nd-order decay with a linear restoring baseline"

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        _, force, rot = words(trial)
        return (f"the restoring {force} is not linear in the "
                f"{'angle' if rot else 'displacement'} "
                f"(cubic term c3 = {fmt(params.get('c3', 0))} {unit('c3', trial)}, e.g. a sin-shaped "
                f"righting arm)")

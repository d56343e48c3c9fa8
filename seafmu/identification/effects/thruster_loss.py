"""Thruster loss: one thruster delivers only a fraction of the thrust its shaft speed should give.

A fouled or damaged propeller, a bent blade, a worn drive or a blocked nozzle turns at the
commanded speed, so the logged thrust (shaft speed through the thrust law) is what it should be,
but the force on the hull is tau = B diag(eta) T with eta_i < 1 for that thruster. Only a log
with one thrust column per thruster can show it (a ``seafmu run`` results.csv, a hardware
recording): the thruster configuration matrix B of the vessel file tells each thruster's force
apart from the others'.

Which thruster is lost is itself unknown: the effect is fitted once per thruster (each a
one-parameter extension, ``maneuver_variants``) and the variant that explains the log best (lowest
fitting cost; with one parameter each, the lowest AIC) is the located thruster
(``maneuver.estimation._output_error``). The diagnosis's acceptance rule (held-out error, dAIC,
the efficiency's CI excluding 1) then decides whether any thruster is lost at all.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from seafmu.identification.effects.base import CatalogueEffect, register

if TYPE_CHECKING:
    from seafmu.identification.trial import Trial

PARAM = "eta_T"  # eta_T[i]: efficiency of thruster i (1-based), relative to the vessel file's


def param_name(thruster: int) -> str:
    """The fit parameter of a 0-based thruster index."""
    return f"{PARAM}[{thruster + 1}]"


def thruster_of(param: str) -> int | None:
    """The 0-based thruster index of an ``eta_T[i]`` name, None for any other name."""
    if param.startswith(f"{PARAM}[") and param.endswith("]") and param[len(PARAM) + 1 : -1].isdigit():
        return int(param[len(PARAM) + 1 : -1]) - 1
    return None


@register
class ThrusterLoss(CatalogueEffect):
    name = "thruster_loss"
    meaning = "one thruster delivers only a fraction of its nominal thrust (fouled, damaged, worn)"
    params = (PARAM,)
    observable_in = ("maneuver logs with one thrust column per thruster (seafmu run results, hardware "
                     "recordings): eta_T[i] of the located thruster i")
    position = 15
    absent = 1.0  # all of the nominal thrust acts
    # A loss below 5 % of the nominal thrust is within what a thrust law (a bollard-pull
    # coefficient) is known to: the fit reports no loss then, however narrow its interval
    # (a noise-free log makes every deviation "significant").
    min_effect: ClassVar[float] = 0.05
    maneuver = True
    variants_combine: ClassVar[bool] = True  # two thrusters can be lost at once
    units: ClassVar[dict[str, tuple[str, bool]]] = {PARAM: ("ratio", False)}

    def __init__(self, thruster: int | None = None, n_thrusters: int = 0) -> None:
        # the registered object is the effect "some thruster"; its variants name one thruster each
        self.thruster = thruster
        self.n_thrusters = n_thrusters

    def applies(self, trial: Trial) -> str | None:
        if trial.kind != "maneuver":
            return ("a lost thruster shows in a multi-DOF maneuver log with one thrust column per thruster, "
                    "not in a 1-2-DOF trial")
        return None

    def evidence(self, params: dict[str, float], trial: Trial) -> str:
        return self.maneuver_evidence(params)

    def contradiction(self, params: dict[str, float], trial: Trial, fit: Any, noise: float) -> str | None:
        """A "lost" thruster fitted to deliver more than its nominal thrust (beyond the thrust law's
        known accuracy, ``min_effect``, and its CI above 1) is not a loss: the log says something
        else is wrong (another thruster, a current, the thrust law)."""
        ci = getattr(fit, "ci95", None) or {}
        for k, v in params.items():
            i = thruster_of(k)
            lo = ci.get(k, (v, v))[0]
            if i is not None and v > self.absent + self.min_effect and lo > self.absent:
                return (f"thruster {i + 1} would deliver {100.0 * v:.0f} % of its nominal thrust: more than "
                        "the vessel file gives is not a loss")
        return None

    # -- maneuver model --

    def maneuver_variants(self, n_thrusters: int) -> list[ThrusterLoss]:
        """One hypothesis per thruster: "thruster i is the lost one"."""
        return [ThrusterLoss(i, n_thrusters) for i in range(n_thrusters)]

    def maneuver_params(self, d: int) -> list[str]:
        """eta_T[i] of the hypothesised thruster (the unlocated effect: eta_T)."""
        return [PARAM if self.thruster is None else param_name(self.thruster)]

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
        return [0.1]  # a tenth of the nominal thrust

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        """thrust_gain (K, m): 1 for every thruster but the hypothesised one."""
        if self.thruster is None or not 0 <= self.thruster < self.n_thrusters:
            raise ValueError("thruster_loss: a thruster must be hypothesised (maneuver_variants) before "
                             "its efficiency can be simulated")
        gain = np.ones((P.shape[0], self.n_thrusters))
        gain[:, self.thruster] = P[:, 0]
        return {"thrust_gain": gain}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        found = [(i, v) for k, v in params.items() if (i := thruster_of(k)) is not None]
        if not found:
            return "a thruster delivers less thrust than the vessel file says"
        i, eta = found[0]
        return (f"thruster {i + 1} delivers {100.0 * eta:.0f} % of the thrust the vessel file gives for its "
                f"shaft speed (efficiency {eta:.3g}): a fouled or damaged propeller, a worn drive or a "
                "blocked nozzle; the other thrusters act as the file says")

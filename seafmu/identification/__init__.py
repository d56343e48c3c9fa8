"""Identification and model diagnosis from measured trials (docs/identification.md).

    from seafmu.identification import load_trial, identify, diagnose
    d = diagnose(load_trial("scenarios/data/rov_cfd_force_speed.yaml"))
    d.effect, d.evidence, d.to_json()

Names are resolved lazily so that importing one submodule (e.g. ``fitting`` from the maneuver
module) does not pull in the rest.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "TrialError": "trial", "Trial": "trial", "Run": "trial", "load_trial": "trial", "make_trial": "trial",
    "write_trial": "trial", "csv_trial": "trial",
    "FitResult": "fitting",
    "CATALOGUE": "catalogue", "Effect": "catalogue",
    "identify": "diagnosis", "diagnose": "diagnosis", "Diagnosis": "diagnosis", "Identification": "diagnosis",
    "Rule": "diagnosis", "demo_trial": "synthetic", "write_vessel": "writeback",
    "vessel_updates": "writeback", "plant_trial": "plant_trials",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(f"seafmu.identification.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'seafmu.identification' has no attribute {name!r}")

"""Catalogue effects as objects (seafmu/identification/effects/): registry, the maneuver family's
hooks, and adding an effect as one class (docs/architecture.md, "Identification: where changes go")."""

from __future__ import annotations

import numpy as np
import pytest

from seafmu.components.vessel_spec import load_vessel
from seafmu.identification import catalogue, effects
from seafmu.identification.effects.base import REGISTRY, CatalogueEffect
from seafmu.identification.maneuver import (
    MANEUVER_EFFECTS,
    add_sensor_noise,
    effect_names,
    identify_maneuver,
    simulate_maneuver,
)


def test_registry_holds_catalogue_effects_and_the_maneuver_family() -> None:
    effects.get("current")  # loads the package's modules
    assert set(REGISTRY) == set(catalogue.CATALOGUE)  # every catalogue effect is an object
    for name, obj in REGISTRY.items():
        assert obj.name == name
        for method in ("applies", "evidence"):
            assert getattr(type(obj), method) is not getattr(CatalogueEffect, method), (name, method)
    assert MANEUVER_EFFECTS == catalogue.MANEUVER_EFFECTS == ("current", "constant_force")
    assert effect_names("current", 3) == ["v_c_north", "v_c_east"]
    assert effect_names("constant_force", 6) == [f"F_0[{n}]" for n in "XYZKMN"]
    with pytest.raises(ValueError, match="maneuver effect must be one of current, constant_force"):
        effect_names("deadband", 3)
    tau = np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]])
    expected = list(0.05 * np.maximum(tau.std(axis=0), 1e-3))
    assert effects.get("constant_force").maneuver_scales(tau) == expected
    P = np.array([[0.1, -0.2]])
    assert set(effects.get("current").maneuver_terms(P)) == {"vc"}


def test_evidence_of_a_maneuver_effect_comes_from_its_object() -> None:
    text = effects.get("current").maneuver_evidence({"v_c_north": 0.0, "v_c_east": 0.1})
    assert "0.1 m/s towards 90 deg" in text
    text = effects.get("constant_force").maneuver_evidence({"F_0[X]": 2.0, "F_0[N]": -1.0})
    assert "X = 2 N" in text and "N = -1 N·m" in text


class _SurgePull(CatalogueEffect):
    """The worked example of docs/architecture.md: a tow-line pull in surge only."""

    name = "surge_pull_example"
    maneuver = True

    def applies(self, trial: object) -> str | None:
        return "a tow line is a maneuver-level effect"

    def evidence(self, params: dict[str, float], trial: object) -> str:
        return f"a tow line pulls with {params['F_pull']:.3g} N"

    def maneuver_params(self, d: int) -> list[str]:
        return ["F_pull"]

    def maneuver_scales(self, tau: np.ndarray) -> list[float]:
        return [0.05 * max(float(tau[:, 0].std()), 1e-3)]

    def maneuver_terms(self, P: np.ndarray) -> dict[str, np.ndarray]:
        F0 = np.zeros((P.shape[0], 3))
        F0[:, 0] = P[:, 0]
        return {"F0": F0}

    def maneuver_evidence(self, params: dict[str, float]) -> str:
        return self.evidence(params, None)


def test_a_new_effect_is_one_class(monkeypatch: pytest.MonkeyPatch) -> None:
    """Registered, the class is fitted by the maneuver output error without touching the fitter."""
    effects.get("current")
    monkeypatch.setitem(REGISTRY, _SurgePull.name, _SurgePull())
    vessel = load_vessel("amv_osf")
    data, _ = simulate_maneuver(vessel, duration=60.0, dt=0.05, seed=2, plant_params={})
    data = add_sensor_noise(data, vessel, 1.0, seed=2)
    fit = identify_maneuver(data, vessel, method="output_error", effect=_SurgePull.name, max_nfev=4)
    assert fit.param_names[-1] == "F_pull" and np.isfinite(fit.params["F_pull"])
    assert "F_pull" in fit.ci95
    assert effects.get(_SurgePull.name).maneuver_evidence(fit.params).startswith("a tow line pulls")


def test_applicability_and_words_come_from_the_objects() -> None:
    """catalogue.not_applicable and catalogue.evidence ask the effect's object."""
    from seafmu.identification.synthetic import demo_trial

    trial = demo_trial("deadband", seed=0)
    assert catalogue.not_applicable("deadband", trial) == effects.get("deadband").applies(trial) is None
    assert catalogue.not_applicable("nonlinear_restoring", trial) == (
        "needs a 2nd-order decay with a linear restoring baseline")
    text = catalogue.evidence("deadband", {"n_0": 0.25}, trial, 0.5, 0.25, -12.0)
    assert text.startswith("The thruster gives no thrust below 0.25 rev/s (deadband)")


def test_bounds_and_absent_values_are_the_effects_own() -> None:
    from seafmu.identification import static, timeseries
    from seafmu.identification.synthetic import demo_trial

    assert timeseries.BOUNDS["T_lag"] == (0.0, np.inf) and timeseries.BOUNDS["u_sat"] == (1e-6, np.inf)
    assert static._BOUNDS["eta_rev"] == (-0.99, 10.0) and "T_lag" not in static._BOUNDS
    trial = demo_trial("saturation", seed=0)
    sat = effects.get("saturation")
    assert not sat.start_at_absent
    cap = catalogue.input_scale(trial)
    assert catalogue.null_value("u_sat", trial) == sat.absent_values(trial)["u_sat"] == cap
    assert catalogue.null_value("F_0[X]", trial) == catalogue.null_value("v_c_north", trial) == 0.0


def test_start_grids_are_the_effects_own() -> None:
    from seafmu.identification import static

    assert static._NONLINEAR == {"v_c", "n_0", "u_sat", "eta_rev"}
    assert effects.static_grids(2.0)["n_0"] == [0.1, 0.4]
    s = {"V": 2.0, "U": 3.0, "F": 10.0, "M": 5.0, "Tv": 4.0, "h": 0.1, "dur": 30.0}
    grid = effects.get("time_delay").timeseries_start_grid(s, {}, None, [])
    assert [g["t_d"] for g in grid] == [0.05, 0.1, 0.2, 0.4, 0.8]

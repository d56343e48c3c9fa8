"""Catalogue effects as objects (seafmu/identification/effects/): registry, the maneuver family's
hooks, and adding an effect as one class (docs/architecture.md, "Identification: where changes go")."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import pytest

from seafmu.components.vessel_spec import load_vessel
from seafmu.identification import catalogue, effects
from seafmu.identification.effects.base import REGISTRY, CatalogueEffect, Hiding
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
    assert MANEUVER_EFFECTS == catalogue.MANEUVER_EFFECTS
    assert MANEUVER_EFFECTS[:2] == ("current", "constant_force")  # thruster_loss follows where it is
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

    def maneuver_scales(self, tau: np.ndarray, nu: np.ndarray | None = None) -> list[float]:
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

    assert static._NONLINEAR == {"v_c", "n_0", "u_sat", "eta_rev", "p_n", "p_v"}  # p_*: the power laws
    assert effects.static_grids(2.0)["n_0"] == [0.1, 0.4]
    s = {"V": 2.0, "U": 3.0, "F": 10.0, "M": 5.0, "Tv": 4.0, "h": 0.1, "dur": 30.0}
    grid = effects.get("time_delay").timeseries_start_grid(s, {}, None, [])
    assert [g["t_d"] for g in grid] == [0.05, 0.1, 0.2, 0.4, 0.8]


# -- the 1-2-DOF families: the worked example of docs/architecture.md ----------------------------

class _CubicDrag(CatalogueEffect):
    """A drag term d_C v^3 (the worked example of docs/architecture.md): a table term, a state
    force of the time-series loops, an equation-error column, a start grid and its hiding."""

    name = "cubic_drag_example"
    meaning = "drag term proportional to v^3 missing"
    params = ("d_C",)
    observable_in = "static force-speed, decay"
    position = 99
    units: ClassVar[dict[str, tuple[str, bool]]] = {"d_C": ("force", True)}
    families = ("first", "second")
    demo_kinds = ("decay", "static")

    def applies(self, trial: object) -> str | None:
        ok = getattr(trial, "kind", "") == "decay" or getattr(trial, "table", "") == "force_speed"
        return None if ok else "needs a force-speed table or a decay"

    def evidence(self, params: dict[str, float], trial: object) -> str:
        return f"a cubic drag term d_C = {params.get('d_C', 0):.4g} is missing"

    def static_term(self, x: np.ndarray, w: np.ndarray, v: dict[str, float]) -> np.ndarray | None:
        return v["d_C"] * w**3 if "d_C" in v else None

    def state_force(self, v: dict[str, float]) -> Callable[[float, float], float] | None:
        d = v.get("d_C", 0.0)
        return (lambda x, w: d * w * w * w) if d else None

    def regressors(self, family: str, pos: np.ndarray | None, speed: np.ndarray, acc: np.ndarray,
                   u: np.ndarray | None) -> dict[str, np.ndarray]:
        return {"d_C": -speed**3}

    def timeseries_start_grid(self, s: dict[str, float], vals: dict[str, float], model: Any,
                              preps: list[Any]) -> list[dict[str, float]]:
        return [{"d_C": x * s["F"] / s["V"] ** 3} for x in (0.1, 0.5)]

    def hide(self, kind: str, amplitude: float) -> Hiding:
        return Hiding(truth={"d_C": 150.0 if kind == "static" else 40.0})


@pytest.fixture()
def cubic(monkeypatch: pytest.MonkeyPatch) -> CatalogueEffect:
    """The example registered and in the catalogue, for one test."""
    effects.get("current")
    obj = _CubicDrag()
    monkeypatch.setitem(REGISTRY, obj.name, obj)
    monkeypatch.setitem(catalogue.CATALOGUE, obj.name, catalogue.Effect(obj.name, obj.meaning, obj.params,
                                                                        obj.observable_in))
    return obj


@pytest.mark.parametrize("kind", ["decay", "static"])
def test_a_new_static_and_time_series_effect_is_one_class(cubic: CatalogueEffect, kind: str) -> None:
    """Hidden by its own hide(), fitted by the fitters' sum of terms, named by the diagnosis; its unit
    comes from its object. Without it in the data the diagnosis does not name it."""
    from seafmu.identification.diagnosis import diagnose
    from seafmu.identification.synthetic import demo_trial

    trial = demo_trial(cubic.name, kind, seed=3)
    d = diagnose(trial)
    assert d.effect == cubic.name, d.evidence
    c = next(c for c in d.candidates if c.effect == cubic.name)
    truth = 150.0 if kind == "static" else 40.0
    lo, hi = c.fit.ci95["d_C"]
    assert lo < truth < hi or abs(c.fit.params["d_C"] / truth - 1) < 0.1
    assert catalogue.param_unit("d_C", trial) == "N"
    clean = diagnose(demo_trial(None, kind, seed=3))
    assert clean.effect != cubic.name


def test_catalogue_is_built_from_the_objects_in_the_interface_order() -> None:
    """The names and order reports and JSON use, each entry the object's own."""
    first = ["linear_damping", "quadratic_damping", "coulomb_friction", "current", "constant_force",
             "added_mass", "thrust_quadratic", "thrust_asymmetry", "deadband", "actuator_lag", "time_delay",
             "saturation", "nonlinear_restoring", "coupling"]
    assert list(catalogue.CATALOGUE)[:14] == first
    for name, entry in catalogue.CATALOGUE.items():
        obj = effects.get(name)
        assert (entry.meaning, entry.params, entry.observable_in) == (
            obj.meaning, obj.params, obj.observable_in)
        assert entry.meaning and entry.params


def test_units_and_hiding_come_from_the_objects() -> None:
    """param_unit asks the owner of an effect parameter; demo and plant kinds follow the objects."""
    from seafmu.identification import plant_trials
    from seafmu.identification.synthetic import DEMO_EFFECTS, demo_trial

    step = demo_trial("deadband", seed=0)
    assert catalogue.param_unit("n_0", step) == "rev/s"
    assert catalogue.param_unit("F_0", step) == "N"
    assert catalogue.param_unit("k", step) == "N/rps"
    decay = demo_trial("linear_damping", seed=0)
    assert catalogue.param_unit("d_L", decay) == "N/(m/s)"
    no_mass = dataclasses.replace(decay, constants={})
    assert catalogue.param_unit("d_L", no_mass) == "N/(m/s) per unit inertia"
    assert catalogue.param_unit("c3", demo_trial("nonlinear_restoring", seed=0)) == "N·m/rad³"
    assert catalogue.param_unit("Y_r", demo_trial("coupling", seed=0)) == "N/(rad/s)"
    for obj in effects.all_effects():
        for kind in obj.demo_kinds:
            assert obj.name in DEMO_EFFECTS[kind]
        if obj.plant is not None:
            assert plant_trials.DESIGN[obj.name] == obj.plant
        assert not (obj.plant and obj.plant_missing)


def test_no_effect_name_switches_in_the_fitters() -> None:
    """The fitters, the generators and the diagnosis sum the objects' terms: no effect named in code."""
    import re
    from pathlib import Path

    import seafmu.identification as ident

    root = Path(ident.__file__).parent
    names = "|".join(catalogue.CATALOGUE)
    pattern = re.compile(rf"effect\s*(==|!=|in)\s*[\(\[{{]?\s*\"({names})\"")
    for mod in ("static", "timeseries", "synthetic", "plant_trials", "diagnosis", "catalogue"):
        text = (root / f"{mod}.py").read_text()
        assert not pattern.search(text), mod


def _offset_thrust_table(folder: Any, seed: int) -> Any:
    """A bollard-pull table, T = 4 n + 3 N (a load-cell offset), n = -20..20 rev/s, 1.5 % noise."""
    from seafmu.identification.trial import load_trial

    rng = np.random.default_rng(seed)
    n = np.arange(-20.0, 20.1, 2.0)
    T = 4.0 * n + 3.0
    T = T + rng.normal(scale=0.015 * (T.max() - T.min()), size=n.size)
    rows = "".join(f"{a:g},{b:.5f}\n" for a, b in zip(n, T, strict=True))
    (folder / "table.csv").write_text("shaft_rev_s,thrust_N\n" + rows)
    (folder / "trial.yaml").write_text(
        "name: offset\nkind: static\ntable: thrust_rpm\ndof: surge\nfiles: [table.csv]\ncolumns:\n"
        "  input: {column: shaft_rev_s, unit: rev/s}\n  output: {column: thrust_N, unit: N}\n"
        "baseline: linear\n")
    return load_trial(folder / "trial.yaml")


def test_unphysical_names_a_parameter_outside_its_range_that_the_baseline_kept() -> None:
    """Only a whole 95 % CI outside the physical range counts (one reaching into it is noise), and
    only where the baseline's did not: the baseline's own is its warning, not the effect's fault."""
    from types import SimpleNamespace

    from seafmu.identification.diagnosis import unphysical

    def fit(**ci: tuple[float, float]) -> Any:
        return SimpleNamespace(ci95=ci, params={k: 0.5 * (lo + hi) for k, (lo, hi) in ci.items()})

    base = fit(d_L=(0.5, 2.0), m_a=(-3.0, -1.0))
    assert unphysical(base, fit(d_Q=(-9.5, -6.6), m_a=(-2.0, -1.0), d_L=(-3.0, -1.0))) == [
        "d_Q = -8.05 (95 % CI [-9.5, -6.6]; >= 0 physically)"]  # m_a: the baseline's; d_L: a warning
    assert unphysical(base, fit(d_Q=(-1.0, 0.5), k_q=(-0.25, -0.2))) == [
        "k_q = -0.225 (95 % CI [-0.25, -0.2]; >= 0 physically)"]
    assert unphysical(base, fit(Y_v=(0.1, 0.3), N_r=(-2.0, 0.1))) == [
        "Y_v = 0.2 (95 % CI [0.1, 0.3]; <= 0 physically)"]
    assert unphysical(base, fit(d_Q=(0.0, 1.0), gamma=(-1.0, 3.0))) == []


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_load_cell_offset_is_named_a_constant_force(tmp_path: Any, seed: int) -> None:
    """A bollard table with an offset names constant_force, and no accepted candidate is unphysical
    (the gate's reason is given where one is blocked)."""
    from seafmu.identification.diagnosis import diagnose, unphysical

    d = diagnose(_offset_thrust_table(tmp_path, seed))
    assert d.cause is not None and d.cause.effect == "constant_force"
    assert d.cause.fit.params["F_0"] == pytest.approx(3.0, abs=1.2)
    for c in d.candidates:
        if c.fit is not None and unphysical(d.baseline, c.fit):
            assert not c.accepted and "unphysical model" in c.reason


def test_a_friction_and_a_force_on_speeds_of_one_sign_are_said_to_be_one_model(tmp_path: Any) -> None:
    """A tow table ahead only with a 5 N offset: friction opposing the motion and a constant force
    are the same term there, so whichever is named, the evidence says the data cannot tell them
    apart and where they would differ (astern)."""
    from seafmu.identification.diagnosis import diagnose
    from seafmu.identification.trial import load_trial

    rng = np.random.default_rng(0)
    v = np.linspace(0.1, 2.0, 20)
    F = 8.0 * v + 25.0 * v * np.abs(v) + 5.0
    F = F + rng.normal(scale=0.015 * (F.max() - F.min()), size=v.size)
    rows = "".join(f"{a:.4g},{b:.5f}\n" for a, b in zip(v, F, strict=True))
    (tmp_path / "table.csv").write_text("speed_m_s,force_N\n" + rows)
    (tmp_path / "trial.yaml").write_text(
        "name: tow\nkind: static\ntable: force_speed\ndof: surge\nfiles: [table.csv]\ncolumns:\n"
        "  input: {column: speed_m_s, unit: m/s}\n  output: {column: force_N, unit: N}\n")
    d = diagnose(load_trial(tmp_path / "trial.yaml"))
    assert d.cause is not None and d.cause.effect in ("coulomb_friction", "constant_force")
    other = ({"coulomb_friction", "constant_force"} - {d.cause.effect}).pop()
    assert f"'{other}' fits these data exactly as well" in d.evidence, d.evidence
    assert "cannot tell them apart" in d.evidence and "measure at speed -" in d.evidence


def test_the_console_summary_names_the_effects_not_tried() -> None:
    """A "none" or a cause covers only what was tried: the console says which effects were not
    applicable (their reasons are in diagnosis.md), not only the report."""
    from seafmu.identification.diagnosis import diagnose
    from seafmu.identification.report import summary_lines
    from seafmu.identification.trial import load_trial
    from seafmu.scenario import REPO

    d = diagnose(load_trial(REPO / "scenarios" / "data" / "rov_cfd_force_speed.yaml"))
    line = next(x for x in summary_lines(d) if "not tried" in x)
    assert d.skipped and all(name in line for name in d.skipped)
    assert "coupling" in line and "quadratic_damping" not in line  # tried (and named)

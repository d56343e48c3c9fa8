"""Two effects at once in a maneuver log: both named, each with its values, and no third.

The logs are flown by seafmu's plant (``simulate_maneuver``: multisine excitation through the
thrusters, the vessel file's sensor noise added, one thrust column per thruster) with two effects
in the plant at once: two thrusters lost, a lost thruster in a current, a buoyancy error (a
constant heave force) with a lost thruster or with a current. Which thruster is lost is drawn
from the seed, not chosen by hand. The diagnosis must name both (``cause.effects``, each lost
thruster located), with the values within the stated tolerances, and nothing else; a clean log
stays silent, and a log with one effect still gives exactly one.

What a maneuver pair can be is decided by the effects (``effects/*.py``): ``current``,
``constant_force`` and ``thruster_loss`` (whose variants, one per thruster, may combine: two
thrusters lost). A change of damping is no effect of a maneuver log: every fit, the baseline's
included, estimates the damping diagonals itself.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.identification import diagnosis
from seafmu.identification.diagnosis import Diagnosis, diagnose
from seafmu.identification.effects import get
from seafmu.identification.effects.base import Combined
from seafmu.identification.effects.thruster_loss import thruster_of
from seafmu.identification.maneuver import add_sensor_noise, simulate_maneuver, write_maneuver_csv
from seafmu.identification.report import write_diagnosis_report
from seafmu.identification.trial import Trial, csv_trial

ETA_TOL = 0.05  # efficiency, absolute (the issue's +-5 points)
CURRENT_TOL = 0.02  # m/s, each component
DIRECTION_TOL = 10.0  # deg
FORCE_TOL = 0.15  # relative, constant heave force


def _log(tmp: Path, vessel: str, seed: int, plant: dict[str, float], duration: float, dt: float,
         truth: VesselSpec | None = None) -> Trial:
    """A plant-made maneuver log with sensor noise, one thrust column per thruster."""
    spec = load_vessel(vessel)
    data, _ = simulate_maneuver(truth or spec, duration=duration, dt=dt, seed=seed, plant_params=plant)
    data = add_sensor_noise(data, spec, 1.0, seed=seed)
    return csv_trial(write_maneuver_csv(data, tmp / f"{vessel}_{seed}.csv", per_thruster=True), vessel)


def _lost(d: Diagnosis) -> dict[int, float]:
    """1-based thruster -> fitted efficiency, of the cause."""
    assert d.cause is not None and d.cause.fit is not None
    f = d.cause.fit
    return {thruster_of(p) + 1: f.params[p] for p in f.param_names if thruster_of(p) is not None}  # type: ignore[operator]


def _report(d: Diagnosis, truth: str) -> None:
    members = "; ".join(f"{m['effect']} " + ", ".join(f"{k} = {v:.4g}" for k, v in m["params"].items())
                        for m in d.to_json()["cause"]["members"])
    print(f"{d.trial.name}: truth {truth} -> {members or 'none'} ({d.seconds:.1f} s)")


def _check_pair(d: Diagnosis, names: list[str]) -> None:
    """Both named, no third; every effect's parameter significant; the JSON has them all."""
    assert sorted(d.effects) == sorted(names), d.evidence
    assert d.cause is not None and d.cause.size == 2 and d.cause.accepted, d.evidence
    assert d.cause.significant  # each effect's parameter: its CI excludes "absent"
    doc = d.to_json()
    assert doc["cause"]["effects"] == d.effects == [m["effect"] for m in doc["cause"]["members"]]
    assert all(k in doc["extended"]["params"] for m in doc["cause"]["members"] for k in m["params"])
    ratio = doc["gain"]["validation_nrmse_ratio"]  # None: infinite (the baseline diverges held out)
    assert (ratio is None and not math.isfinite(d.baseline.nrmse_validation)) or ratio > 1.02
    assert doc["gain"]["delta_aic"] < -10
    # the pair beats each of its parts alone (fitted in the search) held out
    parts = [c for c in d.candidates if c.fit is not None and c.size == 1
             and set(c.members()) <= set(d.cause.members())]
    assert len(parts) == 2
    for p in parts:
        assert p.fit.nrmse_validation > 1.02 * d.cause.fit.nrmse_validation  # type: ignore[union-attr]
    # ordered by contribution: dropping the first effect costs more AIC than dropping the second
    aic = {frozenset(p.members()): p.fit.aic for p in parts}  # type: ignore[union-attr]
    mine, order = d.cause.members(), diagnosis._member_order(d.cause, d.candidates)
    first, second = mine[order[0]], mine[order[1]]
    assert aic[frozenset([second])] >= aic[frozenset([first])]
    assert d.evidence.startswith("2 effects act together")


# (vessel, seed, efficiencies of the two lost thrusters): the thrusters are drawn from the seed
TWO_LOST = [("minerva2", 1, (0.6, 0.75)), ("minerva2", 2, (0.6, 0.75)), ("amv_osf", 5, (0.6, 0.8))]


@pytest.mark.parametrize(("vessel", "seed", "efficiency"), TWO_LOST)
def test_two_lost_thrusters_are_both_located(tmp_path: Path, vessel: str, seed: int,
                                             efficiency: tuple[float, float]) -> None:
    m = load_vessel(vessel).thrusters.count
    lost = [int(k) + 1 for k in np.random.default_rng(seed).choice(m, 2, replace=False)]
    truth = dict(zip(lost, efficiency, strict=True))
    duration, dt = (120.0, 0.05) if vessel == "minerva2" else (200.0, 0.1)
    d = diagnose(_log(tmp_path, vessel, seed, {f"thruster_efficiency_{k}": e for k, e in truth.items()},
                      duration, dt))
    _report(d, f"thrusters {truth}")
    _check_pair(d, ["thruster_loss", "thruster_loss"])
    found = _lost(d)
    assert set(found) == set(truth), d.evidence
    for k, e in truth.items():
        assert found[k] == pytest.approx(e, abs=ETA_TOL)
        assert f"thruster {k} delivers" in d.evidence.lower()
    updates = d.to_json()["cause"]["members"]
    assert {thruster_of(next(iter(u["params"]))) + 1 for u in updates} == set(truth)  # type: ignore[operator]
    # the report names each located thruster, in the cause and in the candidates' table
    text = write_diagnosis_report(d, tmp_path / "report").read_text()
    for k in truth:
        assert f"`thruster_loss` (eta_T[{k}] = " in text and f"| thruster_loss (eta_T[{k}])" in text


# (vessel, seed, duration s, dt s): one thruster (drawn from the seed) at 60 % in a 0.1 m/s current
LOST_IN_CURRENT = [("minerva2", 3, 120.0, 0.05), ("amv_osf", 4, 200.0, 0.1)]


@pytest.mark.parametrize(("vessel", "seed", "duration", "dt"), LOST_IN_CURRENT)
def test_lost_thruster_in_a_current(tmp_path: Path, vessel: str, seed: int, duration: float,
                                    dt: float) -> None:
    m = load_vessel(vessel).thrusters.count
    lost = int(np.random.default_rng(seed).integers(m)) + 1
    speed, direction = 0.1, 0.8
    d = diagnose(_log(tmp_path, vessel, seed, {f"thruster_efficiency_{lost}": 0.6, "current_speed": speed,
                                               "current_direction": direction}, duration, dt))
    _report(d, f"thruster {lost} at 0.6, current {speed} m/s towards {math.degrees(direction):.0f} deg")
    _check_pair(d, ["current", "thruster_loss"])
    assert _lost(d) == {lost: pytest.approx(0.6, abs=ETA_TOL)}
    p = d.extended.params
    assert p["v_c_north"] == pytest.approx(speed * math.cos(direction), abs=CURRENT_TOL)
    assert p["v_c_east"] == pytest.approx(speed * math.sin(direction), abs=CURRENT_TOL)
    towards = math.degrees(math.atan2(p["v_c_east"], p["v_c_north"]))
    assert towards == pytest.approx(math.degrees(direction), abs=DIRECTION_TOL)



def test_a_steady_force_standing_in_for_a_lost_thruster_is_swapped_out(tmp_path: Path) -> None:
    """AMV, 500 s at 20 Hz (``bench_maneuver_pairs.py``'s case): thruster 1 at 60 % in a 0.1 m/s
    current. The pair search accepts current + steady force; grown by the lost thruster, the force
    loses its significance, and the combination without it, the truth, is fitted and chosen (it
    was never fitted before: the answer was current + steady force)."""
    speed, direction = 0.1, 0.8
    d = diagnose(_log(tmp_path, "amv_osf", 28, {"thruster_efficiency_1": 0.6, "current_speed": speed,
                                                 "current_direction": direction}, 499.95, 0.05))
    _check_pair(d, ["current", "thruster_loss"])
    assert _lost(d) == {1: pytest.approx(0.6, abs=ETA_TOL)}
    p = d.cause.fit.params  # type: ignore[union-attr]
    assert p["v_c_north"] == pytest.approx(speed * math.cos(direction), abs=CURRENT_TOL)
    assert p["v_c_east"] == pytest.approx(speed * math.sin(direction), abs=CURRENT_TOL)
    grown = next(c for c in d.candidates if c.size == 3)
    assert not grown.accepted and "constant_force: parameter not significant" in grown.reason

@pytest.mark.parametrize(("seed", "other"), [(6, "thruster_loss"), (13, "current")])
def test_buoyancy_error_with_a_lost_thruster_or_a_current(tmp_path: Path, seed: int, other: str) -> None:
    """Minerva 2 with 100 N more buoyancy than its file says (a constant heave force, upwards: z
    down) and either one thruster at 60 % or a 0.1 m/s current: both named."""
    m2 = load_vessel("minerva2")
    assert m2.restoring is not None
    truth = dataclasses.replace(m2, restoring=dataclasses.replace(m2.restoring,
                                                                  buoyancy=m2.restoring.buoyancy + 100.0))
    lost = int(np.random.default_rng(seed).integers(m2.thrusters.count)) + 1
    plant = ({f"thruster_efficiency_{lost}": 0.6} if other == "thruster_loss"
             else {"current_speed": 0.1, "current_direction": 0.8})
    d = diagnose(_log(tmp_path, "minerva2", seed, plant, 120.0, 0.05, truth))
    _report(d, f"{plant}, buoyancy +100 N")
    _check_pair(d, ["constant_force", other])
    assert d.extended.params["F_0[Z]"] == pytest.approx(-100.0, rel=FORCE_TOL)
    if other == "thruster_loss":
        assert _lost(d) == {lost: pytest.approx(0.6, abs=ETA_TOL)}
    else:
        p = d.extended.params
        assert p["v_c_north"] == pytest.approx(0.1 * math.cos(0.8), abs=CURRENT_TOL)
        assert p["v_c_east"] == pytest.approx(0.1 * math.sin(0.8), abs=CURRENT_TOL)


def test_lost_thruster_with_changed_damping_names_the_thruster_and_fits_the_damping(tmp_path: Path) -> None:
    """A damping change is not a catalogue effect of a maneuver log: every fit estimates the damping
    diagonals. Minerva 2 with 50 % more yaw and 30 % more surge quadratic damping than its file and
    one thruster at 60 %: the thruster alone is named, and the extended fit's damping is the
    changed one."""
    m2 = load_vessel("minerva2")
    DQ = np.array(m2.D_Q, dtype=float)
    DQ[0, 0] *= 1.3
    DQ[5, 5] *= 1.5
    seed = 14
    lost = int(np.random.default_rng(seed).integers(m2.thrusters.count)) + 1
    d = diagnose(_log(tmp_path, "minerva2", seed, {f"thruster_efficiency_{lost}": 0.6}, 120.0, 0.05,
                      dataclasses.replace(m2, D_Q=DQ)))
    _report(d, f"thruster {lost} at 0.6, D_Q[0,0] x1.3, D_Q[5,5] x1.5")
    assert d.effects == ["thruster_loss"], d.evidence
    assert _lost(d) == {lost: pytest.approx(0.6, abs=ETA_TOL)}
    p = d.extended.params
    assert p["D_Q[0,0]"] == pytest.approx(DQ[0, 0], rel=0.1)
    assert p["D_Q[5,5]"] == pytest.approx(DQ[5, 5], rel=0.1)


# three effects at once (Minerva 2, 0.1 m/s current towards 46 deg): the combination grows by one
# effect while each earns its place; (seed, plant parameters besides the current, buoyancy error)
THREE = [(15, 1, 100.0), (16, 2, 0.0)]


@pytest.mark.parametrize(("seed", "n_lost", "buoyancy"), THREE)
def test_three_effects_are_all_named(tmp_path: Path, seed: int, n_lost: int, buoyancy: float) -> None:
    m2 = load_vessel("minerva2")
    assert m2.restoring is not None
    rng = np.random.default_rng(seed)
    lost = ([int(rng.integers(m2.thrusters.count)) + 1] if n_lost == 1
            else [int(k) + 1 for k in rng.choice(m2.thrusters.count, 2, replace=False)])
    truth_eta = dict(zip(lost, (0.6, 0.75), strict=False))
    truth = dataclasses.replace(m2, restoring=dataclasses.replace(m2.restoring,
                                                                  buoyancy=m2.restoring.buoyancy + buoyancy))
    plant = {**{f"thruster_efficiency_{k}": e for k, e in truth_eta.items()}, "current_speed": 0.1,
             "current_direction": 0.8}
    d = diagnose(_log(tmp_path, "minerva2", seed, plant, 120.0, 0.05, truth))
    _report(d, f"{plant}, buoyancy +{buoyancy:g} N")
    expected = ["current", *(["thruster_loss"] * n_lost), *(["constant_force"] if buoyancy else [])]
    assert sorted(d.effects) == sorted(expected), d.evidence
    assert d.cause is not None and d.cause.accepted and d.cause.significant
    assert _lost(d) == {k: pytest.approx(e, abs=ETA_TOL) for k, e in truth_eta.items()}
    p = d.extended.params
    assert p["v_c_north"] == pytest.approx(0.1 * math.cos(0.8), abs=CURRENT_TOL)
    assert p["v_c_east"] == pytest.approx(0.1 * math.sin(0.8), abs=CURRENT_TOL)
    if buoyancy:
        assert p["F_0[Z]"] == pytest.approx(-buoyancy, rel=FORCE_TOL)
    # it beats every combination of one effect fewer, each fitted in the search
    subs = [c for c in d.candidates if c.fit is not None and c.size == 2
            and set(c.members()) <= set(d.cause.members())]
    assert len(subs) == 3 and all(c.fit.nrmse_validation > 1.02 * d.cause.fit.nrmse_validation  # type: ignore[union-attr]
                                  for c in subs)
    assert d.evidence.startswith("3 effects act together")


def test_three_effects_in_a_long_log_where_each_single_fit_wanders(tmp_path: Path) -> None:
    """A 10 000-sample log (500 s) of Minerva 2 with thruster 2 at 60 %, a 0.1 m/s current and
    100 N more buoyancy: the baseline takes the buoyancy into a negative heave damping, the current
    alone is accepted with a roll damping of 1e6 and a current half-way to the thrust loss's, and a
    pair warm started from it diverges held out. From the baseline the pair converges and grows by
    the constant force: all three named, with their values."""
    m2 = load_vessel("minerva2")
    assert m2.restoring is not None
    truth = dataclasses.replace(m2, restoring=dataclasses.replace(m2.restoring,
                                                                  buoyancy=m2.restoring.buoyancy + 100.0))
    plant = {"thruster_efficiency_2": 0.6, "current_speed": 0.1, "current_direction": 0.8}
    d = diagnose(_log(tmp_path, "minerva2", 26, plant, 9999 * 0.05, 0.05, truth))
    _report(d, f"{plant}, buoyancy +100 N")
    assert sorted(d.effects) == ["constant_force", "current", "thruster_loss"], d.evidence
    assert d.cause is not None and d.cause.accepted and d.cause.significant
    assert _lost(d) == {2: pytest.approx(0.6, abs=ETA_TOL)}
    p = d.extended.params
    assert p["v_c_north"] == pytest.approx(0.1 * math.cos(0.8), abs=CURRENT_TOL)
    assert p["v_c_east"] == pytest.approx(0.1 * math.sin(0.8), abs=CURRENT_TOL)
    assert p["F_0[Z]"] == pytest.approx(-100.0, rel=FORCE_TOL)
    subs = [c for c in d.candidates if c.fit is not None and c.size == 2
            and set(c.members()) <= set(d.cause.members())]
    assert len(subs) == 3 and all(c.fit.nrmse_validation > 1.02 * d.cause.fit.nrmse_validation  # type: ignore[union-attr]
                                  for c in subs)


@pytest.mark.parametrize(("vessel", "seed", "duration", "dt"), [("minerva2", 7, 120.0, 0.05),
                                                                ("amv_osf", 8, 200.0, 0.1)])
def test_clean_maneuver_log_names_nothing(tmp_path: Path, vessel: str, seed: int, duration: float,
                                          dt: float) -> None:
    d = diagnose(_log(tmp_path, vessel, seed, {}, duration, dt))
    _report(d, "clean")
    assert d.effect == "none" and d.effects == [], d.evidence
    assert not any(c.accepted for c in d.candidates)
    assert d.to_json()["cause"]["members"] == []


# one effect only: (vessel, seed, plant parameters, the effect)
SINGLE = [("minerva2", 9, {"thruster_efficiency_4": 0.6}, "thruster_loss"),
          ("amv_osf", 10, {"current_speed": 0.1, "current_direction": 0.8}, "current"),
          ("amv_osf", 11, {"thruster_efficiency_2": 0.7}, "thruster_loss")]


@pytest.mark.parametrize(("vessel", "seed", "plant", "effect"), SINGLE)
def test_one_effect_still_gives_exactly_one(tmp_path: Path, vessel: str, seed: int, plant: dict[str, float],
                                            effect: str) -> None:
    duration, dt = (120.0, 0.05) if vessel == "minerva2" else (200.0, 0.1)
    d = diagnose(_log(tmp_path, vessel, seed, plant, duration, dt))
    _report(d, str(plant))
    assert d.effects == [effect], d.evidence
    assert d.cause is not None and d.cause.size == 1
    if effect == "thruster_loss":
        (k, e), = ((int(key.rsplit("_", 1)[1]), v) for key, v in plant.items())
        assert _lost(d) == {k: pytest.approx(e, abs=ETA_TOL)}


def test_combined_terms_merge_as_the_plant_adds_them() -> None:
    """Thrust gains multiply (two thrusters lost), forces and currents add, parameters side by side."""
    tl = get("thruster_loss")
    assert tl is not None
    a, b = tl.maneuver_variants(4)[0], tl.maneuver_variants(4)[2]
    both = Combined((a, b), 3)
    assert both.maneuver_params(3) == ["eta_T[1]", "eta_T[3]"]
    gain = both.maneuver_terms(np.array([[0.6, 0.8], [1.0, 0.5]]))["thrust_gain"]
    assert gain.tolist() == [[0.6, 1.0, 0.8, 1.0], [1.0, 1.0, 0.5, 1.0]]
    cur, force = get("current"), get("constant_force")
    assert cur is not None and force is not None
    mix = Combined((cur, force, a), 3)
    terms = mix.maneuver_terms(np.array([[0.1, -0.2, 1.0, 2.0, 3.0, 0.7]]))
    assert terms["vc"].tolist() == [[0.1, -0.2]] and terms["F0"].tolist() == [[1.0, 2.0, 3.0]]
    assert terms["thrust_gain"].tolist() == [[0.7, 1.0, 1.0, 1.0]]
    assert len(mix.maneuver_scales(np.ones((5, 3)))) == 6
    text = mix.maneuver_evidence({"v_c_north": 0.1, "v_c_east": 0.0, "F_0[X]": 1.0, "eta_T[1]": 0.7})
    assert "current of 0.1 m/s" in text and "thruster 1 delivers 70 %" in text


def test_a_log_is_read_and_prepared_once_per_diagnosis(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Every fit of a diagnosis (baseline, each effect, the pairs) shares one prepared log."""
    from seafmu.identification.maneuver import fit as maneuver_fit

    trial = _log(tmp_path, "amv_osf", 12, {"thruster_efficiency_1": 0.6}, 120.0, 0.1)
    calls = {"read": 0, "prepare": 0}
    read, prepare = diagnosis.maneuver_data, maneuver_fit.prepare_maneuver

    def counted_read(*a: object, **k: object) -> object:
        calls["read"] += 1
        return read(*a, **k)  # type: ignore[arg-type]

    def counted_prepare(*a: object, **k: object) -> object:
        calls["prepare"] += 1
        return prepare(*a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(diagnosis, "maneuver_data", counted_read)
    monkeypatch.setattr(maneuver_fit, "prepare_maneuver", counted_prepare)
    d = diagnose(trial)
    fits = sum(c.fit is not None for c in d.candidates) + 1
    assert fits >= 3 and calls == {"read": 1, "prepare": 1}
    assert diagnosis._PREPARED == {}  # nothing kept after the diagnosis


def test_a_named_combination_is_fitted_and_a_located_effect_refused(tmp_path: Path) -> None:
    """``fit_extension`` with several names fits them together on a maneuver log; an effect that
    must first be located (which thruster) is refused with one line."""
    trial = _log(tmp_path, "amv_osf", 13, {"current_speed": 0.1, "current_direction": 0.8}, 120.0, 0.1)
    base = diagnosis.fit_baseline(trial, diagnosis=True)
    fit = diagnosis.fit_extension(trial, base, ("current", "constant_force"))
    assert {"v_c_north", "v_c_east", "F_0[X]", "F_0[Y]", "F_0[N]"} <= set(fit.param_names)
    assert fit.params["v_c_north"] == pytest.approx(0.1 * math.cos(0.8), abs=CURRENT_TOL)
    with pytest.raises(diagnosis.TrialError, match="thruster_loss cannot be fitted in a named combination"):
        diagnosis.fit_extension(trial, base, ("current", "thruster_loss"))

"""Issue 11: several effects at once, ambiguity stated, claims checked against the data, power laws.

Pairs of effects are hidden in every 1-2-DOF trial kind where two can coexist (the generator's own
models, as tests/test_ident_hidden.py does for one effect); the diagnosis must name both and no
third. A table whose thrust grows like n^1.5 (an Archimedes screw, as the AMV's bollard pull) has
competing explanations: the power law is named with p's interval, the quadratic law is a credible
alternative with its Akaike weight and the measurement that tells them apart, and a deadband that
contradicts thrust measured inside it is rejected. Clean data stay silent (test_ident_hidden.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from seafmu.identification.diagnosis import diagnose
from seafmu.identification.fitting import covariance_from_jacobian, fit_statistics
from seafmu.identification.report import summary_lines, write_diagnosis_report
from seafmu.identification.synthetic import demo_trial
from seafmu.identification.trial import Run, Trial, make_trial

# Pairs that can coexist in each trial kind (a static force-speed table of one direction cannot tell
# a constant force from Coulomb friction, so its pairs are tested on the bollard table; a sway_yaw
# trial has one effect; a maneuver fit takes one extension at a time).
PAIRS = [
    ("thrust", ("thrust_asymmetry", "constant_force")),
    ("thrust", ("deadband", "thrust_asymmetry")),
    ("decay", ("linear_damping", "constant_force")),
    ("decay", ("current", "coulomb_friction")),
    ("step", ("thrust_asymmetry", "actuator_lag")),
    ("step", ("deadband", "time_delay")),
    ("decay2", ("quadratic_damping", "coulomb_friction")),
    ("decay2", ("nonlinear_restoring", "constant_force")),
    ("pendulum", ("coulomb_friction", "constant_force")),
]


@pytest.mark.parametrize(("kind", "pair"), PAIRS)
def test_a_hidden_pair_is_named_both_and_no_third(kind: str, pair: tuple[str, str]) -> None:
    trial = demo_trial(pair, kind, seed=1)
    d = diagnose(trial)
    assert sorted(d.effects) == sorted(pair), d.evidence
    doc = d.to_json()
    assert sorted(doc["cause"]["effects"]) == sorted(pair) and doc["cause"]["effect"] == d.effects[0]
    # the extended model has every effect's parameters, each significant
    assert d.cause is not None and d.cause.significant
    for name in pair:
        assert any(k in doc["extended"]["params"] for k in d.cause.effect_params()), name
    assert doc["gain"]["validation_nrmse_ratio"] > 1.02 and doc["gain"]["delta_aic"] < -10
    assert d.evidence.startswith("2 effects act together")


def test_a_pair_explains_what_each_effect_alone_makes_worse() -> None:
    """A cap and a steady force together: each alone predicts the held-out run worse than the
    baseline, so a search built on accepted singles would say "none"; the pair search finds both."""
    d = diagnose(demo_trial(("saturation", "constant_force"), "step", seed=1))
    singles = {c.effect: c for c in d.candidates if c.size == 1}
    assert singles["saturation"].ratio < 1.0 and singles["constant_force"].ratio < 1.0
    assert not singles["saturation"].accepted and not singles["constant_force"].accepted
    assert sorted(d.effects) == ["constant_force", "saturation"], d.evidence


def _screw_table(seed: int = 1) -> Trial:
    """Forward bollard pull of a screw whose thrust grows like n^1.5, 0.85 N at 0.38 rev/s (the
    shape and the low point the issue reports for the AMV's tables), 0.08 N noise."""
    rng = np.random.default_rng(seed)
    n = np.array([0.38, 0.6, 0.8, 1.0, 1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.3])
    thrust = 0.85 / 0.38**1.5 * n**1.5 + rng.normal(0.0, 0.08, n.size)
    return make_trial("static", [Run("bollard", thrust, u=n)], dof="surge", table="thrust_rpm",
                      baseline="linear", name="screw_bollard")


def test_competing_thrust_laws_are_stated_with_weights_and_the_measurement_between(tmp_path: Path) -> None:
    d = diagnose(_screw_table())
    assert d.effect == "thrust_power", d.evidence
    p = d.extended.params["p_n"]
    lo, hi = d.extended.ci95["p_n"]
    assert lo < 1.5 < hi and hi - lo < 0.2 and p == pytest.approx(1.5, abs=0.05)
    assert "faster than linear" in d.evidence and "p = 1.5 ±" in d.evidence
    doc = json.loads(json.dumps(d.to_json(), default=float))
    alts = doc["cause"]["alternatives"]
    assert alts[0]["effect"] == "thrust_power" and alts[0]["delta_aic"] == 0.0
    names = [a["effect"] for a in alts]
    assert "thrust_quadratic" in names  # the thesis's law passes the rule too: stated, not hidden
    assert math.isclose(sum(a["weight"] for a in alts), 1.0, rel_tol=1e-9)
    quad = alts[names.index("thrust_quadratic")]
    assert quad["validation_nrmse_ratio"] > 1.02 and quad["delta_aic"] > 0
    exp = quad["discriminating_experiment"]
    assert exp["between"] == ["thrust_power", "thrust_quadratic"]
    assert exp["difference_over_noise"] > 2 and exp["input_unit"] == "rev/s"
    # the predicted difference at that input is what the two fitted laws say
    fits = {c.effect: c.fit for c in d.candidates if c.fit is not None}
    x = np.array([exp["input"]])
    pred = [fits[e].extras["model"].predict(x, np.array([fits[e].params[q] for q in fits[e].param_names]))[0]
            for e in ("thrust_power", "thrust_quadratic")]
    assert abs(pred[0] - pred[1]) == pytest.approx(exp["difference"], rel=1e-9)
    # the deadband's claim (no thrust below n_0) is contradicted by the 0.85 N at 0.38 rev/s
    dead = next(c for c in d.candidates if c.effect == "deadband")
    assert not dead.accepted and dead.flags and "0.38 rev/s" in dead.flags[0]
    assert "deadband" not in names
    # terminal and report say it too
    text = "\n".join(summary_lines(d))
    assert "also credible: thrust_quadratic" not in text or "to tell them apart" in text
    report = write_diagnosis_report(d, tmp_path).read_text()
    assert "Credible alternatives" in report and "`thrust_quadratic`" in report


def test_a_cap_above_every_command_is_not_a_finding() -> None:
    """Saturation fitted where no command reaches the cap: its claim has no support (flagged), its
    parameter unidentifiable."""
    d = diagnose(_screw_table(), effects=["saturation"])
    c = d.candidates[0]
    assert not c.accepted and c.fit is not None
    assert c.fit.params["u_sat"] >= 2.3  # every command is 2.3 rev/s or less
    assert any("above every command" in f for f in c.flags)
    lo, hi = c.fit.ci95["u_sat"]
    assert not (math.isfinite(lo) and math.isfinite(hi))  # infinite variance, not zero
    assert any("not identifiable" in w for w in c.fit.warnings)


def test_an_unidentifiable_parameter_has_infinite_variance() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=100)
    J = np.column_stack([x, np.zeros(100)])  # the second parameter does not move the output
    cov = covariance_from_jacobian(J, rng.normal(size=100))
    assert math.isinf(cov[1, 1]) and math.isfinite(cov[0, 0]) and cov[0, 0] > 0
    ci, _, _ = fit_statistics(["a", "b"], np.ones(2), J, rng.normal(size=100))
    assert ci["b"] == (-math.inf, math.inf) and all(map(math.isfinite, ci["a"]))
    # more parameters than rows: the directions the data cannot see are infinite too
    cov = covariance_from_jacobian(np.ones((1, 2)), np.ones(1))
    assert np.all(np.isinf(np.diag(cov)))


def test_the_drag_exponent_is_stated_with_its_interval() -> None:
    d = diagnose(demo_trial("damping_power", seed=1))
    assert d.effect == "damping_power", d.evidence
    lo, hi = d.extended.ci95["p_v"]
    assert lo < 1.5 < hi and "slower than the square of speed" in d.evidence


def test_clean_data_stay_silent_with_the_combination_search() -> None:
    for kind in ("thrust", "step", "decay2"):
        d = diagnose(demo_trial(None, kind, noise=0.03, seed=2))
        assert d.effect == "none", d.evidence
        assert any(c.size > 1 for c in d.candidates) or kind == "decay2"
        assert d.to_json()["cause"]["alternatives"] == []


def test_aliased_explanations_are_stated_as_about_equal_with_the_experiment_between() -> None:
    """A force-speed table measured ahead only, with a steady force on top of quadratic drag: on
    one-directional speeds a constant force and Coulomb friction are the same model. The diagnosis
    names one beside the quadratic drag and states the other at about equal weight, and the
    experiment that tells them apart is running astern (where friction changes sign)."""
    rng = np.random.default_rng(4)
    v = np.linspace(0.1, 1.0, 16)
    force = 15.6 * v + 42.7 * v * np.abs(v) + 2.0 + rng.normal(0.0, 0.15, v.size)
    trial = make_trial("static", [Run("table", force, u=v)], dof="surge", table="force_speed",
                       baseline="linear", name="drag_plus_offset")
    d = diagnose(trial)
    assert d.effects[0] == "quadratic_damping" and len(d.effects) == 2, d.evidence
    other = {"constant_force", "coulomb_friction"} - set(d.effects)
    assert len(other) == 1
    alt = next(a for a in d.alternatives if set(a.candidate.effects) == {"quadratic_damping", *other})
    assert 0.3 < alt.weight < 0.7  # about equal: the data cannot tell them apart
    assert alt.experiment is not None and alt.experiment["input"] < 0  # astern
    assert alt.experiment["difference_over_noise"] > 10

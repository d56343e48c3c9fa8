"""Hide an effect in synthetic data and require the diagnosis to name it (and nothing on clean data).

Every catalogue effect is generated in the trial kind where it is observable, at two noise levels
and two excitation amplitudes, simulated with 10 RK4 sub-steps per sample (the fits use one), so
the fit never shares the generator's discretisation. The same rule must stay silent on clean
trials of every kind over several seeds: a false alarm is as wrong as a miss.
"""

from __future__ import annotations

import math

import pytest

from seafmu.identification.catalogue import CATALOGUE, null_value
from seafmu.identification.diagnosis import diagnose
from seafmu.identification.synthetic import demo_trial

# What was hidden (see synthetic.demo_trial) and how close the fitted effect parameter must come.
# Friction is fitted with a smooth law (creep instead of stiction), which biases f_c upwards.
TRUTH = {
    "linear_damping": ("d_L", lambda a: 8.0, 0.15), "quadratic_damping": ("d_Q", lambda a: 34.0, 0.1),
    "coulomb_friction": ("f_c", lambda a: 0.06, 0.5), "current": ("v_c", lambda a: 0.1, 0.1),
    "constant_force": ("F_0", lambda a: 1.5, 0.1), "added_mass": ("m_a", lambda a: 12.0, 0.1),
    "thrust_quadratic": ("k_q", lambda a: 6.0, 0.1), "thrust_asymmetry": ("eta_rev", lambda a: -0.35, 0.1),
    "deadband": ("n_0", lambda a: 0.3 * a, 0.15), "actuator_lag": ("T_lag", lambda a: 0.8, 0.15),
    "time_delay": ("t_d", lambda a: 0.5, 0.15), "saturation": ("u_sat", lambda a: 1.4 * a, 0.1),
    # sin(x) = x - x^3/6 + ...: a cubic term near -c/6 = -20/6 on these amplitudes.
    "nonlinear_restoring": ("c3", lambda a: -20.0 / 6.0, 0.3), "coupling": ("Y_r", lambda a: 12.0, 0.1),
    # the power laws (issue 11): an Archimedes-screw-like thrust n^1.5, a drag v|v|^0.5
    "thrust_power": ("p_n", lambda a: 1.5, 0.05), "damping_power": ("p_v", lambda a: 1.5, 0.05),
}
# Effects of the maneuver model only (no 1-2-DOF trial shows them): their own test modules.
MANEUVER_ONLY = {"thruster_loss": "tests/test_thruster_loss.py"}
HIDDEN = [e for e in CATALOGUE if e not in MANEUVER_ONLY]


def test_every_catalogue_effect_is_tested() -> None:
    assert set(TRUTH) == set(HIDDEN)
    assert set(TRUTH) | set(MANEUVER_ONLY) == set(CATALOGUE)
    assert len(CATALOGUE) >= 16  # the 14 of the issue-1 catalogue, the two power laws, thruster_loss


@pytest.mark.parametrize("amplitude", [0.6, 1.0])
@pytest.mark.parametrize("noise", [0.01, 0.03])
@pytest.mark.parametrize("effect", HIDDEN)
def test_hidden_effect_is_named(effect: str, noise: float, amplitude: float) -> None:
    trial = demo_trial(effect, noise=noise, amplitude=amplitude, seed=1)
    d = diagnose(trial)
    assert d.effect == effect, d.evidence
    doc = d.to_json()
    assert doc["cause"]["effect"] == effect
    assert doc["gain"]["validation_nrmse_ratio"] > 1.0
    assert doc["gain"]["delta_aic"] < -10
    # The named effect's parameter is significant and near the hidden value.
    name, truth, tol = TRUTH[effect]
    value = doc["extended"]["params"][name]
    lo, hi = doc["extended"]["ci95"][name]
    assert not lo <= null_value(name, trial) <= hi
    assert value == pytest.approx(truth(amplitude), rel=tol)
    # The evidence sentence carries the numbers it rests on.
    assert "held-out NRMSE" in d.evidence and "dAIC" in d.evidence
    # Among single effects (a combination with a lower held-out error must still earn its extra
    # parameters over the simpler explanation to be named: diagnosis.choose).
    accepted = [r for r in doc["cause"]["ranking"] if r["accepted"] and len(r["effects"]) == 1]
    best = min(r["nrmse_validation"] for r in accepted)
    named = next(r for r in accepted if r["effect"] == effect)
    assert named["nrmse_validation"] <= 1.01 * best


CLEAN_KINDS = ["static", "thrust", "decay", "step", "decay2", "pendulum", "sway_yaw"]


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("noise", [0.01, 0.03])
@pytest.mark.parametrize("kind", CLEAN_KINDS)
def test_clean_trial_gives_no_effect(kind: str, noise: float, seed: int) -> None:
    d = diagnose(demo_trial(None, kind=kind, noise=noise, seed=seed))
    assert d.effect == "none", d.evidence
    assert d.evidence.startswith("No effect found")
    doc = d.to_json()
    assert doc["gain"]["validation_nrmse_ratio"] == pytest.approx(1.0)
    assert doc["extended"]["params"] == doc["baseline"]["params"]
    assert d.candidates, "at least one effect must have been tried"


def test_the_rule_is_what_rejects_a_weak_effect() -> None:
    """A real but tiny effect must fail the rule, not slip through on fit data alone."""
    trial = demo_trial(None, kind="decay", noise=0.03, seed=3)
    d = diagnose(trial, effects=["constant_force", "coulomb_friction"])
    for c in d.candidates:
        assert not c.accepted
        assert c.reason and c.reason != "accepted"
    assert math.isfinite(d.baseline.nrmse_validation)


TABLE_CASES = [("thrust", e, n) for e in ("thrust_quadratic", "thrust_asymmetry", "deadband", "saturation",
                                          "constant_force") for n in (0.01, 0.03)]
TABLE_CASES += [("static", "quadratic_damping", 0.01), ("static", "quadratic_damping", 0.03),
                ("static", "linear_damping", 0.01)]


@pytest.mark.parametrize(("kind", "effect", "noise"), TABLE_CASES)
def test_hidden_effect_in_a_table(kind: str, effect: str, noise: float) -> None:
    """Bollard-pull (thrust vs shaft speed) and force-speed tables, leave-one-out held-out error."""
    d = diagnose(demo_trial(effect, kind=kind, noise=noise, seed=1))
    assert d.effect == effect, d.evidence
    assert d.to_json()["gain"]["validation_nrmse_ratio"] > 1.0
    assert d.baseline.extras["validation"].startswith("leave-one-out")


def test_demo_refuses_an_effect_its_kind_cannot_show() -> None:
    with pytest.raises(ValueError, match="not hidden in a 'pendulum' trial"):
        demo_trial("time_delay", kind="pendulum")

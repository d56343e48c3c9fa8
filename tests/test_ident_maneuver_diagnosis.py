"""Maneuver-level diagnosis: a current or a constant force hidden in a plant-made maneuver log.

The logs are made by PlantBlock (simulate_maneuver: multisine excitation through the thrusters)
with the effect in the plant's environment or vessel, plus the vessel file's sensor noise; the
diagnosis fits the whole 3-/6-DOF model by output error with and without each maneuver-level
extension (a NED current under the damping, a constant force per DOF) and applies the same
acceptance rule as for 1-2-DOF trials. Clean logs must give "none", not a false current.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.identification.catalogue import MANEUVER_EFFECTS
from seafmu.identification.diagnosis import diagnose
from seafmu.identification.maneuver import add_sensor_noise, simulate_maneuver, write_maneuver_csv
from seafmu.identification.trial import Trial, csv_trial


def _trial(tmp: Path, truth: VesselSpec, vessel: str, seed: int, duration: float, dt: float,
           plant_params: dict[str, float] | None = None) -> Trial:
    data, _ = simulate_maneuver(truth, duration=duration, dt=dt, seed=seed, plant_params=plant_params)
    data = add_sensor_noise(data, load_vessel(vessel), 1.0, seed=seed)
    return csv_trial(write_maneuver_csv(data, tmp / f"log{seed}.csv"), vessel)


@pytest.mark.parametrize("seed", [0, 1])
def test_current_in_a_maneuver_log_is_named(tmp_path: Path, seed: int) -> None:
    """AMV, 200 s, 0.1 m/s current towards 46 deg: the damping acts on nu - nu_c."""
    amv = load_vessel("amv_osf")
    trial = _trial(tmp_path, amv, "amv_osf", seed, 200.0, 0.1,
                   {"current_speed": 0.1, "current_direction": 0.8})
    d = diagnose(trial)
    assert d.effect == "current", d.evidence
    doc = d.to_json()
    assert doc["cause"]["tested"] and doc["gain"]["validation_nrmse_ratio"] > 2.0
    p = doc["extended"]["params"]
    assert p["v_c_north"] == pytest.approx(0.1 * math.cos(0.8), rel=0.1)
    assert p["v_c_east"] == pytest.approx(0.1 * math.sin(0.8), rel=0.1)
    assert "current of 0.09" in d.evidence or "current of 0.1" in d.evidence
    assert "towards 46 deg" in d.evidence
    assert d.baseline.method.startswith("maneuver output error")  # the diagnosis baseline


@pytest.mark.parametrize("seed", [0, 1])
def test_clean_maneuver_log_gives_no_effect(tmp_path: Path, seed: int) -> None:
    amv = load_vessel("amv_osf")
    d = diagnose(_trial(tmp_path, amv, "amv_osf", seed, 200.0, 0.1))
    assert d.effect == "none", d.evidence
    # every maneuver-level extension is tried (thruster_loss where the log has per-thruster thrust)
    assert {"current", "constant_force"} <= {c.effect for c in d.candidates} <= set(MANEUVER_EFFECTS)
    assert all(not c.accepted for c in d.candidates)
    # The restarted simulation's residual is coloured by the noisy start states even for the true
    # model (Ljung-Box against white noise rejects); against what the noise alone leaves, it is
    # white, and the evidence does not claim structure that is not there.
    w = d.baseline.whiteness
    assert w["ljung_box_p"] < 0.01 and w["white"] and w["noise_only_p"] >= 0.01, w
    assert "structure remains" not in d.evidence, d.evidence


def test_a_model_structure_error_in_a_maneuver_log_is_flagged_as_structure(tmp_path: Path) -> None:
    """The AMV's sway-yaw quadratic coupling (D_Q[1,2] = D_Q[2,1]) is 0 in the water, 60 in its
    vessel file: no catalogue effect is that, and the baseline (diagonal damping fitted) cannot
    absorb it. The diagnosis must not call the log clean."""
    amv = load_vessel("amv_osf")
    DQ = np.array(amv.D_Q, dtype=float)
    assert DQ[1, 2] == DQ[2, 1] == 60.0
    DQ[1, 2] = DQ[2, 1] = 0.0
    d = diagnose(_trial(tmp_path, dataclasses.replace(amv, D_Q=DQ), "amv_osf", 0, 200.0, 0.1))
    w = d.baseline.whiteness
    assert not w["white"] and w["noise_only_p"] < 0.01, w
    assert d.effect == "none" and "structure remains that no catalogue effect explains" in d.evidence


def test_constant_force_in_a_6dof_maneuver_log_is_named(tmp_path: Path) -> None:
    """Minerva 2 with 100 N more buoyancy than its vessel file says (a float, a tether): the
    identified model's g(eta) misses it, and the diagnosis names a constant heave force."""
    m2 = load_vessel("minerva2")
    assert m2.restoring is not None
    truth = dataclasses.replace(m2, restoring=dataclasses.replace(m2.restoring, buoyancy=m2.restoring.buoyancy
                                                                  + 100.0))
    d = diagnose(_trial(tmp_path, truth, "minerva2", 0, 120.0, 0.05))
    assert d.effect == "constant_force", d.evidence
    p, ci = d.extended.params, d.extended.ci95
    assert p["F_0[Z]"] == pytest.approx(-100.0, rel=0.15)  # upwards (z down)
    assert not ci["F_0[Z]"][0] <= 0.0 <= ci["F_0[Z]"][1]
    assert d.to_json()["gain"]["delta_aic"] < -10
    assert "_halfwidt" not in d.evidence and "Z = -" in d.evidence and " ± " in d.evidence, d.evidence

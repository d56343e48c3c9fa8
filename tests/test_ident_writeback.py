"""Write-back of identified parameters into vessel files (issue 3), and closing the loop:
identify, write back, and the plant built from the written file reproduces the measurement."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seafmu.components.plant import PlantBlock
from seafmu.components.vessel_spec import VesselFileError, load_vessel, vessel_path
from seafmu.identification import fitting
from seafmu.identification.fitting import FitResult
from seafmu.identification.maneuver import identify_maneuver, simulate_maneuver
from seafmu.identification.writeback import updates_from_fit, write_back

PROV = {"trial": "trials/m2_multisine.csv", "method": "maneuver output error", "date": "2026-01-02"}


def test_write_back_replaces_values_and_sources_and_keeps_the_rest(tmp_path: Path) -> None:
    out = write_back("minerva2", {"quadratic_damping[0][0]": 813.06, "D_L[2,2]": 1.5e-5},
                     tmp_path / "m2.yaml", {**PROV, "quadratic_damping[0][0]": "95 % CI [805.1, 821.0]"})
    orig, new = load_vessel("minerva2"), load_vessel(out)
    assert new.D_Q[0, 0] == 813.06 and new.D_L[2, 2] == 1.5e-5
    np.testing.assert_array_equal(new.D_Q[1:], orig.D_Q[1:])
    src = new.provenance["quadratic_damping"]
    for part in ("[0][0] = 813.06 (95 % CI [805.1, 821.0])", "trial trials/m2_multisine.csv",
                 "maneuver output error", "2026-01-02", "earlier source: thesis: steady-flow CFD"):
        assert part in src, part
    assert "[2][2] = 1.5e-05" in new.provenance["linear_damping"]
    # every other field and provenance is unchanged, and so are the comments and the layout
    for f in ("M_RB", "M_A"):
        np.testing.assert_array_equal(getattr(new, f), getattr(orig, f))
    assert new.thrusters.names == orig.thrusters.names
    np.testing.assert_array_equal(new.thrusters.positions, orig.thrusters.positions)
    assert new.restoring is not None and orig.restoring is not None
    assert new.restoring.buoyancy == orig.restoring.buoyancy
    changed = {"quadratic_damping", "linear_damping"}
    assert {k: v for k, v in new.provenance.items() if k not in changed} == \
        {k: v for k, v in orig.provenance.items() if k not in changed}
    text, before = out.read_text(), vessel_path("minerva2").read_text()
    assert text.startswith("# Written by seafmu write_back on 2026-01-02")
    assert "# DEFAULT-FILE DECISION (linear damping)" in text and "# Sensor rates and noise" in text
    kept = [ln for ln in before.splitlines() if "damping" not in ln]
    assert sum(ln in text.splitlines() for ln in kept) >= len(kept) - 8  # only the two blocks differ
    assert "  value: [813.06, 945.1, 2268.3, 1118.8, 3867.7, 942.1947]" in text  # stays a diagonal list


def test_matrix_forms_whole_fields_and_aliases(tmp_path: Path) -> None:
    # an off-diagonal entry turns a diagonal list into a full matrix
    out = write_back("minerva2", {"quadratic_damping[1][5]": 12.5, "added_mass[2]": 7000.0},
                     tmp_path / "a.yaml", PROV)
    v = load_vessel(out)
    assert v.D_Q[1, 5] == 12.5 and v.D_Q[5, 1] == 0.0 and v.D_Q[1, 1] == 945.1
    assert v.M_A[2, 2] == 7000.0 and v.M_A[2, 4] == 61.56  # the full published matrix otherwise
    # whole fields: a diagonal list, a full matrix (AMV coupling terms)
    full = [[30.0, 0.0, 0.0], [0.0, 280.0, 55.0], [0.0, 55.0, 190.0]]
    out = write_back("amv_osf", {"linear_damping": [1.0, 2.0, 3.0], "D_Q": full}, tmp_path / "b.yaml", PROV)
    v = load_vessel(out)
    np.testing.assert_array_equal(v.D_L, np.diag([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(v.D_Q, np.array(full))
    assert "all entries" in v.provenance["quadratic_damping"]
    # a written file can itself be the input (a second trial refines the first)
    again = write_back(out, {"quadratic_damping[0][0]": 31.0}, tmp_path / "c.yaml", PROV)
    assert load_vessel(again).D_Q[0, 0] == 31.0 and load_vessel(again).D_Q[1, 2] == 55.0


@pytest.mark.parametrize(("updates", "match"), [
    ({"hull_drag[0][0]": 1.0}, "no top-level field 'hull_drag'"),
    ({"quadratic_damping[6][6]": 1.0}, "index out of range"),
    ({"linear_damping": [1.0, 2.0]}, "expected 6 numbers"),
    ({"added_mass[0][0]": -5000.0}, "did not validate.*positive definite"),
    ({"quadratic_damping[0][0]": float("nan")}, "not finite"),
    ({"quadratic damping": 1.0}, "cannot read the field name"),
])
def test_bad_updates_are_refused_and_leave_no_file(tmp_path: Path, updates: dict, match: str) -> None:
    out = tmp_path / "x.yaml"
    with pytest.raises(VesselFileError, match=match):
        write_back("minerva2", updates, out, PROV)
    assert not out.exists() and not list(tmp_path.iterdir())
    # writing over the input itself: a refused update leaves the input intact
    own = write_back("minerva2", {}, tmp_path / "own.yaml", PROV)
    before = own.read_text()
    with pytest.raises(VesselFileError):
        write_back(own, updates, own, PROV)
    assert own.read_text() == before


def test_updates_from_a_fit() -> None:
    """Fit names -> vessel fields; added mass = identified total inertia minus the rigid body."""
    m2 = load_vessel("minerva2")
    names = ["M[0,0]", "M[0,2]", "D_L[0,0]", "D_Q[0,0]", "D_Q[0,1]"]
    vals = [3400.0, -70.0, 5.0, 800.0, 3.0]
    fit = FitResult(params=dict(zip(names, vals, strict=True)),
                    ci95={n: (v - 1.0, v + 1.0) for n, v in zip(names, vals, strict=True)},
                    correlation=np.eye(5), param_names=names, nonidentifiable=[], nrmse_fit=0.1,
                    nrmse_validation=0.1, aic=0.0, bic=0.0, whiteness={}, warnings=[], n_samples=10,
                    method="maneuver LS (force form)", extras={"source": "log.csv"})
    up, prov = updates_from_fit(fit, m2)
    assert up == {"added_mass[0][0]": 600.0, "linear_damping[0][0]": 5.0, "quadratic_damping[0][0]": 800.0}
    assert prov["added_mass[0][0]"] == "95 % CI [599, 601]" and prov["trial"] == "log.csv"
    up, _ = updates_from_fit(fit, m2, entries="all")
    assert up["added_mass[0][2]"] == up["added_mass[2][0]"] == -70.0  # symmetric fit: both mirrors
    assert up["quadratic_damping[0][1]"] == 3.0


def test_plant_block_and_fmu_run_the_written_file(built_fmus: dict, tmp_path: Path) -> None:
    """`vessel_file` = the written file: the FMU and the Block both simulate the new damping
    (surge D_Q doubled -> the same forward push gives a clearly lower surge speed)."""
    from seafmu.master import FmuUnit
    from seafmu.scenario import Instance, interface_variables

    out = write_back("minerva2", {"quadratic_damping[0][0]": 2 * 625.43}, tmp_path / "m2.yaml", PROV)
    cmd = np.array([12.0, 12.0, 12.0, 12.0, 0.0, 0.0, 0.0])
    h, steps = 0.1, 80  # 8 s: before the straight-line instability turns the ROV

    def block_u(spec_name: str | Path) -> float:
        b = PlantBlock(load_vessel(spec_name), {"noise_scale": 0.0})
        for k in range(steps):
            y = b.step(k * h, h, cmd)
        return float(y[6])

    u_new, u_old = block_u(out), block_u("minerva2")
    assert u_old - u_new > 0.08 and u_new > 0.3, (u_old, u_new)
    inst = Instance("plant", "plant", None, 1, {"vessel_file": str(out), "noise_scale": 0.0},
                    interface_variables("minerva2", "plant"))
    unit = FmuUnit(inst, built_fmus[("minerva2", "plant")], ["n_cmd_1", "n_cmd_2", "n_cmd_3", "n_cmd_4",
                   "n_cmd_5", "n_cmd_6", "n_cmd_7"], [])
    try:
        unit.initialize(cmd)
        for k in range(steps):
            unit.do_step(k * h, h)
        u_fmu = float(unit.get_outputs()[unit.out_names.index("u")])
    finally:
        unit.terminate()
    assert u_fmu == pytest.approx(u_new, abs=1e-9)


def test_close_the_loop_identify_write_back_and_replay(tmp_path: Path) -> None:
    """'Measured' data come from a vessel whose surge drag is 30 % above the file's. Identify
    from one maneuver by output error, write back, replay the same thruster commands through
    the plant built from the written file: the simulation error against the measurement drops
    by more than an order of magnitude."""
    true_file = write_back("minerva2", {"quadratic_damping[0][0]": 1.3 * 625.43}, tmp_path / "true.yaml",
                           {"note": "test truth: surge quadratic damping +30 %"})
    measured, commands = simulate_maneuver(load_vessel(true_file), duration=150.0, dt=0.05, seed=4)
    prior = load_vessel("minerva2")
    fit = identify_maneuver(measured, prior, method="output_error")
    assert fit.params["D_Q[0,0]"] == pytest.approx(1.3 * 625.43, rel=0.005)
    lo, hi = fit.ci95["D_Q[0,0]"]
    assert lo < 1.3 * 625.43 < hi
    updates, prov = updates_from_fit(fit, prior)
    written = write_back("minerva2", updates, tmp_path / "identified.yaml", {**prov, "trial": "sim"})
    assert "output error" in load_vessel(written).provenance["quadratic_damping"]

    def replay_nrmse(spec_file: str | Path) -> float:
        rep, _ = simulate_maneuver(load_vessel(spec_file), duration=150.0, dt=0.05, commands=commands)
        return float(np.mean([fitting.nrmse(measured.nu[:, j], rep.nu[:, j]) for j in range(6)]))

    before, after = replay_nrmse("minerva2"), replay_nrmse(written)
    assert before > 0.03 and after < before / 20.0, (before, after)


def _maneuver_fit(d_l: float, warnings: list[str]) -> FitResult:
    names = ["D_L[0,0]", "D_Q[0,0]", "D_L[5,5]"]
    vals = {"D_L[0,0]": d_l, "D_Q[0,0]": 200.0, "D_L[5,5]": 10.0}
    return FitResult(params=vals, ci95={n: (v - 1.0, v + 1.0) for n, v in vals.items()},
                     correlation=np.eye(3), param_names=names, nonidentifiable=[], nrmse_fit=0.1,
                     nrmse_validation=0.1, aic=0.0, bic=0.0, whiteness={}, warnings=warnings,
                     n_samples=100, method="ls")


def test_maneuver_write_back_never_writes_energy_injecting_damping(tmp_path: Path) -> None:
    """A negative diagonal damping is written as 0 and said so (as for 1-2-DOF trials); a fit that
    diverges when simulated writes no vessel file at all (every later run would diverge)."""
    from types import SimpleNamespace

    from seafmu.identification.writeback import write_vessel_file

    trial = SimpleNamespace(kind="maneuver", vessel="minerva2", name="log")
    msg, path = write_vessel_file(trial, _maneuver_fit(-28.9, []), tmp_path / "v.yaml", "ls")  # type: ignore[arg-type]
    assert path is not None and "linear_damping[0][0] = -28.9 < 0 is unphysical: written as 0" in msg
    spec = load_vessel(path)
    assert spec.D_L[0, 0] == 0.0 and spec.D_Q[0, 0] == 200.0 and spec.D_L[5, 5] == 10.0
    warn = ["the fitted model diverges when simulated against the trial (unstable)"]
    msg, path = write_vessel_file(trial, _maneuver_fit(5.0, warn), tmp_path / "w.yaml", "ls")  # type: ignore[arg-type]
    assert path is None and msg.startswith("write-back refused") and not (tmp_path / "w.yaml").exists()
    with pytest.raises(ValueError, match="diverges when simulated"):  # the API refuses it too
        updates_from_fit(_maneuver_fit(5.0, warn), load_vessel("minerva2"))


def test_a_written_file_that_replays_worse_says_so_and_why() -> None:
    """A write-back whose replay is worse than the file it started from is a warning naming what the
    fit holds beside the file's matrices (not written: an effect's parameters)."""
    from types import SimpleNamespace

    from seafmu.identification.cli import _worse_note

    params = {"D_L[5,5]": 21.7, "D_Q[1,1]": 941.0, "Y_r": -15.0, "v_c_north": 0.0707, "eta_T[3]": 0.604}
    fit = SimpleNamespace(params=params)
    note = _worse_note(fit, SimpleNamespace(ratio=0.888))  # type: ignore[arg-type]
    assert note.startswith("warning: the written file replays this trial worse") and "0.888x" in note
    assert "v_c_north = 0.0707, eta_T[3] = 0.604 are no vessel-file properties" in note
    assert "D_L" not in note and "Y_r" not in note  # written to the file (coupling: its D entries)
    assert "\n" not in note

"""`seafmu identify` / `seafmu diagnose`: summary, JSON shape, report files, errors, write-back."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seafmu.identification import timeseries as ts
from seafmu.identification.cli import main
from seafmu.identification.synthetic import demo_trial
from seafmu.identification.trial import write_trial

DATA = Path(__file__).resolve().parents[1] / "scenarios" / "data"


def test_diagnose_json_has_the_issue_shape(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["diagnose", str(DATA / "rov_cfd_force_speed.yaml"), "--json", "-o", str(tmp_path)])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    for part in ("baseline", "extended"):
        assert set(doc[part]) >= {"params", "nrmse_fit", "nrmse_validation", "aic"}
    assert doc["cause"]["effect"] == "quadratic_damping"
    assert isinstance(doc["cause"]["evidence"], str) and doc["cause"]["evidence"]
    assert all(set(r) >= {"effect", "nrmse_validation", "delta_aic"} for r in doc["cause"]["ranking"])
    g = doc["gain"]
    assert g["validation_nrmse_ratio"] == pytest.approx(
        doc["baseline"]["nrmse_validation"] / doc["extended"]["nrmse_validation"])
    assert g["delta_aic"] == pytest.approx(doc["extended"]["aic"] - doc["baseline"]["aic"])
    assert (tmp_path / "diagnosis.md").is_file() and (tmp_path / "fit.png").is_file()
    assert json.loads((tmp_path / "diagnosis.json").read_text())["cause"]["effect"] == "quadratic_damping"


def test_identify_prints_a_readable_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["identify", str(DATA / "amv_osf_tow_resistance.yaml"), "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "d_L = -0.6587" in out and "d_Q = 34.078" in out and "RMSE 0.04411 (n - p)" in out
    assert "warning: negative linear damping" in out
    md = (tmp_path / "identification.md").read_text()
    assert "| d_Q | 34.078" in md and "![fit](fit.png)" in md


def test_hidden_effect_through_files_and_the_report(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    trial_yaml = write_trial(demo_trial("time_delay", noise=0.02, seed=4), tmp_path / "trial")
    out = tmp_path / "out"
    assert main(["diagnose", str(trial_yaml), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "cause: time_delay" in text
    md = (out / "diagnosis.md").read_text()
    assert "**Cause: `time_delay`**" in md and "| time_delay |" in md
    for fig in ("overlay.png", "residuals.png", "residual_vs_regressors.png", "ranking.png"):
        assert (out / fig).stat().st_size > 5000, fig


@pytest.mark.parametrize(("argv", "expected"), [
    (["identify", "nope.yaml"], "nope.yaml: cannot read"),
    (["diagnose", str(DATA / "rov_cfd_force_speed.yaml"), "--baseline", "cubic"],
     "--baseline cubic: not one of"),
    (["diagnose", str(DATA / "rov_cfd_force_speed.yaml"), "--effects", "wind"], "unknown effect(s) wind"),
    (["identify", str(DATA / "rov_cfd_force_speed.csv")], "needs --vessel"),
])
def test_errors_are_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str],
                                        expected: str) -> None:
    assert main([*argv, "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("seafmu: error: ") and expected in err and "\n" not in err


def test_write_back_closes_the_loop(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Identified added mass and damping go into a vessel file that the plant then simulates."""
    pytest.importorskip("seafmu.identification.writeback")
    from seafmu.components.vessel_model import VesselModel
    from seafmu.components.vessel_spec import load_vessel

    trial_yaml = write_trial(demo_trial("added_mass", noise=0.01, seed=2), tmp_path / "trial")
    out_vessel = tmp_path / "amv_identified.yaml"
    rc = main(["diagnose", str(trial_yaml), "--vessel", "amv_osf", "--write-vessel", str(out_vessel),
               "-o", str(tmp_path / "out")])
    assert rc == 0
    assert "wrote" in capsys.readouterr().out
    spec = load_vessel(out_vessel)
    assert spec.M_A[0, 0] == pytest.approx(12.0, rel=0.05)  # hidden: 40 kg rigid + 12 kg added
    assert spec.D_Q[0, 0] == pytest.approx(34.0, rel=0.05) and spec.D_L[0, 0] == pytest.approx(3.0, rel=0.3)
    assert Path(spec.source_file) == out_vessel
    assert "hidden_added_mass" in spec.provenance["added_mass"]
    # The plant with the written file coasts down like the hidden truth; the shipped file does not.
    truth = {**ts.DEFAULTS["first"], "M": 40.0, "m_a": 12.0, "d_L": 3.0, "d_Q": 34.0}
    t = np.arange(0, 6, 0.01)
    want = ts.simulate(ts.TSModel("first", truth, []), truth, t, None, (1.0,))

    def coast(vessel: object) -> np.ndarray:
        vm = VesselModel(vessel)  # type: ignore[arg-type]
        x = np.zeros(vm.n_states)
        x[3] = 1.0
        out = [1.0]
        h = 0.01
        for _ in t[1:]:
            k1 = vm.rhs(x, [0.0, 0.0])
            k2 = vm.rhs(x + h / 2 * k1, [0.0, 0.0])
            k3 = vm.rhs(x + h / 2 * k2, [0.0, 0.0])
            k4 = vm.rhs(x + h * k3, [0.0, 0.0])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            out.append(x[3])
        return np.array(out)

    err_new = np.max(np.abs(coast(spec) - want))
    err_old = np.max(np.abs(coast(load_vessel("amv_osf")) - want))
    assert err_new < 0.01 < err_old


def test_a_maneuver_log_is_a_valid_trial(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A multi-DOF log in the `seafmu run` column layout goes to the maneuver identification."""
    man = pytest.importorskip("seafmu.identification.maneuver")
    from seafmu.components.vessel_spec import load_vessel

    vessel = load_vessel("amv_osf")
    data, _ = man.simulate_maneuver(vessel, duration=120.0, dt=0.1, seed=1)
    cols = {"time": data.t}
    for j, name in enumerate(vessel.eta_names):
        cols[f"plant.{name}"] = data.eta[:, j]
    for j, name in enumerate(vessel.nu_names):
        cols[f"plant.{name}"] = data.nu[:, j]
    for j, name in enumerate(vessel.tau_names):
        cols[f"allocator.tau_alloc_{name}"] = data.tau[:, j]
    csv = tmp_path / "results.csv"
    np.savetxt(csv, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
    (tmp_path / "summary.json").write_text(json.dumps({"vessel": "amv_osf"}))
    rc = main(["identify", str(csv), "--json", "-o", str(tmp_path / "out")])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["trial"]["kind"] == "maneuver"
    assert any("D_Q" in k for k in doc["fit"]["params"])


def _amv_maneuver_trial(folder: Path, yaw_unit: str = "deg", extra: str = "") -> Path:
    """A 120 s AMV maneuver log made by the plant with surge D_Q 50 (file: 34.08), yaw in degrees
    and yaw rate in deg/s, as a trial YAML naming units (baseline output error)."""
    import dataclasses

    man = pytest.importorskip("seafmu.identification.maneuver")
    from seafmu.components.vessel_spec import load_vessel

    vessel = load_vessel("amv_osf")
    DQ = vessel.D_Q.copy()
    DQ[0, 0] = 50.0
    truth = dataclasses.replace(vessel, D_Q=DQ)
    data, _ = man.simulate_maneuver(truth, duration=120.0, dt=0.1, seed=1)
    folder.mkdir(parents=True, exist_ok=True)
    deg = 180.0 / np.pi
    cols = {"t": data.t, "north_m": data.eta[:, 0], "east_m": data.eta[:, 1], "psi_deg": data.eta[:, 2] * deg,
            "u_ms": data.nu[:, 0], "v_ms": data.nu[:, 1], "r_dps": data.nu[:, 2] * deg,
            "X_N": data.tau[:, 0], "Y_N": data.tau[:, 1], "N_Nm": data.tau[:, 2]}
    np.savetxt(folder / "log.csv", np.column_stack(list(cols.values())), delimiter=",",
               header="# AMV maneuver, plant-made, surge D_Q 50\n" + ",".join(cols), comments="")
    (folder / "trial.yaml").write_text(f"""
name: amv_maneuver_units
kind: maneuver
vessel: amv_osf
files: [log.csv]
baseline: output_error
columns:
  time: {{column: t, unit: s}}
  north: {{column: north_m, unit: m}}
  east: east_m
  yaw: {{column: psi_deg, unit: {yaw_unit}}}
  u: {{column: u_ms, unit: m/s}}
  v: {{column: v_ms, unit: m/s}}
  r: {{column: r_dps, unit: deg/s}}
  tau_X: {{column: X_N, unit: N}}
  tau_Y: {{column: Y_N, unit: N}}
  tau_N: {{column: N_Nm, unit: N.m}}
{extra}""")
    return folder / "trial.yaml"


def test_maneuver_units_plots_write_back_and_replay(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """deg and deg/s columns are converted; the report has overlay and residual plots; the written
    vessel file simulates the log better than the shipped one when the inputs are replayed."""
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.identification.diagnosis import maneuver_data
    from seafmu.identification.trial import load_trial

    trial_yaml = _amv_maneuver_trial(tmp_path / "trial")
    trial = load_trial(trial_yaml)
    data = maneuver_data(trial, load_vessel("amv_osf"))
    raw = np.loadtxt(tmp_path / "trial" / "log.csv", delimiter=",", skiprows=2)
    assert data.eta[:, 2] == pytest.approx(np.radians(raw[:, 3])) and data.nu[:, 2] == pytest.approx(
        np.radians(raw[:, 6]))
    out_vessel = tmp_path / "amv_identified.yaml"
    rc = main(["identify", str(trial_yaml), "--json", "-o", str(tmp_path / "out"),
               "--write-vessel", str(out_vessel)])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["fit"]["params"]["D_Q[0,0]"] == pytest.approx(50.0, rel=0.02)
    assert doc["write_back"].startswith("wrote")
    rep = doc["replay"]
    assert rep["nrmse_new"] < rep["nrmse_old"] and rep["ratio"] > 3, rep
    assert rep["per_channel"]["u"][1] < 0.2 * rep["per_channel"]["u"][0]
    md = (tmp_path / "out" / "identification.md").read_text()
    assert "## Close the loop" in md and "replay through the plant" in md
    for fig in ("overlay.png", "residuals.png"):
        assert (tmp_path / "out" / fig).stat().st_size > 5000, fig
        assert f"({fig})" in md


def test_untested_diagnosis_is_not_tested_rather_than_clean(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Only 1-2-DOF effects asked for on a maneuver log: nothing was tested, and the answer says so
    (effect 'not_tested', not 'none'); the plots of the baseline fit are still written."""
    trial_yaml = _amv_maneuver_trial(tmp_path / "trial")
    rc = main(["diagnose", str(trial_yaml), "--json", "-o", str(tmp_path / "out"),
               "--effects", "quadratic_damping,actuator_lag"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["cause"]["effect"] == "not_tested" and doc["cause"]["tested"] is False
    assert doc["cause"]["evidence"].startswith("Not tested: none of the maneuver-level extensions")
    assert "not a clean bill of health" in doc["cause"]["evidence"]
    assert set(doc["cause"]["not_applicable"]) == {"quadratic_damping", "actuator_lag"}
    assert (tmp_path / "out" / "overlay.png").is_file() and (tmp_path / "out" / "residuals.png").is_file()


@pytest.mark.parametrize(("edit", "expected"), [
    ({"yaw_unit": "m/s"}, "columns.yaw.unit: 'm/s' is m/s, but the angle yaw of a maneuver trial needs rad"),
    ({"yaw_unit": "furlong"}, "columns.yaw.unit: unknown unit 'furlong'"),
    ({"extra": "  rudder: {column: X_N, unit: deg}\n"},
     "columns.rudder: not a column role of a maneuver trial"),
])
def test_maneuver_column_units_are_checked(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          edit: dict[str, str], expected: str) -> None:
    trial_yaml = _amv_maneuver_trial(tmp_path / "trial", **edit)
    assert main(["identify", str(trial_yaml), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("seafmu: error: ") and expected in err and "\n" not in err


def test_write_back_replays_a_plant_made_decay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A coast-down made by the plant with surge D_L = 8 (file: 0): after --write-vessel the trial's
    runs are re-simulated by the plant model with both files and the written one wins."""
    from seafmu.identification.plant_trials import plant_trial

    trial_yaml = write_trial(plant_trial("linear_damping"), tmp_path / "trial")
    out_vessel = tmp_path / "amv_identified.yaml"
    rc = main(["diagnose", str(trial_yaml), "--vessel", "amv_osf", "--write-vessel", str(out_vessel),
               "--json", "-o", str(tmp_path / "out")])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["cause"]["effect"] == "linear_damping"
    rep = doc["replay"]
    assert rep["ratio"] > 2.0 and rep["nrmse_new"] < rep["nrmse_old"], rep
    assert json.loads((tmp_path / "out" / "diagnosis.json").read_text())["replay"] == rep
    # a table is not a vessel motion: the write-back happens, the replay says why it is skipped
    rc = main(["diagnose", str(DATA / "rov_cfd_force_speed.yaml"), "--vessel", "minerva2", "--write-vessel",
               str(tmp_path / "m2.yaml"), "-o", str(tmp_path / "out2")])
    assert rc == 0
    assert "replay skipped: a static trial is not a vessel motion" in capsys.readouterr().out

"""The trial file format: a valid trial loads into SI arrays; every bad file fails with one line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from seafmu.identification.synthetic import demo_trial
from seafmu.identification.trial import TrialError, load_trial, write_trial

DATA = Path(__file__).resolve().parents[1] / "scenarios" / "data"

STEP_YAML = """
name: coast
kind: decay
dof: surge
files: [run.csv]
columns:
  time: {column: t_s, unit: s}
  output: {column: u_kn, unit: kn}
constants: {mass: 50 kg}
baseline: linear_quadratic
"""


def _write(tmp: Path, yaml_text: str, csv_text: str, name: str = "run.csv") -> Path:
    (tmp / name).write_text(csv_text)
    p = tmp / "trial.yaml"
    p.write_text(yaml_text)
    return p


def _csv(n: int = 30, t: list[float] | None = None, u: list[str] | None = None,
         header: str = "t_s,u_kn") -> str:
    t = t if t is not None else [0.1 * i for i in range(n)]
    u = u if u is not None else [f"{2.0 * math.exp(-0.1 * x):.6f}" for x in t]
    rows = "\n".join(f"{a},{b}" for a, b in zip(t, u, strict=True))
    return f"# synthetic coast-down, knots\n{header}\n{rows}\n"


def test_valid_trial_loads_in_si(tmp_path: Path) -> None:
    trial = load_trial(_write(tmp_path, STEP_YAML, _csv()))
    run = trial.runs[0]
    assert trial.kind == "decay" and trial.dof == "surge" and trial.baseline == "linear_quadratic"
    assert run.y[0] == pytest.approx(2.0 * 1852 / 3600)  # knots -> m/s
    assert trial.constants == {"mass": 50.0}
    assert trial.provenance == "synthetic coast-down, knots"  # from the CSV '#' header
    assert run.n == 30 and run.t is not None and np.all(np.diff(run.t) > 0)


@pytest.mark.parametrize(
    ("yaml_edit", "csv_text", "expected"),
    [
        (None, _csv(header="t_s,speed"), "column 'u_kn' (output) not found; the file has: t_s, speed"),
        (None, _csv(u=["1.0"] * 12 + ["nan"] + ["1.0"] * 17),
         "line 15: column 'u_kn' is nan (NaN/inf not allowed)"),
        (None, _csv(u=["1.0"] * 12 + ["abc"] + ["1.0"] * 17), "column 'u_kn' is not a number ('abc')"),
        (None, _csv(t=[0.1 * i for i in range(10)] + [0.85] + [0.1 * i for i in range(11, 30)]),
         "time column 't_s' goes backwards to 0.85 s"),
        (None, _csv(t=[0.1 * i for i in range(10)] + [0.9] + [0.1 * i for i in range(10, 29)]),
         "time column 't_s' repeats 0.9 s"),
        (None, _csv(n=8), "8 samples; a decay trial needs at least 20"),
        ({"columns": {"time": {"column": "t_s", "unit": "s"}, "output": {"column": "u_kn", "unit": "N"}}},
         _csv(), "columns.output.unit: 'N' is N, but the velocity of a surge decay trial needs m/s"),
        ({"columns": {"time": {"column": "t_s", "unit": "s"}, "output": {"column": "u_kn", "unit": "knots"}}},
         _csv(), "columns.output.unit: unknown unit 'knots'"),
        ({"columns": {"time": {"column": "t_s", "unit": "s"}}}, _csv(),
         "the velocity column ('output') is missing"),
        ({"colums": {}}, _csv(), "colums: unknown field"),
        ({"kind": "coastdown"}, _csv(), "kind: Input should be"),
        ({"constants": {"mas": 50}}, _csv(), "constants.mas: unknown constant"),
        ({"constants": {"mass": -5}}, _csv(), "constants.mass: must be a positive number"),
        ({"files": ["missing.csv"]}, _csv(), "files[0]: no such file"),
        ({"baseline": "cubic"}, _csv(),
         "baseline: 'cubic' is not one of linear, quadratic, linear_quadratic"),
        ({"dof": None}, _csv(), "dof: required for a decay trial"),
    ],
)
def test_bad_trial_gives_one_clear_line(tmp_path: Path, yaml_edit: dict | None, csv_text: str,
                                        expected: str) -> None:
    doc = yaml.safe_load(STEP_YAML)
    if yaml_edit:
        doc.update(yaml_edit)
        doc = {k: v for k, v in doc.items() if v is not None}
    path = _write(tmp_path, yaml.safe_dump(doc), csv_text)
    with pytest.raises(TrialError) as err:
        load_trial(path)
    msg = str(err.value)
    assert expected in msg, msg
    assert "\n" not in msg
    assert str(tmp_path) in msg  # names the file


def test_not_yaml_and_not_mapping(tmp_path: Path) -> None:
    p = tmp_path / "t.yaml"
    p.write_text("kind: [unclosed\n")
    with pytest.raises(TrialError, match="not valid YAML"):
        load_trial(p)
    p.write_text("- a list\n")
    with pytest.raises(TrialError, match="expected a mapping"):
        load_trial(p)


def test_static_table_type_from_unit_and_mirror(tmp_path: Path) -> None:
    rows = "\n".join(f"{60 * x},{12.63 * x}" for x in (0.5, 1, 1.5, 2))
    (tmp_path / "b.csv").write_text("n_rpm,T\n" + rows)
    (tmp_path / "b.yaml").write_text(yaml.safe_dump({
        "name": "bollard", "kind": "static", "dof": "surge", "files": ["b.csv"],
        "columns": {"input": {"column": "n_rpm", "unit": "rpm"}, "output": {"column": "T", "unit": "N"}}}))
    trial = load_trial(tmp_path / "b.yaml")
    assert trial.table == "thrust_rpm" and trial.baseline == "linear"
    assert trial.runs[0].u == pytest.approx([0.5, 1, 1.5, 2])  # rpm -> rev/s


def test_shipped_real_data_keep_their_provenance() -> None:
    for name in ("amv_osf_tow_resistance", "rov_cfd_force_speed", "pendulum_free_decay"):
        trial = load_trial(DATA / f"{name}.yaml")
        assert trial.provenance, name
        head = (DATA / f"{name}.csv").read_text().splitlines()[0]
        assert head.startswith("# ") and "Source" in (DATA / f"{name}.csv").read_text().split("\n\n")[0]


@pytest.mark.parametrize("effect", ["actuator_lag", "coupling", "nonlinear_restoring", "deadband"])
def test_write_trial_round_trip(tmp_path: Path, effect: str) -> None:
    """A trial written as CSV + YAML loads back to the same arrays (the format is complete)."""
    trial = demo_trial(effect, seed=0)
    back = load_trial(write_trial(trial, tmp_path))
    assert back.kind == trial.kind and back.dof == trial.dof and back.baseline == trial.baseline
    assert back.constants == pytest.approx(trial.constants)
    assert back.input_kind == trial.input_kind
    runs = [*back.runs, *back.validation_runs]
    assert len(runs) == len(trial.runs)
    for a, b in zip(trial.runs, runs, strict=True):
        np.testing.assert_allclose(b.y, a.y, rtol=1e-7, atol=1e-9)
        if a.u is not None:
            np.testing.assert_allclose(b.u, a.u, rtol=1e-7, atol=1e-9)


# -- CSV cells: every row as wide as the header, no '_' in numbers, no doubled column names ----------

def _pendulum(tmp: Path, edit: str = "", csv_edit=None) -> Path:  # type: ignore[no-untyped-def]
    """The shipped pendulum trial with its CSV beside it as data.csv; ``csv_edit`` maps the CSV's
    lines (line 17 is ``0.2,0.33,-0.39399,-0.63058``) and ``edit`` replaces in the YAML."""
    lines = (DATA / "pendulum_free_decay.csv").read_text().splitlines()
    assert lines[16] == "0.2,0.33,-0.39399,-0.63058"
    (tmp / "data.csv").write_text("\n".join(csv_edit(lines) if csv_edit else lines) + "\n")
    text = (DATA / "pendulum_free_decay.yaml").read_text().replace("[pendulum_free_decay.csv]", "[data.csv]")
    if edit:
        old, new = edit.split("=>")
        assert old in text
        text = text.replace(old, new)
    (tmp / "trial.yaml").write_text(text)
    return tmp / "trial.yaml"


def _line17(new: str):  # type: ignore[no-untyped-def]
    return lambda lines: [*lines[:16], new, *lines[17:]]


def test_the_unedited_pendulum_copy_loads(tmp_path: Path) -> None:
    trial = load_trial(_pendulum(tmp_path))
    assert trial.runs[0].y[5] == pytest.approx(0.33)


@pytest.mark.parametrize("row", ["0.2,0,33,-0.39399,-0.63058", "0.2,0.33,-0.39399,-0.63058,999"])
def test_a_row_wider_than_the_header_is_refused(tmp_path: Path, row: str) -> None:
    """A decimal comma or a stray value shifted the columns silently (alpha -19.97 became +19.66)."""
    with pytest.raises(TrialError) as err:
        load_trial(_pendulum(tmp_path, csv_edit=_line17(row)))
    assert str(err.value) == f"{tmp_path / 'data.csv'}: line 17 has 5 fields, the header has 4"


def test_a_row_narrower_than_the_header_and_a_wide_first_row_are_refused(tmp_path: Path) -> None:
    with pytest.raises(TrialError, match=r"data\.csv: line 17 has 3 fields, the header has 4$"):
        load_trial(_pendulum(tmp_path, csv_edit=_line17("0.2,0.33,-0.39399")))

    def first(lines: list[str]) -> list[str]:  # the first data row, line 12
        return [*lines[:11], lines[11] + ",1", *lines[12:]]

    with pytest.raises(TrialError, match=r"data\.csv: line 12 has 5 fields, the header has 4$"):
        load_trial(_pendulum(tmp_path, csv_edit=first))


def test_a_static_table_row_with_a_stray_field_is_refused(tmp_path: Path) -> None:
    rows = [f"{60 * x},{12.63 * x}" for x in (0.5, 1, 1.5, 2)]
    (tmp_path / "b.yaml").write_text(yaml.safe_dump({
        "name": "bollard", "kind": "static", "dof": "surge", "files": ["b.csv"],
        "columns": {"input": {"column": "n_rpm", "unit": "rpm"}, "output": {"column": "T", "unit": "N"}}}))
    (tmp_path / "b.csv").write_text("n_rpm,T\n" + "\n".join(rows) + "\n")
    assert load_trial(tmp_path / "b.yaml").runs[0].n == 4
    rows[2] = "90,18,945"  # 18.945 N with a decimal comma
    (tmp_path / "b.csv").write_text("n_rpm,T\n" + "\n".join(rows) + "\n")
    with pytest.raises(TrialError, match=r"b\.csv: line 4 has 3 fields, the header has 2$"):
        load_trial(tmp_path / "b.yaml")


@pytest.mark.parametrize("cell", ["0_33", "3_3e-1"])
def test_underscores_in_a_number_are_refused(tmp_path: Path, cell: str) -> None:
    """float() reads '0_33' as 33 and '3_3e-1' as 3.3: a typo, not a measurement."""
    with pytest.raises(TrialError) as err:
        load_trial(_pendulum(tmp_path, csv_edit=_line17(f"0.2,{cell},-0.39399,-0.63058")))
    assert str(err.value) == (f"{tmp_path / 'data.csv'}: line 17: column 'theta_rad' is not a number "
                              f"('{cell}')")


def test_a_column_named_twice_is_refused_when_the_trial_reads_it(tmp_path: Path) -> None:
    def twice(name: str):  # type: ignore[no-untyped-def]
        return lambda lines: [*lines[:10], lines[10] + f",{name}",
                              *(ln + ",0.5" for ln in lines[11:] if ln)]

    with pytest.raises(TrialError) as err:
        load_trial(_pendulum(tmp_path, csv_edit=twice("theta_rad")))
    assert str(err.value) == f"{tmp_path / 'data.csv'}: column 'theta_rad' appears twice in the header"
    load_trial(_pendulum(tmp_path, csv_edit=lambda lines: twice("note")(twice("note")(lines))))


def test_an_overflowing_fit_names_the_trial_file_and_the_output_unit(tmp_path: Path) -> None:
    """The angle logged in rad but declared deg: the message names the file, the column and its
    unit, and gives the range in that unit (0.39 deg for a swing of 22 deg)."""
    from seafmu.identification.diagnosis import identify

    path = _pendulum(tmp_path, edit="{column: theta_rad, unit: rad}=>{column: theta_rad, unit: deg}")
    with pytest.raises(TrialError) as err:
        identify(load_trial(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}: columns.output (theta_rad, unit deg): the output-error fit "
                          "overflowed"), msg
    assert "theta_rad runs from 0.14 to 0.39 deg" in msg and "check the unit" in msg and "\n" not in msg


def test_a_bare_csv_is_named_after_its_run_folder_or_itself(tmp_path: Path) -> None:
    """results/minerva2_dp/results.csv is the minerva2_dp trial; logs/a.csv and logs/b.csv are a and
    b, so their reports do not share (and overwrite) one default folder results/logs."""
    from seafmu.identification.trial import csv_trial

    for rel in ("minerva2_dp/results.csv", "logs/a.csv", "logs/b.csv"):
        (tmp_path / rel).parent.mkdir(exist_ok=True)
        (tmp_path / rel).write_text("time,plant.u\n0,0\n")
    names = [csv_trial(tmp_path / rel, "amv_osf").name for rel in
             ("minerva2_dp/results.csv", "logs/a.csv", "logs/b.csv")]
    assert names == ["minerva2_dp", "a", "b"]

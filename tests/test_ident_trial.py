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

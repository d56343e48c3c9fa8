"""Every shipped scenario runs end to end and passes its own checks, each scenario once.

One scenario per vessel runs through its four FMUs (minerva2_dp by the default-run test below,
amv_osf_autopilot and supply_dp here); the others run in-process, because FMU and in-process runs
of the same scenario are held equal to 1e-9 (``tests/test_fmus.py``), so running them through
the FMUs again would test the FMI layer thirteen more times and the scenario no better.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seafmu.cli import main
from seafmu.master import run
from seafmu.results import evaluate_checks
from seafmu.scenario import SCENARIO_DIR, load_scenario

SHIPPED = sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))
DEFAULT = "minerva2_dp"  # its checks: test_default_run_writes_results_report_and_plots (FMUs)
THROUGH_FMUS = {"amv_osf_autopilot", "supply_dp"}  # with the default: one scenario per vessel


def test_the_issue_scenarios_are_shipped() -> None:
    assert {"minerva2_dp", "amv_osf_autopilot", "amv_osf_autopilot_current"} <= set(SHIPPED)


def test_one_scenario_per_vessel_runs_through_the_fmus() -> None:
    vessels = {load_scenario(n).vessel for n in SHIPPED}
    assert {load_scenario(n).vessel for n in THROUGH_FMUS | {DEFAULT}} == vessels


@pytest.mark.parametrize("name", [n for n in SHIPPED if n != DEFAULT])
def test_shipped_scenario_passes_its_checks(built_fmus: dict, name: str) -> None:
    sc = load_scenario(name)
    assert len(sc.checks) >= 3, "a shipped scenario is an acceptance test: it needs checks"
    result = run(sc, mode="fmu" if name in THROUGH_FMUS else "inprocess", progress=False)
    checks = evaluate_checks(result)
    failed = [f"{c.name}: {c.value:.4g} ({c.bound})" for c in checks if not c.passed]
    assert not failed, failed
    assert result.log == []  # no FMU reported an error or discarded a step
    assert all(np.all(np.isfinite(v)) for v in result.signals.values())


def test_a_check_that_does_not_hold_fails_the_run(built_fmus: dict, tmp_path: Path) -> None:
    """Checks can fail: tighten one bound of the default scenario and the CLI exits with 1."""
    text = (SCENARIO_DIR / "amv_osf_autopilot.yaml").read_text()
    text = text.replace("metric: max, after: 50, max: 1.1}", "metric: max, after: 50, max: 1.0}")
    path = tmp_path / "tight.yaml"
    path.write_text(text)
    assert main(["run", str(path), "-q", "-o", str(tmp_path / "out")]) == 1
    assert (tmp_path / "out" / "report.md").is_file()


def test_default_run_writes_results_report_and_plots(built_fmus: dict, tmp_path: Path) -> None:
    out = tmp_path / "default"
    assert main(["run", "-q", "-o", str(out)]) == 0  # no scenario given: the default, minerva2_dp
    for f in ("results.csv", "summary.json", "report.md", "trajectory.png", "states.png", "thrusters.png"):
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "time" and "plant.north" in header and "controller.north_ref" in header
    report = (out / "report.md").read_text()
    assert "real-time factor" in report and "PASS" in report and "FAIL" not in report
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scenario"] == DEFAULT and len(summary["checks"]) >= 3
    assert all(c["passed"] for c in summary["checks"])


def test_an_output_folder_that_is_a_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """An OSError reads as every other error: '<file>: <what is wrong>', not '[Errno 17] ...'."""
    taken = tmp_path / "taken"
    taken.write_text("not a folder")
    assert main(["run", "minerva2_dp", "-q", "-o", str(taken)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"seafmu: error: {taken}: file exists", err

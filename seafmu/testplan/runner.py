"""The plan end to end: design, run, measure, identify, write the vessel file and the report."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.identification.trial import write_trial
from seafmu.identification.writeback import write_back
from seafmu.outdir import claim_output_folder
from seafmu.scenario import ScenarioError
from seafmu.testplan.design import TrialPlan, plan
from seafmu.testplan.fit import AxisResult, coefficient_names, coupled_terms, identify_axis
from seafmu.testplan.measure import Measurement, TestplanError, run_trial

__all__ = ["TestplanError", "TestplanResult", "identify_measurements", "run_testplan"]


@dataclass
class TestplanResult:
    vessel: VesselSpec
    plans: list[TrialPlan]
    measurements: dict[str, Measurement]
    results: dict[str, AxisResult]
    identified: dict[str, dict[str, Any]] = field(default_factory=dict)  # key -> value, truth, ...
    vessel_file: Path | None = None
    not_written: str = ""  # why no vessel file was written (non-physical coefficients)
    trial_files: list[Path] = field(default_factory=list)
    wall: float = 0.0
    mode: str = "inprocess"
    hardware: str | None = None
    scale: float = 1.0


def identify_measurements(vessel: VesselSpec, measurements: dict[str, Measurement]) -> dict[str, AxisResult]:
    """Fit every trial, then the coupled terms."""
    results = {name: identify_axis(m, vessel) for name, m in measurements.items()}
    coupled_terms(results, measurements, vessel)
    return results


def identified_table(vessel: VesselSpec, results: dict[str, AxisResult]) -> dict[str, dict[str, Any]]:
    """Every identified term: write-back key, value, 95 % CI, the file's value, the trial."""
    out: dict[str, dict[str, Any]] = {}
    for r in results.values():
        j = r.plan.index
        names = coefficient_names(r.plan.axis)
        f = r.fits["record"]
        for p in ("d_L", "d_Q"):
            if p not in f.params:
                continue
            field_ = "linear_damping" if p == "d_L" else "quadratic_damping"
            true = float((vessel.D_L if p == "d_L" else vessel.D_Q)[j, j])
            out[names[p]] = {"key": f"{field_}[{j}][{j}]", "value": float(f.params[p]),
                             "ci95": [float(x) for x in f.ci95[p]], "file": true, "trial": r.plan.name,
                             "axis": r.plan.axis, "kind": "diagonal"}
    nu = vessel.nu_names
    pairs = {("N", "v"): "N_v", ("Y", "r"): "Y_r"}
    for r in results.values():
        j = r.plan.index
        for tau, (dkj, _, _) in r.coupled.items():
            name = pairs.get((tau, nu[j]))
            if name is None:
                continue
            k = vessel.tau_names.index(tau)
            ci = r.coupled_ci.get(tau)
            out[name] = {"key": f"linear_damping[{k}][{j}]", "value": float(dkj),
                         "ci95": [float(x) for x in ci] if ci is not None else None,
                         "file": float(vessel.D_L[k, j]), "trial": r.plan.name, "axis": r.plan.axis,
                         "kind": "coupled"}
    return out


def write_outputs(res: TestplanResult, out: Path) -> None:
    """Trial files (for ``seafmu identify``) and the vessel file with the identified damping."""
    trials_dir = out / "trials"
    for name, r in res.results.items():
        for key, tr in r.trials.items():
            if key == "record":
                continue
            folder = trials_dir / f"{name}_{key}" if r.plan.kind == "method_one" else trials_dir / name
            tr.vessel = res.vessel.name
            res.trial_files.append(write_trial(tr, folder))
        if r.plan.kind == "release":
            res.trial_files.append(write_trial(r.trials["record"], trials_dir / name))
    updates: dict[str, float] = {}
    prov: dict[str, str] = {"method": "seafmu testplan (AAUSHIP method one/two; docs/testplan.md)",
                            "note": f"run against {res.hardware or 'the plant (' + res.mode + ')'}"}
    trials = []
    for name, row in res.identified.items():
        updates[row["key"]] = row["value"]
        ci = f", 95 % CI [{row['ci95'][0]:.6g}, {row['ci95'][1]:.6g}]" if row["ci95"] else ""
        prov[row["key"]] = f"{name}, identified by seafmu testplan from trial {row['trial']}{ci}"
        trials.append(row["trial"])
    prov["trial"] = ", ".join(dict.fromkeys(trials))
    bad = _gaining_energy(res)
    target = out / f"{res.vessel.name}_identified.yaml"
    if bad:
        target.unlink(missing_ok=True)  # not an earlier run's file taken for this one's
        res.not_written = (f"not written: non-physical damping ({', '.join(bad)}); the trials are too short "
                           "or too noisy to identify it (a larger --scale, more trials)")
        return
    res.vessel_file = write_back(res.vessel.name, updates, target, prov)


def _gaining_energy(res: TestplanResult) -> list[str]:
    """The identified diagonal damping of the axes that would gain energy from the water at speed:
    a quadratic term below zero, or a linear one below zero with no positive quadratic term to
    outweigh it (a small negative linear term beside a quadratic one is a fit's usual trade and
    dissipates above a crawl: Minerva 2's yaw over the ptys, N_r = -9 beside N_|r|r = 961). Such a
    file makes every later run diverge (supply at --scale 0.03: N_r = -3.4e9, no quadratic term)."""
    by_key = {row["key"]: (name, row["value"]) for name, row in res.identified.items()
              if row["kind"] == "diagonal"}
    bad = []
    for j in range(len(res.vessel.nu_names)):
        lin = by_key.get(f"linear_damping[{j}][{j}]")
        quad = by_key.get(f"quadratic_damping[{j}][{j}]")
        d_l = lin[1] if lin else float(res.vessel.D_L[j, j])
        d_q = quad[1] if quad else float(res.vessel.D_Q[j, j])
        if quad and not d_q >= 0.0:
            bad.append(f"{quad[0]} = {d_q:.4g}")
        elif lin and not d_l >= 0.0 and not d_q > 0.0:
            bad.append(f"{lin[0]} = {d_l:.4g}")
    return bad


def select_axes(plans: list[TrialPlan], axes: list[str] | None, hardware: str | None,
                vessel: str) -> list[TrialPlan]:
    """The trials asked for (``--axes``; default all). Against hardware a roll/pitch release
    cannot start from an angle (nothing tilts a real vessel to 10 deg and lets go), so the default
    there is the method-one axes and asking for a release is an error."""
    have = [p.axis for p in plans]
    if axes is None:
        return [p for p in plans if hardware is None or p.kind == "method_one"]
    for a in axes:
        if a not in have:
            raise TestplanError(f"--axes: '{a}' is not a trial of vessel '{vessel}' (its trials: "
                                f"{', '.join(have)})")
        if hardware is not None and plans[have.index(a)].kind == "release":
            raise TestplanError(f"--axes: '{a}' is a release from an angle, which the plan sets as the "
                                "plant's initial state; with --hardware choose among "
                                + ", ".join(p.axis for p in plans if p.kind == "method_one"))
    return [p for p in plans if p.axis in axes]


def run_testplan(vessel_name: str, out: Path, hardware: str | None = None, mode: str = "inprocess",
                 seed: int = 1, scale: float = 1.0, report: bool = True,
                 axes: list[str] | None = None) -> TestplanResult:
    """The whole plan: design, run, measure, identify, write trials, vessel file and report.

    ``scale`` multiplies the phase durations (a shorter plan: CI, a first look on hardware);
    ``axes`` picks trials by axis (surge, sway, yaw, roll, pitch)."""
    t0 = time.perf_counter()
    vessel = load_vessel(vessel_name)
    ctrl = vessel.gnc.controller if vessel.gnc is not None else None
    if ctrl != "dp_pid":
        raise TestplanError(f"vessel '{vessel.name}': its controller is '{ctrl}'; the trials' axis_trial "
                            "controller has dp_pid's interface, so the plan runs on dp_pid vessels only")
    if not (0.0 < scale <= 10.0) or not np.isfinite(scale):
        raise TestplanError(f"--scale: must be in (0, 10], got {scale:g}")
    plans = select_axes(plan(vessel, scale), axes, hardware, vessel.name)
    if not plans:
        raise TestplanError(f"vessel '{vessel.name}': no axis the test plan can excite")
    claim_output_folder(out)  # not a folder of the user's own files; marked as seafmu's before the trials
    measurements = {}
    # a plan shortened too far: phases that end before their events, trials with no sample to fit
    short = f"--scale {scale:g} leaves the trials too short"
    for tp in plans:
        try:
            measurements[tp.name] = run_trial(tp, vessel, out / "scenarios", hardware, mode, seed)
        except ScenarioError as exc:
            if scale >= 1.0:
                raise
            why = " ".join(str(exc).split())
            raise TestplanError(f"{short} ({tp.name}: {why}); use a larger one") from None
    try:
        results = identify_measurements(vessel, measurements)
    except (IndexError, ValueError, ZeroDivisionError, np.linalg.LinAlgError) as exc:
        what = f"{short} to identify" if scale < 1.0 else "the trials could not be identified"
        raise TestplanError(f"{what} ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    res = TestplanResult(vessel, plans, measurements, results, mode=mode, hardware=hardware, scale=scale)
    res.identified = identified_table(vessel, results)
    write_outputs(res, out)
    res.wall = time.perf_counter() - t0
    if report:
        from seafmu.testplan.report import write_report

        write_report(res, out)
    return res


def relative_error(row: dict[str, Any]) -> float:
    """|identified - file| / |file| (inf where the file's value is 0 and the identified is not)."""
    if row["file"] == 0.0:
        return 0.0 if row["value"] == 0.0 else float(np.inf)
    return abs(row["value"] - row["file"]) / abs(row["file"])

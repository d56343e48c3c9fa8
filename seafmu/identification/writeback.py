"""Write identified parameters back into a vessel file, with provenance, so the plant uses them.

A vessel file is the project's record of where every number came from (``{value, source}``), so
an identified value must arrive with its own source: trial, date, method and confidence interval,
followed by the field's earlier provenance for the entries that did not change.

The file is edited as text, one top-level field block at a time: every other line — comments,
layout, the other fields — is copied unchanged (ruamel is not a dependency; a PyYAML round trip
would drop the comments). A header comment records the origin. The result is validated with
``load_vessel``, and the values read back must equal the ones written, or nothing is left behind.
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seafmu.components.vessel_spec import VesselFileError, VesselSpec, load_vessel, vessel_path
from seafmu.identification.effects.coupling import sway_yaw_entries
from seafmu.identification.fitting import DIVERGED, FitResult
from seafmu.identification.trial import DOF_INDEX, Trial

# Model-matrix names (fits, the brief) -> vessel-file fields.
FIELD_ALIASES = {
    "D_L": "linear_damping",
    "D_Q": "quadratic_damping",
    "M_A": "added_mass",
    "M_RB": "mass_matrix",
}
MATRIX_FIELDS = ("mass_matrix", "added_mass", "linear_damping", "quadratic_damping")
_KEY = re.compile(r"^(?P<field>[A-Za-z_][A-Za-z0-9_]*)(?P<idx>(\[\s*\d+\s*(,\s*\d+\s*)?\])*)$")
_TOP_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*\s*:")


def _parse_key(key: str) -> tuple[str, tuple[int, ...]]:
    """'quadratic_damping[0][0]', 'D_Q[0,0]', 'added_mass[2]' (diagonal), 'linear_damping'."""
    m = _KEY.match(key.strip())
    if not m:
        raise VesselFileError(
            f"write_back: cannot read the field name '{key}' (e.g. 'quadratic_damping[0][0]')"
        )
    field = FIELD_ALIASES.get(m.group("field"), m.group("field"))
    idx = tuple(int(x) for x in re.findall(r"\d+", m.group("idx")))
    if len(idx) > 2:
        raise VesselFileError(f"write_back: '{key}': at most two indices")
    return field, idx


def _fmt(v: float) -> str:
    """A float that YAML 1.1 (PyYAML) reads back as a float: '1.0e-05', not '1e-05'."""
    v = float(v)
    if not np.isfinite(v):
        raise VesselFileError(f"write_back: value {v} is not finite")
    s = f"{v:.10g}"
    mant, _, exp = s.partition("e")
    if "." not in mant:
        mant += ".0"
    if exp:
        sign = exp[0] if exp[0] in "+-" else "+"
        return f"{mant}e{sign}{exp.lstrip('+-')}"
    return mant


def _matrix(value: Any, d: int, where: str) -> tuple[np.ndarray, bool]:
    """(full d x d matrix, stored as a diagonal list?) of a matrix field's value."""
    arr = np.array(value, dtype=float)
    if arr.shape == (d,):
        return np.diag(arr), True
    if arr.shape == (d, d):
        return arr, False
    raise VesselFileError(
        f"write_back: {where}: expected {d} numbers or a {d} x {d} matrix, got shape {arr.shape}"
    )


def _block(field: str, value_lines: list[str], source: str, other: dict[str, Any]) -> list[str]:
    out = [f"{field}:", *value_lines]
    for k, v in other.items():  # any extra keys of the node are kept (flow style)
        out.append(f"  {k}: {yaml.safe_dump(v, default_flow_style=True, width=10**6).strip()}")
    wrapped = textwrap.wrap(" ".join(source.split()), width=96, break_on_hyphens=False) or [""]
    out += ["  source: >-", *(f"    {ln}" for ln in wrapped)]
    return out


def _value_lines(mat: np.ndarray, diagonal: bool) -> list[str]:
    if diagonal:
        return [f"  value: [{', '.join(_fmt(x) for x in np.diag(mat))}]"]
    return ["  value:", *(f"    - [{', '.join(_fmt(x) for x in row)}]" for row in mat)]


def _find_block(lines: list[str], field: str) -> tuple[int, int] | None:
    """[start, end) of a top-level field's block; trailing blank lines and column-0 comments
    belong to whatever follows."""
    start = next((i for i, ln in enumerate(lines) if re.match(rf"^{re.escape(field)}\s*:", ln)), None)
    if start is None:
        return None
    nxt = next((j for j in range(start + 1, len(lines)) if _TOP_KEY.match(lines[j])), len(lines))
    end = nxt
    while end > start + 1 and (not lines[end - 1].strip() or lines[end - 1].startswith("#")):
        end -= 1
    return start, end


def write_back(vessel: str | Path, updates: dict[str, float | list], out_path: Path,
               provenance: dict[str, str]) -> Path:
    """Copy a vessel file to ``out_path`` with the named fields replaced; returns the path.

    ``updates``: ``{"quadratic_damping[0][0]": 813.1, "linear_damping": [0, 0, 1, 0, 0, 0],
    "added_mass[2][2]": 7000.0, "D_Q[1,1]": ...}`` — one entry of a matrix (a single index means
    the diagonal entry), or a whole field as a diagonal list or a full matrix. A field stored as a
    diagonal list stays one unless an off-diagonal entry becomes non-zero.
    ``provenance``: ``trial``, ``method``, ``date`` (default today), ``note``, and per update
    key a CI text (``{"quadratic_damping[0][0]": "95 % CI [805, 821]"}``); each changed field's
    ``source`` becomes "identified ...: <entries with CIs>; <trial, method, date>; earlier: <old>".
    """
    # Over 80 lines: parse keys, edit each field block as text, add provenance, write atomically and
    # read back: one transaction; it is split into helpers where the steps do not share state
    # (_parse_key, _matrix, _block, _find_block, _check).
    src = vessel_path(vessel)
    original = load_vessel(src)  # the input must be valid to begin with
    text = src.read_text()
    doc = yaml.safe_load(text)
    d = original.dof
    out_path = Path(out_path)

    grouped: dict[str, list[tuple[str, tuple[int, ...], Any]]] = {}
    for key, val in updates.items():
        field, idx = _parse_key(key)
        node = doc.get(field)
        if not isinstance(node, dict) or "value" not in node:
            known = ", ".join(f for f in doc if isinstance(doc[f], dict) and "value" in doc[f])
            raise VesselFileError(f"write_back: '{key}': {src} has no top-level field '{field}' with a "
                                  f"value (fields: {known})")
        grouped.setdefault(field, []).append((key, idx, val))

    date = provenance.get("date") or _dt.date.today().isoformat()
    context = "; ".join(
        f"{k} {provenance[k]}" for k in ("trial", "method") if provenance.get(k)
    )
    context = f"{context}; date {date}" if context else f"date {date}"
    if provenance.get("note"):
        context += f"; {provenance['note']}"

    lines = text.splitlines()
    expected: dict[str, np.ndarray] = {}
    new_sources: dict[str, str] = {}
    for field, items in grouped.items():
        node = doc[field]
        old_source = " ".join(str(node.get("source", "")).split())
        if field in MATRIX_FIELDS:
            mat, diagonal = _matrix(node["value"], d, f"{src}: {field}")
            changed = []
            for key, idx, val in items:
                if not idx:
                    mat, diagonal = _matrix(val, d, f"update '{key}'")
                    mat = mat.copy()
                    what = "all entries"
                else:
                    i, j = (idx[0], idx[0]) if len(idx) == 1 else idx
                    if not (0 <= i < d and 0 <= j < d):
                        raise VesselFileError(
                            f"write_back: '{key}': index out of range for a {d} x {d} matrix"
                        )
                    mat = mat.copy()
                    mat[i, j] = float(val)  # type: ignore[arg-type]
                    if i != j and float(val) != 0.0:  # type: ignore[arg-type]
                        diagonal = False
                    what = f"[{i}][{j}] = {float(val):.6g}"  # type: ignore[arg-type]
                ci = provenance.get(key)
                changed.append(f"{what} ({ci})" if ci else what)
            value_lines = _value_lines(mat, diagonal)
            expected[field] = mat
        else:
            if len(items) != 1 or items[0][1]:
                raise VesselFileError(
                    f"write_back: '{field}' is not a matrix field: give the whole value once"
                )
            key, _, val = items[0]
            arr = np.asarray(val, dtype=float)
            flow = _fmt(float(arr)) if arr.ndim == 0 else f"[{', '.join(_fmt(x) for x in arr.ravel())}]"
            value_lines = [f"  value: {flow}"]
            ci = provenance.get(key)
            changed = [f"{flow}" + (f" ({ci})" if ci else "")]
            expected[field] = arr
        source = f"identified: {'; '.join(changed)}; {context}"
        if old_source:
            source += f"; earlier source: {old_source}"
        new_sources[field] = " ".join(source.split())
        other = {k: v for k, v in node.items() if k not in ("value", "source")}
        block = _block(field, value_lines, source, other)
        where = _find_block(lines, field)
        if where is None:  # pragma: no cover - yaml found it, so a column-0 key line exists
            raise VesselFileError(f"write_back: cannot locate field '{field}' in {src}")
        lines[where[0] : where[1]] = block

    header = [
        f"# Written by seafmu write_back on {date} from {src}:",
        f"# {', '.join(grouped) or 'no field'}: identified values (each field's source says how);",
        "# everything else is copied unchanged from that file.",
    ]
    if not out_path.parent.is_dir():  # never creates folders (a typo must not build a tree)
        raise VesselFileError(f"write_back: {out_path}: the folder {out_path.parent} does not exist "
                              "(it is not created)")
    # validate a temporary copy first, so a bad result never replaces anything (out_path may
    # even be the input file)
    tmp = out_path.with_name(f".{out_path.stem}.writeback-tmp.yaml")
    tmp.write_text("\n".join(header + lines) + "\n")
    try:
        spec = load_vessel(tmp)
        _check(spec, expected, new_sources, d)
    except VesselFileError as exc:
        tmp.unlink(missing_ok=True)
        raise VesselFileError(
            f"write_back: the written file did not validate ({exc}); nothing written"
        ) from None
    os.replace(tmp, out_path)
    return out_path


def _check(spec: VesselSpec, expected: dict[str, np.ndarray], sources: dict[str, str], d: int) -> None:
    attr = {"mass_matrix": "M_RB", "added_mass": "M_A", "linear_damping": "D_L", "quadratic_damping": "D_Q"}
    for field, val in expected.items():
        got = getattr(spec, attr[field]) if field in attr else None
        if got is not None and not np.allclose(got, val, rtol=1e-9, atol=0.0):
            raise VesselFileError(f"{field} reads back as {got.tolist()}, wrote {val.tolist()}")
        src = " ".join(spec.provenance.get(field, "").split())
        if src != sources[field]:
            raise VesselFileError(f"{field}: source reads back differently")


def updates_from_fit(fit: FitResult, vessel: VesselSpec, entries: str = "diagonal",
                     trial: str | None = None) -> tuple[dict[str, float], dict[str, str]]:
    """(updates, provenance) for ``write_back`` from a maneuver fit.

    Fit names map to fields: ``D_L[i,j]`` -> linear_damping, ``D_Q[i,j]`` -> quadratic_damping,
    ``M[i,j]`` (total inertia) -> added_mass = M − M_RB (the vessel file's rigid body is kept).
    ``entries="diagonal"`` writes diagonal entries only (the thesis's off-diagonal estimates
    were unreliable; output error fits only diagonals), ``"all"`` every fitted entry. A fit that
    estimated a symmetric M (upper triangle only) writes both mirror entries.
    """
    if entries not in ("diagonal", "all"):
        raise ValueError(f"entries must be 'diagonal' or 'all', got {entries!r}")
    if any(DIVERGED in w for w in fit.warnings):  # a vessel file from it would make every later run diverge
        raise ValueError(f"{DIVERGED}: no vessel-file values from it (a log that excites every DOF, or "
                         "the output-error method: docs/maneuver_identification.md)")
    updates: dict[str, float] = {}
    prov: dict[str, str] = {"method": fit.method}
    if trial or fit.extras.get("source"):
        prov["trial"] = str(trial or fit.extras.get("source"))
    names = set(fit.param_names)
    for name in fit.param_names:
        m = re.match(r"^(M|D_L|D_Q)\[(\d+),(\d+)\]$", name)
        if not m:
            continue
        kind, i, j = m.group(1), int(m.group(2)), int(m.group(3))
        if entries == "diagonal" and i != j:
            continue
        lo, hi = fit.ci95.get(name, (float("nan"), float("nan")))
        val = fit.params[name]
        field = FIELD_ALIASES["M_A" if kind == "M" else kind]
        pairs = [(i, j)]
        if kind == "M" and i != j and f"M[{j},{i}]" not in names:
            pairs.append((j, i))
        for a, b in pairs:
            shift = vessel.M_RB[a, b] if kind == "M" else 0.0
            key = f"{field}[{a}][{b}]"
            updates[key] = val - shift
            prov[key] = f"95 % CI [{lo - shift:.6g}, {hi - shift:.6g}]"
    _extension_entries(fit, vessel, updates, prov)
    return updates, prov


def _extension_entries(fit: FitResult, vessel: VesselSpec, updates: dict[str, float],
                       prov: dict[str, str]) -> None:
    """A maneuver extension's fitted corrections beyond the vessel file's as the file's entries,
    written whatever ``entries`` says (the extension fits exactly these entries, unlike an LS
    off-diagonal): a sway-yaw coupling (``effects.coupling``) enters D_L/D_Q with the sign changed
    (D = -[derivatives]: the file's minus the derivative, its CI mirrored), an added-mass correction
    (``effects.added_mass``: m_a[X], ...) is added to the file's M_A diagonal (its CI shifted)."""
    from seafmu.components.vessel_spec import TAU_NAMES

    entries = [(param, matrix, a, b, -1.0) for param, matrix, a, b in sway_yaw_entries(vessel.dof)]
    entries += [(f"m_a[{axis}]", "M_A", i, i, 1.0) for i, axis in enumerate(TAU_NAMES[vessel.dof])]
    for param, matrix, a, b, sign in entries:
        if param not in fit.params:
            continue
        now = float(np.asarray(getattr(vessel, matrix))[a, b])
        lo, hi = sorted(now + sign * x for x in fit.ci95.get(param, (float("nan"), float("nan"))))
        key = f"{FIELD_ALIASES[matrix]}[{a}][{b}]"
        updates[key] = now + sign * fit.params[param]
        prov[key] = f"95 % CI [{lo:.6g}, {hi:.6g}]"


def _clamp_negative_damping(updates: dict[str, float]) -> list[str]:
    """Negative diagonal damping (energy injected along that DOF) written as 0, as for 1-2-DOF
    trials; the notes say which. Off-diagonal couplings may be negative."""
    notes: list[str] = []
    for key, val in updates.items():
        m = re.match(r"^(linear_damping|quadratic_damping)\[(\d+)\]\[(\d+)\]$", key)
        if m and m.group(2) == m.group(3):
            updates[key] = _nonnegative(key, val, notes)
    return notes


def _nonnegative(name: str, val: float, notes: list[str]) -> float:
    """A damping that would inject energy is written as 0, with a note saying so."""
    if val < 0:
        notes.append(f"fitted {name} = {val:.4g} < 0 is unphysical: written as 0")
        return 0.0
    return val


# -- writing back into a vessel file --------------------------------------------------------------

def vessel_updates(trial: Trial, fit: FitResult, vessel_dof: int) -> tuple[dict[str, float], dict[str, str],
                                                                           list[str]]:
    """Vessel-file field paths and values from a fit, the fit parameter behind each, and notes."""
    notes: list[str] = []
    idx_map = DOF_INDEX[vessel_dof]
    p = dict(fit.params)
    up: dict[str, float] = {}
    origin: dict[str, str] = {}
    if trial.dof == "sway_yaw":
        i, j = idx_map["sway"], idx_map["yaw"]
        for key, (a, b) in {"Y_v": (i, i), "Y_r": (i, j), "N_v": (j, i), "N_r": (j, j)}.items():
            if key in p:
                up[f"linear_damping[{a}][{b}]"] = -p[key]
                origin[f"linear_damping[{a}][{b}]"] = f"-{key}"
        return up, origin, notes
    if trial.dof not in idx_map:
        return {}, {}, [f"the vessel has no {trial.dof} DOF"]
    i = idx_map[trial.dof]
    physical = trial.kind == "static" or "mass" in trial.constants
    if trial.kind == "pendulum":
        d = fit.extras.get("derived", {})
        if "K_L" in d and "K_Q" in d:
            p = {"d_L": d["K_L"], "d_Q": d["K_Q"]}
        else:
            return {}, {}, ["pendulum alpha, beta, gamma need weight, buoyancy and rod length to become "
                            "K_L, K_Q"]
    elif not physical:
        return {}, {}, ["no 'mass' constant: the parameters are per unit inertia and cannot go into a "
                        "vessel file"]
    if trial.kind == "static" and trial.table == "thrust_rpm":
        return {}, {}, ["thrust coefficients are per thruster: edit thrusters.units[*].k_forward by hand"]
    for key, field_name in (("d_L", "linear_damping"), ("d_Q", "quadratic_damping")):
        if key in p:
            up[f"{field_name}[{i}][{i}]"] = _nonnegative(key, p[key], notes)
            origin[f"{field_name}[{i}][{i}]"] = key
    if "m_a" in p:
        up[f"added_mass[{i}][{i}]"] = trial.constants.get("added_mass", 0.0) + p["m_a"]
        origin[f"added_mass[{i}][{i}]"] = "m_a"
    rest = [k for k in p if k not in ("d_L", "d_Q", "m_a", "k", "c")]
    if rest:
        notes.append(f"not written (no vessel-file field): {', '.join(rest)}")
    return up, origin, notes


def write_vessel(trial: Trial, fit: FitResult, out_path: Path, method: str, vessel: str | None = None) -> str:
    """Write identified values into a copy of the trial's vessel file; returns a one-line message."""
    return write_vessel_file(trial, fit, out_path, method, vessel)[0]


def write_vessel_file(trial: Trial, fit: FitResult, out_path: Path, method: str,
                      vessel: str | None = None) -> tuple[str, Path | None]:
    """As write_vessel, plus the written path (None if nothing was written), for the replay."""
    name = vessel or trial.vessel
    if not name:
        return "write-back skipped: the trial names no vessel (trial 'vessel' or --vessel)", None

    spec = load_vessel(name)
    if trial.kind == "maneuver":  # the maneuver module knows its own parameter names
        try:
            updates, mprov = updates_from_fit(fit, spec, trial=trial.name)
        except ValueError as exc:
            return f"write-back refused: {exc}; no vessel file written", None
        if not updates:
            return "write-back skipped: the maneuver fit has no vessel-file parameters", None
        notes = _clamp_negative_damping(updates)
        mprov = {**mprov, "date": _dt.date.today().isoformat(), "method": method}
        if notes:
            mprov["note"] = "; ".join(notes)
        path = write_back(name, updates, out_path, mprov)
        extra = f" ({'; '.join(notes)})" if notes else ""
        return f"wrote {len(updates)} entries ({', '.join(sorted(updates)[:6])}, ...) to {path}{extra}", path
    updates, origin, notes = vessel_updates(trial, fit, spec.dof)
    if not updates:
        return "write-back skipped: " + "; ".join(notes or ["nothing to write"]), None
    prov = {"trial": trial.name, "date": _dt.date.today().isoformat(), "method": method}
    if notes:
        prov["note"] = "; ".join(notes)
    for key, par in origin.items():
        bare = par.lstrip("-")
        if bare in fit.ci95:
            lo, hi = fit.ci95[bare]
            lo, hi = (-hi, -lo) if par.startswith("-") else (lo, hi)
            prov[key] = f"95 % CI [{lo:.4g}, {hi:.4g}]"
    path = write_back(name, updates, out_path, prov)
    extra = f" ({'; '.join(notes)})" if notes else ""
    return f"wrote {', '.join(f'{k} = {v:.5g}' for k, v in updates.items())} to {path}{extra}", path


# -- a lost thruster: its efficiency into a scenario -------------------------------------------------

def efficiency_updates(fit: FitResult, efficiency: np.ndarray | None = None) -> tuple[dict[str, float],
                                                                                       dict[str, str]]:
    """(plant parameters, 95 % CI text per parameter) from a maneuver fit with ``thruster_loss``:
    ``thruster_efficiency_<i>`` = the fitted eta_T[i] times the efficiency the log was read with
    (``efficiency``, the vessel file's; 1 if not given), so a rerun's plant carries the loss."""
    from seafmu.identification.effects.thruster_loss import thruster_of

    updates: dict[str, float] = {}
    cis: dict[str, str] = {}
    for name in fit.param_names:
        i = thruster_of(name)
        if i is None:
            continue
        base = 1.0 if efficiency is None else float(efficiency[i])
        key = f"thruster_efficiency_{i + 1}"
        updates[key] = base * fit.params[name]
        lo, hi = fit.ci95.get(name, (float("nan"), float("nan")))
        cis[key] = f"95 % CI [{base * lo:.4g}, {base * hi:.4g}]"
    return updates, cis


def write_scenario_parameters(scenario: str | Path, updates: dict[str, float], out_path: Path,
                              provenance: dict[str, str], instance: str = "plant") -> Path:
    """A copy of a scenario with parameters of one FMU instance set (e.g. the plant's
    ``thruster_efficiency_3`` from ``efficiency_updates``); the description records what was
    identified from which trial, with the CIs. The copy is validated with ``load_scenario`` before
    it replaces anything. The scenario is rewritten as YAML: comments of the original are not kept
    (a header comment says so)."""
    from seafmu.scenario import ScenarioError, load_scenario, scenario_path

    src = scenario_path(scenario)
    doc = yaml.safe_load(src.read_text())
    fmus = doc.get("fmus") if isinstance(doc, dict) else None
    node = fmus.get(instance) if isinstance(fmus, dict) else None
    if not isinstance(node, dict):
        raise ScenarioError(f"write_scenario_parameters: {src} has no FMU instance '{instance}'")
    params = dict(node.get("parameters") or {})
    params.update({k: float(v) for k, v in updates.items()})
    node["parameters"] = params
    date = provenance.get("date") or _dt.date.today().isoformat()
    what = ", ".join(f"{instance}.{k} = {v:.4g}" + (f" ({provenance[k]})" if provenance.get(k) else "")
                     for k, v in updates.items())
    origin = "; ".join(f"{k} {provenance[k]}" for k in ("trial", "method") if provenance.get(k))
    doc["description"] = (f"{str(doc.get('description', '')).strip()} Identified on {date}: {what}"
                          f"{'; ' + origin if origin else ''}.").strip()
    out_path = Path(out_path)
    if not out_path.parent.is_dir():
        raise ScenarioError(f"write_scenario_parameters: {out_path}: the folder {out_path.parent} does not "
                            "exist (it is not created)")
    header = (f"# Written by seafmu write_scenario_parameters on {date} from {src} (comments of that file "
              "are not kept).\n")
    tmp = out_path.with_name(f".{out_path.stem}.writeback-tmp.yaml")
    tmp.write_text(header + yaml.safe_dump(doc, sort_keys=False))  # key order is the FMU stepping order
    try:
        load_scenario(tmp)
    except ScenarioError as exc:
        tmp.unlink(missing_ok=True)
        raise ScenarioError(f"write_scenario_parameters: the written scenario did not validate ({exc}); "
                            "nothing written") from None
    os.replace(tmp, out_path)
    return out_path

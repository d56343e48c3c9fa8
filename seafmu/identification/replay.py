"""Close the loop: re-run a trial's inputs through the plant model with the old and the new vessel file.

After ``--write-vessel`` the question is not "did the numbers change" but "does the plant now
simulate the trial better". Both vessel files drive seafmu's own ``VesselModel`` (the plant's
dynamics: full 3/6-DOF, Coriolis, added-mass coupling, restoring) with the same inputs and the
same starts, and the NRMSE of the simulated against the measured output is reported for each:
the gain in simulation.

- Maneuver logs: the logged generalised force tau (thrust on the hull) enters as the plant's
  external force, thrusters idle; 30 s segments restart from the measured eta and nu (as the
  maneuver NRMSE does, so a model with open-loop drift is still compared on its dynamics);
  NRMSE is the mean over the DOFs of nu.
- Decay / step / 2nd-order decay / sway-yaw trials of a DOF the vessel has: each run starts at
  its smoothed first sample in that DOF, the rest at rest; a step's command enters as the force
  the fitted model computes from it (thrust law, lag, ... of the fit), the same for both files.
- Tables and pendulum rigs are not vessel motions: not replayed (the reason is returned).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.components.vessel_model import VesselModel
from seafmu.components.vessel_spec import VesselSpec, load_vessel
from seafmu.identification import timeseries
from seafmu.identification.fitting import FitResult, nrmse
from seafmu.identification.trial import DOF_INDEX, Trial

SEGMENT_S = 30.0  # maneuver replays restart from the measured state this often
GRID_S = 0.05  # coarsest replay grid step of a maneuver log (finer logs are decimated)
MAX_SUBSTEP = 0.01  # RK4 step of the plant model (as PlantBlock's default substep)


@dataclass
class Replay:
    """NRMSE of the plant model against the trial with the old and the new vessel file."""

    nrmse_old: float
    nrmse_new: float
    method: str
    per_channel: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def ratio(self) -> float:
        """Old / new NRMSE (> 1: the written file simulates the trial better)."""
        return self.nrmse_old / self.nrmse_new if self.nrmse_new > 0 else math.inf

    def to_json(self) -> dict[str, Any]:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {"nrmse_old": num(self.nrmse_old), "nrmse_new": num(self.nrmse_new),
                "ratio": num(self.ratio), "method": self.method,
                "per_channel": {k: [num(a), num(b)] for k, (a, b) in self.per_channel.items()}}

    def line(self, old: str, new: str) -> str:
        return (f"replay through the plant: NRMSE {self.nrmse_old:.4g} with {old} -> {self.nrmse_new:.4g} "
                f"with {new} (gain {self.ratio:.3g}x; {self.method})")


def replay(trial: Trial, fit: FitResult, old: str | Path, new: str | Path) -> Replay | str:
    """Replay the trial through the plant model with both vessel files; a string says why not."""
    if trial.kind in ("static", "pendulum"):
        return f"a {trial.kind} trial is not a vessel motion: nothing to replay"
    old_spec, new_spec = load_vessel(old), load_vessel(new)
    if trial.kind == "maneuver":
        from seafmu.identification.diagnosis import maneuver_data

        data = maneuver_data(trial, old_spec)
        return _replay_maneuver(data.t, data.eta, data.nu, data.tau, old_spec, new_spec)
    return _replay_timeseries(trial, fit, old_spec, new_spec)


# -- maneuver logs ------------------------------------------------------------------------------

def simulate_log(spec: VesselSpec, t: np.ndarray, eta: np.ndarray, nu: np.ndarray,
                 tau: np.ndarray) -> np.ndarray:
    """nu simulated by the plant model driven by the logged tau, restarted every SEGMENT_S."""
    vm = VesselModel(spec)
    d, m = spec.dof, spec.thrusters.count
    idle = [0.0] * m
    stride = max(1, round(GRID_S / float(np.median(np.diff(t)))))
    sel = np.arange(0, t.size, stride)
    out = np.full((sel.size, d), np.nan)
    x = vm.initial_state(eta[0], nu[0])
    seg_start = t[0]
    out[0] = nu[0]
    for k in range(sel.size - 1):
        i0, i1 = sel[k], sel[k + 1]
        if t[i0] - seg_start >= SEGMENT_S - 1e-9:  # restart from the measured state
            x = vm.initial_state(eta[i0], nu[i0])
            seg_start = t[i0]
        h = float(t[i1] - t[i0])
        steps = max(1, math.ceil(h / MAX_SUBSTEP - 1e-9))
        force = (0.5 * (tau[i0] + tau[i1])).tolist()  # trapezoidal mean over the interval
        x = vm.rk4(x, idle, h / steps, steps, tau_ext=force)
        if not np.all(np.isfinite(x)) or np.max(np.abs(x[d:2 * d])) > 1e3:
            break  # diverged: the rest stays NaN
        out[k + 1] = x[d:2 * d]
    return out


def _replay_maneuver(t: np.ndarray, eta: np.ndarray, nu: np.ndarray, tau: np.ndarray, old: VesselSpec,
                     new: VesselSpec) -> Replay:
    stride = max(1, round(GRID_S / float(np.median(np.diff(t)))))
    meas = nu[::stride]
    per: dict[str, tuple[float, float]] = {}
    sims = [simulate_log(s, t, eta, nu, tau) for s in (old, new)]
    for j, name in enumerate(old.nu_names):
        vals = []
        for sim in sims:
            ok = np.isfinite(sim[:, j]).all()
            vals.append(nrmse(meas[:, j], sim[:, j]) if ok else math.inf)
        per[name] = (vals[0], vals[1])
    mean_old = float(np.mean([a for a, _ in per.values()]))
    mean_new = float(np.mean([b for _, b in per.values()]))
    return Replay(mean_old, mean_new, f"logged tau as external force on the plant model, restarted every "
                                      f"{SEGMENT_S:g} s from the measured state; mean NRMSE of nu over "
                                      f"{old.dof} DOFs", per)


# -- 1-2 DOF time series -----------------------------------------------------------------------

def _replay_timeseries(trial: Trial, fit: FitResult, old: VesselSpec, new: VesselSpec) -> Replay | str:
    idx = DOF_INDEX[old.dof]
    if trial.dof == "sway_yaw":
        if "sway" not in idx or "yaw" not in idx:
            return "the vessel has no sway and yaw DOFs"
        chans = [idx["sway"], idx["yaw"]]
    elif trial.dof in idx:
        chans = [idx[trial.dof]]
    else:
        return f"the vessel has no {trial.dof} DOF"
    model: timeseries.TSModel = fit.extras["model"]
    values: dict[str, float] = fit.extras["values"]
    second = trial.kind == "decay2"
    sp = timeseries.split(trial)
    # every run, fitted and held out (a single run split in time is held whole in sp.validation)
    preps = list(sp.validation) if sp.segment_start is not None else [*sp.fit, *sp.validation]
    ys: list[np.ndarray] = []
    sims: dict[str, list[np.ndarray]] = {"old": [], "new": []}
    for p in preps:
        ic = timeseries.initial_state(model, p)
        force = np.zeros((len(p.t), len(chans)))
        if p.u is not None and model.input_kind is not None:
            if model.family == "sway_yaw":
                force = np.asarray(p.u, dtype=float).reshape(len(p.t), 2)
            else:
                f, _ = timeseries.generalised_force(values, model, p.t, p.u, p.uniform, p.before)
                force[:, 0] = f
        ys.append(np.asarray(p.y, dtype=float).reshape(len(p.t), -1))
        for key, spec in (("old", old), ("new", new)):
            sims[key].append(_simulate_dofs(spec, p.t, chans, ic, force, second))
    y = np.vstack(ys)
    names = ["v", "r"] if trial.dof == "sway_yaw" else [trial.dof or "y"]
    sim_old, sim_new = np.vstack(sims["old"]), np.vstack(sims["new"])
    per = {nm: (nrmse(y[:, j], sim_old[:, j]), nrmse(y[:, j], sim_new[:, j])) for j, nm in enumerate(names)}
    res = [float(np.mean([v[k] for v in per.values()])) for k in (0, 1)]
    how = ("each run from its smoothed first sample, the other DOFs at rest"
           + ("; the command enters as the fitted model's force" if model.input_kind else ""))
    return Replay(res[0], res[1], f"{len(preps)} run(s) through the {old.dof}-DOF plant model, {how}", per)


def _simulate_dofs(spec: VesselSpec, t: np.ndarray, chans: list[int], ic: tuple[float, ...],
                   force: np.ndarray, second: bool) -> np.ndarray:
    """The plant model from rest except the trial's DOF(s); output: their velocity (or position)."""
    vm = VesselModel(spec)
    d, m = spec.dof, spec.thrusters.count
    eta, nu = np.zeros(d), np.zeros(d)
    if second:
        eta[chans[0]], nu[chans[0]] = ic[0], ic[1]
    else:
        for c, v in zip(chans, ic, strict=True):
            nu[c] = v
    x = vm.initial_state(eta, nu)
    idle = [0.0] * m
    out = np.full((len(t), len(chans)), np.nan)
    out[0] = [x[c] if second else x[d + c] for c in chans]
    tau = np.zeros(d)
    for k in range(len(t) - 1):
        h = float(t[k + 1] - t[k])
        steps = max(1, math.ceil(h / MAX_SUBSTEP - 1e-9))
        tau[chans] = force[k]  # held over the sample interval, as the trial model does
        x = vm.rk4(x, idle, h / steps, steps, tau_ext=tau.tolist())
        if not np.all(np.isfinite(x)):
            break
        out[k + 1] = [x[c] if second else x[d + c] for c in chans]
    return out

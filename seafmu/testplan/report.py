"""The test plan's report: the results table filled, and each step from measurement to coefficient."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from seafmu.identification.timeseries import simulate
from seafmu.testplan.fit import coefficient_names

UNITS = {"surge": ("m/s", "N"), "sway": ("m/s", "N"), "yaw": ("rad/s", "N.m"), "roll": ("rad", "N.m"),
         "pitch": ("rad", "N.m")}


def _g(x: float | None) -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.5g}"


def _err(row: dict[str, Any]) -> str:
    if row["file"] == 0.0:
        return f"abs {row['value']:.3g}"
    return f"{100.0 * (row['value'] - row['file']) / abs(row['file']):+.2f} %"


def _intervals_line(f: Any, names: dict[str, str]) -> str:
    """How each 95 % interval was made: the three standard errors, the wider of the last two used."""
    rows = f.extras.get("intervals", {})
    parts = [f"{names.get(q, q)}: white-noise {_g(x['se_white'])}, sensor noise propagated "
             f"{_g(x['se_noise'])}, Newey-West {_g(x['se_newey_west'])}"
             for q, x in rows.items() if q in names]
    if not parts:
        return ""
    return ("   Standard errors (the 95 % interval is 1.96 times the wider of the last two; the white-noise "
            "one assumes uncorrelated residuals, which a filtered or differentiated velocity and a model "
            "misfit are not): " + "; ".join(parts) + ".")


def _plot(res: Any, out: Path) -> list[str]:
    names = []
    for name, r in res.results.items():
        m = res.measurements[name]
        tp = r.plan
        fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        unit = UNITS[tp.axis][0]
        axes[0].plot(m.t, m.y, ".", ms=2, color="0.6", label=f"measured ({m.source.split('(')[0].strip()})")
        if tp.nu in res.measurements[name].truth and tp.kind == "method_one":
            tr = m.truth
            axes[0].plot(tr["time"], tr[tp.nu], "-", lw=0.8, color="C2", label="true (simulation only)")
        f = r.fits["record"]
        for p in f.extras["predictions"]:
            t0 = (tp.t_accelerate - 2.0) if p["run"] == "fit" else (tp.t_step - 2.0)
            if tp.kind == "release":
                t0 = m.t[0]
            axes[0].plot(p["t"] + t0, p["yhat"], "-", lw=1.4, color="C0" if p["run"] == "fit" else "C1",
                         label=f"model, {'fitted' if p['run'] == 'fit' else 'predicted (held out)'}")
        axes[0].set_ylabel(f"{tp.nu if tp.kind == 'method_one' else tp.dof} ({unit})")
        axes[0].legend(fontsize=7)
        axes[0].set_title(f"{res.vessel.name}: {tp.axis} trial")
        for k, tn in enumerate(res.vessel.tau_names):
            axes[1].plot(m.t, m.tau[:, k], lw=0.8, label=f"tau_{tn} (thrusters)")
        axes[1].set_xlabel("time (s)")
        axes[1].set_ylabel("force / moment")
        axes[1].legend(fontsize=7, ncol=3)
        fig.tight_layout()
        fn = f"{name}.png"
        fig.savefig(out / fn, dpi=90)
        plt.close(fig)
        names.append(fn)
    return names


def _decay_curve(r: Any) -> str:
    f = r.fits["decay"]
    model, vals = f.extras["model"], f.extras["values"]
    p = f.extras["predictions"][0]
    yh = simulate(model, vals, p["t"], None, f.extras["initial_states"][0])
    return f"{len(p['t'])} samples, model end value {yh[-1]:.3g}"


def write_report(res: Any, out: Path) -> Path:
    """report.md, one PNG per trial, summary.json."""
    # Long because the report is written top to bottom as the reader sees it (results table, then
    # each trial from measurement to coefficient); one sequence keeps the text in reading order.
    figs = _plot(res, out)
    v = res.vessel
    L: list[str] = [f"# Test plan: {v.name}", ""]
    where = f"the vessel through hardware profile `{res.hardware}`" if res.hardware else \
        f"the plant ({res.mode}, sensors with the vessel file's noise)"
    vf = res.vessel_file.name if res.vessel_file else f"- ({res.not_written})"
    short = f" (phase durations x {res.scale:g}: a shortened plan)" if res.scale != 1.0 else ""
    L += [f"Run against {where}; {len(res.plans)} trials{short}, wall time {res.wall:.1f} s. "
          f"Identified vessel file: `{vf}`; trials for `seafmu identify`: `trials/`.", ""]
    L += ["## Results table (the plan's, filled)", "",
          "| term | identified | 95 % CI | vessel file | difference | from trial |",
          "|---|---|---|---|---|---|"]
    for name, row in res.identified.items():
        ci = f"[{_g(row['ci95'][0])}, {_g(row['ci95'][1])}]" if row["ci95"] else "—"
        L.append(f"| {name} ({row['key']}) | {_g(row['value'])} | {ci} | {_g(row['file'])} | {_err(row)} | "
                 f"{row['trial']} |")
    L += ["", "Sign convention: the vessel file's D (positive on the diagonal); Fossen's coefficients are "
          "their negatives (X_u = -D_11, Y_r = -D_23, N_v = -D_32).", ""]
    L += ["## From measurement to coefficient", ""]
    for name, r in res.results.items():
        tp, m = r.plan, res.measurements[name]
        vu, fu = UNITS[tp.axis]
        L += [f"### {tp.axis} ({name})", "",
              f"Measured: {m.source}; sensor noise {m.noise:.3g} {vu} per sample.", ""]
        if tp.kind == "method_one":
            mo = r.method_one
            L += [f"1. **Accelerate and hold**: open-loop {tp.tau} = {tp.force_hold:.4g} {fu} from t = "
                  f"{tp.t_accelerate:g} s (40 % of the thrust capability), the other DOFs held by "
                  "`axis_trial`; "
                  f"steady {tp.nu} = {r.levels['hold']['v']:.4g} {vu}.",
                  f"2. **Release** at t = {tp.t_release:g} s: decay from {tp.nu}0 = {mo['u0']:.4g} {vu}; fit "
                  f"of M v' + d v = 0 ({_decay_curve(r)}): time constant T = M/d = {mo['T_decay']:.4g} s.",
                  f"3. **Step from rest** at t = {tp.t_step:g} s, measured force "
                  f"{mo['force_step']:.4g} {fu}: "
                  f"{tp.nu}_ss = {mo['v_ss_step']:.4g} {vu}, so d = F/{tp.nu}_ss = {mo['d_step']:.5g}, and "
                  f"m = d T = {mo['m_method_one']:.5g} (file: {tp.mass:.5g}).",
                  "4. **Coefficient written**: output-error fit of the accelerate-hold-release record "
                  "with the measured force, damping and inertia free: "
                  + ", ".join(f"{coefficient_names(tp.axis).get(k, k)} = {val:.5g}"
                              for k, val in r.fits["record"].params.items())
                  + f"; held-out NRMSE on the step {r.fits['record'].nrmse_validation:.3g} "
                  f"(fit {r.fits['record'].nrmse_fit:.3g}); {r.fits['record'].method}.",
                  _intervals_line(r.fits["record"], coefficient_names(tp.axis)), ""]
            if r.coupled:
                L.append("5. **Coupled terms** (impulse on each held axis from rest to rest, over the trial "
                         "axis' displacement):")
                for tau, (dkj, imp, disp) in r.coupled.items():
                    lo, hi = r.coupled_ci.get(tau, (math.nan, math.nan))
                    L.append(f"   - int tau_{tau} dt = {imp:.4g}, int {tp.nu} dt = {disp:.4g}: "
                             f"D[{tau},{tp.nu}] = {dkj:.5g}, 95 % CI [{_g(lo)}, {_g(hi)}] (the file's "
                             "sensor noise through the same balance, 300 draws)")
                L.append("")
        else:
            f1, f = r.fits["decay"], r.fits["record"]
            free = ", ".join(tp.free) if tp.free else "none"
            names = coefficient_names(tp.axis)
            L += [f"1. **Release** from {math.degrees(tp.angle0):.3g} deg, {tp.dof} free and the DOFs its "
                  f"inertia couples to left free too ({free}); the others held by `axis_trial`.",
                  "2. **Free oscillation** (the plan's 1-DOF model) m_eff phi'' + d phi' (+ d_Q phi'|phi'|) "
                  "+ c phi = 0, restoring from the file: "
                  + ", ".join(f"{k} = {val:.5g}" for k, val in f1.params.items())
                  + f"; omega_n = {r.method_one.get('natural_frequency', float('nan')):.4g} rad/s, "
                  f"zeta (linear part) = {r.method_one.get('zeta', float('nan')):.3g}; "
                  f"NRMSE {f1.nrmse_fit:.3g}.",
                  f"3. **Coefficient written**: {f.method}: the free DOFs "
                  f"({', '.join(f.extras.get('free_dofs', [tp.nu]))}) simulated, the held DOFs' measured "
                  "motion and the thrusters' measured forces as inputs, the angle"
                  + (" and its rate" if f.extras.get("uses_rate") else "") + " as outputs: "
                  + ", ".join(f"{names.get(k, k)} = {val:.5g}" for k, val in f.params.items())
                  + f"; NRMSE {f.nrmse_fit:.3g}.", _intervals_line(f, names), ""]
        for w in r.fits["record"].warnings:
            L.append(f"- warning: {w}")
        L += [f"![{name}]({figs[list(res.results).index(name)]})", ""]
    path = out / "report.md"
    path.write_text("\n".join(L) + "\n")
    summary = {"vessel": v.name, "wall_time_s": res.wall, "mode": res.mode, "hardware": res.hardware,
               "scale": res.scale, "axes": [p.axis for p in res.plans],
               "identified": res.identified,
               "vessel_file": str(res.vessel_file) if res.vessel_file else None,
               "trials": [str(p) for p in res.trial_files]}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return path

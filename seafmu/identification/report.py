"""Plots and the Markdown report of an identification or a diagnosis.

The figures answer the diagnosis questions in order: where does the baseline simulation go wrong
(overlay, residual vs time), what does the residual line up with (residual vs candidate regressors),
and how much does each candidate effect gain on held-out data (ranking).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: runs on machines with no display
import matplotlib.pyplot as plt
import numpy as np

from seafmu.identification.catalogue import CATALOGUE, param_unit
from seafmu.identification.diagnosis import Diagnosis, Identification
from seafmu.identification.fitting import FitResult, noise_only_text
from seafmu.identification.trial import ROTATIONAL, Trial


def _labels(trial: Trial) -> tuple[str, str]:
    """Axis labels of the output and the input."""
    rot = trial.dof in ROTATIONAL
    if trial.kind == "static":
        if trial.table == "thrust_rpm":
            return "thrust [N]", "shaft speed [rev/s]"
        return ("moment [N·m]", "rate [rad/s]") if rot else ("force [N]", "speed [m/s]")
    if trial.kind in ("decay2", "pendulum"):
        return ("angle [rad]" if rot or trial.kind == "pendulum" else "displacement [m]"), ""
    if trial.dof == "sway_yaw":
        return "v [m/s], r [rad/s]", "Y [N], N [N·m]"
    out = "rate [rad/s]" if rot else "speed [m/s]"
    inp = "command [rev/s]" if trial.input_kind == "rpm" else ("moment [N·m]" if rot else "force [N]")
    return out, inp


# -- figures --------------------------------------------------------------------------------------

def plot_static(trial: Trial, base: FitResult, ext: FitResult | None, path: Path, effect: str = "") -> None:
    x, y = base.extras["x"], base.extras["y"]
    ylab, xlab = _labels(trial)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    xs = np.linspace(float(np.min(x)), float(np.max(x)), 300)
    a1.plot(x, y, "ko", ms=5, label="measured")
    a1.plot(xs, base.extras["model"].predict(xs, np.array([base.params[p] for p in base.param_names])),
            "C0-", label=f"baseline ({trial.baseline})")
    a2.plot(x, base.extras["residual"], "C0o", label="baseline")
    if ext is not None and ext is not base:
        a1.plot(xs, ext.extras["model"].predict(xs, np.array([ext.params[p] for p in ext.param_names])),
                "C3--", label=f"+ {effect}")
        a2.plot(x, ext.extras["residual"], "C3s", ms=4, label=f"+ {effect}")
    a2.axhline(0, color="k", lw=0.6)
    a1.set_ylabel(ylab)
    a2.set_ylabel("residual")
    a2.set_xlabel(xlab)
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    a1.set_title(f"{trial.name}: table and fits")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_overlay(trial: Trial, base: FitResult, ext: FitResult | None, path: Path, effect: str = "") -> None:
    """Measured vs simulated output per run (fit and held-out), baseline and extended."""
    preds = base.extras["predictions"]
    epreds = ext.extras["predictions"] if ext is not None and ext is not base else None
    two = trial.dof == "sway_yaw"
    n = min(len(preds), 4)
    cols = 2 if two else 1
    fig, axes = plt.subplots(n, cols, figsize=(9 * cols / 1.4 if two else 9, 2.6 * n + 0.5), squeeze=False)
    ylab, _ = _labels(trial)
    for i in range(n):
        p = preds[i]
        for j in range(cols):
            ax = axes[i, j]
            def sel(a: np.ndarray, j: int = j) -> np.ndarray:
                return a if not two else a[:, j]

            ax.plot(p["t"], sel(p["y"]), "k.", ms=2 if len(p["t"]) > 100 else 5, label="measured")
            ax.plot(p["t"], sel(p["yhat"]), "C0-", lw=1.2, label="baseline")
            if epreds is not None and i < len(epreds):
                ax.plot(epreds[i]["t"], sel(epreds[i]["yhat"]), "C3--", lw=1.2, label=f"+ {effect}")
            ax.set_ylabel(["v [m/s]", "r [rad/s]"][j] if two else ylab)
            ax.set_title(f"{p['run']} data" + (f" ({['sway', 'yaw rate'][j]})" if two else ""), fontsize=9)
            ax.grid(True, alpha=0.3)
            if i == 0 and j == 0:
                ax.legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"{trial.name}: measured vs simulated")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_residuals(trial: Trial, base: FitResult, ext: FitResult | None, path: Path,
                   effect: str = "") -> None:
    preds = base.extras["predictions"]
    epreds = ext.extras["predictions"] if ext is not None and ext is not base else None
    fig, ax = plt.subplots(figsize=(9, 3.4))
    for i, p in enumerate(preds):
        r = np.asarray(p["y"]) - np.asarray(p["yhat"])
        r = r if r.ndim == 1 else r[:, 0]
        ax.plot(p["t"], r, "C0-" if p["run"] == "fit" else "C0:", lw=0.8,
                label="baseline" if i == 0 else None)
        if epreds is not None and i < len(epreds):
            q = epreds[i]
            re = np.asarray(q["y"]) - np.asarray(q["yhat"])
            re = re if re.ndim == 1 else re[:, 0]
            ax.plot(q["t"], re, "C3-" if q["run"] == "fit" else "C3:", lw=0.8,
                    label=f"+ {effect}" if i == 0 else None)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("time [s] (solid: fitted runs, dotted: held-out)")
    ax.set_ylabel("measured - simulated")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{trial.name}: output-error residual")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


_NU_UNIT = {"u": "m/s", "v": "m/s", "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s"}


def _maneuver_traces(fit: FitResult) -> list[dict[str, Any]]:
    return list(fit.extras.get("predictions") or [])


def plot_maneuver_overlay(trial: Trial, base: FitResult, other: FitResult | None, path: Path,
                          label: str = "baseline", other_label: str = "") -> None:
    """Measured vs simulated nu per DOF over the whole log (fitted part, then held-out part).

    The simulation restarts from the measured state at every segment start (thin grey lines), as
    the maneuver NRMSE does, so the overlay shows what the NRMSE measures.
    """
    traces = _maneuver_traces(base)
    names = base.extras.get("nu_names") or [f"nu{j}" for j in range(np.asarray(traces[0]["y"]).shape[1])]
    others = _maneuver_traces(other) if other is not None else []
    d = len(names)
    fig, axes = plt.subplots(d, 1, figsize=(10, 1.7 * d + 0.8), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        for i, tr in enumerate(traces):
            t, y, yh = tr["t"], np.asarray(tr["y"])[:, j], np.asarray(tr["yhat"])[:, j]
            ax.plot(t, y, "k.", ms=1.5, label="measured" if i == 0 else None)
            ax.plot(t, yh, "C0-", lw=0.9, label=label if i == 0 else None)
            for t0 in tr["restarts"]:
                ax.axvline(t0, color="0.85", lw=0.5, zorder=0)
        for i, tr in enumerate(others):
            ax.plot(tr["t"], np.asarray(tr["yhat"])[:, j], "C3--", lw=0.9,
                    label=other_label if i == 0 else None)
        if len(traces) > 1:
            ax.axvline(traces[1]["restarts"][0], color="C2", lw=1.2,
                       label="held-out from here" if j == 0 else None)
        ax.set_ylabel(f"{name} [{_NU_UNIT.get(name, '')}]")
        ax.grid(True, alpha=0.3)
        if j == 0:
            ax.legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1, 0].set_xlabel("time [s] (grey: simulation restarts from the measured state)")
    fig.suptitle(f"{trial.name}: measured vs simulated body velocities")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_maneuver_residuals(trial: Trial, base: FitResult, other: FitResult | None, path: Path,
                            label: str = "baseline", other_label: str = "") -> None:
    """Residual (measured - simulated) nu per DOF against time, fitted and held-out parts."""
    traces = _maneuver_traces(base)
    names = base.extras.get("nu_names") or [f"nu{j}" for j in range(np.asarray(traces[0]["y"]).shape[1])]
    others = _maneuver_traces(other) if other is not None else []
    d = len(names)
    fig, axes = plt.subplots(d, 1, figsize=(10, 1.5 * d + 0.8), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        for i, tr in enumerate(traces):
            r = np.asarray(tr["y"])[:, j] - np.asarray(tr["yhat"])[:, j]
            ax.plot(tr["t"], r, "C0-" if tr["run"] == "fit" else "C0:", lw=0.7,
                    label=label if i == 0 else None)
        for i, tr in enumerate(others):
            r = np.asarray(tr["y"])[:, j] - np.asarray(tr["yhat"])[:, j]
            ax.plot(tr["t"], r, "C3-" if tr["run"] == "fit" else "C3:", lw=0.7,
                    label=other_label if i == 0 else None)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{name} [{_NU_UNIT.get(name, '')}]")
        ax.grid(True, alpha=0.3)
        if j == 0:
            ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s] (solid: fitted part, dotted: held-out)")
    fig.suptitle(f"{trial.name}: simulation residual (measured - simulated nu)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def regressors(trial: Trial, base: FitResult) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Baseline residual against each candidate regressor (fitted runs), for the scatter plots."""
    out: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for p in base.extras["predictions"]:
        y, yh = np.asarray(p["y"]), np.asarray(p["yhat"])
        r = y - yh
        if trial.dof == "sway_yaw":
            for j, nm in enumerate(("v", "r")):
                out.setdefault(f"resid v vs {nm}", []).append((y[:, j], r[:, 0]))
                out.setdefault(f"resid r vs {nm}", []).append((y[:, j], r[:, 1]))
            continue
        t = np.asarray(p["t"])
        if trial.kind in ("decay2", "pendulum"):
            xd = np.gradient(y, t)
            cand = {"x": y, "x_dot": xd, "x_dot|x_dot|": xd * np.abs(xd), "sign(x_dot)": np.sign(xd),
                    "x^3": y**3}
        else:
            cand = {"v": y, "v|v|": y * np.abs(y), "sign(v)": np.sign(y)}
            if p.get("u") is not None:
                u = np.asarray(p["u"])
                cand |= {"u": u, "u|u|": u * np.abs(u)}
        for k, v in cand.items():
            out.setdefault(k, []).append((v, r))
    return {k: (np.concatenate([a for a, _ in v]), np.concatenate([b for _, b in v])) for k, v in out.items()}


def plot_regressors(trial: Trial, base: FitResult, path: Path) -> dict[str, float]:
    """Scatter of the baseline residual vs each regressor; returns the correlations."""
    regs = regressors(trial, base)
    corr = {}
    n = len(regs)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False)
    for ax, (name, (x, r)) in zip(axes.ravel(), regs.items(), strict=False):
        c = float(np.corrcoef(x, r)[0, 1]) if np.std(x) > 0 and np.std(r) > 0 else 0.0
        corr[name] = c
        ax.plot(x, r, ".", ms=2, alpha=0.5)
        ax.set_title(f"{name} (corr {c:+.2f})", fontsize=9)
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(True, alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(f"{trial.name}: baseline residual vs candidate regressors")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return corr


def plot_ranking(diag: Diagnosis, path: Path) -> None:
    rk = diag.ranking()
    if not rk:
        return
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(rk) + 1.4))
    names = [c.label() for c in rk][::-1]  # two located thrusters: two bars
    vals = [c.fit.nrmse_validation for c in rk][::-1]  # type: ignore[union-attr]
    finite = [v for v in [*vals, diag.baseline.nrmse_validation] if math.isfinite(v)]
    cap = 1.5 * max(finite) if finite else 1.0  # every fit diverged: the bars only name them
    names = [n + (" (diverged)" if not math.isfinite(v) else "") for n, v in zip(names, vals, strict=True)]
    vals = [v if math.isfinite(v) else cap for v in vals]
    colors = ["C3" if c.accepted else "C7" for c in rk][::-1]
    ax.barh(names, vals, color=colors)
    ax.set_xlabel("held-out NRMSE (red: passes the acceptance rule)")
    if math.isfinite(diag.baseline.nrmse_validation):
        ax.axvline(diag.baseline.nrmse_validation, color="C0", ls="--", label="baseline")
        ax.legend(fontsize=8)
    ax.grid(True, axis="x", alpha=0.3)
    ax.set_title(f"{diag.trial.name}: candidate effects")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# -- text ------------------------------------------------------------------------------------------

def _g(x: float | None, digits: int = 4) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}g}"


def fit_table(fit: FitResult, trial: Trial) -> list[str]:
    lines = ["| parameter | value | 95 % CI | unit |", "|---|---|---|---|"]
    for p in fit.param_names:
        lo, hi = fit.ci95.get(p, (math.nan, math.nan))
        lines.append(f"| {p} | {_g(fit.params[p], 5)} | [{_g(lo)}, {_g(hi)}] | {param_unit(p, trial)} |")
    lines.append("")
    w = fit.whiteness
    white = "–" if w.get("white") is None else ("white" if w["white"] else
                                                 f"NOT white ({_g(100 * w['fraction_outside'], 3)} % of "
                                                 f"{w['lags']} lags outside ±1.96/√n)")
    if "noise_only_p" in w:  # a maneuver's restarted simulation: its null is the noise-only residual
        white = (f"{'no structure' if w['white'] else 'STRUCTURE'} beyond the sensor noise "
                 f"({noise_only_text(w)}; against white noise p = {_g(w['ljung_box_p'], 2)})")
    lines += [
        f"- method: {fit.method}; {fit.n_samples} fitted samples",
        f"- NRMSE fit {_g(fit.nrmse_fit)} (fit {_g(fit.fit_percent())} %), "
        f"held-out {_g(fit.nrmse_validation)}"
        f" ({fit.extras.get('validation', 'held-out data')})",
        f"- AIC {_g(fit.aic, 6)}, BIC {_g(fit.bic, 6)}; residual whiteness: {white}",
    ]
    if "rmse" in fit.extras:
        lines.append(f"- RMSE {_g(fit.extras['rmse'])} (n − p), {_g(fit.extras['rmse_plain'])} (n)")
    for k, v in (fit.extras.get("derived") or {}).items():
        lines.append(f"- {k}: {_g(v)}")
    if fit.nonidentifiable:
        lines.append(f"- NOT separately identifiable (|corr| > 0.95): "
                     f"{', '.join(f'{a}–{b}' for a, b in fit.nonidentifiable)}")
    for warn in fit.warnings:
        lines.append(f"- **warning:** {warn}")
    return lines


def _header(trial: Trial, title: str) -> list[str]:
    from seafmu.identification.effects.base import vessel_dof

    dof = trial.dof if trial.dof is not None else vessel_dof(trial)  # a maneuver log: its vessel's
    return [f"# {title}: {trial.name}", "",
            f"- kind: {trial.kind}, DOF: {dof if dof is not None else 'not stated'}, "
            f"baseline model: {trial.baseline}",
            f"- data: {', '.join(str(f) for f in trial.files) or '(in memory)'}",
            f"- provenance: {trial.provenance}",
            *([f"- description: {' '.join(trial.description.split())}"] if trial.description else []), ""]


def write_identify_report(ident: Identification, out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    trial, fit = ident.trial, ident.fit
    lines = _header(trial, "Identification")
    # A maneuver's alternative method (LS vs output error) is drawn over the baseline fit.
    alt_name, alt = next(iter(ident.alternatives.items()), ("", None))
    if trial.kind == "maneuver" and alt is not None:
        figs = _figures(trial, fit, alt, out, "", label=alt_name)
    else:
        figs = _figures(trial, fit, None, out, "")
    lines += ["## Fit", "", *fit_table(fit, trial), ""]
    for name, alt in ident.alternatives.items():
        lines += [f"## Alternative: {name}", "", *fit_table(alt, trial)]
        if "theta_simulation_nrmse" in alt.extras:
            lines.append("- theta simulated with these parameters: NRMSE "
                         f"{_g(alt.extras['theta_simulation_nrmse'])}")
        lines.append("")
    if ident.notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in ident.notes] + [""]
    lines += ["## Figures", ""] + [f"![{f.stem}]({f.name})" for f in figs] + [""]
    path = out / "identification.md"
    path.write_text("\n".join(lines))
    return path


def write_diagnosis_report(diag: Diagnosis, out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    trial = diag.trial
    ext = diag.extended if diag.cause else None
    effect = diag.effect
    lines = _header(trial, "Diagnosis")
    if _baseline_name(trial, diag.baseline) != trial.baseline:
        lines += ["- the diagnosis baseline is the output-error fit: the extensions are output-error fits, "
                  "and an LS baseline would credit the method, not the effect", ""]
    j = diag.to_json()
    # every effect of the cause, a located one with its parameter (two lost thrusters: both named)
    named = " + ".join(f"`{e}`" for e in diag.cause.label().split("+")) if diag.cause else f"`{effect}`"
    lines += ["## Answer", "", f"**Cause: {named}** — {diag.evidence}", ""]
    if diag.cause:
        g = j["gain"]
        lines += [f"Gain: held-out NRMSE {_g(g['nrmse_validation_before'])} → "
                  f"{_g(g['nrmse_validation_after'])} "
                  f"(ratio {_g(g['validation_nrmse_ratio'])}), ΔAIC {_g(g['delta_aic'])}.", ""]
        if len(diag.effects) > 1:
            listed = [f"`{m['effect']}` (" + ", ".join(f"{k} = {_g(v)}" for k, v in m["params"].items()) + ")"
                      for m in j["cause"]["members"]]
            lines += ["Effects of the cause, largest contribution first: " + ", ".join(listed) + ".", ""]
    lines += alternatives_lines(diag)
    figs = _figures(trial, diag.baseline, ext, out, "+".join(diag.effects) or effect)
    corr: dict[str, float] = {}
    if trial.kind not in ("static", "maneuver"):
        corr = plot_regressors(trial, diag.baseline, out / "residual_vs_regressors.png")
        figs.append(out / "residual_vs_regressors.png")
    plot_ranking(diag, out / "ranking.png")
    if (out / "ranking.png").exists():
        figs.append(out / "ranking.png")
    lines += ["## 1. Baseline", "", *fit_table(diag.baseline, trial), ""]
    if corr:
        lines += ["Baseline residual vs candidate regressors (correlation): " +
                  ", ".join(f"{k} {v:+.2f}" for k, v in sorted(corr.items(), key=lambda kv: -abs(kv[1]))), ""]
    lines += ["## 2. Candidate effects (each refitted as an extension of the baseline)", "",
              "| effect | held-out NRMSE | ratio | ΔAIC | significant | verdict |",
              "|---|---|---|---|---|---|"]
    for c in diag.ranking():
        lines.append(f"| {c.label()} | {_g(c.fit.nrmse_validation)} | {_g(c.ratio)} | {_g(c.delta_aic)} | "  # type: ignore[union-attr]
                     f"{'yes' if c.significant else 'no'} | {c.reason} |")
    for c in diag.candidates:
        if c.fit is None:
            lines.append(f"| {c.label()} | – | – | – | – | {c.reason} |")
    lines.append("")
    if diag.skipped:
        lines += ["Not applicable to this trial: " +
                  "; ".join(f"`{k}` ({v})" for k, v in diag.skipped.items()), ""]
    r = diag.rule
    lines += [f"Acceptance rule: held-out ratio ≥ {r.min_ratio} and n_val·ln(ratio²) ≥ "
              f"{r.min_heldout_gain:g}, "
              f"ΔAIC ≤ {r.max_delta_aic:g}, 95 % CI of the effect parameter excludes its no-effect value; "
              "best = lowest held-out NRMSE (within 1 %: lowest AIC).", ""]
    if diag.cause and diag.cause.fit:
        added = " + ".join(f"`{e}`: {CATALOGUE[e].meaning}" for e in dict.fromkeys(diag.effects))
        lines += [f"## 3. Extended model (baseline + {added})", ""]
        lines += [*fit_table(diag.extended, trial), ""]
    lines += ["## Figures", ""] + [f"![{f.stem}]({f.name})" for f in figs] + [""]
    path = out / "diagnosis.md"
    path.write_text("\n".join(lines))
    return path


def alternatives_lines(diag: Diagnosis) -> list[str]:
    """The credible explanations (each passes the acceptance rule) with their Akaike weights, and
    the experiments that would tell them from the cause."""
    if len(diag.alternatives) < 2:
        return []
    lines = ["### Credible alternatives", "",
             "More than one explanation passes the acceptance rule. Akaike weight: the relative "
             "likelihood of each among them; ΔAIC from the lowest.", "",
             "| explanation | Akaike weight | held-out ratio | ΔAIC | to tell it from the cause |",
             "|---|---|---|---|---|"]
    for i, a in enumerate(diag.alternatives):
        c = a.candidate
        exp = "(the cause)" if i == 0 else (a.experiment["text"] if a.experiment else "–")
        lines.append(f"| `{c.effect}` | {a.weight:.3f} | {_g(c.ratio)} | {_g(a.delta_aic)} | {exp} |")
    return [*lines, ""]


def _figures(trial: Trial, base: FitResult, ext: FitResult | None, out: Path, effect: str,
             label: str = "baseline") -> list[Path]:
    figs = []
    if trial.kind == "maneuver":
        if _maneuver_traces(base):
            other = f"+ {effect}" if effect and ext is not None else label
            first = f"baseline ({_baseline_name(trial, base)})"
            plot_maneuver_overlay(trial, base, ext, out / "overlay.png", first, other)
            plot_maneuver_residuals(trial, base, ext, out / "residuals.png", first, other)
            figs += [out / "overlay.png", out / "residuals.png"]
    elif trial.kind == "static":
        plot_static(trial, base, ext, out / "fit.png", effect)
        figs.append(out / "fit.png")
    elif trial.kind != "maneuver" and "predictions" in base.extras:
        plot_overlay(trial, base, ext, out / "overlay.png", effect)
        plot_residuals(trial, base, ext, out / "residuals.png", effect)
        figs += [out / "overlay.png", out / "residuals.png"]
    return figs


def _baseline_name(trial: Trial, fit: FitResult) -> str:
    """The baseline actually fitted (a maneuver diagnosis uses output error whatever the trial says)."""
    if trial.kind == "maneuver" and fit.method.startswith("maneuver output error"):
        return "output_error"
    return trial.baseline


def summary_lines(obj: Identification | Diagnosis) -> list[str]:
    """A short readable console summary."""
    trial = obj.trial

    def params(f: FitResult) -> str:
        return ", ".join(f"{p} = {_g(f.params[p], 5)} [{_g(f.ci95[p][0])}, {_g(f.ci95[p][1])}]"
                         for p in f.param_names if p in f.ci95)

    if isinstance(obj, Identification):
        f = obj.fit
        lines = [f"{trial.label}: {f.method}",
                 f"  {params(f)}",
                 f"  NRMSE fit {_g(f.nrmse_fit)}, held-out {_g(f.nrmse_validation)}, AIC {_g(f.aic, 6)}"]
        if "rmse" in f.extras:
            lines.append(f"  RMSE {_g(f.extras['rmse'])} (n - p), {_g(f.extras['rmse_plain'])} (n)")
        lines += [f"  warning: {w}" for w in f.warnings]
        for name, alt in obj.alternatives.items():
            lines.append(f"  {name}: {params(alt)}")
            lines += [f"    warning: {w}" for w in alt.warnings]
        return lines
    d = obj
    b = d.baseline
    lines = [f"{trial.label}: baseline {_baseline_name(trial, b)}",
             f"  baseline: {params(b)}; held-out NRMSE {_g(b.nrmse_validation)}, AIC {_g(b.aic, 6)}",
             *(f"    baseline warning: {w}" for w in b.warnings),  # each under the model it is about
             f"  cause: {' + '.join(d.effects) or d.effect} — {d.evidence}"]
    for a in d.alternatives[1:]:
        if a.weight < 0.01:
            continue
        lines.append(f"  also credible: {a.candidate.label()} (Akaike weight {a.weight:.3f}, held-out ratio "
                     f"{_g(a.candidate.ratio)}, dAIC {_g(a.delta_aic)} from the best)")
        if a.experiment:
            lines.append(f"    to tell them apart: {a.experiment['text']}")
    if d.cause and d.cause.fit:
        e = d.extended
        lines.append(f"  extended: {params(e)}; held-out NRMSE {_g(e.nrmse_validation)}, AIC {_g(e.aic, 6)}")
        lines += [f"    extended warning: {w}" for w in e.warnings if w not in b.warnings]
    if d.skipped:  # what "none" did not cover, on the console too (not only in diagnosis.md)
        lines.append(f"  not tried, not applicable to this trial (why: diagnosis.md): {', '.join(d.skipped)}")
    return lines


def _jsonable(obj: Any) -> Any:
    """json.dumps default: numpy scalars and arrays."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")

"""The study report: pass rates with confidence intervals, distributions, inputs against checks,
sensitivity, and the worst cases with the command that reproduces each one (Markdown + PNG).

Confidence intervals are Wilson score intervals, which keep their coverage at pass rates near 0 or
1, where a study of a good controller lives. Sensitivity is Spearman's rank correlation for any
study (monotone, not only linear, effects; categorical inputs are left out), and first-order and
total Sobol indices (SALib) when the study was sampled for them (``sampling.method: saltelli``, no
grid inputs, seeds paired or absent).

Both statistics are written out from their closed forms instead of taken from ``scipy.stats``
(``binomtest``, ``spearmanr``): importing ``scipy.stats`` costs ~0.7 s of CPU, a tenth of a
40-case study's fixed cost on two cores, for two formulas. Wilson's normal quantile comes from the
standard library (``statistics.NormalDist``), Student's t from ``scipy.special.stdtr`` (imported
only by a study with a numeric input, ~0.13 s); the tests hold both equal to ``scipy.stats``.
"""

from __future__ import annotations

import math
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from seafmu.outdir import atomic_path, atomic_write_text
from seafmu.results import check_name
from seafmu.sweep.study import Study
from seafmu.sweep.worker import CHECK, METRIC, PASS

CONFIDENCE = 0.95
MAX_SCATTER_PANELS = 80


def wilson(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of a pass rate k/n (nan, nan for n = 0)."""
    if n == 0:
        return math.nan, math.nan
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    centre, half = p + z * z / (2 * n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    scale = 1 + z * z / n
    # the interval holds p exactly (k = 0 or n: a bound at 0 or 1 with no rounding below or above)
    return max(0.0, min(p, (centre - half) / scale)), min(1.0, max(p, (centre + half) / scale))


def spearman(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(Spearman's rho, two-sided p-value of rho = 0 from Student's t with n - 2 degrees of freedom), as
    ``scipy.stats.spearmanr``: Pearson's r of the ranks, ties at their mean rank."""
    import pandas as pd
    from scipy.special import stdtr

    rx, ry = pd.Series(x).rank().to_numpy(), pd.Series(y).rank().to_numpy()
    rho = float(np.clip(np.corrcoef(rx, ry)[0, 1], -1.0, 1.0))
    dof = len(x) - 2
    if abs(rho) == 1.0:
        return rho, 0.0
    t = rho * math.sqrt(dof / ((1 - rho) * (1 + rho)))
    return rho, float(2 * stdtr(dof, -abs(t)))


def check_bounds(study: Study) -> dict[str, tuple[float | None, float | None]]:
    """Each check of the base scenario: (min, max), by the name the results carry."""
    return {check_name(c): (c.min, c.max) for c in study.base_scenario().checks}


def check_units(study: Study) -> dict[str, str]:
    """The unit of each check's value, by check name: its signal's (rad for an angle check). A
    label's decoration: a scenario that does not load gives none, never a failed report."""
    try:
        sc = study.base_scenario()
        units = {}
        for c in sc.checks:
            inst, var = c.signal.split(".", 1)
            units[check_name(c)] = "rad" if c.angle else sc.instance(inst).variables[var].unit
        return units
    except Exception:
        return {}


def margin(value: float, lo: float | None, hi: float | None) -> float:
    """How far inside its bounds a value is, relative to the bound (negative: outside; -inf: none)."""
    if value is None or not math.isfinite(value):
        return -math.inf
    m = math.inf
    for bound, sign in ((hi, 1.0), (lo, -1.0)):
        if bound is not None:
            m = min(m, sign * (bound - value) / (abs(bound) if bound != 0 else 1.0))
    return m


def _bound_text(lo: float | None, hi: float | None) -> str:
    parts = [f">= {lo:g}" if lo is not None else "", f"<= {hi:g}" if hi is not None else ""]
    return " and ".join(p for p in parts if p)


def _figure(width: float, height: float, nrow: int = 1, ncol: int = 1,
            **share: Any) -> tuple[Any, np.ndarray]:
    """A figure on the Agg canvas, outside pyplot (no global figure list), and its axes grid
    (``sharex``/``sharey`` as ``Figure.subplots`` takes them)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrow, ncol, squeeze=False, **share)


def _margins(fig: Any, left: float, right: float, bottom: float, top: float, wspace: float = 0.2,
             hspace: float = 0.2) -> None:
    """Margins in inches, set directly: the panels are a fixed grid, so tight_layout's measuring
    of every label (most of a figure's drawing time) is not needed."""
    w, h = fig.get_size_inches()
    fig.subplots_adjust(left=min(left / w, 0.6), right=1 - right / w, bottom=min(bottom / h, 0.4),
                        top=max(1 - top / h, 0.5), wspace=wspace, hspace=hspace)


def _wrapped(text: str, width: int, lines: int = 2) -> str:
    """A check's name on up to ``lines`` lines of ``width`` characters (its unit is often at the end:
    cut, the label lost it), with '…' only where even those are not enough."""
    import textwrap

    parts = textwrap.wrap(text, width) or [""]
    if len(parts) > lines:
        parts = parts[:lines]
        parts[-1] = parts[-1][: width - 1] + "…"
    return "\n".join(parts)


def _save(fig: Any, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")


def _numeric(col: Any) -> bool:
    import pandas as pd

    return bool(pd.api.types.is_numeric_dtype(col)) and not bool(pd.api.types.is_bool_dtype(col))


Bounds = dict[str, tuple[float | None, float | None]]


def worst_cases(frame: Any, bounds: Bounds, n: int) -> list[dict[str, Any]]:
    """The n cases closest to (or furthest beyond) a bound; cases that could not run first."""
    out = []
    for _, r in frame.iterrows():
        best = (math.inf, "", math.nan, "")
        if r["status"] == "error":
            best = (-math.inf, "could not run", math.nan, str(r.get("error", "")))
        for name, (lo, hi) in bounds.items():
            col = CHECK + name
            if col not in frame.columns:
                continue
            v = r[col]
            v = float(v) if v is not None and not (isinstance(v, float) and math.isnan(v)) else math.nan
            m = margin(v, lo, hi)
            if m < best[0]:
                best = (m, name, v, _bound_text(lo, hi))
        out.append({"case": int(r["case"]), "status": r["status"], "margin": best[0], "check": best[1],
                    "value": best[2], "bound": best[3], "command": r["command"]})
    out.sort(key=lambda d: (d["margin"], d["case"]))
    return out[:n]


def _plot_pass_rates(rows: list[tuple[str, int, int]], path: Path) -> None:
    fig, axes = _figure(9, 0.45 * len(rows) + 1.2)
    ax = axes[0, 0]
    y = np.arange(len(rows))
    for i, (_, k, n) in enumerate(rows):
        p = k / n if n else math.nan
        lo, hi = wilson(k, n)
        ax.errorbar([100 * p], [i], xerr=[[100 * (p - lo)], [100 * (hi - p)]], fmt="o",
                    color="C2" if k == n else "C3", capsize=3)
    ax.set_yticks(y, [r[0][:70] for r in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(-2, 102)
    ax.set_xlabel(f"pass rate [%] with {CONFIDENCE:.0%} Wilson interval")
    ax.grid(True, axis="x", alpha=0.3)
    _margins(fig, 0.25 + 0.055 * max(len(r[0][:70]) for r in rows), 0.25, 0.55, 0.15)
    _save(fig, path)


def _plot_distributions(frame: Any, cols: list[str], bounds: Bounds, path: Path,
                        units: dict[str, str] | None = None) -> None:
    n = len(cols)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = _figure(4.2 * ncol, 3.0 * nrow + 0.4, nrow, ncol)
    for ax, col in zip(axes.flat, cols, strict=False):
        v = frame[col].astype(float).to_numpy()
        v = v[np.isfinite(v)]
        name = col.split(": ", 1)[1]
        if v.size:  # histogram and ECDF on one axis, both as fractions of the cases
            counts, edges = np.histogram(v, bins=min(30, max(5, v.size // 3)))
            ax.stairs(counts / v.size, edges, fill=True, color="C0", alpha=0.6)  # one patch, not one per bar
            xs = np.sort(v)
            ax.step(xs, np.arange(1, xs.size + 1) / xs.size, where="post", color="k", lw=1)
            ax.set_ylim(0, 1.02)
            ax.set_yticks([0, 0.5, 1])
        ax.locator_params(axis="x", nbins=5)  # few tick labels: text is most of the drawing time
        lo, hi = bounds.get(name, (None, None)) if col.startswith(CHECK) else (None, None)
        for b in (lo, hi):
            if b is not None:
                ax.axvline(b, color="C3", ls="--", lw=1.2)
        ax.set_title(_wrapped(name, 60), fontsize=7)
        unit = (units or {}).get(name)
        if unit:
            ax.set_xlabel(f"[{unit}]", fontsize=7, labelpad=1)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle("distribution of each check value (red: its bound) and metric: fraction of cases per bin "
                 "(bars) and cumulative (line)", fontsize=9)
    _margins(fig, 0.45, 0.2, 0.35, 0.6, wspace=0.25, hspace=0.6)  # two-line titles
    _save(fig, path)


def _positions(col: Any) -> tuple[np.ndarray, list[str] | None]:
    """Numbers as they are; categories as 0..k-1 (with their labels)."""
    if _numeric(col):
        return col.astype(float).to_numpy(), None
    labels = sorted({str(v) for v in col})
    idx = {s: i for i, s in enumerate(labels)}
    return np.array([idx[str(v)] for v in col], dtype=float), labels


def _plot_inputs(frame: Any, inputs: list[str], cols: list[str], bounds: Bounds, path: Path) -> None:
    nrow, ncol = len(cols), len(inputs)
    # A column is one input, a row one check: shared axes, tick labels on the outer panels only
    # (also a third of the figure's drawing time: most of it is tick labels)
    fig, axes = _figure(3.4 * ncol + 0.6, 2.3 * nrow + 0.6, nrow, ncol, sharex="col", sharey="row")
    rng = np.random.default_rng(0)
    for j, inp in enumerate(inputs):
        x, labels = _positions(frame[inp])
        if labels is not None:
            x = x + rng.uniform(-0.15, 0.15, x.size)
        for i, col in enumerate(cols):
            ax = axes[i, j]
            y = frame[col].astype(float).to_numpy()
            name = col.split(": ", 1)[1]
            passed = frame.get(PASS + name)
            if passed is not None:
                ok = passed.fillna(False).to_numpy(dtype=bool)
                ax.scatter(x[ok], y[ok], s=8, color="C2", label="pass")
                ax.scatter(x[~ok], y[~ok], s=10, color="C3", marker="x", label="fail")
                lo, hi = bounds.get(name, (None, None))
                for b in (lo, hi):
                    if b is not None:
                        ax.axhline(b, color="C3", ls="--", lw=0.8)
            else:
                ax.scatter(x, y, s=8, color="C0")
            if labels is not None:
                ax.set_xticks(range(len(labels)), labels, fontsize=6)
            ax.tick_params(labelsize=6)
            if i == nrow - 1:
                ax.set_xlabel(inp, fontsize=7)
            if j == 0:
                ax.set_ylabel(_wrapped(name, 30, 3), fontsize=6)
            ax.label_outer()
    fig.suptitle("each varied input against each check (green pass, red fail) and metric", fontsize=9)
    _margins(fig, 0.75, 0.15, 0.5, 0.5, wspace=0.08, hspace=0.2)
    _save(fig, path)


def _plot_maps(frame: Any, a: str, b: str, cols: list[str], path: Path) -> None:
    """Two grid inputs: the mean of each value over the other inputs and seeds, as a map."""
    n = len(cols)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = _figure(4.4 * ncol, 3.6 * nrow + 0.4, nrow, ncol)
    xs = sorted(frame[a].unique())
    ys = sorted(frame[b].unique())
    for ax, col in zip(axes.flat, cols, strict=False):
        table = frame.pivot_table(index=b, columns=a, values=col, aggfunc="mean")
        z = table.reindex(index=ys, columns=xs).to_numpy(dtype=float)
        im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(xs)), [f"{v:.3g}" for v in xs], fontsize=6)
        ax.set_yticks(range(len(ys)), [f"{v:.3g}" for v in ys], fontsize=6)
        ax.set_xlabel(a, fontsize=7)
        ax.set_ylabel(b, fontsize=7)
        name = col.split(": ", 1)[1]
        passed = PASS + name
        if passed in frame.columns:
            ok = frame.pivot_table(index=b, columns=a, values=passed, aggfunc="mean").reindex(
                index=ys, columns=xs).to_numpy(dtype=float)
            for (r, c), v in np.ndenumerate(ok):
                if np.isfinite(v) and v < 1:
                    ax.text(c, r, "x", ha="center", va="center", color="red", fontsize=8)
        for (r, c), v in np.ndenumerate(z):
            if np.isfinite(v):
                ax.text(c, r - 0.3, f"{v:.3g}", ha="center", va="center", color="w", fontsize=5)
        fig.colorbar(im, ax=ax)
        ax.set_title(_wrapped(name, 60), fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(f"maps over {a} and {b} (x: a failed check)", fontsize=9)
    _margins(fig, 0.6, 0.1, 0.5, 0.6, wspace=0.45, hspace=0.45)
    _save(fig, path)


def spearman_table(frame: Any, inputs: list[str], cols: list[str]) -> list[list[str]]:
    rows = []
    for col in cols:
        cells = [col.split(": ", 1)[1]]
        y = frame[col].astype(float).to_numpy()
        for inp in inputs:
            x = frame[inp].astype(float).to_numpy()
            ok = np.isfinite(x) & np.isfinite(y)
            if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
                cells.append("—")
                continue
            rho, p = spearman(x[ok], y[ok])
            cells.append(f"**{rho:+.2f}**" if p < 0.05 else f"{rho:+.2f}")
        rows.append(cells)
    return rows


def sobol_table(study: Study, frame: Any, cols: list[str]) -> list[list[str]] | None:
    """First-order / total Sobol indices (SALib) per value, when the design is SALib's Saltelli."""
    m = study.model
    if m.sampling.method != "saltelli" or study.design is None or any(
            not study.inputs[n].sampled for n in study.inputs):
        return None
    if m.seeds is not None and not m.pair_seeds:
        return None
    from SALib.analyze import sobol as salib_sobol

    names = study.sampled_names
    problem = {"num_vars": len(names), "names": names, "bounds": [[0.0, 1.0]] * len(names)}
    by_sample = frame.set_index("sample")
    rows = []
    for col in cols:
        if len(by_sample) != len(study.design):
            return None
        y = by_sample[col].reindex(range(len(study.design))).astype(float).to_numpy()
        if not np.all(np.isfinite(y)) or np.ptp(y) == 0:
            rows.append([col.split(": ", 1)[1], *["—"] * len(names)])
            continue
        res = salib_sobol.analyze(problem, y, calc_second_order=False, seed=0)
        rows.append([col.split(": ", 1)[1], *[f"{s1:.2f} / {st:.2f}" for s1, st in zip(res["S1"], res["ST"],
                                                                                       strict=True)]])
    return rows


def _md_table(head: list[str], rows: list[list[str]]) -> list[str]:
    def cell(s: str) -> str:
        return str(s).replace("|", "\\|")

    return ["| " + " | ".join(map(cell, head)) + " |", "|" + "---|" * len(head),
            *("| " + " | ".join(map(cell, r)) + " |" for r in rows)]


def write_study_report(study: Study, outcome: Any, out: Path) -> tuple[Path, list[str]]:
    """report.md and its figures in the study folder; returns its path and the worst-case lines."""
    # Long because the report is one document written top to bottom, section after section.
    from seafmu.sweep.execute import cases_frame

    frame = cases_frame(study, outcome.rows)
    bounds = check_bounds(study)
    lines = [f"# Study {study.name}", "", study.description.strip(), ""]
    n_done, total = len(frame), len(study.cases)
    wall = frame["wall_time_s"].astype(float).to_numpy() if n_done else np.array([math.nan])
    cpu = float(np.nansum(wall))
    median = float(np.nanmedian(wall)) if np.isfinite(wall).any() else math.nan
    lines += ["## Study", "", "| item | value |", "|---|---|",
              f"| study file | `{study.source}` |",
              f"| base scenario | `{study.scenario_arg}` |",
              f"| varied | {', '.join(f'`{n}`' for n in study.inputs) or 'nothing'}"
              f"{'' if study.model.seeds is None else ', seeds'} |",
              f"| sampling | {study.model.sampling.method}, {study.model.sampling.samples} samples |"
              if study.sampled_names else "| sampling | grids and lists only |",
              f"| cases finished | {n_done} of {total}"
              f"{' (**interrupted**: run the sweep again to finish)' if n_done < total else ''} |",
              f"| this run | {outcome.ran} cases on {outcome.workers} workers in {outcome.wall_time:.1f} s"
              f" ({outcome.skipped} finished before) |",
              f"| case wall time | {cpu:.1f} s in total, median {median:.2f} s |", ""]
    if not n_done:
        lines.append("No case has finished yet.")
        path = out / "report.md"
        atomic_write_text(path, "\n".join(lines) + "\n")
        return path, []

    status = frame["status"]
    k = int((status == "pass").sum())
    lo, hi = wilson(k, n_done)
    lines += ["## Pass rate", "",
              f"**{k} of {n_done} cases pass every check: {100 * k / n_done:.1f} % "
              f"({CONFIDENCE:.0%} Wilson interval {100 * lo:.1f}–{100 * hi:.1f} %).** "
              f"{int((status == 'fail').sum())} fail a check, "
              f"{int((status == 'error').sum())} could not run.",
              ""]
    check_cols = [CHECK + n for n in bounds if CHECK + n in frame.columns]
    metric_cols = [c for c in frame.columns if c.startswith(METRIC)]
    rate_rows, table = [("all checks", k, n_done)], []
    units = check_units(study)
    ran = frame[status != "error"]  # a case that could not run to its end evaluated no check
    for col in check_cols:
        name = col[len(CHECK):]
        passed = ran[PASS + name].dropna()
        kk, nn = int(passed.sum()), int(passed.size)
        a, b = wilson(kk, nn)
        v = ran[col].astype(float)
        rate_rows.append((name, kk, nn))
        table.append([name, f"{_bound_text(*bounds[name])} {units.get(name, '')}".strip(), str(nn), str(kk),
                      f"{100 * kk / nn:.1f} %" if nn else "—",
                      f"{100 * a:.1f}–{100 * b:.1f} %" if nn else "—",
                      f"{v.min():.4g}", f"{v.median():.4g}", f"{v.max():.4g}"])
    lines += _md_table(["check", "bound", "evaluated", "pass", "rate", f"{CONFIDENCE:.0%} CI", "min",
                        "median", "max"], table)
    for col in metric_cols:
        v = frame[col].astype(float)
        lines.append(f"\nMetric **{col[len(METRIC):]}**: min {v.min():.4g}, median {v.median():.4g}, "
                     f"max {v.max():.4g} ({int(v.isna().sum())} cases without a value)")
    figures: list[tuple[str, str]] = []
    _plot_pass_rates(rate_rows, out / "pass_rates.png")
    figures.append(("Pass rates", "pass_rates.png"))
    value_cols = check_cols + metric_cols
    if value_cols:
        _plot_distributions(frame, value_cols, bounds, out / "distributions.png", units)
        figures.append(("Distribution of every check value against its bound", "distributions.png"))
    inputs = [n for n in study.inputs if n in frame.columns and frame[n].nunique() > 1]
    if inputs and value_cols and len(inputs) * len(value_cols) <= MAX_SCATTER_PANELS:
        _plot_inputs(frame, inputs, value_cols, bounds, out / "inputs_vs_checks.png")
        figures.append(("Each varied input against each check", "inputs_vs_checks.png"))
    grids = [n for n in inputs if not study.inputs[n].sampled and _numeric(frame[n])]
    if len(grids) == 2 and len(inputs) == 2 and value_cols:
        _plot_maps(frame, grids[0], grids[1], value_cols, out / "maps.png")
        figures.append((f"Maps over {grids[0]} and {grids[1]}", "maps.png"))
    lines += ["", "## Figures", ""]
    for title, name in figures:
        lines += [f"### {title}", "", f"![{title}]({name})", ""]

    lines += ["## Sensitivity", ""]
    numeric_inputs = [n for n in inputs if _numeric(frame[n])]
    if numeric_inputs and value_cols:
        lines += ["Spearman rank correlation of each check value with each numeric input over the finished "
                  "cases (bold: p < 0.05).", ""]
        lines += _md_table(["value", *numeric_inputs], spearman_table(frame, numeric_inputs, value_cols))
    else:
        lines.append("No numeric input varies: no rank correlation.")
    left_out = [n for n in inputs if n not in numeric_inputs]
    if left_out:
        lines += ["", f"Categorical inputs ({', '.join(left_out)}): see the figure of inputs against checks."]
    sob = sobol_table(study, frame, value_cols) if value_cols and n_done == total else None
    if sob:
        lines += ["", "Sobol indices (SALib, first order / total), from the Saltelli design:", ""]
        lines += _md_table(["value", *study.sampled_names], sob)
    lines.append("")

    worst = worst_cases(frame, bounds, study.model.worst)
    worst_lines = []
    if worst:
        lines += ["## Worst cases", "", "Closest to or furthest beyond a bound (margin relative to the "
                  "bound; cases that could not run first). Each command reproduces its case exactly.", ""]
        rows = []
        for w in worst:
            value = "—" if not math.isfinite(w["value"]) else f"{w['value']:.4g}"
            rows.append([str(w["case"]), w["status"], w["check"], value, w["bound"][:160],
                         "—" if not math.isfinite(w["margin"]) else f"{100 * w['margin']:+.1f} %"])
            why = (f"could not run: {w['bound'][:160]}" if w["status"] == "error"
                   else f"{w['status']}; {w['check']}: {value}, bound {w['bound']}")
            worst_lines.append(f"case {w['case']} ({why}): {w['command']}")
        lines += _md_table(["case", "status", "worst check", "value", "bound", "margin"], rows)
        lines += ["", "```bash", *(w["command"] for w in worst), "```", ""]
    errors = frame[frame["status"] == "error"]
    if len(errors):
        lines += ["## Cases that could not run", ""]
        lines += _md_table(["case", "error"], [[str(int(r["case"])), str(r["error"])[:300]]
                                               for _, r in errors.head(20).iterrows()])
        if len(errors) > 20:
            lines.append(f"\n… and {len(errors) - 20} more (cases.parquet, column `error`).")
        lines.append("")
    lines += ["## Files", "", "- `cases.parquet`: one row per case: inputs, seed, each check's value "
              "(`check: NAME`) and result (`pass: NAME`), metrics, wall time, status, error, command",
              "- `cases/`: the row of each finished case (a rerun skips them)",
              *(["- `timeseries/<key>.parquet`: the kept signals of each case (column `timeseries`)"]
                if study.model.keep else []),
              "- `study.yaml`: the study as run", ""]
    path = out / "report.md"
    atomic_write_text(path, "\n".join(lines))
    return path, worst_lines

"""Table (and figure) of the thesis's allocation benchmark: a pure sway force ramped past saturation.

Runs the shipped scenario ``minerva2_allocation_sway_ramp`` (five allocator FMUs, one per variant,
fed the same staircase tau_Y = 10, 20, ... 800 N) and prints per variant:

- saturation onset: the first stair with allocation error > 1e-6 (from the FMU run), and the exact
  onset found by bisection on the same allocator in-process (no stair resolution);
- the thesis's indicator, the sum of the negative thrust of thrusters 1 and 2, and the energy
  sum(T_i^2), each summed over the stairs up to 320 N (every variant unsaturated there, so the
  sums compare the allocation laws, not their saturation) and over the whole ramp;
- the allocation error at the last stair (800 N).

    python benchmarks/allocation_sway_ramp_table.py [--inprocess] [--plot sway_ramp.png] [--markdown]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from seafmu.components.allocation import METHODS, AllocatorBlock
from seafmu.components.block import full_params
from seafmu.components.vessel_spec import load_vessel
from seafmu.master import RunResult, run
from seafmu.scenario import Scenario, load_scenario

SCENARIO = "minerva2_allocation_sway_ramp"
COMMON = 320.0  # N: the last stair where every variant is still unsaturated
TOL = 1e-6


def exact_onset(sc: Scenario, name: str, hi: float = 2000.0) -> float:
    """Smallest pure sway force (N) with allocation error > TOL, by bisection (0.01 N)."""
    vessel = load_vessel(sc.vessel)
    params = full_params(AllocatorBlock.interface(vessel), sc.instance(name).parameters)
    block = AllocatorBlock(vessel, params)
    k = 2 * vessel.thrusters.count + vessel.dof  # alloc_error

    def error(y: float) -> float:
        return float(block.step(0.0, sc.step, np.array([0.0, y, 0, 0, 0, 0]))[k])

    lo = 0.0
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if error(mid) <= TOL else (lo, mid)
    return hi


def table(result: RunResult) -> list[dict[str, object]]:
    sc = result.scenario
    rows = []
    for inst in sc.instances:
        s = result.signals
        n = inst.name
        tau = s[f"{n}.tau_Y"][1:]  # row 0 holds the initial outputs, before the first stair
        err = s[f"{n}.alloc_error"][1:]
        neg = s[f"{n}.front_negative_thrust"][1:]
        energy = s[f"{n}.thrust_energy"][1:]
        common = tau <= COMMON + 1e-9
        sat = np.flatnonzero(err > TOL)
        p = inst.parameters
        variant = METHODS[int(p.get("method", 0))]
        if int(p.get("enable_1", 1)) == 0:
            variant += ", thruster 1 dropped"
        rows.append({
            "variant": n, "method": variant,
            "onset_stair": float(tau[sat[0]]) if sat.size else float("nan"),
            "onset_exact": exact_onset(sc, n),
            "indicator_common": float(neg[common].sum()), "energy_common": float(energy[common].sum()),
            "indicator_all": float(neg.sum()), "energy_all": float(energy.sum()),
            "error_last": float(err[-1]),
        })
    return rows


def print_table(rows: list[dict[str, object]], markdown: bool) -> None:
    head = ["variant", "method", "saturation onset, stair (N)", "exact onset (N)",
            f"indicator up to {COMMON:g} N (N)", f"energy up to {COMMON:g} N (N^2)",
            "indicator, whole ramp (N)", "energy, whole ramp (N^2)", "alloc. error at 800 N"]
    fmt = ["{}", "{}", "{:.0f}", "{:.2f}", "{:.1f}", "{:.4g}", "{:.1f}", "{:.4g}", "{:.1f}"]
    keys = ["variant", "method", "onset_stair", "onset_exact", "indicator_common", "energy_common",
            "indicator_all", "energy_all", "error_last"]
    cells = [[f.format(r[k]) for f, k in zip(fmt, keys, strict=True)] for r in rows]
    if markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for c in cells:
            print("| " + " | ".join(c) + " |")
        return
    widths = [max(len(h), *(len(c[j]) for c in cells)) for j, h in enumerate(head)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)))
    for c in cells:
        print("  ".join(x.ljust(w) for x, w in zip(c, widths, strict=True)))


def plot(result: RunResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result.signals
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for inst in result.scenario.instances:
        n = inst.name
        tau = s[f"{n}.tau_Y"][1:]
        # QP variants dashed: they lie on their pseudo-inverse twins until saturation
        qp = int(inst.parameters.get("method", 0)) in (1, 3)
        kw = {"where": "post", "label": n, "ls": "--" if qp else "-"}
        axes[0].step(tau, s[f"{n}.alloc_error"][1:], **kw)
        axes[1].step(tau, s[f"{n}.front_negative_thrust"][1:], **kw)
        axes[2].step(tau, s[f"{n}.thrust_energy"][1:] / 1e3, **kw)
    axes[0].set_ylabel("allocation error ‖BT − τ‖")
    axes[1].set_ylabel("negative thrust of\nthrusters 1, 2 (N)")
    axes[2].set_ylabel("energy Σ T² (10³ N²)")
    axes[2].set_xlabel("demanded sway force τ_Y (N)")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title("Minerva 2: pure sway force ramped past saturation")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--inprocess", action="store_true", help="run the allocators without FMI")
    ap.add_argument("--plot", type=Path, help="write the figure (PNG) here")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = ap.parse_args()
    sc = load_scenario(SCENARIO)
    result = run(sc, mode="inprocess" if args.inprocess else "fmu", progress=False)
    print_table(table(result), args.markdown)
    if args.plot:
        plot(result, args.plot)
        print(f"figure: {args.plot}")


if __name__ == "__main__":
    main()

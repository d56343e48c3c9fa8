"""Benchmark: how maneuver-identification errors grow with sensor noise, LS against output error.

Data: seafmu's plant (PlantBlock, no noise) driven by the multisine excitation of
``simulate_maneuver`` (200 s, 100 Hz log), then white noise of ``level`` x the vessel file's sensor
noise std on every sample of eta and nu (Minerva 2: DVL 0.01 m/s, gyro 0.002 rad/s, AHRS
0.2/0.2/0.5 deg); tau stays exact. Errors are the thesis's measure: diagonal error in % of the
matrix's largest element (max over the 6 DOFs, averaged over noise seeds). Also: noise-free LS
error against the log's sample interval (differentiation error grows as dt^2).

    python benchmarks/bench_maneuver_noise.py [--vessel minerva2_published_damping]
        [--levels 0 0.1 0.3 1 3] [--seeds 2] [--duration 200]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from seafmu.components.vessel_spec import load_vessel
from seafmu.identification.fitting import FitResult
from seafmu.identification.maneuver import (
    add_sensor_noise,
    identify_maneuver,
    plant_matrices,
    simulate_maneuver,
)


def errors(fit: FitResult, truth: dict[str, np.ndarray], key: str) -> np.ndarray | None:
    d = truth[key].shape[0]
    names = [f"{key}[{i},{i}]" for i in range(d)]
    if not all(n in fit.params for n in names):
        return None
    est = np.array([fit.params[n] for n in names])
    return 100.0 * (est - np.diag(truth[key])) / np.max(np.abs(truth[key]))


def covered(fit: FitResult, truth: dict[str, np.ndarray], key: str) -> int:
    d = truth[key].shape[0]
    return sum(fit.ci95[f"{key}[{i},{i}]"][0] <= truth[key][i, i] <= fit.ci95[f"{key}[{i},{i}]"][1]
               for i in range(d))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vessel", default="minerva2_published_damping")
    ap.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.1, 0.3, 1.0, 3.0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--duration", type=float, default=200.0)
    args = ap.parse_args()
    vessel = load_vessel(args.vessel)
    truth = plant_matrices(vessel)
    t0 = time.perf_counter()
    clean, _ = simulate_maneuver(vessel, duration=args.duration, dt=0.01, seed=0)
    print(f"vessel {args.vessel}: {args.duration:g} s multisine trial at 100 Hz "
          f"(generated in {time.perf_counter() - t0:.1f} s); {args.seeds} noise seed(s) per level\n")

    methods = {
        "LS": {"method": "ls"},
        "OE": {"method": "output_error"},
        "OE+M": {"method": "output_error", "oe_added_mass": True},
    }
    print("| noise x | method | M diag max err % | D_L diag max err % | D_Q diag max err % | "
          "D_Q CI covers (of 6) | NRMSE fit | NRMSE held-out | smoothing | s/fit |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    per_dof: dict[str, list[np.ndarray]] = {}
    for level in args.levels:
        acc: dict[str, dict[str, list]] = {m: {} for m in methods}
        for seed in range(args.seeds if level > 0 else 1):
            data = add_sensor_noise(clean, vessel, level, seed=seed + 1) if level > 0 else clean
            for name, kw in methods.items():
                t1 = time.perf_counter()
                fit = identify_maneuver(data, vessel, **kw)
                a = acc[name]
                a.setdefault("time", []).append(time.perf_counter() - t1)
                for key in ("M", "D_L", "D_Q"):
                    e = errors(fit, truth, key)
                    if e is not None:
                        a.setdefault(key, []).append(np.max(np.abs(e)))
                        if key == "D_Q" and level == 1.0:
                            per_dof.setdefault(name, []).append(e)
                a.setdefault("cov", []).append(covered(fit, truth, "D_Q"))
                a.setdefault("fit", []).append(fit.nrmse_fit)
                a.setdefault("val", []).append(fit.nrmse_validation)
                a.setdefault("sm", []).append(fit.extras.get("smoothing_s"))
        for name, a in acc.items():
            def col(k: str, a: dict = a) -> str:
                return f"{np.mean(a[k]):.3g}" if k in a else "(vessel file)"
            sm = {("none" if s is None else f"{s:g} s") for s in a["sm"]}
            print(f"| {level:g} | {name} | {col('M')} | {col('D_L')} | {col('D_Q')} | "
                  f"{np.mean(a['cov']):.1f} | {np.mean(a['fit']):.4f} | {np.mean(a['val']):.4f} | "
                  f"{', '.join(sorted(sm))} | {np.mean(a['time']):.1f} |")

    if per_dof:
        print("\nD_Q diagonal errors per DOF at noise x1 (% of the largest element; mean over seeds; "
              "the thesis's HIL figures were 6.6/5.0/-0.18/-2.7/-0.04/-0.36):")
        for name, es in per_dof.items():
            print(f"  {name:5s} " + "  ".join(f"{x:+.2f}" for x in np.mean(es, axis=0)))

    print("\nnoise-free LS against the log's sample interval (max diagonal error, % of largest element):")
    print("| dt s | M | D_L | D_Q |")
    print("|---|---|---|---|")
    for dt in (0.01, 0.02, 0.05, 0.1):
        data, _ = simulate_maneuver(vessel, duration=args.duration, dt=dt, seed=0)
        fit = identify_maneuver(data, vessel)
        cells = [f"{np.max(np.abs(errors(fit, truth, k))):.3g}" for k in ("M", "D_L", "D_Q")]
        print(f"| {dt:g} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()

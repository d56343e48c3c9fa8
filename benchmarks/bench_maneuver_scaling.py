"""Benchmark: time and peak memory of maneuver identification against the log length.

One long AMV OSF maneuver log is made by seafmu's own plant (``simulate_maneuver``: multisine
excitation, 0.1 s sampling, the vessel file's sensor noise x1), and its first 10k / 30k / 100k rows
are identified the way ``seafmu identify LOG.csv --vessel amv_osf`` does it: CSV read, LS baseline
(smoothing window chosen on the noisy log) and the output-error fit beside it (no report figures).
Each size runs in a fresh process, so the peak resident memory (``ru_maxrss``) is that size's own;
the growth exponent is the slope of log(time) and log(peak memory above the interpreter's) against
log(rows) between consecutive sizes and over the whole range (1 = linear, 2 = quadratic).

    python benchmarks/bench_maneuver_scaling.py [--rows 10000 30000 100000] [--vessel amv_osf]
                                                [--dt 0.1] [--noise 1.0] [--method both|ls|output_error]

Goal (issue 8): 100 000 rows in under 60 s and under 2 GB on the 2-core machine.

Issue 13 (compiled simulator): each size also runs with the former NumPy simulator swapped in
(``--numpy-sim`` in the child: the batched RK4 of before, NumPy calls on (K, S, ...) arrays per
step), interleaved with the compiled one, each child fitting ``--repeat`` times; the table gives the
first fit (compiled: includes loading the cached kernels) and the best, and the ratio of the best
output-error fits NumPy / compiled. That swap keeps today's optimiser, LS and BLAS settings, so it
isolates the simulator. The goal ("a 10 000-sample output-error fit at least 5x faster than today")
is measured against the code as it was: ``--reference COMMIT`` (default: the last commit before the
simulator was compiled) is exported with ``git archive`` and the same log fitted by it in a child
(its package first on PYTHONPATH), as it shipped (BLAS threads as the library sets them) and with
single-threaded BLAS (``OPENBLAS_NUM_THREADS=1``, as today's fit runs: the ratio of the code alone).
``--no-compare`` skips both comparisons.
"""

from __future__ import annotations

import argparse
import io
import itertools
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path


def _rss_mb() -> float:
    """Peak resident memory of this process so far, MB.

    /proc's VmHWM belongs to the process image (reset by exec); ru_maxrss would also count the
    parent's memory at fork time, here the plant-made log.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def child(path: str, vessel_name: str, method: str, repeat: int = 1, numpy_sim: bool = False) -> None:
    """Identify one log in this (fresh) process; print one JSON line with the figures."""
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.identification.maneuver import identify_maneuver, load_maneuver_csv

    if numpy_sim:
        from seafmu.components.kernels import maneuver as kernel

        kernel.simulate = kernel.simulate_numpy
    vessel = load_vessel(vessel_name)
    base_mb = _rss_mb()  # interpreter, numpy, scipy, the vessel: not the log's
    t0 = time.perf_counter()
    data = load_maneuver_csv(Path(path), vessel)
    t_load = time.perf_counter() - t0
    out: dict[str, float | int | str] = {"rows": data.n, "load_s": t_load, "base_mb": base_mb}
    methods = ("ls", "output_error") if method == "both" else (method,)
    for m in methods:
        times = []
        for _ in range(max(1, repeat)):
            t1 = time.perf_counter()
            fit = identify_maneuver(data, vessel, method=m)
            times.append(time.perf_counter() - t1)
        out[f"{m}_s"] = times[0]
        out[f"{m}_best_s"] = min(times)
        out[f"{m}_nrmse_val"] = fit.nrmse_validation
    out["seconds"] = time.perf_counter() - t0
    out["peak_mb"] = _rss_mb()
    print(json.dumps(out))


def make_log(rows: int, vessel_name: str, dt: float, noise: float, folder: Path) -> Path:
    """The plant-made log (max rows) as a CSV in the folder."""
    from seafmu.components.vessel_spec import load_vessel
    from seafmu.identification.maneuver import add_sensor_noise, simulate_maneuver, write_maneuver_csv

    vessel = load_vessel(vessel_name)
    data, _ = simulate_maneuver(vessel, duration=(rows - 1) * dt, dt=dt, seed=1)
    if noise > 0:
        data = add_sensor_noise(data, vessel, noise, seed=0)
    return write_maneuver_csv(data, folder / f"{vessel_name}_{rows}.csv")


def prefix(src: Path, rows: int, dst: Path) -> Path:
    """The first ``rows`` data rows of a maneuver CSV (comment and header lines kept)."""
    with open(src) as fin, open(dst, "w") as fout:
        kept = 0
        for line in fin:
            if not (line[:1].isdigit() or line[:1] == "-"):  # comment and header lines
                fout.write(line)
                continue
            if kept == rows:
                break
            fout.write(line)
            kept += 1
    return dst


# The last commit whose output-error fit ran the NumPy simulator: issue 13's "today".
REFERENCE = "c9989e6^"


def reference_tree(commit: str, folder: Path) -> Path | None:
    """``commit``'s seafmu/ and components/ exported into ``folder`` (git archive) and laid out as
    installed (components/ as seafmu.components); None (and why, printed) when that fails."""
    root = Path(__file__).resolve().parent.parent
    try:
        tar = subprocess.run(["git", "-C", str(root), "archive", commit, "seafmu", "components"],
                             capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"# reference {commit}: cannot export it ({exc}); comparison skipped")
        return None
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(folder, filter="data")
    (folder / "seafmu" / "components").symlink_to(folder / "components", target_is_directory=True)
    return folder


def _child(path: Path, vessel: str, repeat: int, numpy_sim: bool = False,
           env: dict[str, str] | None = None) -> dict:
    cmd = [sys.executable, __file__, "--child", str(path), vessel, "--method", "output_error",
           "--repeat", str(repeat)] + (["--numpy-sim"] if numpy_sim else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _compare_reference(path: Path, vessel: str, repeat: int, ref: Path) -> dict[str, dict]:
    """Best output-error fits by the reference commit (as shipped; single-threaded BLAS) and by this
    code, children interleaved twice."""
    envs = {"reference": {**os.environ, "PYTHONPATH": str(ref)},
            "reference_1blas": {**os.environ, "PYTHONPATH": str(ref), "OPENBLAS_NUM_THREADS": "1",
                                "OMP_NUM_THREADS": "1"},
            "compiled": None}
    best: dict[str, dict] = {}
    for _ in range(2):
        for name, env in envs.items():
            r = _child(path, vessel, repeat, env=env)
            if name not in best or r["output_error_best_s"] < best[name]["output_error_best_s"]:
                best[name] = r
    return best


def _compare(path: Path, vessel: str, repeat: int) -> tuple[dict, dict]:
    """Best output-error fits with the NumPy and the compiled simulator, children interleaved twice."""
    best: dict[bool, dict] = {}
    for _ in range(2):
        for numpy_sim in (True, False):
            cmd = [sys.executable, __file__, "--child", str(path), vessel, "--method", "output_error",
                   "--repeat", str(repeat)] + (["--numpy-sim"] if numpy_sim else [])
            proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            if numpy_sim not in best or r["output_error_best_s"] < best[numpy_sim]["output_error_best_s"]:
                best[numpy_sim] = r
    return best[True], best[False]


def slope(x0: float, y0: float, x1: float, y1: float) -> float:
    return math.log(y1 / y0) / math.log(x1 / x0) if y0 > 0 and y1 > 0 else math.nan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, nargs="+", default=[10_000, 30_000, 100_000])
    ap.add_argument("--vessel", default="amv_osf")
    ap.add_argument("--dt", type=float, default=0.1, help="sample interval of the log, s")
    ap.add_argument("--noise", type=float, default=1.0, help="x the vessel file's sensor noise")
    ap.add_argument("--method", choices=("both", "ls", "output_error"), default="both")
    ap.add_argument("--repeat", type=int, default=3, help="fits per child for the comparison (best counts)")
    ap.add_argument("--no-compare", action="store_true", help="skip the NumPy-simulator comparison")
    ap.add_argument("--reference", default=REFERENCE,
                    help="the commit whose fit is 'today' (issue 13; default: before the compiled simulator)")
    ap.add_argument("--numpy-sim", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--child", nargs=2, metavar=("CSV", "VESSEL"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child[0], args.child[1], args.method, args.repeat, args.numpy_sim)
        return
    print(f"# {platform.processor() or platform.machine()}, Python {platform.python_version()}; "
          f"{args.vessel}, dt {args.dt:g} s, sensor noise x{args.noise:g}, method {args.method}")
    sizes = sorted(args.rows)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t0 = time.perf_counter()
        full = make_log(sizes[-1], args.vessel, args.dt, args.noise, folder)
        print(f"# log of {sizes[-1]} rows made by the plant in {time.perf_counter() - t0:.1f} s")
        results = []
        compare = []
        against = []
        ref = None if args.no_compare else reference_tree(args.reference, folder / "reference")
        for n in sizes:
            path = prefix(full, n, folder / f"log_{n}.csv")
            proc = subprocess.run([sys.executable, __file__, "--child", str(path), args.vessel,
                                   "--method", args.method], capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                print(f"{n:>8} rows: failed (exit {proc.returncode}): {proc.stderr.strip()[-300:]}")
                continue
            results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
            if not args.no_compare:
                compare.append((n, _compare(path, args.vessel, args.repeat)))
                if ref is not None:
                    against.append((n, _compare_reference(path, args.vessel, args.repeat, ref)))
    print("|   rows | total s | load s | LS s | OE s | peak MB | above interpreter MB | "
          "held-out NRMSE LS / OE |")
    print("|---:|---:|---:|---:|---:|---:|---:|---|")
    for r in results:
        print(f"| {r['rows']:>6} | {r['seconds']:7.2f} | {r['load_s']:6.2f} | "
              f"{r.get('ls_s', math.nan):5.2f} | {r.get('output_error_s', math.nan):5.2f} | "
              f"{r['peak_mb']:7.0f} | "
              f"{r['peak_mb'] - r['base_mb']:7.0f} | {r.get('ls_nrmse_val', math.nan):.3g} / "
              f"{r.get('output_error_nrmse_val', math.nan):.3g} |")
    if compare:
        print("compiled simulator vs the former NumPy simulator (output-error fit, interleaved runs, "
              f"{args.repeat} fits per run):")
        print("|   rows | NumPy first / best s | compiled first / best s | ratio (best) | "
              "held-out NRMSE NumPy / compiled |")
        print("|---:|---:|---:|---:|---|")
        for n, (a, b) in compare:
            ratio = a["output_error_best_s"] / b["output_error_best_s"]
            print(f"| {n:>6} | {a['output_error_s']:.2f} / {a['output_error_best_s']:.2f} | "
                  f"{b['output_error_s']:.2f} / {b['output_error_best_s']:.2f} | **{ratio:.1f}** | "
                  f"{a['output_error_nrmse_val']:.6g} / {b['output_error_nrmse_val']:.6g} |")
            met = "met" if ratio >= 5 else "NOT met"
            print(f"goal (issue 13) ratio >= 5 at {n} rows: {met} ({ratio:.1f})")
    if against:
        print(f"this code vs the fit of {args.reference} (before the compiled simulator), interleaved runs, "
              f"{args.repeat} fits per run, best of each:")
        print("|   rows | reference as shipped s | reference, 1 BLAS thread s | now s | ratio (shipped) | "
              "ratio (1 BLAS thread) | held-out NRMSE reference / now |")
        print("|---:|---:|---:|---:|---:|---:|---|")
        for n, b in against:
            a, a1, c = b["reference"], b["reference_1blas"], b["compiled"]
            r, r1 = a["output_error_best_s"] / c["output_error_best_s"], a1["output_error_best_s"] / c[
                "output_error_best_s"]
            print(f"| {n:>6} | {a['output_error_best_s']:.3f} | {a1['output_error_best_s']:.3f} | "
                  f"{c['output_error_best_s']:.3f} | **{r:.1f}** | **{r1:.1f}** | "
                  f"{a['output_error_nrmse_val']:.6g} / {c['output_error_nrmse_val']:.6g} |")
            print(f"goal (issue 13) >= 5x faster than {args.reference} at {n} rows: "
                  f"{'met' if min(r, r1) >= 5 else 'met as shipped only' if r >= 5 else 'NOT met'} "
                  f"(as shipped {r:.1f}, single-threaded BLAS both {r1:.1f})")
    if len(results) >= 2:
        print("growth exponent (d log y / d log rows; 1 = linear, 2 = quadratic):")
        pairs = list(itertools.pairwise(results))
        if len(results) > 2:
            pairs.append((results[0], results[-1]))
        for a, b in pairs:
            mem = slope(a["rows"], a["peak_mb"] - a["base_mb"], b["rows"], b["peak_mb"] - b["base_mb"])
            tim = slope(a["rows"], a["seconds"], b["rows"], b["seconds"])
            print(f"  {a['rows']:>6} -> {b['rows']:>6} rows: time {tim:.2f}, memory {mem:.2f}")


if __name__ == "__main__":
    main()

"""Benchmark: per-block step cost of the components of another commit against this working tree.

The four blocks of minerva2_dp (plant in a 0.1 m/s current, observer, DP controller with a 1 m
north / 2 m down setpoint, allocator) are wired by name and stepped in-process, the same loop for
both versions, in alternating rounds; the figure per block is the best round's CPU time of this
thread per step (``time.thread_time``), which other processes on a shared machine disturb far
less than wall time. Also says whether both versions end in bit-identical plant outputs.

    python benchmarks/bench_blocks_ab.py [--base adffa6b] [--rounds 10] [--steps 3000]
"""

from __future__ import annotations

import argparse
import importlib
import io
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
BLOCKS = ("plant", "observer", "controller", "allocator")


def _package(root: Path, name: str, tree: Path | None, rev: str | None) -> None:
    """components/ of ``rev`` (git archive) or of the working tree, as package ``name`` in root."""
    dest = root / name
    if rev is not None:
        data = subprocess.run(["git", "archive", rev, "components"], cwd=REPO, check=True,
                              capture_output=True).stdout
        with tarfile.open(fileobj=io.BytesIO(data)) as tar:
            tar.extractall(root / "_x", filter="data")
        shutil.move(root / "_x" / "components", dest)
    else:
        assert tree is not None
        shutil.copytree(tree, dest, ignore=shutil.ignore_patterns("__pycache__"))
    (dest / "__init__.py").touch()


def _mod(pkg: str, name: str) -> ModuleType:
    return importlib.import_module(f"{pkg}.{name}")


def run(pkg: str, steps: int, h: float = 0.05) -> tuple[dict[str, float], np.ndarray]:
    """CPU microseconds per step of each block, and the plant's last outputs."""
    vessel = _mod(pkg, "vessel_spec").load_vessel("minerva2")
    full = _mod(pkg, "block").full_params
    classes = {"plant": _mod(pkg, "plant").PlantBlock, "observer": _mod(pkg, "observer").ObserverBlock,
               "controller": _mod(pkg, "controller").ControllerBlock,
               "allocator": _mod(pkg, "allocation").AllocatorBlock}
    given: dict[str, dict[str, Any]] = {"plant": {"current_speed": 0.1, "current_direction": 0.5}}
    blocks = {k: c(vessel, full(c.interface(vessel), given.get(k, {}))) for k, c in classes.items()}
    names = {k: (c.interface(vessel).input_names(), c.interface(vessel).output_names())
             for k, c in classes.items()}

    def wire(src: str, dst: str) -> tuple[np.ndarray, np.ndarray]:
        ins, outs = names[dst][0], names[src][1]
        pairs = [(ins.index(n), outs.index(n)) for n in ins if n in outs]
        return np.array([d for d, _ in pairs], dtype=int), np.array([s for _, s in pairs], dtype=int)

    o_p, o_a, c_o, a_c, p_a = (wire("plant", "observer"), wire("allocator", "observer"),
                               wire("observer", "controller"), wire("controller", "allocator"),
                               wire("allocator", "plant"))
    u = {k: np.zeros(len(names[k][0])) for k in BLOCKS}
    ci = names["controller"][0]
    u["controller"][ci.index("north_ref")], u["controller"][ci.index("down_ref")] = 1.0, 2.0
    y = {"plant": blocks["plant"].output(), "allocator": blocks["allocator"].output()}
    u["observer"][o_p[0]], u["observer"][o_a[0]] = y["plant"][o_p[1]], y["allocator"][o_a[1]]
    y["observer"] = blocks["observer"].start(u["observer"])
    u["controller"][c_o[0]] = y["observer"][c_o[1]]
    blocks["controller"].start(u["controller"])
    cost = dict.fromkeys(BLOCKS, 0.0)
    clock = time.thread_time
    feeds = {  # what each block reads from the others' newest outputs before its step
        "plant": ((p_a, "allocator"),),
        "observer": ((o_p, "plant"), (o_a, "allocator")),
        "controller": ((c_o, "observer"),),
        "allocator": ((a_c, "controller"),),
    }
    for k in range(steps):
        for name in BLOCKS:
            for (dst, src), frm in feeds[name]:
                u[name][dst] = y[frm][src]
            t0 = clock()
            y[name] = blocks[name].step(k * h, h, u[name])
            cost[name] += clock() - t0
    return {k: 1e6 * v / steps for k, v in cost.items()}, y["plant"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="adffa6b", help="git revision to compare with (default adffa6b)")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=3000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="seafmu_ab_") as tmp:
        root = Path(tmp)
        _package(root, "ab_base", None, args.base)
        _package(root, "ab_work", REPO / "components", None)
        sys.path.insert(0, str(root))
        best: dict[str, dict[str, float]] = {"ab_base": {}, "ab_work": {}}
        last: dict[str, np.ndarray] = {}
        for r in range(args.rounds):
            for pkg in ("ab_base", "ab_work") if r % 2 == 0 else ("ab_work", "ab_base"):
                cost, last[pkg] = run(pkg, args.steps)
                for k, v in cost.items():
                    best[pkg][k] = min(best[pkg].get(k, np.inf), v)
    print(f"minerva2 blocks in-process, {args.steps} steps of 0.05 s, best of {args.rounds} rounds, "
          "CPU time of this thread")
    print(f"same final plant outputs: {np.array_equal(last['ab_base'], last['ab_work'])}")
    print(f"{'block':<12}{args.base + ' [us/step]':>22}{'working tree [us/step]':>24}{'change':>9}")
    for k in BLOCKS:
        b, w = best["ab_base"][k], best["ab_work"][k]
        print(f"{k:<12}{b:>22.1f}{w:>24.1f}{100 * (w / b - 1):>8.1f}%")
    tb, tw = sum(best["ab_base"].values()), sum(best["ab_work"].values())
    print(f"{'sum':<12}{tb:>22.1f}{tw:>24.1f}{100 * (tw / tb - 1):>8.1f}%")


if __name__ == "__main__":
    main()

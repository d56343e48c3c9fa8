"""The figures of a run's report (PNG): trajectory, states vs references, thruster use, allocation.

Drawing them costs about a second, half of it importing matplotlib. ``Plotter`` starts a worker
process (``python -m seafmu.plots``) when the run starts: it imports matplotlib and loads its
fonts while the FMUs load and simulate, then draws the figures from the recorded signals it is
sent, shared with forks of itself (one per core). ``Plotter.draw`` returns only when every
figure is written (or has failed), so the report written after it never names a figure that is
not there; if the worker cannot start or dies, the figures are drawn in this process instead,
with the same code (tests/test_startup.py: the same pixels either way).

This module imports only the standard library, NumPy and (when drawing) matplotlib, so the worker
starts without seafmu's scenario or simulation code. Lines of more samples than four per pixel
column are reduced to each column's first, lowest, highest and last sample (M4 aggregation: in
every pixel column the line covers the same rows; only antialiasing inside it may differ).
"""

from __future__ import annotations

import contextlib
import json
import pickle
import signal
import subprocess
import sys
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.cores import core_count  # standard library only, as the next: the worker stays light
from seafmu.outdir import atomic_path  # standard library only: the worker stays light

DPI = 110
ANGLES = {"roll", "pitch", "yaw"}
ETA = ("north", "east", "down", "roll", "pitch", "yaw")
REPLY_TIMEOUT_S = 600.0  # a worker that has not answered by then is stopped; this process draws


@dataclass
class Series:
    """What the figures read: the scenario's name (titles), the time and the recorded signals."""

    name: str
    time: np.ndarray
    signals: dict[str, np.ndarray]

    def find(self, var: str) -> str | None:
        """The first recorded 'instance.var' with this variable name."""
        return next((k for k in self.signals if k.split(".", 1)[1] == var), None)


def _figure(width: float, height: float) -> Any:
    """A figure on the Agg canvas, outside pyplot: no global figure list, nothing to close."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: Path) -> None:
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png")


def m4(t: np.ndarray, y: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """The samples a line of ``columns`` pixel columns needs: per column (equal spans of t), the
    first, lowest, highest and last sample, in time order. Unchanged when that is not fewer.
    Non-finite samples are kept (they break the line where they are)."""
    n = len(t)
    if columns < 1 or n <= 4 * columns or n < 2 or not (np.isfinite(t[0]) and np.isfinite(t[-1])):
        return t, y
    col = np.minimum(((t - t[0]) / max(t[-1] - t[0], 1e-300) * columns).astype(np.int64), columns - 1)
    starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    ends = np.r_[starts[1:], n]
    keep = np.zeros(n, dtype=bool)
    keep[starts] = True
    keep[ends - 1] = True
    finite = np.isfinite(y)
    keep[~finite] = True
    big = np.where(finite, y, -np.inf)
    small = np.where(finite, y, np.inf)
    seg = np.repeat(np.arange(len(starts)), ends - starts)
    order_hi = np.lexsort((-big, seg))  # per column, the highest first
    order_lo = np.lexsort((small, seg))  # per column, the lowest first
    keep[order_hi[starts]] = True
    keep[order_lo[starts]] = True
    return t[keep], y[keep]


def _columns(fig: Any) -> int:
    """Pixel columns at least as many as any axes of the figure has (the figure's width): each
    M4 column then spans at most one pixel column, wherever the layout puts the axes."""
    return max(int(np.ceil(fig.get_figwidth() * DPI)), 1)


# (variable suffix or prefix, legend label, line style) of a state's sources. A hardware link has no
# true state (a real vessel does not report it): its figures show what was measured instead, and
# what the observer estimated; a simulation's show the true state, not the noisy measurements.
SOURCES = (("", "true", "-"), ("meas_", "measured", "."), ("_hat", "estimated", "--"))


def _source(s: Series, name: str, tag: str) -> str | None:
    """The recorded signal of ``name`` from one source (``tag``), or None; measured only where
    there is no true one."""
    if tag == "meas_" and s.find(name):
        return None
    return s.find(tag + name if tag.endswith("_") else name + tag)


def trajectory(s: Series, path: Path) -> bool:
    pairs = [(label, style, n, e) for tag, label, style in SOURCES
             if (n := _source(s, "north", tag)) and (e := _source(s, "east", tag))]
    if not pairs:
        return False
    fig = _figure(6, 6)
    ax = fig.subplots()
    for i, (label, style, n, e) in enumerate(pairs):
        kw: dict[str, Any] = {"ms": 2} if style == "." else {"lw": 1.5 if i == 0 else 1}
        ax.plot(s.signals[e], s.signals[n], style, label=label, **kw)
    nr, er = s.find("north_ref"), s.find("east_ref")
    if nr and er:
        ax.plot(s.signals[er], s.signals[nr], "k+", ms=10, label="setpoints")
    _, _, n0, e0 = pairs[0]
    ax.plot(s.signals[e0][0], s.signals[n0][0], "go", label="start")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(f"{s.name}: trajectory (NED{'' if pairs[0][0] == 'true' else ', ' + pairs[0][0]})")
    _save(fig, path)
    return True


def states(s: Series, path: Path) -> bool:
    eta = [n for n in ETA if any(_source(s, n, tag) for tag, _, _ in SOURCES)]
    if not eta:
        return False
    fig = _figure(9, 1.9 * len(eta) + 0.6)
    axes = fig.subplots(len(eta), 1, sharex=True, squeeze=False)
    cols = _columns(fig)
    legend: dict[str, Any] = {}  # every source that appears in any panel (a link measures few states)
    for ax, n in zip(axes[:, 0], eta, strict=True):
        scale, unit = (180 / np.pi, "deg") if n in ANGLES else (1.0, "m")
        for tag, style, label, color in (("", "-", "true", "C0"), ("meas_", ".", "measured", "C7"),
                                         ("_hat", "--", "estimate", "C1"), ("_d", ":", "desired", "C2"),
                                         ("_ref", "-", "reference", "k")):
            key = _source(s, n, tag)
            if key is None:
                continue
            kw: dict[str, Any] = {"lw": 0.8, "alpha": 0.5} if tag == "_ref" else {"lw": 1.2}
            if tag == "meas_":  # held samples: dots, not a line through the holds
                kw = {"ms": 1.5, "alpha": 0.6}
            (line,) = ax.plot(*m4(s.time, s.signals[key] * scale, cols), style, color=color, **kw)
            legend.setdefault(label, line)
        ax.set_ylabel(f"{n} [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(list(legend.values()), list(legend), loc="best", fontsize=8, ncol=5, markerscale=4)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"{s.name}: states vs references")
    _save(fig, path)
    return True


def _numbered(s: Series, prefix: str) -> list[str]:
    """The signals named ``<prefix><number>``, by number."""
    keys = [k for k in s.signals if k.split(".", 1)[1].startswith(prefix)
            and k.split(".", 1)[1][len(prefix):].isdigit()]
    return sorted(keys, key=lambda k: int(k.rsplit("_", 1)[1]))


def thrusters(s: Series, path: Path) -> bool:
    """One row per thruster (seven lines on one axis are unreadable): its shaft speed with the
    allocator's command, and its thrust where the plant reports it (a hardware link does not)."""
    speeds, thrusts = _numbered(s, "n_"), _numbered(s, "thrust_")
    if not speeds and not thrusts:
        return False
    commands = {k.rsplit("_", 1)[1]: k for k in _numbered(s, "n_cmd_")}
    number = sorted({int(k.rsplit("_", 1)[1]) for k in speeds + thrusts})
    kinds = [keys for keys in (speeds, thrusts) if keys]
    fig = _figure(9, 0.3 + 1.15 * len(number) + 0.5)
    axes = fig.subplots(len(number), len(kinds), sharex=True, squeeze=False)
    cols = _columns(fig) // len(kinds)
    for j, keys in enumerate(kinds):
        by_number = {int(k.rsplit("_", 1)[1]): k for k in keys}
        for i, num in enumerate(number):
            ax = axes[i, j]
            cmd = commands.get(str(num)) if keys is speeds else None
            if cmd is not None:  # under the measured speed: where they differ, the command shows
                ax.plot(*m4(s.time, s.signals[cmd], cols), lw=0.8, color="C1", alpha=0.8)
            k = by_number.get(num)
            if k is not None:
                ax.plot(*m4(s.time, s.signals[k], cols), lw=1, color="C0")
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=7)
            if j == 0:
                ax.set_ylabel(f"thruster {num}", fontsize=8)
        axes[0, j].set_title("shaft speed [rev/s]" + (" (blue: shaft, orange: command)" if commands else "")
                            if keys is speeds else "thrust [N]", fontsize=9)
        axes[-1, j].set_xlabel("time [s]")
    fig.suptitle(f"{s.name}: thruster use")
    _save(fig, path)
    return True


EXACT = 1e-6  # N or N.m: an allocation error below this is rounding (the scenarios' checks use it too)
FLOOR = 1e-16  # what a log axis shows for an error of exactly 0


def allocation(s: Series, path: Path) -> bool:
    """‖Bu − τ‖ on a log axis: a linear one would magnify rounding (1e-13) into a curve that looks
    like a fault; the line at 1e-6 separates rounding from a real shortfall (saturation, a loss)."""
    keys = sorted(k for k in s.signals if k.endswith(".alloc_error"))
    if not keys:
        return False
    fig = _figure(9, 4)
    ax = fig.subplots()
    cols = _columns(fig)
    for k in keys:
        t, y = m4(s.time, s.signals[k], cols)
        ax.plot(t, np.maximum(y, FLOOR), lw=1.2, label=k.split(".", 1)[0])
    ax.set_yscale("log")
    ax.axhline(EXACT, color="C3", ls="--", lw=1, label=f"{EXACT:g}: below is rounding")
    worst = max(float(np.nanmax(s.signals[k], initial=0.0)) for k in keys)
    ax.set_ylim(top=100 * max(worst, EXACT))  # room above the line and the legend
    if worst < EXACT:
        ax.text(0.01, 0.03, f"exact to rounding throughout (max {worst:.2g})", transform=ax.transAxes,
                va="bottom", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("allocation error ‖Bu − τ‖ [N, N·m]")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"{s.name}: allocation error")
    _save(fig, path)
    return True


# ((title, file) of each figure drawn, 'file: why' of each that failed)
Drawn = tuple[list[tuple[str, str]], list[str]]
# (file, title in the report, function): the report's figures, in its order
FIGURES: tuple[tuple[str, str, Callable[[Series, Path], bool]], ...] = (
    ("trajectory.png", "Trajectory", trajectory),
    ("states.png", "States vs references", states),
    ("thrusters.png", "Thruster use", thrusters),
    ("allocation.png", "Allocation error", allocation),
)


def draw_all(s: Series, out: Path, only: Collection[str] | None = None) -> Drawn:
    """Every figure that applies (of ``only``, file names, if given), in ``out``: ((title, file)
    drawn, 'file: why' of each that failed), in the report's order."""
    drawn: list[tuple[str, str]] = []
    failed: list[str] = []
    for name, title, fn in FIGURES:
        if only is not None and name not in only:
            continue
        try:
            if fn(s, out / name):
                drawn.append((title, name))
        except Exception as exc:  # a figure that cannot be drawn must not cost the report
            failed.append(f"{name}: {type(exc).__name__}: {' '.join(str(exc).split())[:200]}")
    return drawn, failed


def _in_order(parts: list[Drawn]) -> Drawn:
    """Shares of the figures merged, in the report's order."""
    order = {name: i for i, (name, _, _) in enumerate(FIGURES)}
    drawn = sorted((d for part in parts for d in part[0]), key=lambda d: order[d[1]])
    failed = sorted((f for part in parts for f in part[1]),
                    key=lambda f: order.get(f.split(":", 1)[0], len(order)))
    return drawn, failed


def draw_shared(s: Series, out: Path, parts: int) -> Drawn:
    """``draw_all`` with the figures shared (round robin in the report's order) by this process
    and ``parts - 1`` forks of it: made once matplotlib is loaded, they start drawing at once.
    A share whose process fails is drawn here."""
    names = [name for name, _, _ in FIGURES]
    parts = max(1, min(parts, len(names)))
    shares = [names[i::parts] for i in range(parts)]
    if parts == 1:
        return draw_all(s, out)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    results: list[Drawn] = []
    with ProcessPoolExecutor(parts - 1, mp_context=multiprocessing.get_context("fork")) as pool:
        futures = [pool.submit(draw_all, s, out, share) for share in shares[1:]]
        results.append(draw_all(s, out, shares[0]))
        for share, future in zip(shares[1:], futures, strict=True):
            try:
                results.append(future.result())
            except Exception:  # the forked process failed (not a figure: those are caught inside)
                results.append(draw_all(s, out, share))
    return _in_order(results)


class Plotter:
    """``with Plotter() as p: ... p.draw(series, out)`` — the figures drawn by a worker process
    started on entry (so matplotlib is imported while the run goes), else in this process.

    The worker shares the figures with ``parts - 1`` forks of itself (default: one per core, as
    the run's process only waits while they draw); a second worker started with the run would
    instead import matplotlib again, taking CPU from the simulation on a two-core machine.
    """

    def __init__(self, parts: int | None = None) -> None:
        self.parts = core_count() if parts is None else parts
        self._proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> Plotter:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Start the worker; without one (no interpreter path, no process), ``draw`` draws here."""
        if not sys.executable:
            return
        # Started beside this seafmu (the folder holding the package): the worker runs the same
        # code whatever the current folder; its own session, so a terminal's Ctrl-C stops the
        # run (which still wants its figures), not the worker.
        root = Path(__file__).resolve().parents[1]
        try:
            self._proc = subprocess.Popen([sys.executable, "-m", "seafmu.plots"], cwd=root,
                                          stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          start_new_session=True)
        except OSError:
            self._proc = None

    def draw(self, s: Series, out: Path) -> Drawn:
        """Draw every figure into ``out``; returns when they are all written (see ``draw_all``)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            # plain data (no seafmu class): the worker's module is __main__, not seafmu.plots
            request = {"name": s.name, "time": s.time, "signals": s.signals, "out": str(Path(out).resolve()),
                       "parts": self.parts}
            try:
                reply, _ = proc.communicate(pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL),
                                            timeout=REPLY_TIMEOUT_S)
                answer = json.loads(reply.decode("utf-8").strip().splitlines()[-1])
                return [(str(t), str(n)) for t, n in answer["drawn"]], [str(f) for f in answer["failed"]]
            except (OSError, ValueError, IndexError, KeyError, TypeError, subprocess.TimeoutExpired):
                _stop(proc)  # the worker failed: the figures are drawn here
        return draw_all(s, out)

    def close(self) -> None:
        """Stop a worker that was not used (the run failed before its figures)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            _stop(proc)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.kill()
    with contextlib.suppress(OSError, ValueError):
        proc.communicate(timeout=10)


def _warm_up() -> None:
    """Import matplotlib and load the fonts of the figures (what the first figure would pay)."""
    import io

    fig = _figure(1, 1)
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], label="x")
    ax.legend(fontsize=7)
    ax.set_title("x")
    fig.savefig(io.BytesIO(), dpi=DPI, format="png")


def serve() -> int:
    """The worker: warm up, read one pickled request from stdin, draw, answer one JSON line.
    Ends at once when stdin closes first (the run ended without figures, or was killed)."""
    for sig in (signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    with contextlib.suppress(Exception):  # a failure here fails the figures below, one by one
        _warm_up()
    try:
        request = pickle.load(sys.stdin.buffer)  # from the parent run, over its private pipe
    except EOFError:
        return 0
    series = Series(request["name"], request["time"], request["signals"])
    drawn, failed = draw_shared(series, Path(request["out"]), int(request.get("parts", 1)))
    sys.stdout.write(json.dumps({"drawn": drawn, "failed": failed}) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(serve())

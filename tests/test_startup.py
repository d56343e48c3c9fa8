"""Start-up of the ``seafmu`` command (issue 13): what a command line imports, and the figures'
worker. No timing here (benchmarks/bench_startup.py measures it); these tests check the structure
that makes it fast: the CLI registers only the subcommand named, ``seafmu run`` imports no
plotting, hardware or sweep code in its own process, and the figures drawn by the worker (or by
the fallback in this process) are the ones the report names, pixel for pixel the same.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seafmu import plots
from seafmu.cli import all_commands, build_parser

REPO = Path(__file__).resolve().parents[1]
# Never needed by `seafmu run` in its own process (the figures' worker imports matplotlib).
NOT_FOR_RUN = ("matplotlib", "pandas", "seafmu.hardware", "seafmu.sweep", "seafmu.identification",
               "seafmu.testplan", "can", "cantools", "dask")


def _loaded(code: str) -> list[str]:
    """The modules loaded after running ``code`` in a fresh interpreter (printed as JSON)."""
    code += "\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def _heavy(mods: list[str]) -> list[str]:
    return [m for m in mods if any(m == h or m.startswith(h + ".") for h in NOT_FOR_RUN)]


def test_importing_the_cli_imports_no_subcommand_code() -> None:
    mods = _loaded("import seafmu.cli")
    assert not _heavy(mods)
    assert "seafmu.scenario" not in mods and "pydantic" not in mods and "numpy" not in mods


@pytest.mark.parametrize("command", ["run", "check", "build", "export"])
def test_a_command_line_registers_only_its_subcommand(command: str) -> None:
    mods = _loaded(f"from seafmu.cli import build_parser\nbuild_parser({command!r})")
    assert not _heavy(mods)


def test_every_subcommand_parses_as_in_the_full_parser() -> None:
    full = build_parser(None)
    subs = next(a for a in full._actions if a.dest == "command")
    assert tuple(subs.choices) == all_commands()  # the list is complete and in --help's order
    for name in all_commands():
        one = build_parser(name)
        one_subs = next(a for a in one._actions if a.dest == "command")
        assert list(one_subs.choices) == [n for n in all_commands() if n in one_subs.choices]
        assert name in one_subs.choices
        assert one_subs.choices[name].format_help() == subs.choices[name].format_help()
        assert one.format_usage() == full.format_usage()


def test_unknown_or_missing_command_gets_the_full_parser() -> None:
    for argv in (["bogus"], [], ["-h"]):
        p = subprocess.run([sys.executable, "-m", "seafmu.cli", *argv], cwd=REPO, capture_output=True,
                           text=True, timeout=120)
        text = p.stdout + p.stderr
        assert all(name in text for name in all_commands()), argv


def test_seafmu_run_imports_no_plotting_in_its_own_process(tmp_path: Path) -> None:
    out = tmp_path / "o"
    mods = _loaded("import sys\nfrom seafmu.cli import main\n"
                   f"rc = main(['run', 'minerva2_dp', '-q', '-o', {str(out)!r}])\n"
                   "assert rc in (0, 1), rc")
    assert not _heavy(mods)
    report = (out / "report.md").read_text()
    for name, title, _ in plots.FIGURES:  # drawn by the worker, complete before the report
        assert f"![{title}]({name})" in report
        assert (out / name).stat().st_size > 1000
    assert not list(out.glob(".*.tmp"))


def _series(n: int = 3001, seed: int = 0) -> plots.Series:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 300.0, n)
    sig: dict[str, np.ndarray] = {}
    for i, name in enumerate(("north", "east", "down", "roll", "pitch", "yaw")):
        sig[f"plant.{name}"] = np.cumsum(rng.normal(0, 0.02, n)) + i
        sig[f"observer.{name}_hat"] = sig[f"plant.{name}"] + rng.normal(0, 0.01, n)
        sig[f"controller.{name}_ref"] = np.where(t > 50 * (i + 1), 1.0, 0.0)
    for k in range(1, 4):
        sig[f"allocator.n_{k}"] = rng.normal(0, 5, n)
        sig[f"allocator.thrust_{k}"] = rng.normal(0, 50, n)
    sig["allocator.alloc_error"] = np.abs(rng.normal(0, 1e-3, n))
    return plots.Series("synthetic", t, sig)


def _pixels(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path)).astype(int)


def test_the_worker_draws_the_same_figures_as_this_process(tmp_path: Path) -> None:
    s = _series()
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    drawn_here, failed_here = plots.draw_all(s, here)
    with plots.Plotter(parts=2) as p:  # the worker and a fork of it, whatever the cores
        assert p._proc is not None  # the worker was started
        drawn_there, failed_there = p.draw(s, there)
    assert drawn_here == drawn_there and len(drawn_here) == len(plots.FIGURES)
    assert failed_here == failed_there == []
    for _, name in drawn_here:
        assert np.array_equal(_pixels(here / name), _pixels(there / name)), name


def test_a_dead_worker_leaves_the_figures_to_this_process(tmp_path: Path) -> None:
    s = _series()
    with plots.Plotter() as p:
        assert p._proc is not None
        plots._stop(p._proc)
        p._proc = subprocess.Popen([sys.executable, "-c", "import sys; sys.exit(3)"], stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE)
        drawn, failed = p.draw(s, tmp_path)
    assert [name for _, name in drawn] == [name for name, _, _ in plots.FIGURES] and not failed
    assert all((tmp_path / name).is_file() for _, name in drawn)


def test_an_unused_worker_is_stopped() -> None:
    with plots.Plotter() as p:
        proc = p._proc
        assert proc is not None and proc.poll() is None
    assert proc.poll() is not None


def test_a_figure_that_fails_is_reported_not_raised(tmp_path: Path) -> None:
    s = _series()
    s.signals["plant.north"] = s.signals["plant.north"][:10]  # a wrong length: that figure fails
    drawn, failed = plots.draw_all(s, tmp_path)
    assert any(f.startswith("trajectory.png:") for f in failed)
    assert ("Thruster use", "thrusters.png") in drawn


def test_m4_keeps_every_column_extreme_and_the_drawn_line() -> None:
    rng = np.random.default_rng(1)
    n, columns = 50_000, 300
    t = np.linspace(0, 10, n)
    y = np.cumsum(rng.normal(0, 1, n))
    y[1234] = 500.0  # one spike: must survive
    y[40_000] = np.nan  # a gap: must stay a gap
    tr, yr = plots.m4(t, y, columns)
    assert len(tr) <= 4 * columns + 1 and np.all(np.diff(tr) > 0)
    assert np.nanmax(yr) == 500.0 and np.nanmin(yr) == np.nanmin(y) and np.isnan(yr).sum() == 1
    col = np.minimum((t / 10 * columns).astype(int), columns - 1)
    colr = np.minimum((tr / 10 * columns).astype(int), columns - 1)
    for c in rng.choice(columns, 20, replace=False):
        full, kept = y[col == c], yr[colr == c]
        assert np.nanmax(kept) == np.nanmax(full) and np.nanmin(kept) == np.nanmin(full)
        assert kept[0] == full[0] or (np.isnan(kept[0]) and np.isnan(full[0]))
    short = np.arange(100.0)
    assert plots.m4(short, short, columns)[0] is short  # no fewer samples: unchanged


def test_m4_draws_the_same_line(tmp_path: Path) -> None:
    """A long line drawn whole and reduced to its pixel columns: in every pixel column the line
    covers the same rows; inside, a few pixels differ by antialiasing (matplotlib also simplifies
    the whole line's path before drawing it)."""
    rng = np.random.default_rng(2)
    t = np.linspace(0, 300, 60_000)
    y = np.cumsum(rng.normal(0, 1, t.size))
    images = []
    for reduce in (False, True):
        fig = plots._figure(9, 3)
        ax = fig.subplots()
        ax.plot(*(plots.m4(t, y, plots._columns(fig)) if reduce else (t, y)), lw=1)
        fig.savefig(tmp_path / f"{reduce}.png", dpi=plots.DPI)
        images.append(_pixels(tmp_path / f"{reduce}.png"))
    ink = [im[..., :3].sum(axis=-1) < 600 for im in images]
    for a, b in ((ink[0], ink[1]), (ink[0][::-1], ink[1][::-1])):  # the top and bottom rows of ink
        assert np.array_equal(a.any(axis=0), b.any(axis=0))
        assert np.abs(np.argmax(a, axis=0) - np.argmax(b, axis=0)).max() <= 1
    differ = np.any(images[0] != images[1], axis=-1)
    assert differ.mean() < 0.02, differ.mean()


def test_csv_rows_are_written_as_savetxt_writes_them() -> None:
    import io

    from seafmu.results import CSV_FORMAT, format_rows

    rng = np.random.default_rng(3)
    cases = [rng.normal(size=(50, 9)) * 10.0 ** rng.integers(-300, 300, size=(50, 9)),
             np.array([[np.nan, np.inf, -np.inf, -0.0, 0.0, 5e-324, 1.7976931348623157e308, 0.1, 1 / 3]]),
             rng.integers(-9, 9, size=(5, 4)), np.array([1.5, 2.0]), np.zeros((0, 3))]
    for x in cases:
        buf = io.StringIO()
        np.savetxt(buf, x, delimiter=",", fmt=CSV_FORMAT)
        assert format_rows(x) == buf.getvalue()


def test_a_figure_failing_in_a_worker_is_reported_as_here(tmp_path: Path) -> None:
    s = _series()
    s.signals["plant.north"] = s.signals["plant.north"][:10]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with plots.Plotter(parts=2) as p:
        there = p.draw(s, tmp_path / "a")
    assert there == plots.draw_all(s, tmp_path / "b")
    assert there[1] and there[1][0].startswith("trajectory.png:")


def test_figures_shared_by_forks_are_the_same(tmp_path: Path) -> None:
    s = _series()
    (tmp_path / "one").mkdir()
    (tmp_path / "shared").mkdir()
    one = plots.draw_all(s, tmp_path / "one")
    shared = plots.draw_shared(s, tmp_path / "shared", 3)
    assert one == shared and len(one[0]) == len(plots.FIGURES)
    for _, name in one[0]:
        assert np.array_equal(_pixels(tmp_path / "one" / name), _pixels(tmp_path / "shared" / name)), name


def test_validating_a_scenario_loads_no_scipy_special() -> None:
    """The observer's chi-square gate imports scipy.special when a block is made, not when the
    registry imports the module for its interface (a sweep validates every case; ~0.06 s)."""
    mods = _loaded("from seafmu.scenario import load_scenario\nload_scenario('minerva2_dp')")
    assert "seafmu.components.observer" in mods and "scipy.special" not in mods

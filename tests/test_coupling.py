"""Coupling: seafmu's master in Jacobi mode runs as OSP libcosim and ecos do; Gauss-Seidel vs Jacobi.

The other engines run the files ``seafmu export`` writes, each in a child process (libcosim aborts
its host on some FMU errors, and each child starts with a clean interpreter like a user's host).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path

import numpy as np
import pytest

from seafmu.cli import main
from seafmu.export import export_osp, export_ssp
from seafmu.master import run
from seafmu.scenario import Scenario, ScenarioError, load_scenario

pytest.importorskip("libcosimpy")
if importlib.util.find_spec("ecospy") is None:  # not imported here: it needs TBB preloaded (seafmu.hosts)
    pytest.skip("ecospy is not installed", allow_module_level=True)

DURATION = 60.0  # s of minerva2_dp: station keeping, then the north step at 40 s
SIGNALS = [("plant", "north"), ("plant", "east"), ("plant", "down"), ("plant", "roll"), ("plant", "pitch"),
           ("plant", "yaw"), ("allocator", "n_cmd_1"), ("controller", "tau_X"), ("observer", "north_hat"),
           ("controller", "north_ref")]

_ENGINE = """
import sys, numpy as np
from pathlib import Path
from seafmu import hosts
kind, path, events, out, duration, step = sys.argv[1:7]
rec = [tuple(x.split('.')) for x in sys.argv[7].split(',')]
events = Path(events) if events != '-' else None
if kind == 'libcosim':
    r = hosts.run_osp_libcosim(Path(path), rec, float(duration), float(step))
else:
    r = hosts.run_ssp_ecos(Path(path), rec, float(duration), float(step), events)
np.savez(out, **r)
"""


def _engine(kind: str, path: Path, events: Path | None, out: Path, duration: float, step: float,
            record: list[tuple[str, str]]) -> dict[str, np.ndarray]:
    rec = ",".join(f"{i}.{v}" for i, v in record)
    proc = subprocess.run([sys.executable, "-c", _ENGINE, kind, str(path), str(events or "-"), str(out),
                           repr(duration), repr(step), rec],
                          capture_output=True, text=True, timeout=600, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr[-2000:]
    with np.load(out) as data:
        return {k: data[k] for k in data.files}


def _short(sc: Scenario, duration: float) -> Scenario:
    """The scenario cut to ``duration``, every step recorded (the engines' rows)."""
    return dataclasses.replace(sc, duration=duration, events=[e for e in sc.events if e[0] < duration],
                               checks=[], record_every=1)


@pytest.fixture(scope="module")
def minerva(tmp_path_factory: pytest.TempPathFactory, built_fmus: object) -> dict[str, dict[str, np.ndarray]]:
    """minerva2_dp, 60 s: seafmu (both couplings, FMUs and in-process), libcosim (OSP), ecos (SSP)."""
    out = tmp_path_factory.mktemp("coupling")
    sc = _short(load_scenario("minerva2_dp"), DURATION)
    export_ssp(sc, out / "m.ssp")
    export_osp(sc, out / "osp")
    res = {
        "libcosim": _engine("libcosim", out / "osp", None, out / "lc.npz", sc.duration, sc.step, SIGNALS),
        "ecos": _engine("ecos", out / "m.ssp", out / "m.events.json", out / "ec.npz", sc.duration, sc.step,
                        SIGNALS),
    }
    for coupling in ("jacobi", "gauss-seidel"):
        for mode in ("fmu", "inprocess"):
            r = run(dataclasses.replace(sc, coupling=coupling), mode=mode, progress=False)
            res[f"{coupling}/{mode}"] = r.signals
    return res


def _max_diff(a: dict[str, np.ndarray], b: dict[str, np.ndarray], key: str) -> float:
    assert len(a[key]) == len(b[key]) == round(DURATION / 0.05) + 1
    return float(np.max(np.abs(a[key] - b[key])))


@pytest.mark.parametrize("signal", [f"{i}.{v}" for i, v in SIGNALS])
def test_seafmu_jacobi_libcosim_and_ecos_agree(minerva: dict[str, dict[str, np.ndarray]],
                                               signal: str) -> None:
    """Every row from t = 0 (after initialisation) to 60 s, through the event at 40 s."""
    j, lc, ec = minerva["jacobi/fmu"], minerva["libcosim"], minerva["ecos"]
    assert _max_diff(j, lc, signal) <= 1e-9
    assert _max_diff(j, ec, signal) <= 1e-9
    assert _max_diff(lc, ec, signal) <= 1e-9


def test_the_run_moved_and_gauss_seidel_differs(minerva: dict[str, dict[str, np.ndarray]]) -> None:
    j, gs = minerva["jacobi/fmu"], minerva["gauss-seidel/fmu"]
    assert j["controller.north_ref"][-1] == 3.0 and j["plant.north"][-1] > 1.0  # the 40 s event acted
    # Gauss-Seidel is another (valid) scheme: centimetres apart on the plant, far beyond 1e-9
    assert 1e-3 < _max_diff(j, gs, "plant.north") < 0.1
    np.testing.assert_array_equal(j["plant.north"][0], gs["plant.north"][0])  # same initialisation


def test_inprocess_mode_honours_the_coupling(minerva: dict[str, dict[str, np.ndarray]]) -> None:
    for coupling in ("jacobi", "gauss-seidel"):
        fmu, inproc = minerva[f"{coupling}/fmu"], minerva[f"{coupling}/inprocess"]
        for i, v in SIGNALS:
            assert _max_diff(fmu, inproc, f"{i}.{v}") <= 1e-9
    assert _max_diff(minerva["jacobi/inprocess"], minerva["gauss-seidel/inprocess"], "plant.north") > 1e-3


@pytest.mark.parametrize("mode", ["fmu", "inprocess"])
def test_the_fmus_order_in_the_scenario_changes_nothing_under_jacobi(
        minerva: dict[str, dict[str, np.ndarray]], mode: str) -> None:
    """Listed against the data flow (allocator first, plant last), the FMUs still start from
    settled initial values (propagated along the connections, as libcosim does): the run equals
    the one in data-flow order, so libcosim's. Before, the observer started from a plant at 0."""
    sc = _short(load_scenario("minerva2_dp"), DURATION)
    backwards = dataclasses.replace(sc, coupling="jacobi", instances=list(reversed(sc.instances)))
    assert [i.name for i in backwards.instances] == ["allocator", "controller", "observer", "plant"]
    r = run(backwards, mode=mode, progress=False).signals
    for i, v in SIGNALS:
        assert _max_diff(r, minerva["jacobi/fmu"], f"{i}.{v}") <= 1e-9, (i, v)
    assert r["observer.north_hat"][0] == minerva["libcosim"]["observer.north_hat"][0] != 0.0


# -- a chain of tiny FMUs: the one-step delay per connection ----------------------------------

TOKEN = uuid.uuid4().hex[:8]

SOURCE = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class CplSource(Fmi2Slave):
    \"\"\"y = gain * t.\"\"\"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.gain = 1.0
        self.y = 0.0
        self.register_variable(Real("gain", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def exit_initialization_mode(self):
        self.y = 0.0

    def do_step(self, current_time, step_size):
        self.y = self.gain * (current_time + step_size)
        return True
"""

INTEGRATOR = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class CplIntegrator(Fmi2Slave):
    \"\"\"Explicit Euler: x(t + h) = x(t) + h u(t), x(0) = 0.\"\"\"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.x = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("x", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        self.x += step_size * self.u
        return True
"""


@pytest.fixture(scope="module")
def chain(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scenario src -> i1 -> i2 over tiny pythonfmu FMUs (unique module names: FMUs share sys.modules)."""
    from pythonfmu import FmuBuilder

    src, out = tmp_path_factory.mktemp("cpl_src"), tmp_path_factory.mktemp("cpl_chain")
    for kind, code in (("source", SOURCE), ("integrator", INTEGRATOR)):
        script = src / f"cpl_{kind}_{TOKEN}.py"
        script.write_text(textwrap.dedent(code))
        FmuBuilder.build_FMU(script, dest=out / f"{kind}.fmu")
    return _chain_file(out, "chain", 1, 1)


def _chain_file(folder: Path, name: str, m_src: int, m_i2: int) -> Path:
    path = folder / f"{name}.yaml"
    path.write_text(
        f"name: {name}\nvessel: minerva2\nduration: 2\nstep: 0.1\n"
        f"fmus:\n  src: {{fmu: source.fmu, step_multiple: {m_src}, parameters: {{gain: 2.0}}}}\n"
        f"  i1: {{fmu: integrator.fmu}}\n  i2: {{fmu: integrator.fmu, step_multiple: {m_i2}}}\n"
        "connect: explicit\nconnections: ['src.y -> i1.u', 'i1.x -> i2.u']\n"
        "outputs: [src.y, i1.x, i2.x]\n"
    )
    return path


def test_jacobi_delays_each_connection_by_one_step(chain: Path, tmp_path: Path) -> None:
    """Gauss-Seidel hands each FMU its producer's value of the same step; Jacobi the one before:
    i1 lags by one step, i2 (two connections down) by two. libcosim and ecos equal seafmu's Jacobi."""
    sc = load_scenario(chain)
    h, n, gain = 0.1, 20, 2.0
    gs = run(sc, progress=False).signals
    jac = run(dataclasses.replace(sc, coupling="jacobi"), progress=False).signals
    k = np.arange(n + 1)
    np.testing.assert_allclose(gs["src.y"], gain * h * k, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(jac["src.y"], gs["src.y"])
    # closed forms: Gauss-Seidel integrates y(t_k+1), Jacobi y(t_k) (left Riemann sum)
    np.testing.assert_allclose(gs["i1.x"], gain * h**2 * k * (k + 1) / 2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jac["i1.x"], gain * h**2 * k * (k - 1) / 2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(jac["i1.x"][1:], gs["i1.x"][:-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(jac["i2.x"][2:], gs["i2.x"][:-2], rtol=0, atol=1e-12)
    assert gs["i2.x"][-1] - jac["i2.x"][-1] > 0.1

    export_ssp(sc, tmp_path / "chain.ssp")
    export_osp(sc, tmp_path / "osp")
    rec = [("src", "y"), ("i1", "x"), ("i2", "x")]
    lc = _engine("libcosim", tmp_path / "osp", None, tmp_path / "lc.npz", sc.duration, sc.step, rec)
    ec = _engine("ecos", tmp_path / "chain.ssp", None, tmp_path / "ec.npz", sc.duration, sc.step, rec)
    for key in ("src.y", "i1.x", "i2.x"):
        np.testing.assert_allclose(lc[key], jac[key], rtol=0, atol=1e-12)
        np.testing.assert_allclose(ec[key], jac[key], rtol=0, atol=1e-12)


def test_step_multiples_under_jacobi_run_as_in_libcosim(chain: Path, tmp_path: Path) -> None:
    """src and i2 step every 2 master steps: their outputs reach the others at t + 2h, held in
    between, in seafmu (either coupling) and libcosim. ecos passes them on right after the FMU
    stepped, at t + h (a value from t + 2h one step early): a documented difference."""
    sc = load_scenario(_chain_file(chain.parent, "multirate", 2, 2))
    jac = run(dataclasses.replace(sc, coupling="jacobi"), progress=False).signals
    np.testing.assert_allclose(jac["src.y"][:6], [0, 0, 0.4, 0.4, 0.8, 0.8], rtol=0, atol=1e-12)
    export_osp(sc, tmp_path / "osp")
    export_ssp(sc, tmp_path / "multirate.ssp")
    rec = [("src", "y"), ("i1", "x"), ("i2", "x")]
    lc = _engine("libcosim", tmp_path / "osp", None, tmp_path / "lc.npz", sc.duration, sc.step, rec)
    ec = _engine("ecos", tmp_path / "multirate.ssp", None, tmp_path / "ec.npz", sc.duration, sc.step, rec)
    for key in ("src.y", "i1.x", "i2.x"):
        np.testing.assert_allclose(lc[key], jac[key], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ec["src.y"][1:-1], jac["src.y"][2:], rtol=0, atol=1e-12)  # ecos: early


# -- the scenario field and the command line ---------------------------------------------------

def _scenario_file(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text("name: cpl\nvessel: amv_osf\nduration: 1\nstep: 0.05\n" + extra)
    return path


def test_coupling_field_default_and_errors(tmp_path: Path) -> None:
    assert load_scenario("minerva2_dp").coupling == "gauss-seidel"
    assert load_scenario(_scenario_file(tmp_path, "coupling: jacobi\n")).coupling == "jacobi"
    with pytest.raises(ScenarioError, match="coupling") as err:
        load_scenario(_scenario_file(tmp_path, "coupling: parallel\n"))
    assert "\n" not in str(err.value)


def test_run_coupling_override_on_the_command_line(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    path = _scenario_file(tmp_path, "coupling: jacobi\n")
    assert main(["run", str(path), "--inprocess", "-q", "-o", str(tmp_path / "a")]) == 0
    assert "jacobi coupling" in capsys.readouterr().out
    assert main(["run", str(path), "--inprocess", "-q", "-o", str(tmp_path / "b"),
                 "--coupling", "gauss-seidel"]) == 0
    assert "gauss-seidel coupling" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["run", str(path), "--coupling", "parallel"])
    assert exc.value.code == 2

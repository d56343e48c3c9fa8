"""Tests for seafmu.libcosim_runner: pythonfmu FMUs under OSP libcosim, in this very process.

Three tiny pythonfmu 0.7.0 FMUs are built once per session (~1 s each) under unique module
names -- all pythonfmu FMUs share the host interpreter's ``sys.modules``, so two FMUs whose
scripts have the same module name would silently share code.
"""

from __future__ import annotations

import faulthandler
import gc
import os
import signal
import subprocess
import sys
import textwrap
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("libcosimpy")
pytest.importorskip("pythonfmu")

from seafmu.libcosim_runner import run_with_libcosim

TOKEN = uuid.uuid4().hex[:8]

SOURCE = """
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String


class LcrSource(Fmi2Slave):
    \"\"\"y = (-1 if negate) * gain * t**power ("ramp") or * 1 ("const"); count = steps taken.\"\"\"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.gain = 1.0
        self.power = 1
        self.negate = False
        self.shape = "ramp"
        self.y = 0.0
        self.count = 0
        par, fixed = Fmi2Causality.parameter, Fmi2Variability.fixed
        self.register_variable(Real("gain", causality=par, variability=Fmi2Variability.tunable))
        self.register_variable(Integer("power", causality=par, variability=fixed))
        self.register_variable(Boolean("negate", causality=par, variability=fixed))
        self.register_variable(String("shape", causality=par, variability=fixed))
        self.register_variable(Real("y", causality=Fmi2Causality.output))
        # pythonfmu defaults to variability="continuous", which FMI forbids for integers (fmpy rejects it)
        self.register_variable(
            Integer("count", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete)
        )

    def _value(self, t):
        base = self.gain * t**self.power if self.shape == "ramp" else self.gain
        return -base if self.negate else base

    def exit_initialization_mode(self):
        self.y = self._value(0.0)

    def do_step(self, current_time, step_size):
        self.y = self._value(current_time + step_size)
        self.count += 1
        return True
"""

INTEGRATOR = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class LcrIntegrator(Fmi2Slave):
    \"\"\"Explicit Euler: x(t+h) = x(t) + h * u(t); x(0) = x0.\"\"\"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.x0 = 0.0
        self.x = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(
            Real("x0", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        )
        self.register_variable(Real("x", causality=Fmi2Causality.output))

    def exit_initialization_mode(self):
        self.x = self.x0

    def do_step(self, current_time, step_size):
        self.x += step_size * self.u
        return True
"""

FAULTY = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real, String
from pythonfmu.enums import Fmi2Status


class LcrFaulty(Fmi2Slave):
    \"\"\"Fails where told: instance 'ctor_fail*'; fail_in 'init'|'step' (raise), 'discard' (t >= 0.2)\"\"\"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        if self.instance_name.startswith("ctor_fail"):
            raise RuntimeError("boom in constructor")
        self.fail_in = ""
        self.y = 0.0
        self.register_variable(
            String("fail_in", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        )
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def exit_initialization_mode(self):
        if self.fail_in == "init":
            raise ValueError("boom in init")

    def do_step(self, current_time, step_size):
        if self.fail_in == "step" and current_time >= 0.2 - 1e-9:
            raise ValueError("boom in step")
        if self.fail_in == "discard" and current_time >= 0.2 - 1e-9:
            self.log(f"{self.instance_name}: cannot go on", Fmi2Status.error)
            return False
        self.y = current_time + step_size
        return True
"""


@pytest.fixture(scope="module", autouse=True)
def deadlock_watchdog() -> Iterator[None]:
    """A GIL deadlock would hang forever; dump all threads' stacks and exit instead."""
    faulthandler.dump_traceback_later(180, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture(scope="module")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from pythonfmu import FmuBuilder

    src = tmp_path_factory.mktemp("lcr_src")
    out = tmp_path_factory.mktemp("lcr_fmus")
    built = {}
    for kind, code in (("source", SOURCE), ("integrator", INTEGRATOR), ("faulty", FAULTY)):
        script = src / f"lcr_{kind}_{TOKEN}.py"
        script.write_text(textwrap.dedent(code))
        built[kind] = Path(FmuBuilder.build_FMU(script, dest=out / f"{kind}.fmu"))
    return built


def test_chain_shows_one_step_delay_per_connection(fmus: dict[str, Path]) -> None:
    """src -> i1 -> i2 under Jacobi: i1 lags a Gauss-Seidel master by one step, i2 by two."""
    h, n, gain = 0.1, 20, 2.0
    res = run_with_libcosim(
        fmus={"src": fmus["source"], "i1": fmus["integrator"], "i2": fmus["integrator"]},
        connections=[("src", "y", "i1", "u"), ("i1", "x", "i2", "u")],
        initial_values={"src": {"gain": gain}},
        step_size=h,
        duration=n * h,
        record={"src": ["y", "count"], "i1": ["u", "x"], "i2": ["u", "x"]},
    )
    k = np.arange(n + 1)
    t = k * h
    np.testing.assert_allclose(res["time"], t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res["src.y"], gain * t, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(res["src.count"], k)
    assert res["src.count"].dtype == np.int64

    # Jacobi: every slave steps [t_k, t_k+h] with the inputs it got at t_k.
    x1 = np.zeros(n + 1)
    x2 = np.zeros(n + 1)
    for j in range(n):
        x1[j + 1] = x1[j] + h * res["src.y"][j]
        x2[j + 1] = x2[j] + h * x1[j]
    np.testing.assert_allclose(res["i1.x"], x1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res["i2.x"], x2, rtol=1e-12, atol=1e-12)
    # Closed form of the Jacobi result: left Riemann sum of gain * t.
    np.testing.assert_allclose(res["i1.x"], gain * h**2 * k * (k - 1) / 2, rtol=1e-12, atol=1e-12)

    # Gauss-Seidel in data-flow order would hand each consumer the fresh value at t_k+h.
    y_gs = gain * t
    x1_gs = np.concatenate([[0.0], np.cumsum(h * y_gs[1:])])
    x2_gs = np.concatenate([[0.0], np.cumsum(h * x1_gs[1:])])
    np.testing.assert_allclose(res["i1.x"][1:], x1_gs[:-1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res["i2.x"][2:], x2_gs[:-2], rtol=1e-12, atol=1e-12)

    # A recorded input is the value used in the step that ended there: the producer's previous value.
    np.testing.assert_allclose(res["i1.u"][1:], res["src.y"][:-1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res["i2.u"][1:], res["i1.x"][:-1], rtol=1e-12, atol=1e-12)


def test_initial_values_of_every_fmi_type_reach_the_fmus(fmus: dict[str, Path]) -> None:
    """Also: outputs set in exit_initialization_mode are seen at t=0 and fed to the first step,
    although pythonfmu's modelDescription declares no InitialUnknowns."""
    res = run_with_libcosim(
        fmus={
            "ramp": fmus["source"],
            "const": fmus["source"],
            "integ": fmus["integrator"],
            "sum": fmus["integrator"],
        },
        connections=[("const", "y", "sum", "u")],
        initial_values={
            "ramp": {"gain": 3, "power": 2, "negate": True, "shape": "ramp"},
            "const": {"gain": 1.5, "shape": "const"},
            "integ": {"x0": 0.5},
        },
        step_size=0.25,
        duration=1.0,
        record={"ramp": ["y"], "const": ["y"], "integ": ["x", "x0"], "sum": ["u", "x"]},
    )
    t = np.arange(5) * 0.25
    np.testing.assert_allclose(res["ramp.y"], -3.0 * t**2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res["const.y"], np.full(5, 1.5), rtol=0, atol=0)
    np.testing.assert_allclose(res["integ.x"], np.full(5, 0.5), rtol=0, atol=0)
    np.testing.assert_allclose(res["integ.x0"], np.full(5, 0.5), rtol=0, atol=0)
    np.testing.assert_allclose(res["sum.u"][1:], np.full(4, 1.5), rtol=0, atol=0)
    np.testing.assert_allclose(res["sum.x"], 1.5 * t, rtol=1e-12, atol=1e-12)


def test_events_apply_from_the_next_communication_point(fmus: dict[str, Path]) -> None:
    h = 0.1
    res = run_with_libcosim(
        fmus={"src": fmus["source"], "integ": fmus["integrator"]},
        connections=[],
        initial_values={"src": {"gain": 1.0}},
        step_size=h,
        duration=1.0,
        record={"src": ["y", "gain"], "integ": ["x"]},
        events=[(0.3, "integ", "u", 1.0), (0.55, "src", "gain", 10.0), (0.8, "integ", "u", -2.0)],
    )
    t = res["time"]
    # u = 1 from t = 0.3 and -2 from t = 0.8 (both exact grid points).
    x = np.zeros(11)
    for j in range(10):
        u = 0.0 if j < 3 else (1.0 if j < 8 else -2.0)
        x[j + 1] = x[j] + h * u
    np.testing.assert_allclose(res["integ.x"], x, rtol=1e-12, atol=1e-12)
    # 0.55 is between grid points: the new gain is first used in the step starting at 0.6.
    gain = np.where(np.arange(11) <= 6, 1.0, 10.0)
    np.testing.assert_allclose(res["src.y"], gain * t, rtol=1e-12, atol=1e-12)
    assert res["src.gain"][6] == 1.0 and res["src.gain"][7] == 10.0


def test_runs_longer_than_libcosims_default_buffer_keep_every_sample(fmus: dict[str, Path]) -> None:
    """libcosimc's default time-series observer keeps 10000 samples; the runner must size it."""
    n = 10_500
    res = run_with_libcosim(
        {"integ": fmus["integrator"]}, [], {}, 0.001, n * 0.001, {"integ": ["x"]}, [(0.0, "integ", "u", 1.0)]
    )
    assert len(res["time"]) == len(res["integ.x"]) == n + 1
    assert res["time"][0] == 0.0 and res["integ.x"][0] == 0.0
    np.testing.assert_allclose(res["time"], np.arange(n + 1) * 0.001, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res["integ.x"], res["time"], rtol=0, atol=1e-9)


def test_libcosim_and_fmpy_share_one_process(fmus: dict[str, Path]) -> None:
    """pythonfmu FMUs run by fmpy before and after libcosim, all in this interpreter."""
    from fmpy import simulate_fmu

    before = simulate_fmu(
        str(fmus["source"]), stop_time=1.0, step_size=0.5, output_interval=0.5, start_values={"gain": 4.0}
    )
    np.testing.assert_allclose(before["y"], [0.0, 2.0, 4.0])
    res = run_with_libcosim(
        {"src": fmus["source"], "integ": fmus["integrator"]},
        [("src", "y", "integ", "u")],
        {"src": {"gain": 4.0}},
        0.5,
        1.0,
        {"src": ["y"], "integ": ["x"]},
    )
    np.testing.assert_allclose(res["src.y"], [0.0, 2.0, 4.0])
    np.testing.assert_allclose(res["integ.x"], [0.0, 0.0, 1.0])
    after = simulate_fmu(
        str(fmus["integrator"]), stop_time=1.0, step_size=0.5, output_interval=0.5, start_values={"u": 1.0}
    )
    np.testing.assert_allclose(after["x"], [0.0, 0.5, 1.0])


def test_isolated_run_gives_identical_results(fmus: dict[str, Path]) -> None:
    args = (
        {"src": fmus["source"], "integ": fmus["integrator"]},
        [("src", "y", "integ", "u")],
        {"src": {"gain": 2.0, "shape": "ramp"}},
        0.05,
        0.5,
        {"src": ["y", "count"], "integ": ["x"]},
        [(0.2, "src", "gain", -1.0)],
    )
    here = run_with_libcosim(*args)
    there = run_with_libcosim(*args, isolate=True, timeout=60)
    assert here.keys() == there.keys()
    for key in here:
        np.testing.assert_array_equal(here[key], there[key], err_msg=key)
        assert here[key].dtype == there[key].dtype


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"record": {"nosuch": ["y"]}}, "unknown instance 'nosuch'"),
        ({"record": {"src": ["nope"]}}, "'src' has no variable 'nope'"),
        ({"record": {"src": ["shape"]}}, "record src.shape: string variables cannot be recorded"),
        ({"initial_values": {"src": {"gian": 1.0}}}, "initial value: instance 'src' has no variable 'gian'"),
        ({"initial_values": {"src": {"gain": "2"}}}, "initial value src.gain: real variable needs a number"),
        (
            {"initial_values": {"src": {"power": 2.5}}},
            "initial value src.power: integer variable needs an int",
        ),
        (
            {"initial_values": {"src": {"negate": 1}}},
            "initial value src.negate: boolean variable needs a bool",
        ),
        ({"initial_values": {"src": {"shape": 3}}}, "initial value src.shape: string variable needs a str"),
        (
            {"connections": [("src", "y", "integ", "v")]},
            "connection src.y -> integ.v: instance 'integ' has no",
        ),
        ({"connections": [("src", "y", "integ", "x0")]}, "integ.x0 is not an input (parameter)"),
        ({"connections": [("integ", "u", "src", "gain")]}, "integ.u is not an output (input)"),
        ({"connections": [("src", "count", "integ", "u")]}, "src.count is integer, only real connections"),
        ({"events": [(0.2, "src", "shape", 1.0)]}, "event src.shape: only real variables"),
        ({"events": [(0.2, "integ", "w", 1.0)]}, "event at t=0.2: instance 'integ' has no variable 'w'"),
        ({"events": [(2.0, "integ", "u", 1.0)]}, "event integ.u: time 2.0 outside [0, 1.0]"),
        ({"events": [(0.5, "integ", "u", "1")]}, "event integ.u: value must be a number, got '1'"),
        ({"duration": 1.05}, "duration 1.05 s is not a whole number of steps of 0.1 s"),
        ({"step_size": 0.0}, "step_size must be a positive number"),
        ({"step_size": 1e-10, "duration": 1e-9}, "not a whole number of nanoseconds"),
    ],
)
def test_bad_descriptions_raise_one_line_runtime_errors(
    fmus: dict[str, Path], kwargs: dict[str, object], message: str
) -> None:
    args: dict[str, object] = {
        "fmus": {"src": fmus["source"], "integ": fmus["integrator"]},
        "connections": [],
        "initial_values": {},
        "step_size": 0.1,
        "duration": 1.0,
        "record": {"src": ["y"]},
    }
    args.update(kwargs)
    with pytest.raises(RuntimeError) as info:
        run_with_libcosim(**args)  # type: ignore[arg-type]
    assert message in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("name", "fmu", "message"),
    [
        ("missing", None, "No such file"),
        ("corrupt", "corrupt", "Not a zip archive"),
        ("ctor_fail", "faulty", "RuntimeError('boom in constructor')"),
    ],
)
def test_fmus_that_fail_to_load_are_named(
    fmus: dict[str, Path], tmp_path: Path, name: str, fmu: str | None, message: str
) -> None:
    path = {None: tmp_path / "missing.fmu", "corrupt": tmp_path / "corrupt.fmu"}.get(fmu, fmus.get(fmu or ""))
    if fmu == "corrupt":
        path.write_bytes(b"not a zip")
    with pytest.raises(RuntimeError) as info:
        run_with_libcosim({"integ": fmus["integrator"], name: path}, [], {}, 0.1, 0.5, {"integ": ["x"]})
    text = str(info.value)
    assert text.startswith(f"instance '{name}': cannot load") and message in text and "\n" not in text


def test_exception_in_do_step_is_reported_and_process_survives(
    fmus: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Isolated: an in-process failure leaks the failed instance and libcosim's threads on purpose
    # (freeing them segfaults), and leftovers like that can corrupt the heap at interpreter exit.
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # the leaked libcosim unpack dir lands here
    with pytest.raises(RuntimeError) as info:
        run_with_libcosim(
            {"bad": fmus["faulty"], "integ": fmus["integrator"]},
            [],
            {"bad": {"fail_in": "step"}},
            0.1,
            1.0,
            {"bad": ["y"]},
            isolate=True,
            timeout=60,
        )
    text = str(info.value)
    assert "step starting at t=0.2 s" in text and "bad:" in text and "boom in step" in text
    gc.collect()
    res = run_with_libcosim({"bad": fmus["faulty"]}, [], {}, 0.1, 0.3, {"bad": ["y"]})
    np.testing.assert_allclose(res["bad.y"], [0.0, 0.1, 0.2, 0.3])


def test_step_refused_without_exception_is_reported_with_the_fmu_log(
    fmus: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """do_step returning False (how seafmu's slaves fail) is a clean libcosim error."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    args = ({"bad": fmus["faulty"]}, [], {"bad": {"fail_in": "discard"}}, 0.1, 1.0, {"bad": ["y"]})
    expected = "libcosim failed in the step starting at t=0.2 s: Simulation error: bad: Step not complete"
    with pytest.raises(RuntimeError) as there:
        run_with_libcosim(*args, isolate=True, timeout=60)
    assert str(there.value) == f"{expected} (last FMU error log: bad: cannot go on)"


def test_exception_during_initialisation_is_named_when_isolated(fmus: dict[str, Path]) -> None:
    with pytest.raises(RuntimeError) as info:
        run_with_libcosim(
            {"integ": fmus["integrator"], "bad": fmus["faulty"]},
            [],
            {"bad": {"fail_in": "init"}},
            0.1,
            1.0,
            {"integ": ["x"]},
            isolate=True,
            timeout=60,
        )
    assert str(info.value) == (
        "instance 'bad' raised ValueError('boom in init') in exit_initialization_mode; "
        "libcosim aborted the process (signal SIGABRT)"
    )


def test_exception_during_initialisation_aborts_an_in_process_host(
    fmus: dict[str, Path], tmp_path: Path
) -> None:
    """Documents the libcosim limitation that makes ``isolate=True`` necessary."""
    code = textwrap.dedent(
        f"""
        from pathlib import Path
        from seafmu.libcosim_runner import run_with_libcosim
        try:
            run_with_libcosim({{"bad": Path({str(fmus["faulty"])!r})}}, [], {{"bad": {{"fail_in": "init"}}}},
                              0.1, 1.0, {{"bad": ["y"]}})
        except RuntimeError:
            raise SystemExit(7)
        """
    )
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == -signal.SIGABRT, proc.stderr[-2000:]
    assert "terminate called after throwing an instance of 'cosim::error'" in proc.stderr

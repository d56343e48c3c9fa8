"""The FMUs' life cycle under fmpy: memory safety over many instantiations, failed ones included,
clean process exits, and no silently wrong value (issue 8).

pythonfmu 0.7.0's wrapper over-releases the model class, the instance and its log queue on every
Python exception it sees, and its static PyState is written after being freed at process exit
(see fmus/_slave.py). Both corrupt memory only sometimes and late, so the cycles run in fresh
child processes, many times, and a child that dies from a signal fails the test.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from seafmu.build import KINDS, VESSELS

REPO = Path(__file__).resolve().parents[1]
FMI_OK, FMI_DISCARD, FMI_FATAL = 0, 2, 4

# The child: cycles of instantiate / initialise / step / terminate / free on the given FMUs, and
# the RSS after a warm-up and at the end. "valid": everything succeeds (with fmi2Reset and FMU
# state round trips in between); "fail": each cycle's initialisation fails on a bad parameter,
# with other refused calls in between and a valid run every 10th cycle. Exits 0 only if every
# call gave the expected status; a crash is a negative return code.
CHILD = textwrap.dedent(r'''
    import json, math, os, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    mode, n, paths = sys.argv[1], int(sys.argv[2]), sys.argv[3:]

    def rss_mb():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

    units = []
    for p in paths:
        md = read_model_description(p)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(p),
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        out = [v.valueReference for v in md.modelVariables if v.causality == "output"]
        par = [v.valueReference for v in md.modelVariables if v.causality == "parameter" and v.type == "Real"]
        units.append((fmu, out, par[0]))

    def status(fn, *args):
        try:
            fn(*args)
            return 0
        except FMICallException as exc:
            return exc.status

    def valid(fmu, out, k):
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        if k % 10 == 3:  # fmi2Reset makes a new Python instance inside the same FMI instance
            fmu.doStep(0.0, 0.05)
            fmu.reset()
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
        for j in range(5):
            fmu.doStep(j * 0.05, 0.05)
        if k % 10 == 7:
            state = fmu.getFMUstate()
            again = fmu.deSerializeFMUstate(fmu.serializeFMUstate(state))
            fmu.setFMUstate(again)
            fmu.freeFMUstate(state)
            fmu.freeFMUstate(again)
        y = fmu.getReal(out)
        assert all(math.isfinite(v) for v in y), y
        fmu.terminate()
        fmu.fmi2FreeInstance(fmu.component)

    def failing(fmu, out, par, k):
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.setReal([par], [float("nan")])
        assert status(fmu.exitInitializationMode) == 4
        if k % 5 == 1:  # other refused calls on the same (still usable) instance
            assert status(fmu.setReal, [out[0]], [1.0]) == 4            # an output
            assert status(fmu.getReal, [10**6]) == 4                    # no such variable
            assert status(fmu.deSerializeFMUstate, b"\x80\x04junk") == 4
            assert status(fmu.doStep, 0.0, 0.05) == 2                   # not initialised
        status(fmu.terminate)
        fmu.fmi2FreeInstance(fmu.component)

    warm = 2 * len(units)
    rss = {}
    for k in range(n):
        fmu, out, par = units[k % len(units)]
        if mode == "valid" or k % 10 == 9:
            valid(fmu, out, k)
        else:
            failing(fmu, out, par, k)
        if k + 1 == warm:
            rss["warm"] = rss_mb()
    rss["end"] = rss_mb()
    if mode == "fail":  # instances left alive after a fatal error, never freed: exit must be clean
        for fmu, out, par in units[:2]:
            fmu.instantiate()
            fmu.enterInitializationMode()
            fmu.setReal([par], [float("inf")])
            assert status(fmu.exitInitializationMode) == 4
    print(json.dumps({"cycles": n, "warm": warm, "rss": rss, "sys_path": len(sys.path)}))
''')


# Without glibc's per-thread cache a freed block goes straight into glibc's bins, where the
# wrapper's exit-time write into freed memory corrupts a list pointer: the "corrupted
# double-linked list" abort became about 4 % of valid runs with the unfixed FMUs (9 of 210
# processes; 0 of 210 with the fix). The children exit that way to make a regression visible.
def _exit_env() -> dict[str, str]:
    """Read when a child starts, not at import: the session's TMPDIR (conftest) is set after."""
    return {**os.environ, "GLIBC_TUNABLES": "glibc.malloc.tcache_count=0"}


def _children(args_list: list[list[str]], timeout: float = 240.0) -> list[dict]:
    """Run the child once per argument list, all at once; every one must exit 0."""
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, *args], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, cwd=REPO, env=_exit_env())
             for args in args_list]
    results = []
    for p in procs:
        out, err = p.communicate(timeout=timeout)
        assert p.returncode == 0, f"child exited with {p.returncode}: {err[-2000:]}"
        results.append(json.loads(out.strip().splitlines()[-1]))
    return results


def _paths(built: dict, vessels: tuple[str, ...] = VESSELS) -> list[str]:
    return [str(built[(v, k)]) for v in vessels for k in KINDS]


def test_300_valid_runs_in_fresh_processes(built_fmus: dict) -> None:
    """3 processes x 100 cycles over all eight FMUs: no crash (also not at exit), bounded memory."""
    results = _children([["valid", "100", *_paths(built_fmus)] for _ in range(3)])
    assert sum(r["cycles"] for r in results) == 300
    for r in results:
        assert r["rss"]["end"] - r["rss"]["warm"] < 20.0, r
        assert r["sys_path"] < 20, r  # one resources entry per FMU, not one per instantiation


def test_200_failed_initialisations_in_a_fresh_process(built_fmus: dict) -> None:
    """Each failure reaches pythonfmu's handle_py_exception (fmi2Fatal); the instance is freed and
    the FMU instantiated again. Before the fix the third cycle segfaulted."""
    (r,) = _children([["fail", "200", *_paths(built_fmus)]])
    assert r["cycles"] == 200
    assert r["rss"]["end"] - r["rss"]["warm"] < 20.0, r


def test_the_issue_repro_cycles(built_fmus: dict) -> None:
    """The reported sequence: bad fail_value_1 on the Minerva 2 plant, free, instantiate again."""
    code = textwrap.dedent('''
        import sys
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        path = sys.argv[1]
        md = read_model_description(path)
        vr = {v.name: v.valueReference for v in md.modelVariables}["fail_value_1"]
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path),
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        for k in range(25):
            fmu.instantiate()
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            try:
                fmu.setReal([vr], [25.0])
                fmu.exitInitializationMode()
            except Exception:
                pass
            try:
                fmu.terminate()
            except Exception:
                pass
            fmu.fmi2FreeInstance(fmu.component)
        print("END ok")
    ''')
    p = subprocess.run([sys.executable, "-c", code, str(built_fmus[("minerva2", "plant")])],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "END ok" in p.stdout, p.stderr[-2000:]


def _symbol_offset(lib: str, name: bytes) -> int | None:
    """st_value of a (local) symbol from an ELF64 little-endian .symtab, or None."""
    import struct

    data = Path(lib).read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        return None
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]
    for sh in sections:
        if sh[1] != 2:  # SHT_SYMTAB
            continue
        strtab = sections[sh[6]]
        for off in range(sh[4], sh[4] + sh[5], 24):
            st_name, _, _, _, st_value, _ = struct.unpack_from("<IBBHQQ", data, off)
            start = strtab[4] + st_name
            if data[start : data.index(b"\0", start)] == name:
                return st_value
    return None


@pytest.mark.skipif(sys.platform != "linux", reason="reads the loaded library through /proc/self/maps")
def test_wrapper_pystate_is_empty_after_instantiation(built_fmus: dict, tmp_path: Path) -> None:
    """The exit-time use-after-free needs a live static ``pyState`` in the wrapper library when the
    process exits: after each instantiation in a Python host it must be empty (two null pointers).
    Without the fix it holds the PyState made by the first fmi2Instantiate until exit."""
    code = textwrap.dedent(r'''
        import ctypes, os, sys
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        path, offset = sys.argv[1], int(sys.argv[2])
        md = read_model_description(path)
        unzip = extract(path)
        name = md.coSimulation.modelIdentifier + ".so"
        lib = os.path.realpath(os.path.join(unzip, "binaries", "linux64", name))
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        def pystate():
            with open("/proc/self/maps") as f:
                base = min(int(line.split("-")[0], 16) for line in f if line.rstrip().endswith(lib))
            return ctypes.string_at(base + offset, 16)
        seen = []
        for k in range(3):
            fmu.instantiate()
            seen.append(pystate().hex())
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            fmu.doStep(0.0, 0.1)
            fmu.terminate()
            fmu.fmi2FreeInstance(fmu.component)
        print(" ".join(seen))
    ''')
    path = built_fmus[("amv_osf", "allocator")]
    lib = Path(extract(str(path), unzipdir=str(tmp_path))) / "binaries" / "linux64" / "AmvOsfAllocator.so"
    offset = _symbol_offset(str(lib), b"_ZN12_GLOBAL__N_17pyStateE")
    assert offset is not None, "pythonfmu 0.7.0's wrapper library exports the pyState symbol"
    p = subprocess.run([sys.executable, "-c", code, str(path), str(offset)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.split() == ["00" * 16] * 3


def test_two_fmus_one_after_another_with_unpacking_and_unloading(built_fmus: dict) -> None:
    """fmpy's simulate_fmu unpacks, runs, unloads the library and deletes the folder; the next
    seafmu FMU in the same process must still find its modules and vessel file."""
    code = textwrap.dedent('''
        import sys
        from fmpy import simulate_fmu
        for p in sys.argv[1:]:
            r = simulate_fmu(p, stop_time=0.5, output_interval=0.1, fmi_type="CoSimulation")
            assert len(r) == 6, len(r)
        print("END ok")
    ''')
    paths = [built_fmus[("minerva2", "plant")], built_fmus[("amv_osf", "controller")],
             built_fmus[("minerva2", "observer")], built_fmus[("minerva2", "plant")]]
    p = subprocess.run([sys.executable, "-c", code, *map(str, paths)], capture_output=True, text=True,
                       timeout=120, cwd="/")
    assert p.returncode == 0 and "END ok" in p.stdout, p.stderr[-2000:]


SHORT_SCENARIO = """\
name: short_lifecycle
vessel: minerva2
duration: 1
step: 0.05
fmus:
  plant: {kind: plant, parameters: {seed: 1, current_speed: 0.1 m/s}}
  observer: {kind: observer}
  controller: {kind: controller, parameters: {down_ref: 5 m}}
  allocator: {kind: allocator}
"""


def test_cli_run_exits_normally_every_time(built_fmus: dict, tmp_path: Path) -> None:
    """`seafmu run` of a short scenario, four times (two at a time): exit 0, no glibc abort."""
    scenario = tmp_path / "short.yaml"
    scenario.write_text(SHORT_SCENARIO)
    for round_ in range(2):
        procs = [subprocess.Popen([sys.executable, "-m", "seafmu.cli", "run", str(scenario), "-q",
                                   "-o", str(tmp_path / f"out{round_}{i}")],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                                  env=_exit_env())
                 for i in range(2)]
        for p in procs:
            _, err = p.communicate(timeout=180)
            assert p.returncode == 0, f"exit {p.returncode}: {err[-2000:]}"
            assert "corrupted" not in err and "double free" not in err, err[-2000:]


# -- no silently wrong values ------------------------------------------------------------------

class _Log:
    def __init__(self) -> None:
        self.lines: list[tuple[int, str]] = []

    def errors(self) -> list[str]:
        return [m for s, m in self.lines if s == 3]


_LOGS: dict[str, _Log] = {}
_CB: list[object] = []


def _route(env: object, instance: bytes, status: int, category: bytes, message: bytes) -> None:
    log = _LOGS.get((instance or b"").decode())
    if log is not None:
        log.lines.append((status, (message or b"").decode()))


def _callbacks() -> object:
    """One set of callbacks for the process: fmpy's logger proxy keeps a single Python callback
    (a callback per instance would leave it pointing at freed ones); routed by instance name."""
    import ctypes

    from fmpy.fmi2 import (
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
    )
    from fmpy.logging import addLoggerProxy

    if not _CB:
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(_route)
        libc = ctypes.CDLL(None)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(libc.calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(libc.free)
        addLoggerProxy(ctypes.byref(cb))
        _CB.append(cb)
    return _CB[0]


def _open(path: Path, params: dict[str, float] | None = None,
          init: bool = True) -> tuple[FMU2Slave, dict, _Log]:
    name = f"x{len(_LOGS)}"
    log = _LOGS[name] = _Log()
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate(callbacks=_callbacks(), loggingOn=True)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for k, v in (params or {}).items():
        fmu.setReal([vr[k]], [v])
    if init:
        fmu.exitInitializationMode()
    return fmu, vr, log


def _step(fmu: FMU2Slave, t: float, h: float) -> int:
    return fmu._functions["fmi2DoStep"](fmu.component, t, h, 1)  # the status, without raising


def _close(fmu: FMU2Slave) -> None:
    try:
        fmu.terminate()
    finally:
        fmu.fmi2FreeInstance(fmu.component)


def _outputs(fmu: FMU2Slave, path: Path) -> np.ndarray:
    md = read_model_description(str(path))
    return np.array(fmu.getReal([v.valueReference for v in md.modelVariables if v.causality == "output"]))


def test_non_finite_input_is_a_discarded_step_naming_it(built_fmus: dict) -> None:
    path = built_fmus[("minerva2", "controller")]
    fmu, vr, log = _open(path)
    assert _step(fmu, 0.0, 0.05) == FMI_OK
    before = _outputs(fmu, path)
    fmu.setReal([vr["north_hat"], vr["yaw_hat"]], [math.nan, math.inf])
    assert _step(fmu, 0.05, 0.05) == FMI_DISCARD
    assert "north_hat = nan" in log.errors()[-1] and "yaw_hat = inf" in log.errors()[-1]
    np.testing.assert_array_equal(_outputs(fmu, path), before)  # no NaN output, ever
    fmu.setReal([vr["north_hat"], vr["yaw_hat"]], [0.0, 0.0])
    assert _step(fmu, 0.05, 0.05) == FMI_OK
    _close(fmu)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NumPy's overflow warnings on the way to NaN
@pytest.mark.parametrize(("path_key", "params", "named"), [
    (("minerva2", "controller"), {"ref_omega": 1e300}, "ref_omega = 1e+300"),
    (("minerva2", "plant"), {"u_0": 1e300}, "u_0 = 1e+300"),
])
def test_non_finite_outputs_are_a_discarded_step_naming_them(built_fmus: dict, path_key: tuple,
                                                              params: dict, named: str) -> None:
    path = built_fmus[path_key]
    fmu, _, log = _open(path, params)
    with np.errstate(all="ignore"):
        status = _step(fmu, 0.0, 0.05)
    assert status == FMI_DISCARD
    msg = log.errors()[-1]
    assert "not finite" in msg and named in msg, msg  # the outputs, and the suspect parameter
    assert np.isfinite(_outputs(fmu, path)).all()
    _close(fmu)


def test_calls_out_of_fmi_order_are_refused_naming_the_order(built_fmus: dict) -> None:
    """FMI 2.0's state machine, which pythonfmu leaves to the FMU: no step before initialisation or
    after fmi2Terminate, one initialisation per instance. Each refusal says which call and why."""
    path = built_fmus[("minerva2", "plant")]
    fmu, _, log = _open(path, init=False)
    assert _step(fmu, 0.0, 0.05) == FMI_DISCARD  # in initialisation mode
    assert "before exitInitializationMode" in log.errors()[-1]
    fmu.exitInitializationMode()
    with pytest.raises(FMICallException):
        fmu.exitInitializationMode()
    assert "exitInitializationMode without enterInitializationMode" in log.errors()[-1]
    with pytest.raises(FMICallException):
        fmu.enterInitializationMode()
    assert "initialised already" in log.errors()[-1]
    assert _step(fmu, 0.0, 0.05) == FMI_OK  # the refusals left the instance as it was
    fmu.terminate()
    assert _step(fmu, 0.05, 0.05) == FMI_DISCARD
    assert "called after fmi2Terminate" in log.errors()[-1]
    with pytest.raises(FMICallException):
        fmu.enterInitializationMode()
    assert "after fmi2Terminate" in log.errors()[-1]
    fmu.fmi2FreeInstance(fmu.component)


@pytest.mark.parametrize("h", [0.0, -0.05, math.nan, math.inf, 1e6, 10.000001])
def test_bad_step_size_is_refused_at_once(built_fmus: dict, h: float) -> None:
    """h = 1e6 used to hang the plant (2e7 RK4 sub-steps); now: 0 < h <= 10 s or fmi2Discard."""
    import time

    path = built_fmus[("minerva2", "plant")]
    fmu, _, log = _open(path)
    t0 = time.perf_counter()
    assert _step(fmu, 0.0, h) == FMI_DISCARD
    assert time.perf_counter() - t0 < 0.5
    assert "0 < h <= 10 s" in log.errors()[-1]
    assert _step(fmu, 0.0, 10.0) == FMI_OK  # the stated maximum itself is fine
    _close(fmu)


def test_bad_parameters_are_fatal_naming_them_and_the_fmu_stays_usable(built_fmus: dict) -> None:
    """pythonfmu 0.7.0 cannot return fmi2Error from Python: a bad value is fmi2Fatal (the only other
    status), logged at error level first, and safe: the instance can still be used and freed."""
    path = built_fmus[("minerva2", "plant")]
    for value, why in ((math.nan, "must be finite"), (-1.0, "must be within [0, 100], got -1.0")):
        fmu, vr, log = _open(path, {"noise_scale": value}, init=False)
        with pytest.raises(FMICallException) as err:
            fmu.exitInitializationMode()
        assert err.value.status == FMI_FATAL
        assert any("noise_scale" in m and why in m and "\n" not in m for m in log.errors()), log.lines
        _close(fmu)
    # a tunable parameter set during the run: checked at once, the run goes on unchanged
    fmu, vr, log = _open(path)
    assert _step(fmu, 0.0, 0.05) == FMI_OK
    with pytest.raises(FMICallException) as err:
        fmu.setReal([vr["current_speed"]], [math.inf])
    assert err.value.status == FMI_FATAL and "current_speed" in log.errors()[-1]
    with pytest.raises(FMICallException):
        fmu.setReal([vr["noise_scale"]], [0.5])  # fixed after initialisation
    assert "noise_scale" in log.errors()[-1]
    with pytest.raises(FMICallException):  # the FMU's own parameter: fixed too, and said so
        fmu.setString([vr["vessel_file"]], ["minerva2_published_damping"])
    assert "'vessel_file' is fixed after initialisation" in log.errors()[-1], log.errors()[-1]
    assert _step(fmu, 0.05, 0.05) == FMI_OK and np.isfinite(_outputs(fmu, path)).all()
    _close(fmu)


def test_every_fmu_describes_its_step_limit(built_fmus: dict) -> None:
    for v in VESSELS:
        for k in KINDS:
            assert "0 < h <= 10 s" in read_model_description(str(built_fmus[(v, k)])).description


def test_a_refused_set_call_changes_nothing(built_fmus: dict) -> None:
    """fmi2SetReal/Integer of several values, one refused: fmi2Fatal, and the others not applied."""
    path = built_fmus[("minerva2", "plant")]
    fmu, vr, log = _open(path)
    assert _step(fmu, 0.0, 0.05) == FMI_OK
    calls = (
        (fmu.setReal, [vr["current_speed"], vr["wave_hs"]], [0.5, -1.0], "wave_hs"),
        (fmu.setReal, [vr["n_cmd_1"], vr["north"]], [7.0, 1.0], "north"),  # an output
        (fmu.setInteger, [vr["fail_mode_1"], vr["fail_mode_2"]], [1, 99], "fail_mode_2"),
    )
    for setter, refs, values, named in calls:
        getter = fmu.getInteger if setter == fmu.setInteger else fmu.getReal
        before = getter(refs[:1])
        with pytest.raises(FMICallException):
            setter(refs, values)
        assert named in log.errors()[-1]
        assert getter(refs[:1]) == before, named
    fmu.setReal([vr["current_speed"], vr["wave_hs"]], [0.5, 1.0])  # both valid: both applied
    assert fmu.getReal([vr["current_speed"], vr["wave_hs"]]) == [0.5, 1.0]
    assert _step(fmu, 0.05, 0.05) == FMI_OK
    _close(fmu)


def _crafted_state(fmu: FMU2Slave, path: Path, change: object) -> bytes:
    """This FMU's own state with values changed and its checksum recomputed: a SHA-256 is no
    signature, anyone can write such bytes."""
    from seafmu.fmus import _state

    guid = read_model_description(str(path)).guid
    tree = _state.decode(fmu.serializeFMUstate(fmu.getFMUstate()), guid)
    change(tree["block"]["attrs"])  # type: ignore[operator]
    return _state.encode(tree, guid)


def test_a_crafted_state_with_an_index_out_of_range_is_a_discarded_step(built_fmus: dict) -> None:
    """The kernels index arrays with positions kept in the state: out of range they raise (the
    process used to die of SIGSEGV, or its heap was silently corrupted)."""
    path = built_fmus[("minerva2", "plant")]
    fmu, _, log = _open(path)
    assert _step(fmu, 0.0, 0.05) == FMI_OK

    def far(attrs: dict) -> None:
        attrs["_layout"]["value"][:] = 10**12

    fmu.setFMUstate(fmu.deSerializeFMUstate(_crafted_state(fmu, path, far)))
    assert _step(fmu, 0.05, 0.05) == FMI_DISCARD
    assert "out of bounds" in log.errors()[-1]
    _close(fmu)


def test_a_crafted_state_that_would_loop_for_hours_is_refused(built_fmus: dict) -> None:
    """A sub-step of 1e-12 s (the parameter still 0.01 s, or both changed) would make one step
    loop for hours: the restored values must be those the parameters give, and fit them."""
    path = built_fmus[("minerva2", "plant")]
    fmu, _, log = _open(path)
    assert _step(fmu, 0.0, 0.05) == FMI_OK
    expected = _outputs(fmu, path)

    def substep(attrs: dict) -> None:
        attrs["_substep"] = 1e-12

    def both(attrs: dict) -> None:
        attrs["_substep"] = 1e-12
        attrs["params"]["items"] = [[k, 1e-12 if k == "substep" else v] for k, v in attrs["params"]["items"]]

    for change, why in ((substep, "sub-step 1e-12 s is not its parameter"), (both, "'substep' must be")):
        with pytest.raises(FMICallException):
            fmu.setFMUstate(fmu.deSerializeFMUstate(_crafted_state(fmu, path, change)))
        assert why in log.errors()[-1], log.errors()[-1]
        np.testing.assert_array_equal(_outputs(fmu, path), expected)  # the instance is as it was
    assert _step(fmu, 0.05, 0.05) == FMI_OK
    _close(fmu)


@pytest.mark.parametrize("vessel", ["minerva2", "supply"])
def test_an_allocator_that_cannot_serve_the_vessel_is_refused(built_fmus: dict, vessel: str) -> None:
    path = built_fmus[(vessel, "allocator")]
    fmu, vr, log = _open(path)
    assert _step(fmu, 0.0, 0.05) == FMI_OK
    with pytest.raises(FMICallException):
        fmu.setString([vr["allocator"]], ["two_screw"])
    assert "'allocator'" in log.errors()[-1] and "two thrusters" in log.errors()[-1]
    assert _step(fmu, 0.05, 0.05) == FMI_OK  # still allocating with its own variant
    _close(fmu)


def test_declared_bounds_are_those_the_fmu_accepts(built_fmus: dict) -> None:
    """Integer parameters carry min/max; an open bound (> 0) is declared as the next number up,
    which the FMU accepts (FMI's min is inclusive); the number of lawnmower lines is bounded."""
    path = built_fmus[("minerva2", "controller")]
    md = read_model_description(str(path))
    var = {v.name: v for v in md.modelVariables}
    assert (var["mode"].min, var["mode"].max) == ("0", "5")
    assert var["lm_lines"].max is not None and int(var["lm_lines"].max) <= 1000
    ref_omega = float(var["ref_omega"].min)
    assert 0.0 < ref_omega < 1e-300
    fmu, vr, log = _open(path, {"ref_omega": 1.0})
    assert _step(fmu, 0.0, 0.05) == FMI_OK
    with pytest.raises(FMICallException):
        fmu.setInteger([vr["lm_lines"]], [int(var["lm_lines"].max) + 1])
    assert "lm_lines" in log.errors()[-1]
    _close(fmu)

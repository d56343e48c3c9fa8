"""seafmu's co-simulation master: stepping of FMUs on fmpy, events, recording, timing.

fmpy simulates one FMU at a time; this is the multi-FMU closed loop it lacks. Each master step,
the FMUs step in scenario order (plant -> observer -> controller -> allocator by default). The
scenario's ``coupling`` says which outputs they read:

* ``gauss-seidel`` (default): the newest outputs of the others: the plant's fresh state reaches the
  observer in the same step, the allocator's command reaches the plant one step later;
* ``jacobi``: the outputs as they stood when the step began (a snapshot of the output bus), as
  OSP libcosim's fixed-step algorithm and ecos do: each connection delays by one step, the order
  does not matter, and the run equals those engines' runs of the exported system (1e-9, tested).

Both initialise once, in scenario order, each FMU's inputs set from the outputs already
initialised before it leaves initialisation mode (libcosim and ecos iterate N times in
initialisation mode instead, N = number of FMUs; for initial-value dependencies that form chains
shorter than N, as seafmu's FMUs do, all three start from the same values).

The same loop drives Blocks directly (``mode="inprocess"``) — no fmpy, no FMI C layer — which
is how tests prove the FMUs add nothing but overhead, and how the benchmark measures it.

Runs that lose nothing: the recorded rows go to a ``sink`` (``seafmu.results.CsvStream``) in
chunks while the run goes; a stop request (``StopRequest``, set by ``stop_on_signals`` for SIGINT,
SIGTERM and SIGHUP) is checked between master steps — never raised inside an FMU, whose Python code
shares this interpreter — and ends the loop with the results up to there; an FMU that fails
mid-run raises ``SimulationError`` with the results up to the failure in ``.partial``. Every unit
is stopped on every way out (a hardware link through its clean stop: thrusters zeroed and
disabled, recording finished).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from seafmu.fmu_cache import unpacked
from seafmu.outdir import os_error_text
from seafmu.scenario import MAX_RESULT_BYTES, MAX_STEPS, Instance, Scenario
from seafmu.unit import Unit, UnitRequest, is_paced, make_unit, register_unit_kind, run_errors, unit_kind

Mode = Literal["fmu", "inprocess"]


class SimulationError(RuntimeError):
    """A run that failed; the message is one line naming the FMU and what it reported.

    ``partial`` holds the results up to the failure when the loop had started (else None).
    """

    partial: RunResult | None = None


STOP_SIGNALS = tuple(s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s)


class StopRequest:
    """Set by a signal handler, read by the master between steps (an attribute read per step)."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def request(self, signum: int) -> None:
        if self.signum is None:
            self.signum = signum

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""

    @property
    def exit_code(self) -> int:
        """128 + the signal number, as a shell reports a process the signal ended: 130, 143, 129."""
        return 128 + (self.signum or signal.SIGINT)


@contextlib.contextmanager
def stop_on_signals(stop: StopRequest) -> Iterator[StopRequest]:
    """SIGINT, SIGTERM and SIGHUP only set ``stop`` while inside; the old handlers come back after.

    The handler raises nothing: a KeyboardInterrupt would surface inside whatever Python code runs
    at that moment — often an FMU's, which then reports a failed FMI call instead of a stop.
    A signal inherited as ignored (``nohup``; SIGINT in a shell's background job) stays ignored.
    Outside the main thread (where handlers cannot be set) this does nothing.
    """
    old: dict[int, Any] = {}
    try:
        for sig in STOP_SIGNALS:
            if signal.getsignal(sig) is signal.SIG_IGN:  # nohup, or a background job's SIGINT: stays ignored
                continue
            old[sig] = signal.signal(sig, lambda signum, frame: stop.request(signum))
    except ValueError:  # not the main thread
        pass
    try:
        yield stop
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


class Sink(Protocol):
    """Where the master streams its recorded rows (time first) while it runs."""

    def begin(self, columns: list[str]) -> None: ...
    def write(self, rows: np.ndarray) -> None: ...


SINK_ROWS = 1000  # rows per chunk written to the sink ...
SINK_SECONDS = 1.0  # ... or sooner, once this much wall time has passed since the last chunk


@dataclass
class RunResult:
    scenario: Scenario
    time: np.ndarray
    signals: dict[str, np.ndarray]  # "instance.variable" -> samples
    wall_time: float
    step_time: dict[str, float]  # instance -> seconds spent in set/step/get
    steps: dict[str, int]
    mode: str
    log: list[str] = field(default_factory=list)
    pacing: dict[str, Any] | None = None  # real-time runs: factor over windows, jitter percentiles
    pacing_summary: str = ""
    t_end: float | None = None  # simulated time reached (the duration unless stopped early)
    interrupted: str = ""  # the signal that stopped the run early ("SIGTERM"), else ""
    error: str = ""  # the failure that ended the run early, else ""

    def __post_init__(self) -> None:
        if self.t_end is None:
            self.t_end = self.scenario.duration

    @property
    def complete(self) -> bool:
        return not self.interrupted and not self.error

    @property
    def realtime_factor(self) -> float:
        t = self.scenario.duration if self.t_end is None else self.t_end
        return t / self.wall_time if self.wall_time > 0 else math.inf

    def us_per_step(self) -> dict[str, float]:
        return {k: 1e6 * v / max(self.steps[k], 1) for k, v in self.step_time.items()}


# -- units: one FMU, one Block in-process, or a hardware link (protocol: seafmu/unit.py) ---------

_Unit = Unit  # the former name of the protocol


class BlockUnit:
    """A Block driven directly: the in-process composition of the same components."""

    paces_itself = False

    def __init__(self, inst: Instance, vessel: str, in_names: list[str]) -> None:
        from seafmu.components.block import full_params
        from seafmu.components.vessel_spec import load_vessel
        from seafmu.fmus.registry import BLOCKS

        if inst.kind is None:
            raise SimulationError(f"{inst.name}: an FMU file cannot run in-process (only seafmu kinds)")
        self.name = inst.name
        spec_name = inst.parameters.get("vessel_file") or vessel
        spec = load_vessel(spec_name)
        cls = BLOCKS[inst.kind]
        iface = cls.interface(spec)
        params = {k: v for k, v in inst.parameters.items() if k != "vessel_file"}
        all_inputs = iface.input_names()
        self._u = np.array([s.start for s in iface.inputs], dtype=float)
        for k, v in list(params.items()):
            if k in all_inputs:  # initial input values given under 'parameters'
                self._u[all_inputs.index(k)] = v
                del params[k]
        self._new_block = lambda: cls(spec, full_params(iface, params))
        try:
            self.block = self._new_block()
        except ValueError as exc:
            raise SimulationError(f"{inst.name}: {exc}") from None
        self.out_names = iface.output_names()
        self.in_names = in_names
        self._in_idx = np.array([all_inputs.index(n) for n in in_names], dtype=int)
        self._all_inputs = all_inputs
        self._y = np.zeros(len(self.out_names))

    def initial_outputs(self, values: np.ndarray) -> np.ndarray:
        """From a block made for this look only, as the FMU makes one in initialisation mode: the
        block that runs starts once, from the settled inputs (its start draws random numbers)."""
        u = self._u.copy()
        u[self._in_idx] = values
        try:
            return np.asarray(self._new_block().start(u), dtype=float)
        except ValueError as exc:
            raise SimulationError(f"{self.name}: {exc}") from None

    def initialize(self, values: np.ndarray) -> np.ndarray:
        self.set_inputs(values)
        try:
            self._y = np.asarray(self.block.start(self._u.copy()), dtype=float)
        except ValueError as exc:
            raise SimulationError(f"{self.name}: {exc}") from None
        return self._y

    def set_inputs(self, values: np.ndarray) -> None:
        self._u[self._in_idx] = values

    def get_outputs(self) -> np.ndarray:
        return self._y

    def do_step(self, t: float, h: float) -> None:
        try:
            self._y = self.block.step(t, h, self._u)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            raise SimulationError(f"{self.name} at t = {t:.3f} s: {exc}") from None

    def set_value(self, var: str, value: Any) -> None:
        if var in self._all_inputs:
            self._u[self._all_inputs.index(var)] = value
            return
        try:
            self.block.set_parameter(var, value)
        except ValueError as exc:
            raise SimulationError(f"{self.name}: {exc}") from None

    def terminate(self) -> None:
        pass

    def collect_log(self) -> None:
        """A block raises at once; nothing is buffered."""

    def step_error(self, what: str, exc: Exception) -> Exception:
        return exc


class _StatusError(RuntimeError):
    """An FMI call on the hot path returned discard, error or fatal."""


_EXTRACTED: dict[tuple[str, int, int], str] = {}

# fmpy's logger proxy formats the variadic FMI log call and hands it to ONE Python callback for the
# whole process, so messages are routed by the instance name the FMU passes, not by which unit
# registered last. Each FmuUnit subscribes its list under its instance name.
_LOG_ROUTES: dict[str, list[str]] = {}
_CALLBACKS: list[Any] = []  # every set handed to an FMU stays alive as long as the process


def _route_log(env: Any, instance: bytes, status: int, category: bytes, message: bytes) -> None:
    name = instance.decode("utf-8", "replace") if instance else "?"
    text = message.decode("utf-8", "replace") if message else ""
    if status >= 2 and text and "Fatal py exception" not in text and text.strip() != "unknown error":
        _LOG_ROUTES.setdefault(name, []).append(f"{name}: {' '.join(text.split())}")


def _callbacks() -> Any:
    """Callbacks for one instantiation, with the logger routed to ``_route_log``.

    fmpy's native logger proxy (which formats the variadic message) keeps ONE Python logger for
    the whole process, the last one registered: any other code in the process that registers its
    own (a test, a user's script, fmpy's simulate_fmu) would take the FMUs' messages away from the
    master. So every instantiation registers ours again, on a fresh struct (registering a struct
    twice would make the proxy call itself); FMI requires the struct to outlive the instance.
    """
    from fmpy.fmi2 import (
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
    )
    from fmpy.logging import addLoggerProxy

    if not _CALLBACKS:
        libc = ctypes.CDLL(None)
        _CALLBACKS.append((fmi2CallbackLoggerTYPE(_route_log), fmi2CallbackAllocateMemoryTYPE(libc.calloc),
                           fmi2CallbackFreeMemoryTYPE(libc.free)))
    logger, alloc, free = _CALLBACKS[0]
    cb = fmi2CallbackFunctions()
    cb.logger, cb.allocateMemory, cb.freeMemory = logger, alloc, free
    addLoggerProxy(ctypes.byref(cb))
    _CALLBACKS.append(cb)
    return cb


def _extract(fmu: Path) -> str:
    """The FMU's unpacked folder: unpacked once per FMU version and kept between runs
    (``seafmu.fmu_cache``), looked up once per file version and process."""
    st = fmu.stat()
    key = (str(fmu), st.st_mtime_ns, st.st_size)
    if key not in _EXTRACTED:
        _EXTRACTED[key] = str(unpacked(fmu))
    return _EXTRACTED[key]


_MODEL_DESCRIPTIONS: dict[tuple[str, int], Any] = {}


def _model_description(fmu: Path) -> Any:
    """The FMU's parsed modelDescription, once per file version and process (a sweep's worker runs
    many cases on the same FMUs; the parse is a measurable part of setting up a case)."""
    from fmpy import read_model_description

    key = (str(fmu), fmu.stat().st_mtime_ns)
    if key not in _MODEL_DESCRIPTIONS:
        _MODEL_DESCRIPTIONS[key] = read_model_description(str(fmu))
    return _MODEL_DESCRIPTIONS[key]


class FmuUnit:
    """An FMU on fmpy's FMU2Slave, with preallocated ctypes buffers on the hot path."""

    paces_itself = False

    def __init__(self, inst: Instance, fmu_file: Path, in_names: list[str], log: list[str]) -> None:
        from fmpy.fmi2 import FMU2Slave, fmi2Real, fmi2ValueReference

        self.name = inst.name
        self.log = log
        md = _model_description(fmu_file)
        self._vars = {v.name: v for v in md.modelVariables}
        self.out_names = [v.name for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
        # in value-reference order, so the FMU can take all its inputs as one slice
        self.in_names = sorted(in_names, key=lambda n: self._vars[n].valueReference)
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=_extract(fmu_file),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName=inst.name)
        self._messages = _LOG_ROUTES.setdefault(inst.name, [])
        self._messages.clear()
        self._instantiated = False
        self._call("instantiate", lambda: self.fmu.instantiate(callbacks=_callbacks(), loggingOn=True))
        self._instantiated = True
        try:
            self._call("setupExperiment", lambda: self.fmu.setupExperiment(startTime=0.0))
            self._call("enterInitializationMode", self.fmu.enterInitializationMode)
            for k, v in inst.parameters.items():
                self.set_value(k, v)
        except SimulationError:
            self.terminate()
            raise

        out_vr = [self._vars[n].valueReference for n in self.out_names]
        in_vr = [self._vars[n].valueReference for n in self.in_names]
        self._n_out, self._n_in = len(out_vr), len(in_vr)
        self._out_vr = (fmi2ValueReference * self._n_out)(*out_vr)
        self._out_buf = (fmi2Real * self._n_out)()
        self._out_np = np.ctypeslib.as_array(self._out_buf) if self._n_out else np.zeros(0)
        self._in_vr = (fmi2ValueReference * self._n_in)(*in_vr)
        self._in_buf = (fmi2Real * self._n_in)()
        self._in_np = np.ctypeslib.as_array(self._in_buf) if self._n_in else np.zeros(0)
        # The raw ctypes functions: fmpy's wrappers add a Python call and logging check per call,
        # which is measurable at 4 x 3 calls per 50 ms step; the status is checked here instead.
        self._get = self.fmu._functions["fmi2GetReal"]
        self._set = self.fmu._functions["fmi2SetReal"]
        self._step = self.fmu._functions["fmi2DoStep"]
        self._comp = self.fmu.component

    def _call(self, what: str, fn: Any) -> Any:
        try:
            return fn()
        except Exception as exc:  # fmpy raises FMICallException; the FMU's log says why
            raise self.error(what, exc) from None

    def error(self, what: str, exc: Exception) -> SimulationError:
        self.log.extend(m for m in self._messages if m not in self.log)
        detail = self._messages[-1].split(": ", 1)[1] if self._messages else str(exc)
        return SimulationError(f"FMU '{self.name}' failed in {what}: {detail}")

    def collect_log(self) -> None:
        """Warnings and errors the FMU logged during a run that went on (e.g. discarded steps)."""
        self.log.extend(m for m in self._messages if m not in self.log)

    def step_error(self, what: str, exc: Exception) -> Exception:
        return self.error(what, exc)

    def initial_outputs(self, values: np.ndarray) -> np.ndarray:
        self._call("setReal (initial inputs)", lambda: self.set_inputs(values))
        return self._call("getReal (initial outputs)", self.get_outputs).copy()

    def initialize(self, values: np.ndarray) -> np.ndarray:
        """Inputs set in initialisation mode, then exit it: the FMU starts from upstream values."""
        self._call("setReal (initial inputs)", lambda: self.set_inputs(values))
        self._call("exitInitializationMode", self.fmu.exitInitializationMode)
        return self._call("getReal (initial outputs)", self.get_outputs)

    def set_inputs(self, values: np.ndarray) -> None:
        if self._n_in:
            self._in_np[:] = values
            if self._set(self._comp, self._in_vr, self._n_in, self._in_buf) > 1:
                raise _StatusError("fmi2SetReal")

    def get_outputs(self) -> np.ndarray:
        if self._n_out and self._get(self._comp, self._out_vr, self._n_out, self._out_buf) > 1:
            raise _StatusError("fmi2GetReal")
        return self._out_np

    def read_only(self, positions: list[int]) -> None:
        """Name the outputs (positions in ``out_names``) ``get_some_outputs`` reads: a step that is
        not recorded needs only the connected ones, and each value crossing the FMI layer costs."""
        from fmpy.fmi2 import fmi2Real, fmi2ValueReference

        vr = [self._vars[self.out_names[i]].valueReference for i in positions]
        self._some_n = len(vr)
        self._some_vr = (fmi2ValueReference * len(vr))(*vr)
        self._some_buf = (fmi2Real * len(vr))()
        self._some_np = np.ctypeslib.as_array(self._some_buf) if vr else np.zeros(0)

    def get_some_outputs(self) -> np.ndarray:
        """The outputs named by ``read_only``, in that order."""
        if self._some_n and self._get(self._comp, self._some_vr, self._some_n, self._some_buf) > 1:
            raise _StatusError("fmi2GetReal")
        return self._some_np

    def do_step(self, t: float, h: float) -> None:
        if self._step(self._comp, t, h, 1) > 1:  # > fmi2Warning
            raise _StatusError("fmi2DoStep")

    def set_value(self, var: str, value: Any) -> None:
        v = self._vars[var]
        vr = [v.valueReference]
        setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger,
                  "Boolean": self.fmu.setBoolean, "String": self.fmu.setString}[v.type]
        self._call(f"set {var}", lambda: setter(vr, [value]))

    def terminate(self) -> None:
        if not getattr(self, "_instantiated", False):
            return
        self._instantiated = False
        with contextlib.suppress(Exception):  # an FMU that failed may refuse to terminate: freed anyway
            self.fmu.terminate()
        # Free the instance but keep the shared library loaded: unloading pythonfmu's library and
        # loading it again in the same process makes the next instantiate fail.
        with contextlib.suppress(Exception):
            self.fmu.fmi2FreeInstance(self.fmu.component)


# -- the unit kinds (seafmu/unit.py: UNIT_KINDS) -------------------------------------------------

@register_unit_kind("fmu")
def _fmu_unit(req: UnitRequest) -> Unit:
    """The instance's FMU: its ``fmu:`` file, the one given to ``run``, else seafmu's built FMU."""
    path = req.fmu_file
    if path is None:
        from seafmu.build import build_fmu

        path = build_fmu(req.vessel, req.instance.kind or "").path
    return FmuUnit(req.instance, Path(path), req.in_names, req.log)


@register_unit_kind("inprocess")
def _block_unit(req: UnitRequest) -> Unit:
    return BlockUnit(req.instance, req.vessel, req.in_names)


def _hardware_errors() -> tuple[type[Exception], ...]:
    from seafmu.hardware.link import HardwareError

    return (HardwareError,)


@register_unit_kind("hardware", errors=_hardware_errors)
def _hardware_unit(req: UnitRequest) -> Unit:
    """A real or emulated vessel behind the link; it paces the loop and records under record_dir."""
    from seafmu.hardware.link import HardwareError, HardwareLink

    inst = req.instance
    try:
        return HardwareLink(inst.hardware, name=inst.name, in_names=req.in_names, log_lines=req.log,
                            record_dir=req.record_dir, vessel=req.vessel)
    except (HardwareError, ValueError, OSError) as exc:
        raise SimulationError(f"{inst.name}: {' '.join(str(exc).split())}") from None


# -- the master loop ---------------------------------------------------------------------------

def run(scenario: Scenario, mode: Mode = "fmu", progress: bool = True,
        fmu_files: dict[str, Path] | None = None, record_dir: Path | None = None,
        stop: StopRequest | None = None, sink: Sink | None = None) -> RunResult:
    """Run a resolved scenario; ``fmu_files`` maps instance -> FMU (built ones by default).

    An instance with a hardware profile is a ``HardwareLink`` (a real or emulated vessel); the link
    paces the loop to the wall clock and records its traffic under ``record_dir``. ``stop``, once
    requested, ends the loop before the next master step (``RunResult.interrupted``); ``sink``
    receives the recorded rows in chunks while the run goes. A recording file that cannot be
    written stops the recording, not the run (its warning joins ``RunResult.log``); an OSError
    that ends the run mid-way is a SimulationError naming the file, with ``partial`` results.
    """
    # load_scenario bounds these; a Scenario changed in code (dataclasses.replace) is checked here
    if scenario.n_steps > MAX_STEPS or scenario.result_bytes > MAX_RESULT_BYTES:
        raise SimulationError(f"{scenario.name}: {scenario.n_steps} steps, {scenario.n_samples} samples of "
                              f"{len(scenario.outputs)} signals: above the limits ({MAX_STEPS} steps, "
                              f"{MAX_RESULT_BYTES} bytes of results)")
    log: list[str] = []
    inputs_of: dict[str, list[tuple[str, str, str]]] = {}
    for si, sv, di, dv in scenario.connections:
        inputs_of.setdefault(di, []).append((dv, si, sv))

    units: list[Unit] = []
    kinds = {unit_kind(inst, mode) for inst in scenario.instances}
    try:
        for inst in scenario.instances:
            fmu_file = inst.fmu_file or (fmu_files or {}).get(inst.name)
            in_names = [dv for dv, _, _ in inputs_of.get(inst.name, [])]
            request = UnitRequest(inst, in_names, scenario.vessel, log, record_dir=record_dir,
                                  fmu_file=Path(fmu_file) if fmu_file else None)
            units.append(make_unit(unit_kind(inst, mode), request))
        unit_errors = run_errors(kinds)
        try:
            result = _loop(scenario, units, mode, progress, log, stop, sink)
        except unit_errors as exc:  # a port that cannot open, a vessel that never answers
            raise _failed(str(exc), exc) from None
        except OSError as exc:  # a file that failed mid-run (results.csv on a full disk): name it
            if getattr(exc, "partial", None) is None:  # before the first step: as it is
                raise
            raise _failed(os_error_text(exc), exc) from None
        paced = [u for u in units if is_paced(u)]
        for u in paced:  # a link's step waits for the wall clock: its cost (µs/step) is the rest
            result.step_time[u.name] = max(result.step_time[u.name] - u.pacing_stats().waited, 0.0)
        if paced:
            stats = paced[0].pacing_stats()
            result.pacing, result.pacing_summary = stats.as_dict(), stats.summary()
        return result
    finally:
        for u in units:
            u.collect_log()
            _stop_unit(u)


def _failed(text: str, exc: Exception) -> SimulationError:
    """The one-line SimulationError of ``exc``, with the results up to it that the loop attached."""
    err = SimulationError(" ".join(text.split()))
    err.partial = getattr(exc, "partial", None)
    if err.partial is not None:
        err.partial.error = str(err)
    return err


def _stop_unit(u: Unit) -> None:
    """A unit's clean stop: a hardware link's ``close()`` (thrusters zeroed and disabled, recording
    finished) where it has one, else ``terminate()``."""
    close = getattr(u, "close", None)
    (close if callable(close) else u.terminate)()


def _partial_read(u: Unit, out: slice, src_idx: list[np.ndarray]) -> tuple[Any, np.ndarray | None]:
    """(read, bus slots) for a unit that can read some of its outputs (``get_some_outputs``) and whose
    connected outputs are fewer than all: the steps that are not recorded read only those."""
    if getattr(u, "get_some_outputs", None) is None:
        return None, None
    used = sorted({int(s) for idx in src_idx for s in idx.tolist() if out.start <= s < out.stop})
    if len(used) == out.stop - out.start:
        return None, None
    u.read_only([s - out.start for s in used])  # type: ignore[attr-defined]
    return u.get_some_outputs, np.array(used, dtype=int)  # type: ignore[attr-defined]


def _loop(scenario: Scenario, units: list[Unit], mode: str, progress: bool, log: list[str],
          stop: StopRequest | None = None, sink: Sink | None = None) -> RunResult:
    # Long because it is the co-simulation algorithm read in one place: wiring, initial values in
    # causal order, the step loop (events, Gauss-Seidel or Jacobi, multirate, recording, stop
    # requests) and the result; the hot loop's locals would otherwise travel through every call.
    # One flat "bus" of every output; inputs read slices of it through index arrays.
    slot: dict[tuple[str, str], int] = {}
    out_slices = []
    for u in units:
        start = len(slot)
        for n in u.out_names:
            slot[(u.name, n)] = len(slot)
        out_slices.append(slice(start, len(slot)))
    bus = np.zeros(len(slot))
    src_idx = []
    for u in units:
        conn = {dv: (si, sv) for si, sv, di, dv in scenario.connections if di == u.name}
        src_idx.append(np.array([slot[conn[n]] for n in u.in_names], dtype=int))

    # Initial values propagated along every connection until they settle, as libcosim does (in
    # initialisation mode: inputs set, outputs read, again), so that the FMUs' order in the scenario
    # changes nothing (listed against the data flow, the observer started from a plant at 0). A
    # closed loop settles where some FMU's initial outputs do not depend on its inputs (the plant's
    # on its thrust command); one that does not is left after as many rounds as FMUs. Then each FMU
    # leaves initialisation mode from the settled inputs.
    quiet: set[int] = set()  # units that cannot be read in initialisation mode: initialised in order
    for _ in range(len(units)):
        before = bus.copy()
        for j, (u, sl) in enumerate(zip(units, out_slices, strict=True)):
            if j in quiet:
                continue
            try:
                y = u.initial_outputs(bus[src_idx[j]])
            except SimulationError:  # an FMU that refuses it; its initialize below says what is wrong
                y = None
            if y is None:
                quiet.add(j)
            else:
                bus[sl] = y
        if np.array_equal(bus, before, equal_nan=True):
            break
    for j, (u, sl) in enumerate(zip(units, out_slices, strict=True)):
        bus[sl] = u.initialize(bus[src_idx[j]])

    n_steps = round(scenario.duration / scenario.step)
    rec_every = scenario.record_every
    n_rec = n_steps // rec_every + 1
    source_of = {(di, dv): (si, sv) for si, sv, di, dv in scenario.connections}
    rec_slots, rec_keys, extra = [], [], []
    for inst, var in scenario.outputs:
        key = source_of.get((inst, var), (inst, var))  # a connected input is its source's value
        if key in slot:
            rec_slots.append(slot[key])
            rec_keys.append((inst, var))
        else:
            extra.append((inst, var))
    rec_slots_arr = np.array(rec_slots, dtype=int)
    rec = np.empty((n_rec, len(rec_slots)))
    held: dict[tuple[str, str], float] = {}  # recorded inputs/parameters set by events or scenario
    for inst in scenario.instances:
        for info in inst.variables.values():
            if info.causality in ("input", "parameter") and info.type in ("real", "integer"):
                try:
                    held[(inst.name, info.name)] = float(info.start)
                except (TypeError, ValueError):
                    pass
        for k, v in inst.parameters.items():
            if isinstance(v, int | float) and not isinstance(v, bool):
                held[(inst.name, k)] = float(v)
    extra_rec = np.full((n_rec, len(extra)), np.nan)
    times = np.empty(n_rec)

    names = [f"{i}.{v}" for i, v in rec_keys] + [f"{i}.{v}" for i, v in extra]
    n_done = 0  # rows recorded
    n_sent = 0  # rows handed to the sink
    last_sent = time.perf_counter()

    def send() -> None:
        nonlocal n_sent, last_sent
        if sink is not None and n_done > n_sent:
            try:
                sink.write(np.column_stack([times[n_sent:n_done], rec[n_sent:n_done],
                                            extra_rec[n_sent:n_done]]))
            except OSError as exc:  # a write names no file: the sink's (results.csv)
                if exc.filename is None:
                    exc.filename = getattr(sink, "path", None)
                raise
        n_sent, last_sent = n_done, time.perf_counter()

    def record(row: int, t: float) -> None:
        nonlocal n_done
        times[row] = t
        rec[row] = bus[rec_slots_arr]
        for j, key in enumerate(extra):
            extra_rec[row, j] = held.get(key, np.nan)
        n_done = row + 1
        if sink is not None and (n_done - n_sent >= SINK_ROWS
                                 or time.perf_counter() - last_sent >= SINK_SECONDS):
            send()

    events = list(scenario.events)
    ev_i = 0
    by_name = {u.name: u for u in units}
    h = scenario.step
    eps = 1e-9 * h

    def apply_events(t: float) -> None:
        nonlocal ev_i
        while ev_i < len(events) and events[ev_i][0] <= t + eps:
            _, inst, var, value = events[ev_i]
            by_name[inst].set_value(var, value)
            held[(inst, var)] = float(value) if isinstance(value, int | float) else np.nan
            ev_i += 1

    if sink is not None:
        sink.begin(["time", *names])
    apply_events(0.0)
    record(0, 0.0)
    n_events = len(events)
    spent = [0.0] * len(units)  # per unit: seconds in set/step/get, and steps taken
    stepped = [0] * len(units)
    mults = [i.step_multiple for i in scenario.instances]
    # What a unit's step needs, looked up once: its bound calls, output slice, input index map.
    plan = [(j, u.set_inputs if len(src_idx[j]) else None, u.do_step, u.get_outputs, out_slices[j],
             src_idx[j], mults[j], *_partial_read(u, out_slices[j], src_idx)) for j, u in enumerate(units)]
    # An FMU stepping every m master steps computes its outputs for t + m h at once; they are
    # published when the master reaches t + m h, not earlier (no values from the future).
    pending: dict[int, np.ndarray] = {}

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_steps, desc=scenario.name, unit="step", delay=1.0, leave=False)
    perf = time.perf_counter
    # A hardware link paces the loop itself (it sleeps to the wall clock inside its step); a
    # simulation-only run asked to be real-time gets a pacer here.
    pacer = None
    if scenario.realtime and not any(is_paced(u) for u in units):
        from seafmu.hardware.pacing import Pacer

        pacer = Pacer(h)
        pacer.start()
    if stop is None:
        stop = StopRequest()  # never requested: one attribute read per step either way
    jacobi = scenario.coupling == "jacobi"
    k_done = 0  # master steps completed
    wall0 = perf()

    def result(wall: float) -> RunResult:
        signals = {name: col for name, col in zip(names, [*rec[:n_done].T, *extra_rec[:n_done].T],
                                                  strict=True)}
        step_time = {u.name: spent[j] for j, u in enumerate(units)}
        steps = {u.name: stepped[j] for j, u in enumerate(units)}
        r = RunResult(scenario, times[:n_done], signals, wall, step_time, steps, mode, log,
                      t_end=k_done * h, interrupted=stop.name if k_done < n_steps else "")
        if pacer is not None:
            stats = pacer.stats()
            r.pacing, r.pacing_summary = stats.as_dict(), stats.summary()
        return r

    try:
        for k in range(n_steps):
            if stop.signum is not None:
                break
            t = k * h
            if ev_i < n_events and events[ev_i][0] <= t + eps:
                apply_events(t)
            # Jacobi: every FMU reads the bus as it stood before any FMU stepped; Gauss-Seidel the bus
            src = bus.copy() if jacobi else bus
            full = (k + 1) % rec_every == 0  # recorded after this step: every output, else the connected
            for j, set_inputs, do_step, get_outputs, sl, idx, m, get_some, some in plan:
                if m != 1 and k % m:
                    if (k + 1) % m == 0:
                        bus[sl] = pending.pop(j)
                    continue
                t0 = perf()
                try:
                    if set_inputs is not None:
                        set_inputs(src[idx])
                    do_step(t, h * m)
                    if m == 1:
                        if full or get_some is None:
                            bus[sl] = get_outputs()
                        else:
                            bus[some] = get_some()
                    else:
                        pending[j] = get_outputs().copy()
                except SimulationError:
                    raise
                except Exception as exc:
                    err = units[j].step_error(f"step at t = {t:.3f} s", exc)
                    if err is exc and isinstance(exc, OSError):  # a file or port: named, one line
                        err = SimulationError(f"{units[j].name} at t = {t:.3f} s: {os_error_text(exc)}")
                    if err is exc:
                        raise
                    raise err from None
                spent[j] += perf() - t0
                stepped[j] += 1
            k_done = k + 1
            if k_done % rec_every == 0:
                record(k_done // rec_every, k_done * h)
            if pacer is not None:
                pacer.wait_until(k + 1)
            if bar is not None and k % 200 == 0:
                bar.update(min(200, n_steps - k))
        if k_done < n_steps and k_done % rec_every:  # stopped between two samples: keep the last step
            for _, _, _, get_outputs, sl, _, m, get_some, _ in plan:
                if m == 1 and get_some is not None:  # the outputs not read in that step
                    bus[sl] = get_outputs()
            record(n_done, k_done * h)
        send()  # the last rows: a sink that fails here still gets the results up to there
    except BaseException as exc:
        if isinstance(exc, Exception):  # the results up to the failure travel with the error
            partial = result(perf() - wall0)
            partial.interrupted = ""
            partial.error = " ".join(str(exc).split())
            with contextlib.suppress(AttributeError):
                exc.partial = partial  # type: ignore[attr-defined]
        with contextlib.suppress(Exception):
            send()
        raise
    finally:
        if bar is not None:
            bar.close()
    return result(perf() - wall0)

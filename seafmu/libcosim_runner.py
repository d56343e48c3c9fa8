"""Run seafmu's FMUs wired together under OSP libcosim (pip ``libcosimpy``).

Why: it is the proof that the pythonfmu-built FMUs work in an FMI host other than seafmu's own
master on fmpy.  :func:`run_with_libcosim` takes the same kind of description seafmu's master
takes (FMU paths, connections, initial values, events) and returns recorded time series.

Coupling order -- why results differ from seafmu's own master
-------------------------------------------------------------
libcosim's ``fixed_step_algorithm`` is a non-iterative *Jacobi* scheme: at every communication
point ``t_k`` all slaves are stepped (in parallel, on a worker thread pool) over ``[t_k, t_k+h]``
with the inputs they received at ``t_k``; only after *all* steps finished are outputs copied to
the connected inputs.  A Gauss-Seidel master that steps the slaves in data-flow order instead
hands each consumer the output its producer has *just* computed at ``t_k+h``.  So, relative to a
Gauss-Seidel master, **every connection adds one step (h) of delay**: for a chain
``A -> B -> C`` and zero initial states, ``B_jacobi(t_k) = B_gs(t_(k-1))`` and
``C_jacobi(t_k) = C_gs(t_(k-2))`` (the tests check exactly this).  In a feedback loop
(plant -> observer -> controller -> allocator -> plant) the loop delay grows from one step (the
one the Gauss-Seidel loop must break somewhere) to four.

seafmu's master couples the same way when the scenario says ``coupling: jacobi`` (or ``seafmu
run --coupling jacobi``): each FMU then steps with a snapshot of the outputs taken before any FMU
stepped.  With that, :func:`run_scenario_with_libcosim` and seafmu's run of the same scenario
agree to 1e-11 on minerva2_dp (60 s, row 0 included; ``tests/test_coupling.py`` checks 1e-9
against libcosim and ecos running the exported files).  With the default Gauss-Seidel coupling
they differ by what the extra delays explain (centimetres on minerva2_dp).

Other libcosim semantics worth knowing:

* Initialisation: libcosim sets initial values in the *instantiated* state, enters
  initialisation mode, then does N rounds (N = number of slaves) of get-outputs/set-inputs to
  propagate initial outputs along connections, then exits initialisation mode.  The row at
  ``time == 0`` holds the values observed right after initialisation.
* A recorded *input* at ``t_k`` is the value the FMU held during the step that ended at ``t_k``
  (libcosim reads it back from the FMU after the step), i.e. the producer's value at ``t_(k-1)``.
* Time is integer nanoseconds in libcosim; ``step_size`` must be a whole number of ns.

Events
------
Events ``(time, instance, variable, value)`` are applied with libcosim's *override manipulator*
while stepping the execution in chunks between event times: an event takes effect at the first
communication point ``t_k >= time`` (i.e. it is seen by the step starting at ``t_k``), exactly
like a master that calls ``fmi2SetReal`` before ``fmi2DoStep(t_k)``.  The override is
*persistent*: on a connected input it replaces the connection's value for the rest of the run
(libcosim manipulator semantics), unlike a one-off ``fmi2SetReal`` which the next transfer would
overwrite.  Events at ``t == 0`` act from the first step; values needed during initialisation
belong in ``initial_values``.

Threads, the GIL and failure handling (why there is an ``isolate`` option)
-------------------------------------------------------------------------
pythonfmu's C wrapper runs the FMU's Python code in the *host* interpreter and takes the GIL
with ``PyGILState_Ensure``; libcosim calls the FMUs from its worker threads.  This works in
process because libcosimpy loads ``libcosimc`` with ``ctypes.CDLL``, which releases the GIL for
the duration of every C call (a binding that kept the GIL would deadlock).  Verified here:
several pythonfmu FMUs in one execution, two instances of one FMU, and libcosim after/before
fmpy has run pythonfmu FMUs in the same process.  Python code of all FMUs still runs
serialised by the GIL, so libcosim's parallel stepping gives no speed-up.

Two crash modes exist when an FMU's Python code raises (pythonfmu reports ``fmi2Fatal``):

* during initialisation (``setup_experiment``/``enter_``/``exit_initialization_mode``):
  libcosim runs these on pool threads without catching exceptions, so ``std::terminate``
  aborts the whole host process -- this cannot be caught in process.  Use ``isolate=True``
  (runs libcosim in a fresh ``python -m seafmu.libcosim_runner`` child) to turn it into a
  ``RuntimeError`` naming the instance;
* during ``do_step``: libcosim reports a clean error, but freeing the failed instance later
  segfaults (pythonfmu 0.7.0 ``cleanPyObject`` decrefs the Python objects a second time).  We
  therefore deliberately leak the failed execution (its FMU instances, worker threads and
  ``$TMPDIR/libcosim_*`` unpack directories) and raise ``RuntimeError``.  An isolated run points
  ``TMPDIR`` at a directory it removes afterwards, so nothing is left behind.

Loading errors (missing/corrupt FMU, exception in the model's constructor) are reported cleanly
in process.  Only real and integer variables can be recorded (libcosim's time-series observer
does not store booleans or strings).
"""

from __future__ import annotations

import ctypes
import math
import os
import pickle
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["run_with_libcosim"]

Value = float | int | bool | str
Connection = tuple[str, str, str, str]
Event = tuple[float, str, str, float]

_NS = 1_000_000_000
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
_FMU_ERROR_MARKER = "SEAFMU_LIBCOSIM_FMU_ERROR"
# Methods libcosim calls on pool threads; a Python exception there is reported (child only).
_MARKED_METHODS = (
    "setup_experiment",
    "enter_initialization_mode",
    "exit_initialization_mode",
    "get_real",  # in initialisation mode a seafmu FMU initialises when its outputs are read
    "set_real",
    "set_integer",
    "set_string",
    "do_step",
    "terminate",
)


@dataclass(frozen=True)
class _Var:
    name: str
    ref: int
    type: str  # "REAL" | "INTEGER" | "BOOLEAN" | "STRING"
    causality: str  # "INPUT" | "PARAMETER" | "OUTPUT" | "CALCULATED_PARAMETER" | "LOCAL" | ...


def run_with_libcosim(
    fmus: dict[str, Path],
    connections: list[tuple[str, str, str, str]],
    initial_values: dict[str, dict[str, float | int | bool | str]],
    step_size: float,
    duration: float,
    record: dict[str, list[str]],
    events: Sequence[tuple[float, str, str, float]] = (),
    *,
    isolate: bool = False,
    timeout: float | None = None,
    log_level: str = "WARNING",
) -> dict[str, np.ndarray]:
    """Simulate the FMUs wired together under libcosim's fixed-step (Jacobi) algorithm.

    Args:
        fmus: instance name -> path of the ``.fmu``.
        connections: ``(src_instance, src_var, dst_instance, dst_var)``; real output -> real input.
        initial_values: instance -> {variable: value}, set before initialisation; the Python
            type must fit the declared FMI type (real: int/float, integer: int, boolean: bool,
            string: str).
        step_size: communication step in seconds (a whole number of nanoseconds).
        duration: simulated time in seconds; must be a whole number of steps.
        record: instance -> names of real/integer variables to record at every step.
        events: ``(time, instance, variable, value)`` real-valued overrides, applied at the first
            communication point ``>= time`` and kept for the rest of the run (see module doc).
        isolate: run libcosim in a child process so that a crash (FMU exception during
            initialisation aborts the process) becomes a ``RuntimeError``; costs a few
            tenths of a second.
        timeout: seconds before an isolated run is killed (deadlock guard); ``None`` = no limit.
        log_level: libcosim console log level (process-global): TRACE..FATAL.

    Returns:
        ``"time"`` (s, ``n_steps + 1`` points from 0) and ``"instance.variable"`` arrays
        (float64 for reals, int64 for integers).

    Raises:
        RuntimeError: one line naming the instance/variable for unknown names, type or
            causality mismatches, FMUs that fail to load/initialise/step, other libcosim errors.
    """
    spec = {
        "fmus": {str(k): Path(v) for k, v in fmus.items()},
        "connections": [tuple(c) for c in connections],
        "initial_values": {k: dict(v) for k, v in initial_values.items()},
        "step_size": step_size,
        "duration": duration,
        "record": {k: list(v) for k, v in record.items()},
        "events": [tuple(e) for e in events],
        "log_level": log_level,
    }
    if isolate:
        return _run_isolated(spec, timeout)
    return _run_in_process(**spec)


# ----------------------------------------------------------------------------------------------
# In-process run
# ----------------------------------------------------------------------------------------------


def _one_line(text: str) -> str:
    return " ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _steps(step_size: float, duration: float) -> tuple[int, int]:
    """Validate the time grid; libcosim counts time in integer nanoseconds."""
    if not (math.isfinite(step_size) and step_size > 0):
        raise RuntimeError(f"step_size must be a positive number of seconds, got {step_size!r}")
    step_ns = round(step_size * _NS)
    if step_ns < 1 or abs(step_ns - step_size * _NS) > 1e-3:
        raise RuntimeError(f"step_size {step_size!r} s is not a whole number of nanoseconds")
    if not (math.isfinite(duration) and duration > 0):
        raise RuntimeError(f"duration must be a positive number of seconds, got {duration!r}")
    n_steps = round(duration / step_size)
    if n_steps < 1 or abs(n_steps * step_size - duration) > 1e-9 * max(1.0, duration):
        raise RuntimeError(f"duration {duration!r} s is not a whole number of steps of {step_size!r} s")
    return step_ns, n_steps


def _lookup(variables: Mapping[str, Mapping[str, _Var]], instance: str, name: str, what: str) -> _Var:
    if instance not in variables:
        raise RuntimeError(f"{what}: unknown instance '{instance}' (known: {', '.join(variables)})")
    var = variables[instance].get(name)
    if var is None:
        raise RuntimeError(f"{what}: instance '{instance}' has no variable '{name}'")
    return var


def _set_initial(ex: Any, index: int, instance: str, var: _Var, value: Value) -> bool:
    """Dispatch on the FMU's declared type; refuse values that would be silently converted."""
    where = f"initial value {instance}.{var.name}"
    if var.causality in ("CALCULATED_PARAMETER", "INDEPENDENT"):
        raise RuntimeError(f"{where}: variable has causality {var.causality.lower()} and cannot be set")
    if var.type == "REAL":
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            raise RuntimeError(f"{where}: real variable needs a number, got {value!r}")
        return ex.real_initial_value(index, var.ref, float(value))
    if var.type == "INTEGER":
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise RuntimeError(f"{where}: integer variable needs an int, got {value!r}")
        return ex.integer_initial_value(index, var.ref, int(value))
    if var.type == "BOOLEAN":
        if not isinstance(value, bool | np.bool_):
            raise RuntimeError(f"{where}: boolean variable needs a bool, got {value!r}")
        return ex.boolean_initial_value(index, var.ref, bool(value))
    if not isinstance(value, str):
        raise RuntimeError(f"{where}: string variable needs a str, got {value!r}")
    return ex.string_initial_value(index, var.ref, value)


def _event_schedule(
    events: Iterable[Event],
    variables: Mapping[str, Mapping[str, _Var]],
    step_size: float,
    n_steps: int,
    duration: float,
) -> dict[int, list[tuple[str, _Var, float]]]:
    """Map each event to the first communication point k with t_k >= time."""
    schedule: dict[int, list[tuple[str, _Var, float]]] = {}
    for time, instance, name, value in events:
        var = _lookup(variables, instance, name, f"event at t={time}")
        if var.type != "REAL":
            raise RuntimeError(
                f"event {instance}.{name}: only real variables, this one is {var.type.lower()}"
            )
        if var.causality in ("CALCULATED_PARAMETER", "INDEPENDENT"):
            raise RuntimeError(f"event {instance}.{name}: causality {var.causality.lower()} cannot be set")
        if not (math.isfinite(time) and 0.0 <= time <= duration * (1 + 1e-12)):
            raise RuntimeError(f"event {instance}.{name}: time {time!r} outside [0, {duration}]")
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            raise RuntimeError(f"event {instance}.{name}: value must be a number, got {value!r}")
        k = max(0, math.ceil(time / step_size - 1e-9))
        if k < n_steps:  # an event at the very end cannot influence any step
            schedule.setdefault(k, []).append((instance, var, float(value)))
    return schedule


def _samples(observer: Any, index: int, var: _Var, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read all time-series samples through the C API.

    libcosimpy 0.0.6's ``time_series_*_samples`` trims its result by counting zero step
    numbers, which always drops the last sample when reading from step 0, so we call
    ``cosim_observer_slave_get_*_samples`` directly and trust its returned count.
    """
    from libcosimpy._internal import libcosimc

    c_value = ctypes.c_double if var.type == "REAL" else ctypes.c_int
    kind = "real" if var.type == "REAL" else "integer"
    func = libcosimc()[f"cosim_observer_slave_get_{kind}_samples"]  # a fresh object, not libcosimpy's
    func.restype = ctypes.c_int64
    func.argtypes = [
        ctypes.c_void_p,
        ctypes.c_int,
        ctypes.c_uint32,
        ctypes.c_int64,
        ctypes.c_size_t,
        ctypes.POINTER(c_value),
        ctypes.POINTER(ctypes.c_int64),
        ctypes.POINTER(ctypes.c_int64),
    ]
    values = (c_value * n)()
    steps = (ctypes.c_int64 * n)()
    times = (ctypes.c_int64 * n)()
    ptr = ctypes.cast(observer.ptr(), ctypes.c_void_p)
    got = func(ptr, index, var.ref, 0, n, values, steps, times)
    if got < 0:
        from libcosimpy._internal import get_last_error_message

        raise RuntimeError(f"reading samples failed: {_one_line(get_last_error_message())}")
    return np.array(steps[:got]), np.array(times[:got]), np.array(values[:got])


def _abandon(execution: Any, slaves: Iterable[Any]) -> None:
    """Leak a failed execution: destroying it would free FMU instances pythonfmu already freed."""
    execution._CosimExecution__ptr = None
    for slave in slaves:
        slave._CosimLocalSlave__ptr = None


def _run_in_process(
    fmus: dict[str, Path],
    connections: list[Connection],
    initial_values: dict[str, dict[str, Value]],
    step_size: float,
    duration: float,
    record: dict[str, list[str]],
    events: list[Event],
    log_level: str,
) -> dict[str, np.ndarray]:
    # Long because libcosim's execution, slaves, variable indices, manipulator and observer are one
    # handle graph that must live in one frame: split up, each piece would pass the same six
    # handles along and the order libcosim requires (add, connect, set, record, step) would blur.
    try:
        from libcosimpy import CosimLogging
        from libcosimpy._internal import get_last_error_message
        from libcosimpy.CosimEnums import CosimVariableCausality, CosimVariableType
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
        from libcosimpy.CosimSlave import CosimLocalSlave
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise RuntimeError(f"libcosimpy is not installed: {exc}") from exc

    def lib_error() -> str:
        return _one_line(get_last_error_message())

    step_ns, n_steps = _steps(step_size, duration)
    try:
        CosimLogging.log_output_level(CosimLogging.CosimLogLevel[log_level.upper()])
    except KeyError:
        raise RuntimeError(f"unknown libcosim log level {log_level!r}") from None

    execution = CosimExecution.from_step_size(step_ns)
    slaves: list[Any] = []
    indices: dict[str, int] = {}
    variables: dict[str, dict[str, _Var]] = {}
    for instance, path in fmus.items():
        slave = CosimLocalSlave(fmu_path=str(Path(path).resolve()), instance_name=instance)
        if not slave.ptr():
            raise RuntimeError(f"instance '{instance}': cannot load {path}: {lib_error()}")
        slaves.append(slave)
        index = execution.add_local_slave(slave)
        if index < 0:
            raise RuntimeError(f"instance '{instance}': libcosim refused the slave: {lib_error()}")
        indices[instance] = index
        variables[instance] = {
            v.name.decode(): _Var(
                name=v.name.decode(),
                ref=v.reference,
                type=CosimVariableType(v.type).name,
                causality=CosimVariableCausality(v.causality).name,
            )
            for v in execution.slave_variables(index)
        }

    for instance, values in initial_values.items():
        for name, value in values.items():
            var = _lookup(variables, instance, name, "initial value")
            if not _set_initial(execution, indices[instance], instance, var, value):
                raise RuntimeError(f"initial value {instance}.{name}: {lib_error()}")

    for src, src_name, dst, dst_name in connections:
        label = f"connection {src}.{src_name} -> {dst}.{dst_name}"
        out = _lookup(variables, src, src_name, label)
        inp = _lookup(variables, dst, dst_name, label)
        for end, var in ((f"{src}.{src_name}", out), (f"{dst}.{dst_name}", inp)):
            if var.type != "REAL":
                raise RuntimeError(
                    f"{label}: {end} is {var.type.lower()}, only real connections are supported"
                )
        if out.causality != "OUTPUT":
            raise RuntimeError(f"{label}: {src}.{src_name} is not an output ({out.causality.lower()})")
        if inp.causality != "INPUT":
            raise RuntimeError(f"{label}: {dst}.{dst_name} is not an input ({inp.causality.lower()})")
        if execution.connect_real_variables(indices[src], out.ref, indices[dst], inp.ref) != 0:
            raise RuntimeError(f"{label}: {lib_error()}")

    recorded: list[tuple[str, _Var]] = []
    for instance, names in record.items():
        for name in names:
            var = _lookup(variables, instance, name, "record")
            if var.type not in ("REAL", "INTEGER"):
                raise RuntimeError(
                    f"record {instance}.{name}: {var.type.lower()} variables cannot be recorded "
                    "(libcosim's time-series observer stores reals and integers only)"
                )
            recorded.append((instance, var))
    schedule = _event_schedule(events, variables, step_size, n_steps, duration)

    # Size the buffer explicitly: libcosimc's default time-series observer keeps only the
    # last 10000 samples and would silently drop the start of longer runs.
    observer = CosimObserver.create_time_series(buffer_size=n_steps + 1)
    if not execution.add_observer(observer):
        raise RuntimeError(f"adding the time-series observer failed: {lib_error()}")
    for instance, var in recorded:
        kind = CosimVariableType[var.type]
        if not observer.start_time_series(indices[instance], var.ref, kind):
            raise RuntimeError(f"record {instance}.{var.name}: {lib_error()}")
    manipulator = CosimManipulator.create_override()
    if not execution.add_manipulator(manipulator):
        raise RuntimeError(f"adding the override manipulator failed: {lib_error()}")

    done = 0
    for k in [*sorted(schedule), n_steps]:
        if k > done:
            # One C call for the whole chunk; ctypes releases the GIL so FMUs can take it.
            if not execution.step(k - done):
                message = lib_error()
                failed_at = execution.status().current_time / _NS
                _abandon(execution, slaves)
                raise RuntimeError(f"libcosim failed in the step starting at t={failed_at:g} s: {message}")
            done = k
        for instance, var, value in schedule.get(k, []):
            if not manipulator.slave_real_values(indices[instance], [var.ref], [value]):
                raise RuntimeError(f"event {instance}.{var.name} at step {k}: {lib_error()}")

    n = n_steps + 1
    result: dict[str, np.ndarray] = {"time": np.arange(n) * step_ns / _NS}
    for instance, var in recorded:
        steps, times, values = _samples(observer, indices[instance], var, n)
        if not np.array_equal(steps, np.arange(n)):
            raise RuntimeError(
                f"record {instance}.{var.name}: observer returned steps {steps[:5]}... not 0..{n_steps}"
            )
        result["time"] = times / _NS
        result[f"{instance}.{var.name}"] = values.astype(np.float64 if var.type == "REAL" else np.int64)
    return result


# ----------------------------------------------------------------------------------------------
# Isolated run (child process)
# ----------------------------------------------------------------------------------------------


def _run_isolated(spec: dict[str, Any], timeout: float | None) -> dict[str, np.ndarray]:
    """Run in ``python -m seafmu.libcosim_runner`` so an abort cannot take the caller down."""
    with tempfile.TemporaryDirectory(prefix="seafmu_libcosim_") as tmp:
        request, result, error = (Path(tmp) / n for n in ("request.pkl", "result.npz", "error.txt"))
        request.write_bytes(pickle.dumps(spec))
        env = dict(os.environ)
        env["TMPDIR"] = tmp  # libcosim unpacks FMUs there: removed even after an abort or a leak
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_PACKAGE_ROOT), env.get("PYTHONPATH")) if p)
        cmd = [sys.executable, "-m", "seafmu.libcosim_runner", str(request), str(result), str(error)]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, check=False)
        except subprocess.TimeoutExpired:
            raise RuntimeError(
                f"libcosim child process did not finish within {timeout} s (deadlock or very slow FMU?)"
            ) from None
        if proc.returncode == 0 and result.exists():
            with np.load(result) as data:
                return {key: data[key] for key in data.files}
        if error.exists():
            # libcosim's log goes to stdout, C++/marker messages to stderr
            raise RuntimeError(_with_fmu_log(error.read_text().strip(), proc.stdout + proc.stderr))
        raise RuntimeError(_describe_crash(proc.returncode, proc.stderr))


def _with_fmu_log(message: str, stderr: str) -> str:
    """Append the last error an FMU logged (libcosim prints it, its exception omits it), or the
    exception a marked method raised (``_mark_fmu_errors``: e.g. a bad value an event set)."""
    logged = [
        line.split("[FMI status=", 1)[1].split("]", 1)[-1].strip()
        for line in stderr.splitlines()
        if "[FMI status=error" in line or "[FMI status=fatal" in line
    ]
    logged = [line for line in logged if line not in message]  # libcosim's own echo says nothing new
    if not logged:
        logged = [" ".join(line.split("\t")[1:]) for line in stderr.splitlines()
                  if line.startswith(_FMU_ERROR_MARKER)]
    if logged:
        return f"{message} (last FMU error log: {logged[-1]})"
    return message


def _describe_crash(returncode: int, stderr: str) -> str:
    """Turn a dead child's stderr into one line naming the FMU instance when we can."""
    how = f"signal {signal.Signals(-returncode).name}" if returncode < 0 else f"exit code {returncode}"
    lines = stderr.splitlines()
    for line in lines:
        if line.startswith(_FMU_ERROR_MARKER):
            _, instance, method, error = line.split("\t", 3)
            return f"instance '{instance}' raised {error} in {method}; libcosim aborted the process ({how})"
    for i, line in enumerate(lines):
        if "what():" in line:
            detail = " ".join([line.split("what():", 1)[1], *lines[i + 1 : i + 3]])
            return f"libcosim aborted the process ({how}): {_one_line(detail)}"
    tail = _one_line(lines[-1]) if lines else "no output"
    return f"libcosim child process died ({how}): {tail}"


def _mark_fmu_errors() -> None:
    """Child only: report which instance raised, as libcosim's abort message does not say.

    The FMUs' modules import this process's ``pythonfmu`` after this hook is installed, so
    every model class gets its FMI-facing methods wrapped; the exception is re-raised unchanged.
    """
    import functools

    from pythonfmu import Fmi2Slave

    def wrap(method: Any, name: str) -> Any:
        @functools.wraps(method)
        def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
            try:
                return method(self, *args, **kwargs)
            except BaseException as exc:
                sys.stderr.write(f"{_FMU_ERROR_MARKER}\t{self.instance_name}\t{name}\t{exc!r}\n")
                sys.stderr.flush()
                raise

        return wrapper

    def hook(cls: type, **kwargs: Any) -> None:
        for name in _MARKED_METHODS:
            if name in cls.__dict__:
                setattr(cls, name, wrap(cls.__dict__[name], name))

    Fmi2Slave.__init_subclass__ = classmethod(hook)  # type: ignore[assignment]


def _child_main(argv: list[str]) -> int:
    request, result, error = (Path(a) for a in argv)
    spec = pickle.loads(request.read_bytes())
    try:
        _mark_fmu_errors()
    except ImportError:  # pythonfmu absent: the FMUs bring their own copy, markers just vanish
        pass
    try:
        data = _run_in_process(**spec)
    except RuntimeError as exc:
        error.write_text(str(exc))
        return 2
    np.savez(result, **data)
    return 0


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1:]))


def run_scenario_with_libcosim(scenario: Any, isolate: bool = True, timeout: float | None = 600.0,
                               ) -> dict[str, np.ndarray]:
    """Run a resolved seafmu scenario (``seafmu.scenario.Scenario``) under libcosim instead.

    Same FMUs, parameters, connections, events and recorded signals; libcosim couples Jacobi-wise
    (one step of delay per connection, see the module docstring), as seafmu's master does with
    ``coupling: jacobi`` -- then the two agree to 1e-11 on minerva2_dp.
    """
    from seafmu.build import build_fmu

    fmus: dict[str, Path] = {}
    initial: dict[str, dict[str, float | int | bool | str]] = {}
    for inst in scenario.instances:
        if inst.step_multiple != 1:
            raise RuntimeError(f"{inst.name}: step_multiple {inst.step_multiple} is not supported under "
                               "libcosim's fixed-step algorithm here (use 1)")
        fmus[inst.name] = inst.fmu_file or build_fmu(scenario.vessel, inst.kind).path
        initial[inst.name] = dict(inst.parameters)
    record: dict[str, list[str]] = {}
    for inst, var in scenario.outputs:
        info = scenario.instance(inst).variables[var]
        if info.type in ("real", "integer"):
            record.setdefault(inst, []).append(var)
    out = run_with_libcosim(fmus, scenario.connections, initial, scenario.step, scenario.duration, record,
                            [(t, i, v, float(x)) for t, i, v, x in scenario.events],
                            isolate=isolate, timeout=timeout)
    return out

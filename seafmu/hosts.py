"""Run files written by ``seafmu export`` in other engines: OSP libcosim (libcosimpy) and ecos (ecospy).

Used by the cross-engine tests and ``benchmarks/bench_hosts.py``. Each runner returns the
requested real variables after initialisation (row 0) and after every step (row k = after k
steps), so the series line up with seafmu's ``results.csv`` rows when seafmu records every step.
Both engines couple Jacobi-wise: compare with seafmu runs made with ``coupling: jacobi``.

ecos needs the TBB runtime (``libtbb.so.12``); the ``tbb`` wheel installs it into the
environment's ``lib/`` folder, which is not on the loader's path, so :func:`_load_ecos` preloads
it before importing ecospy.
"""

from __future__ import annotations

import ctypes
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.export import load_events

_NS = 1_000_000_000


class EngineError(RuntimeError):
    """An engine could not load or run an exported system; one line."""


def _steps(duration: float, step: float) -> int:
    n = round(duration / step)
    if abs(n * step - duration) > 1e-9 * max(1.0, duration):
        raise EngineError(f"duration {duration} s is not a whole number of {step} s steps")
    return n


def _libcosim_run(execution: Any, record: Sequence[tuple[str, str]], n_steps: int,
                  scenario: Path | None) -> dict[str, np.ndarray]:
    """Step the whole run in one call and read libcosim's time series of the recorded variables.

    A time-series observer, not the last-value one: libcosim initialises lazily, in the first
    ``step``, so values read before it are the FMUs' start values; the time-series observer
    records its first sample when initialisation has finished (row 0 = after initialisation,
    as in seafmu's results and ecos).
    """
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver

    from seafmu.libcosim_runner import _samples, _Var

    index = {info.name.decode(): info.index for info in execution.slave_infos()}
    refs: list[tuple[int, _Var]] = []
    for inst, var in record:
        if inst not in index:
            raise EngineError(f"libcosim: no simulator '{inst}'")
        by_name = {v.name.decode(): v for v in execution.slave_variables(index[inst])}
        if var not in by_name:
            raise EngineError(f"libcosim: simulator '{inst}' has no variable '{var}'")
        if CosimVariableType(by_name[var].type) != CosimVariableType.REAL:
            raise EngineError(f"libcosim: {inst}.{var} is not a real variable")
        refs.append((index[inst], _Var(var, by_name[var].reference, "REAL", "")))
    observer = CosimObserver.create_time_series(buffer_size=n_steps + 1)
    execution.add_observer(observer)
    for slave, v in refs:
        if not observer.start_time_series(slave, v.ref, CosimVariableType.REAL):
            raise EngineError(f"libcosim: cannot record variable {v.name} of simulator {slave}")
    if scenario is not None:
        manager = CosimManipulator.create_scenario_manager()
        execution.add_manipulator(manager)
        if not execution.load_scenario(manager, str(scenario)):
            raise EngineError(f"libcosim: could not load the scenario {scenario}")
    if not execution.step(n_steps):
        raise EngineError(f"libcosim: the run failed at t = {execution.status().current_time / _NS:g} s")
    out = np.empty((n_steps + 1, len(record)))
    for j, (slave, v) in enumerate(refs):
        steps, _, values = _samples(observer, slave, v, n_steps + 1)
        if not len(steps) or steps[0] != 0 or np.any(np.diff(steps) <= 0):
            raise EngineError(f"libcosim: the samples of {v.name} do not start at step 0")
        # a simulator with a longer step (step_multiple) is sampled when it steps: held between
        out[:, j] = values[np.searchsorted(steps, np.arange(n_steps + 1), side="right") - 1]
    return {f"{i}.{v}": out[:, j] for j, (i, v) in enumerate(record)}


def _quiet_libcosim() -> None:
    """libcosim logs every FMI call at debug level to stdout by default; keep warnings only."""
    from libcosimpy import CosimLogging

    CosimLogging.log_output_level(CosimLogging.CosimLogLevel.WARNING)


def run_osp_libcosim(folder: Path, record: Sequence[tuple[str, str]], duration: float,
                     step: float) -> dict[str, np.ndarray]:
    """Run ``folder/OspSystemStructure.xml`` (and ``scenario.json`` when present) in libcosim."""
    from libcosimpy.CosimExecution import CosimExecution

    _quiet_libcosim()
    folder = Path(folder)
    try:
        execution = CosimExecution.from_osp_config_file(str(folder / "OspSystemStructure.xml"))
    except AssertionError as exc:
        raise EngineError(f"libcosim: {exc}") from None
    scenario = folder / "scenario.json"
    return _libcosim_run(execution, record, _steps(duration, step), scenario if scenario.is_file() else None)


def run_ssp_libcosim(ssp: Path, record: Sequence[tuple[str, str]], duration: float, step: float,
                     events: Path | None = None) -> dict[str, np.ndarray]:
    """Run an exported .ssp in libcosim (events from the libcosim scenario file written beside it)."""
    from libcosimpy.CosimExecution import CosimExecution

    _quiet_libcosim()
    try:
        execution = CosimExecution.from_ssp_file(str(ssp), step_size=round(step * _NS))
    except AssertionError as exc:
        raise EngineError(f"libcosim: {exc}") from None
    return _libcosim_run(execution, record, _steps(duration, step), events)


def _load_ecos() -> Any:
    lib = Path(sys.prefix) / "lib" / "libtbb.so.12"
    if lib.is_file():
        ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
    try:
        import ecospy
    except OSError as exc:
        raise EngineError(f"ecos: cannot load its library ({exc}); install the 'tbb' wheel") from None
    return ecospy


def _ecos_events(ecospy: Any, sim: Any, events: list[tuple[float, str, str, Any]], step: float) -> None:
    """Timed overrides as an ecos scenario listener, each by its type: an Integer variable set by a
    real action makes ecos throw ("Real property not found") and abort the process.

    Not ``EcosSimulation.add_scenario``: ecospy 0.7.2 declares the ``ecos_scenario_add_*_action``
    calls without their last argument (``eps``, a C++ default), so ecos reads an undefined
    tolerance and actions after t = 0 never fire; and ecos applies actions from the back of its
    list, sorting them only for XML scenarios, so they are added latest first.
    """
    from ecospy.lib import dll

    create = dll.ecos_scenario_create
    create.restype = ctypes.c_void_p
    adders = {}
    for kind, ctype in (("real", ctypes.c_double), ("int", ctypes.c_int), ("bool", ctypes.c_bool),
                        ("string", ctypes.c_char_p)):
        add = getattr(dll, f"ecos_scenario_add_{kind}_action")
        add.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_char_p, ctype, ctypes.c_double]
        add.restype = ctypes.c_bool
        adders[kind] = add
    listener = create()
    for t, inst, var, value in sorted(events, key=lambda e: -e[0]):
        if isinstance(value, bool):  # the event file keeps the FMI type (export.events_document)
            kind, arg = "bool", value
        elif isinstance(value, int):
            kind, arg = "int", value
        elif isinstance(value, str):
            kind, arg = "string", value.encode()
        else:
            kind, arg = "real", float(value)
        if not adders[kind](listener, t, f"{inst}::{var}".encode(), arg, step / 2):
            raise EngineError(f"ecos: event {inst}.{var} at {t} s: {ecospy.EcosLib.get_last_error()}")
    sim._add_listener(sim.sim, b"scenario", listener)


def run_ssp_ecos(ssp: Path, record: Sequence[tuple[str, str]], duration: float, step: float,
                 events: Path | None = None, parameter_set: str = "initialValues") -> dict[str, np.ndarray]:
    """Run an exported .ssp in ecos, with the exported parameter set and events."""
    ecospy = _load_ecos()
    try:
        sim = ecospy.EcosSimulation(ssp_path=str(ssp), step_size=step)
    except Exception as exc:  # ecospy raises bare Exception with the library's message
        raise EngineError(f"ecos: {exc}") from None
    try:
        if events is not None:
            _ecos_events(ecospy, sim, load_events(events), step)
        sim.init(parameter_set=parameter_set)
        n_steps = _steps(duration, step)
        ids = [f"{i}::{v}" for i, v in record]
        out = np.empty((n_steps + 1, len(record)))
        for k in range(n_steps + 1):
            if k:
                sim.step()
            for j, ident in enumerate(ids):
                out[k, j] = sim.get_real(ident)
        sim.terminate()
    finally:
        sim.free()
    return {f"{i}.{v}": out[:, j] for j, (i, v) in enumerate(record)}

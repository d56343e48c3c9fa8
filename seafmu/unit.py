"""The master's unit protocol, and the kinds of unit it builds from a scenario instance.

A unit is one participant of the master loop (``seafmu.master``): an FMU on fmpy (kind ``fmu``),
a Block driven in-process (``inprocess``) or a vessel behind the hardware link (``hardware``,
``seafmu.hardware.link.HardwareLink``). The protocol is structural (``typing.Protocol``): the
hardware layer implements it without importing this module, which belongs to the layer above.

Pacing is a declared capability, not a guess from attributes: ``paces_itself`` is True for a unit
whose ``do_step`` holds the loop to the wall clock; such a unit is a ``PacedUnit`` and reports
``pacing_stats()``. The master adds its own pacer to a real-time run only when no unit paces.

Unit kinds are a registry (``UNIT_KINDS``), filled by the modules that implement them
(``seafmu.master`` registers all three with ``register_unit_kind``); the master picks the kind of
an instance with ``unit_kind`` and builds it with ``make_unit``, so a new kind is one factory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeGuard, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from seafmu.scenario import Instance


@runtime_checkable
class Unit(Protocol):
    """One participant of the master loop: named float inputs and outputs, stepped in time."""

    name: str
    in_names: list[str]  # the connected inputs, in the order ``set_inputs`` takes them
    out_names: list[str]  # every output, in the order ``get_outputs`` returns them
    paces_itself: bool  # True: ``do_step`` waits for the wall clock (a ``PacedUnit``)

    def initial_outputs(self, values: np.ndarray) -> np.ndarray | None:
        """The outputs these inputs give at t = 0, still in initialisation mode (FMI lets a host set
        inputs and read outputs there, repeatedly, to propagate initial values along connections);
        None where they cannot be had before ``initialize`` (a real vessel)."""
        ...

    def initialize(self, values: np.ndarray) -> np.ndarray:
        """Inputs (``in_names`` order) at t = 0; returns the initial outputs."""
        ...

    def set_inputs(self, values: np.ndarray) -> None: ...

    def do_step(self, t: float, h: float) -> None: ...

    def get_outputs(self) -> np.ndarray: ...

    def set_value(self, var: str, value: Any) -> None:
        """An input or tunable parameter by name (events, scenario parameters)."""
        ...

    def terminate(self) -> None: ...

    def collect_log(self) -> None:
        """Copy the messages the unit buffered during a run that went on (an FMU's discarded steps)
        into the run's log; a unit that logs as it goes has nothing to do."""
        ...

    def step_error(self, what: str, exc: Exception) -> Exception:
        """The error to raise when ``what`` failed with ``exc``: an FMU names itself and adds what
        its log said; others give ``exc`` back unchanged."""
        ...


class PacingStats(Protocol):
    def as_dict(self) -> dict[str, Any]: ...

    def summary(self) -> str: ...


@runtime_checkable
class PacedUnit(Unit, Protocol):
    """A unit that holds the loop to real time itself (``paces_itself`` True) and says how well."""

    def pacing_stats(self) -> PacingStats: ...


def is_paced(unit: Unit) -> TypeGuard[PacedUnit]:
    """The declared capability: ``paces_itself``, never a guess from the unit's other attributes."""
    return bool(unit.paces_itself)


@dataclass(frozen=True)
class UnitRequest:
    """What a unit factory gets: the scenario instance and the run's context."""

    instance: Instance
    in_names: list[str]
    vessel: str  # the scenario's vessel
    log: list[str]  # the run's log lines (warnings and errors the unit reports)
    record_dir: Path | None = None  # where a hardware link records its traffic
    fmu_file: Path | None = None  # the FMU to load (kind fmu; None: seafmu's built FMU of the kind)


UnitFactory = Callable[[UnitRequest], Unit]


def _no_errors() -> tuple[type[Exception], ...]:
    return ()


@dataclass(frozen=True)
class UnitKind:
    """A registered kind: its factory, and the exceptions its units raise while running that end
    the run as a one-line ``SimulationError`` (a callable: their module is imported when used)."""

    name: str
    make: UnitFactory
    errors: Callable[[], tuple[type[Exception], ...]] = _no_errors


UNIT_KINDS: dict[str, UnitKind] = {}


def register_unit_kind(name: str, errors: Callable[[], tuple[type[Exception], ...]] | None = None
                       ) -> Callable[[UnitFactory], UnitFactory]:
    """Decorator: ``factory`` builds the units of kind ``name``."""

    def add(factory: UnitFactory) -> UnitFactory:
        UNIT_KINDS[name] = UnitKind(name, factory, errors or _no_errors)
        return factory

    return add


def unit_kind(instance: Instance, mode: str) -> str:
    """The kind of unit an instance runs as: ``hardware`` when it names a hardware profile, else
    the run's mode (``fmu`` or ``inprocess``)."""
    return "hardware" if instance.hardware is not None else mode


def make_unit(kind: str, request: UnitRequest) -> Unit:
    try:
        entry = UNIT_KINDS[kind]
    except KeyError:
        known = ', '.join(sorted(UNIT_KINDS))
        raise ValueError(f"unknown unit kind '{kind}' (registered: {known})") from None
    return entry.make(request)


def run_errors(kinds: set[str]) -> tuple[type[Exception], ...]:
    """The exceptions, over the given kinds, that end a run as a one-line SimulationError."""
    return tuple(e for k in sorted(kinds) for e in UNIT_KINDS[k].errors())

"""The one interface every GNC block (plant, observer, controller, allocator) offers.

A block is pure numerics: named real inputs and outputs as flat NumPy arrays, named parameters
with defaults, and a fixed-step ``step``. The FMU slaves in ``fmus/`` and seafmu's in-process
composition both drive blocks through exactly this interface, so the two runs execute the same
code and can be compared number for number.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np

ParamType = Literal["real", "integer", "string"]


@dataclass(frozen=True)
class Signal:
    """A scalar input, output or parameter with the metadata a user (and modelDescription) needs."""

    name: str
    unit: str = ""
    description: str = ""
    min: float | None = None
    max: float | None = None
    start: Any = 0.0
    type: ParamType = "real"
    tunable: bool = False  # parameters only: may change during the run (events)


@dataclass
class Interface:
    """Inputs, outputs and parameters of a block for one vessel."""

    inputs: list[Signal] = field(default_factory=list)
    outputs: list[Signal] = field(default_factory=list)
    parameters: list[Signal] = field(default_factory=list)

    def input_names(self) -> list[str]:
        return [s.name for s in self.inputs]

    def output_names(self) -> list[str]:
        return [s.name for s in self.outputs]

    def parameter_defaults(self) -> dict[str, Any]:
        return {p.name: p.start for p in self.parameters}


class Block(ABC):
    """Base class: subclasses define ``interface`` and the numerics.

    Contract:
    - ``interface(vessel)`` is a classmethod, so the FMU can declare its variables before any
      parameter is known;
    - ``__init__(vessel, params)`` receives every parameter (defaults filled in) and raises
      ``ValueError`` with a one-line message naming the parameter when a value is invalid;
    - ``start(u)`` is called once with the initial inputs and returns the initial outputs, so
      the master can propagate consistent initial values in causal order;
    - ``output()`` returns the current outputs (aligned with ``interface.outputs``) without
      stepping;
    - ``step(t, h, u)`` advances from t to t + h with inputs ``u`` (aligned with
      ``interface.inputs``) held constant and returns the outputs at t + h;
    - ``set_parameter(name, value)`` changes a tunable parameter during the run;
    - the whole internal state lives in plain attributes (numbers, NumPy arrays, random
      generators, lists/dicts/tuples of them and helper objects of ``components`` classes), so
      ``export_state`` can capture it as plain data and ``import_state`` write it back into a
      live block (``components.state``); that is how FMU state get/set and serialisation work.
    """

    kind: ClassVar[str] = "block"

    @classmethod
    @abstractmethod
    def interface(cls, vessel: Any) -> Interface:
        """Signals of this block for ``vessel``."""

    def __init__(self, vessel: Any, params: dict[str, Any]) -> None:
        self.vessel = vessel
        self.params = dict(params)

    def start(self, u: np.ndarray) -> np.ndarray:
        """Initial outputs given the initial inputs (propagated from upstream blocks at t = 0).

        Default: the inputs do not matter at t = 0. An observer overrides it to start from the
        first measurements, a controller to start its reference model at the estimate.
        """
        return self.output()

    @abstractmethod
    def output(self) -> np.ndarray:
        """Current outputs, aligned with ``interface.outputs``."""

    @abstractmethod
    def step(self, t: float, h: float, u: np.ndarray) -> np.ndarray:
        """Advance to t + h with inputs ``u`` held; return the outputs at t + h."""

    def export_state(self) -> dict[str, Any]:
        """The whole internal state as a tree of plain data (``components.state.capture``)."""
        from .state import capture

        return capture(self)

    def import_state(self, state: dict[str, Any]) -> None:
        """Write a tree from ``export_state`` back into this block, checked; all or nothing."""
        from .state import restore

        restore(self, state)

    def set_parameter(self, name: str, value: Any) -> None:
        """Default: tunable parameters are read from ``self.params`` at every step."""
        spec = {p.name: p for p in self.interface(self.vessel).parameters}
        if name not in spec:
            raise ValueError(f"{type(self).__name__}: unknown parameter '{name}'")
        if not spec[name].tunable:
            raise ValueError(f"{type(self).__name__}: parameter '{name}' is fixed after initialisation")
        self.params[name] = value


def full_params(interface: Interface, given: dict[str, Any]) -> dict[str, Any]:
    """Defaults overlaid with the given values; unknown names are an error naming them."""
    defaults = interface.parameter_defaults()
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(defaults))}")
    out = dict(defaults)
    out.update(given)
    return out

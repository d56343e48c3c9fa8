"""The one interface every GNC block (plant, observer, controller, allocator) offers.

A block is pure numerics: named real inputs and outputs as flat NumPy arrays, named parameters
with defaults, and a fixed-step ``step``. The FMU slaves in ``fmus/`` and seafmu's in-process
composition both drive blocks through exactly this interface, so the two runs execute the same
code and can be compared number for number.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
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
    choices: tuple[Any, ...] | None = None  # parameters only: the allowed values (None = any in range)
    min_open: bool = False  # parameters only: the value must be > min (a time constant, a weight)

    def check(self, value: Any, owner: str) -> None:
        """ValueError in one line, '<owner>: parameter '<name>' must be ..., got <value>', unless
        ``value`` fits this parameter's type, choices and range (min/max as declared for the FMU)."""
        where = f"{owner}: parameter '{self.name}'"
        if self.type == "string":
            if not isinstance(value, str):
                raise ValueError(f"{where} must be text, got {value!r}")
            if self.choices is not None and value not in self.choices:
                raise ValueError(f"{where} must be one of {', '.join(map(str, self.choices))}, got {value!r}")
            return
        try:
            if isinstance(value, bool):  # a YAML 'true' for a number is a mistake, not 1
                raise TypeError
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where} must be a number, got {value!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"{where} must be finite, got {value!r}")
        if self.choices is not None:
            if v not in self.choices:
                raise ValueError(f"{where} must be one of {', '.join(map(str, self.choices))}, got {value!r}")
            return
        if self.type == "integer" and not v.is_integer():
            raise ValueError(f"{where} must be an integer, got {value!r}")
        lo, hi = self.min, self.max
        below = lo is not None and (v <= lo if self.min_open else v < lo)
        above = hi is not None and v > hi
        if below or above:
            if lo is not None and hi is not None:
                raise ValueError(f"{where} must be within [{lo:g}, {hi:g}], got {value!r}")
            op = ">" if self.min_open else ">="
            raise ValueError(f"{where} must be {op} {lo:g}, got {value!r}" if below
                             else f"{where} must be <= {hi:g}, got {value!r}")


class Slots:
    """Positions of a block's named inputs or outputs in its flat vector, from its ``Interface``.

    The FMU and the master exchange flat arrays in the declared order; inside a block every read
    and write goes through a name here (``slots["yaw_hat"]``, ``slots.at(names)``), so the order
    is written down once, in ``interface()``. Positions are looked up when a block is made and
    kept as plain ints and slices, so a step costs no more than hand-counted indices.
    """

    __slots__ = ("_index", "names")

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self._index = {n: i for i, n in enumerate(self.names)}
        if len(self._index) != len(self.names):
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise ValueError(f"signal name(s) declared twice: {', '.join(dup)}")

    def __len__(self) -> int:
        return len(self.names)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __getitem__(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"no signal '{name}' (have: {', '.join(self.names)})") from None

    def at(self, names: Iterable[str]) -> slice | list[int]:
        """Positions of ``names`` in that order: a slice where they are consecutive (NumPy views and
        slice assignment are cheaper than fancy indexing), else a list of indices."""
        idx = [self[n] for n in names]
        if idx and idx == list(range(idx[0], idx[0] + len(idx))):
            return slice(idx[0], idx[0] + len(idx))
        return idx


@dataclass
class Interface:
    """Inputs, outputs and parameters of a block for one vessel."""

    inputs: list[Signal] = field(default_factory=list)
    outputs: list[Signal] = field(default_factory=list)
    parameters: list[Signal] = field(default_factory=list)
    _by_name: dict[str, Signal] | None = field(default=None, init=False, repr=False, compare=False)

    def parameter(self, name: str) -> Signal | None:
        """The parameter called ``name`` (None if there is none)."""
        if self._by_name is None:
            self._by_name = {p.name: p for p in self.parameters}
        return self._by_name.get(name)

    def input_names(self) -> list[str]:
        return [s.name for s in self.inputs]

    def output_names(self) -> list[str]:
        return [s.name for s in self.outputs]

    def parameter_defaults(self) -> dict[str, Any]:
        return {p.name: p.start for p in self.parameters}

    def input_slots(self) -> Slots:
        return Slots(self.input_names())

    def output_slots(self) -> Slots:
        return Slots(self.output_names())


class Block(ABC):
    """Base class: subclasses define ``interface`` and the numerics.

    Contract:
    - ``interface(vessel)`` is a classmethod, so the FMU can declare its variables before any
      parameter is known;
    - ``__init__(vessel, params)`` receives the parameters (missing ones get their defaults) and
      checks each against its ``Signal`` (type, choices, finite, min/max), raising ``ValueError``
      with a one-line message naming the parameter; a block adds only checks that involve more
      than one value or the vessel. ``self.inp`` and ``self.out`` are the ``Slots`` of the
      interface: read inputs and write outputs by name through them;
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
        iface = type(self).interface(vessel)
        self.vessel = vessel
        self.params = full_params(iface, params)
        self.iface = iface
        for p in iface.parameters:
            p.check(self.params[p.name], self.kind)
        self.inp = iface.input_slots()
        self.out = iface.output_slots()
        self._in_shape = (len(self.inp),)  # what step() checks u against, once per step

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
        """Write a tree from ``export_state`` back into this block, checked; all or nothing.

        The tree's structure is checked by ``restore``; its values then by ``check_restored``: if
        that refuses them, the block gets its previous state back."""
        from .state import StateError, capture, restore

        before = capture(self)
        restore(self, state)
        try:
            self.check_restored()
        except StateError:
            restore(self, before)
            raise

    def check_restored(self) -> None:
        """StateError if restored values break what the block's parameters imply. Why: an FMU state
        comes from outside and its checksum is no signature; values that steer a loop (a sub-step
        count) must be those the parameters gave. Indices are checked where they are used (the
        kernels are bounds-checked). Here: the parameters themselves, as at construction."""
        from .state import StateError

        if not isinstance(self.params, dict) or self.params.keys() != set(self.iface.parameter_defaults()):
            raise StateError(f"state: the {self.kind}'s parameters do not fit it")
        for sig in self.iface.parameters:
            try:
                sig.check(self.params[sig.name], self.kind)
            except ValueError as exc:
                raise StateError(f"state: {exc}") from None

    def check_parameter(self, name: str, value: Any) -> None:
        """ValueError naming the parameter unless it exists, is tunable and ``value`` fits its Signal."""
        sig = self.iface.parameter(name)
        if sig is None:
            raise ValueError(f"{self.kind}: unknown parameter '{name}'")
        if not sig.tunable:
            raise ValueError(f"{self.kind}: parameter '{name}' is fixed after initialisation")
        sig.check(value, self.kind)

    def set_parameter(self, name: str, value: Any) -> None:
        """Default: checked, then stored; tunable parameters are read from ``self.params``."""
        self.check_parameter(name, value)
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

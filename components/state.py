"""A block's internal state as plain data, and its restoration INTO a live block.

``capture(block)`` walks the block's attributes and returns a tree of plain values only: numbers,
strings, ``None``, NumPy arrays (copies) and NumPy scalars of numeric dtypes, and marker dicts
(``{"$t": ...}``) for lists, tuples, named tuples, sets, dicts, slices, random generators
(their bit generator's state dict) and the helper objects a block owns (their attributes,
recursively). Objects seen
twice (aliases: one array under two names, one helper object referenced twice) are captured once
and referenced by number, so a restored block has the same aliasing as the captured one.

``restore(block, tree)`` writes such a tree back into the live block. It never runs code chosen
by the tree: classes are never looked up to be called, random generators only get a new state
dict (which NumPy validates), helper objects are updated in place when the live block has one of
exactly the same class. Only where the live block has no object yet (one the block creates
lazily during the run) is an empty instance of the same ``components`` class made with
``object.__new__`` (no ``__init__``) and filled with plain data. Everything is checked first
(node kinds, dtypes, shapes of arrays the live block already has, classes) and applied only when
the whole tree fits, so a rejected tree leaves the block untouched. Vessel definitions
(``components.vessel_spec``) and a block's interface and slots (``components.block``) are
configuration, not state: their place is recorded and checked, the live ones are kept.

The tree survives ``json`` after ``fmus._state`` encodes arrays and NumPy scalars as bytes; that
is how an FMU state is serialised. Python floats round-trip exactly through ``repr``.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

PLAIN = (type(None), bool, int, float, str)
NUMERIC_KINDS = "biufc"  # bool, signed, unsigned, float, complex: no object, string or void dtypes
BIT_GENERATORS: dict[str, type] = {
    "PCG64": np.random.PCG64, "PCG64DXSM": np.random.PCG64DXSM, "MT19937": np.random.MT19937,
    "Philox": np.random.Philox, "SFC64": np.random.SFC64,
}
# This package's import name: "seafmu.components" when installed, "<build package>.components" in an FMU.
_PACKAGE = __name__.rpartition(".")[0]
# Configuration, not state: vessel definitions, and the signal metadata and slots of block.py.
CONFIG_MODULES = (f"{_PACKAGE}.vessel_spec", f"{_PACKAGE}.block")
STATE_PACKAGE = f"{_PACKAGE}."
_MISSING = object()


class StateError(ValueError):
    """A state that cannot be captured or does not fit the live block (the message names where)."""


def _qualname(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _is_state_class(cls: type) -> bool:
    return cls.__module__.startswith(STATE_PACKAGE) and cls.__module__ not in CONFIG_MODULES


# -- capture ------------------------------------------------------------------------------------

def capture(obj: Any) -> dict[str, Any]:
    """The plain-data tree of ``obj`` (a Block or any ``components`` object)."""
    return _Capture().node(obj, type(obj).__name__)


class _Capture:
    def __init__(self) -> None:
        self.ids: dict[int, int] = {}
        self.keep: list[Any] = []  # keeps captured objects alive so that ids stay unique

    def _memo(self, value: Any) -> tuple[int, bool]:
        key = id(value)
        if key in self.ids:
            return self.ids[key], True
        n = len(self.ids)
        self.ids[key] = n
        self.keep.append(value)
        return n, False

    def node(self, v: Any, path: str) -> Any:
        t = type(v)
        if t in PLAIN:
            return v
        if isinstance(v, np.generic):
            if v.dtype.kind not in NUMERIC_KINDS:
                raise StateError(f"{path}: NumPy scalar of dtype {v.dtype} is not state data")
            return {"$t": "sc", "value": v}
        if t is slice:
            return {"$t": "slice", "items": [self._plain(x, path) for x in (v.start, v.stop, v.step)]}
        if t is tuple:
            return {"$t": "tuple", "items": [self.node(x, f"{path}[{i}]") for i, x in enumerate(v)]}
        if t is frozenset:
            return {"$t": "frozenset", "items": [self._key(x, path) for x in v]}
        if issubclass(t, tuple) and hasattr(t, "_fields") and _is_state_class(t):  # a NamedTuple
            return {"$t": "ntuple", "class": _qualname(t),
                    "items": [self.node(x, f"{path}.{f}") for f, x in zip(t._fields, v, strict=True)]}
        n, seen = self._memo(v)
        if seen:
            return {"$t": "ref", "id": n}
        if t is np.ndarray:
            if v.dtype.kind not in NUMERIC_KINDS:
                raise StateError(f"{path}: array of dtype {v.dtype} is not state data")
            return {"$t": "nd", "id": n, "value": np.array(v, copy=True, order="K")}
        if t is list:
            return {"$t": "list", "id": n, "items": [self.node(x, f"{path}[{i}]") for i, x in enumerate(v)]}
        if t is set:
            return {"$t": "set", "id": n, "items": [self._key(x, path) for x in v]}
        if t is dict:
            items = []
            for k, x in v.items():
                items.append([self._key(k, path), self.node(x, f"{path}[{k!r}]")])
            return {"$t": "dict", "id": n, "items": items}
        if t is np.random.Generator:
            bg = v.bit_generator
            name = type(bg).__name__
            if BIT_GENERATORS.get(name) is not type(bg):
                raise StateError(f"{path}: bit generator {name} is not supported")
            state = self.node(bg.state, f"{path}.state")
            return {"$t": "rng", "id": n, "bit_generator": name, "state": state}
        if t.__module__ in CONFIG_MODULES:
            return {"$t": "cfg", "id": n, "class": _qualname(t)}
        if _is_state_class(t) and hasattr(v, "__dict__") and not isinstance(v, type):
            # A class may leave out what is no state (QPAllocator: the solver's C workspace) with
            # __getstate__, as for copy and pickle, and put it back in __setstate__.
            own = v.__getstate__() if t.__getstate__ is not object.__getstate__ else vars(v)
            if type(own) is not dict:
                raise StateError(f"{path}: {_qualname(t)}.__getstate__ must return a dict")
            attrs = {name: self.node(x, f"{path}.{name}") for name, x in own.items()}
            return {"$t": "obj", "id": n, "class": _qualname(t), "attrs": attrs}
        raise StateError(f"{path}: {_qualname(t)} is not state data")

    def _plain(self, x: Any, path: str) -> Any:
        if type(x) not in PLAIN:
            raise StateError(f"{path}: slice bound {x!r} is not a plain number")
        return x

    def _key(self, k: Any, path: str) -> Any:
        if type(k) in PLAIN:
            return k
        if type(k) is tuple:
            return {"$t": "tuple", "items": [self._key(x, path) for x in k]}
        raise StateError(f"{path}: dict key {k!r} is not plain data")


# -- restore ------------------------------------------------------------------------------------

def restore(live: Any, tree: Any) -> None:
    """Write ``tree`` (from ``capture``) into the live object; all or nothing."""
    if not (isinstance(tree, dict) and tree.get("$t") == "obj"):
        raise StateError("state: not a captured object")
    r = _Restore()
    target = r.build(live, tree, type(live).__name__)
    if target is not live:
        raise StateError(f"state: holds a {tree.get('class')}, this block is a {_qualname(type(live))}")
    r.commit()


def _state_classes() -> dict[str, type]:
    """Classes a tree may name for an object the live block does not have yet: those defined in
    the already imported ``components`` modules (never imported because a state names them)."""
    out: dict[str, type] = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith(STATE_PACKAGE) or name in CONFIG_MODULES or mod is None:
            continue
        for obj in list(vars(mod).values()):
            if not (isinstance(obj, type) and obj.__module__ == name) or issubclass(obj, BaseException):
                continue
            if obj.__new__ is object.__new__ or (issubclass(obj, tuple) and hasattr(obj, "_fields")):
                out[_qualname(obj)] = obj  # plain classes, made with object.__new__; NamedTuples
    return out


class _Restore:
    def __init__(self) -> None:
        self.built: dict[int, Any] = {}
        self.objects: list[tuple[Any, dict[str, Any]]] = []
        self.rngs: list[tuple[Any, dict[str, Any]]] = []
        self._classes: dict[str, type] | None = None

    def commit(self) -> None:
        for target, state in self.rngs:
            target.bit_generator.state = state
        for target, attrs in self.objects:
            target.__dict__.clear()
            setstate = getattr(type(target), "__setstate__", None)
            if setstate is not None:
                setstate(target, attrs)
            else:
                target.__dict__.update(attrs)

    def _id(self, node: dict, path: str) -> int:
        n = node.get("id")
        if type(n) is not int or n in self.built:
            raise StateError(f"{path}: bad object number {n!r}")
        return n

    def _class(self, name: Any, path: str) -> type:
        if self._classes is None:
            self._classes = _state_classes()
        cls = self._classes.get(name) if isinstance(name, str) else None
        if cls is None:
            raise StateError(f"{path}: class {name!r} is not a seafmu component class")
        return cls

    def build(self, live: Any, node: Any, path: str) -> Any:
        t = type(node)
        if t in PLAIN:
            return node
        if t is not dict:
            raise StateError(f"{path}: unexpected {t.__name__} in the state")
        kind = node.get("$t")
        if kind == "ref":
            n = node.get("id")
            if type(n) is not int or n not in self.built:
                raise StateError(f"{path}: reference to unknown object {n!r}")
            return self.built[n]
        if kind == "sc":
            v = node.get("value")
            if not isinstance(v, np.generic) or v.dtype.kind not in NUMERIC_KINDS:
                raise StateError(f"{path}: bad NumPy scalar")
            return v
        if kind == "slice":
            items = node.get("items")
            if type(items) is not list or len(items) != 3 or any(
                type(x) not in (type(None), int) for x in items
            ):
                raise StateError(f"{path}: bad slice")
            return slice(*items)
        if kind == "tuple":
            items = self._items(node, path)
            lv = live if type(live) is tuple and len(live) == len(items) else ()
            return tuple(
                self.build(lv[i] if lv else _MISSING, x, f"{path}[{i}]") for i, x in enumerate(items)
            )
        if kind == "frozenset":
            return frozenset(self._key(x, path) for x in self._items(node, path))
        if kind == "set":
            n = self._id(node, path)
            out_set = {self._key(x, path) for x in self._items(node, path)}
            self.built[n] = out_set
            return out_set
        if kind == "ntuple":
            cls = self._class(node.get("class"), path)
            items = self._items(node, path)
            if not (issubclass(cls, tuple) and hasattr(cls, "_fields")) or len(items) != len(cls._fields):
                raise StateError(f"{path}: bad {node.get('class')!r}")
            lv = live if type(live) is cls else None
            built = [self.build(lv[i] if lv is not None else _MISSING, x, f"{path}.{f}")
                     for i, (f, x) in enumerate(zip(cls._fields, items, strict=True))]
            return tuple.__new__(cls, built)  # immutable: an equal value, made without running code
        if kind == "nd":
            return self._array(live, node, path)
        if kind == "list":
            n = self._id(node, path)
            out: list[Any] = []
            self.built[n] = out
            lv = live if type(live) is list else []
            for i, x in enumerate(self._items(node, path)):
                out.append(self.build(lv[i] if i < len(lv) else _MISSING, x, f"{path}[{i}]"))
            return out
        if kind == "dict":
            n = self._id(node, path)
            d: dict[Any, Any] = {}
            self.built[n] = d
            lv = live if type(live) is dict else {}
            for item in self._items(node, path):
                if type(item) is not list or len(item) != 2:
                    raise StateError(f"{path}: bad dict item")
                k = self._key(item[0], path)
                d[k] = self.build(lv.get(k, _MISSING), item[1], f"{path}[{k!r}]")
            return d
        if kind == "rng":
            return self._rng(live, node, path)
        if kind == "cfg":
            n = self._id(node, path)
            if live is _MISSING or _qualname(type(live)) != node.get("class"):
                raise StateError(f"{path}: expected the vessel definition {node.get('class')!r}")
            self.built[n] = live
            return live
        if kind == "obj":
            return self._object(live, node, path)
        raise StateError(f"{path}: unknown state node {kind!r}")

    def _items(self, node: dict, path: str) -> list:
        items = node.get("items")
        if type(items) is not list:
            raise StateError(f"{path}: bad container")
        return items

    def _key(self, k: Any, path: str) -> Any:
        if type(k) in PLAIN:
            return k
        if type(k) is dict and k.get("$t") == "tuple":
            return tuple(self._key(x, path) for x in self._items(k, path))
        raise StateError(f"{path}: bad dict key")

    def _array(self, live: Any, node: dict, path: str) -> np.ndarray:
        n = self._id(node, path)
        v = node.get("value")
        if type(v) is not np.ndarray or v.dtype.kind not in NUMERIC_KINDS:
            raise StateError(f"{path}: bad array")
        if type(live) is np.ndarray and (live.dtype != v.dtype or live.shape != v.shape):
            raise StateError(f"{path}: array {v.dtype}{list(v.shape)} does not fit the block's "
                             f"{live.dtype}{list(live.shape)}")
        out = np.array(v, copy=True, order="K")  # the state stays reusable: never share its arrays
        self.built[n] = out
        return out

    def _rng(self, live: Any, node: dict, path: str) -> np.random.Generator:
        n = self._id(node, path)
        name = node.get("bit_generator")
        cls = BIT_GENERATORS.get(name) if isinstance(name, str) else None
        if cls is None:
            raise StateError(f"{path}: unknown bit generator {name!r}")
        state = self.build(_MISSING, node.get("state"), f"{path}.state")
        try:
            cls().state = state  # NumPy checks the state dict on a scratch generator
        except (TypeError, ValueError, KeyError, OverflowError) as exc:
            raise StateError(f"{path}: bad {name} state ({exc})") from None
        if type(live) is np.random.Generator and type(live.bit_generator) is cls:
            target = live
        else:
            target = np.random.Generator(cls())
        self.built[n] = target
        self.rngs.append((target, state))
        return target

    def _object(self, live: Any, node: dict, path: str) -> Any:
        n = self._id(node, path)
        name = node.get("class")
        if live is not _MISSING and live is not None and _qualname(type(live)) == name and _is_state_class(
            type(live)
        ):
            target = live
        else:
            if live is not _MISSING and live is not None and hasattr(live, "__dict__") and not isinstance(
                live, (np.ndarray, np.random.Generator)
            ) and _is_state_class(type(live)):
                raise StateError(f"{path}: holds a {name}, the block has a {_qualname(type(live))}")
            cls = self._class(name, path)
            target = object.__new__(cls)
        self.built[n] = target
        attrs = node.get("attrs")
        if type(attrs) is not dict:
            raise StateError(f"{path}: bad attributes")
        current = target.__dict__ if target is live else {}
        new: dict[str, Any] = {}
        for key, child in attrs.items():
            if type(key) is not str:
                raise StateError(f"{path}: bad attribute name")
            new[key] = self.build(current.get(key, _MISSING), child, f"{path}.{key}")
        self.objects.append((target, new))
        return target

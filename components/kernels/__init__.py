"""Compiled (numba) kernels of the hot paths: plant rigid body, EKF, allocation, controller, waves.

Each kernel is the NumPy implementation it replaces written in scalars and loops, compiled once and
cached on disk (``_jit.py``); ``tests/test_kernels.py`` holds each equal to the NumPy form.

The blocks use them as ``kernels.<module>.<kernel>``, and a module is imported on its first use
(PEP 562's module ``__getattr__``), not with the block's module: reading a block's interface
(validating a scenario or a study's cases, ``--dry-run``) then does not import numba (~0.15 s of
CPU, on the critical path of a sweep's start). ``importlib.import_module`` is thread-safe, so
FMUs first stepped in parallel threads (an FMI host's) load a module once.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

MODULES = frozenset(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def __getattr__(name: str) -> ModuleType:
    if name in MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

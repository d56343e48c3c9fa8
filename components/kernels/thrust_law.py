"""The thrust laws, written once: T(n) and its inverse n(T), compiled, used by every caller.

The plant's rigid-body kernel, the allocators' kernels and the NumPy helpers of
``components/thrusters.py`` (controllers, the hardware link, identification, the test plan) all
call these functions, compiled here from their plain forms in ``laws.py`` (a new law goes there).
"""

from __future__ import annotations

import numpy as np

from . import laws
from ._jit import kernel
from .laws import LAWS, code

__all__ = ["LAWS", "code", "speed_of", "speeds", "thrust_of", "thrusts"]

thrust_of = kernel(laws.thrust_of)
speed_of = kernel(laws.speed_of)


@kernel
def thrusts(n: np.ndarray, kf: np.ndarray, kr: np.ndarray, law: int, out: np.ndarray) -> None:
    """``thrust_of`` element by element (flat arrays of equal length)."""
    for i in range(n.shape[0]):
        ni = n[i]
        out[i] = thrust_of(kf[i] if ni >= 0.0 else kr[i], ni, law)


@kernel
def speeds(t: np.ndarray, kf: np.ndarray, kr: np.ndarray, law: int, out: np.ndarray) -> None:
    """``speed_of`` element by element (flat arrays of equal length)."""
    for i in range(t.shape[0]):
        ti = t[i]
        out[i] = speed_of(kf[i] if ti >= 0.0 else kr[i], ti, law)

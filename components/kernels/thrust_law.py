"""The thrust laws, written once: T(n) and its inverse n(T), compiled, used by every caller.

The plant's rigid-body kernel, the allocators' kernels and the NumPy helpers of
``components/thrusters.py`` (controllers, the hardware link, identification, the test plan) all
call these two functions, so a new law is one ``elif`` in each of them and its name in ``LAWS``
(plus its coefficient units in ``vessel_spec.K_UNITS``). A law is carried in the kernels' flags
as its index in ``LAWS``.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import kernel

LAWS: tuple[str, ...] = ("linear", "quadratic")  # index = the code in the kernels' flags


def code(law: str) -> int:
    """The kernels' code of a thrust law name (ValueError naming the known ones)."""
    try:
        return LAWS.index(law)
    except ValueError:
        raise ValueError(f"unknown thrust law '{law}' (known: {', '.join(LAWS)})") from None


@kernel
def thrust_of(k: float, n: float, law: int) -> float:
    """Thrust at shaft speed n with coefficient k (k_forward for n >= 0, else k_reverse)."""
    if law == 1:
        return k * n * abs(n)
    return k * n


@kernel
def speed_of(k: float, t: float, law: int) -> float:
    """Shaft speed giving thrust t with coefficient k (k_forward for t >= 0, else k_reverse)."""
    if law == 1:
        sg = 1.0 if t > 0.0 else (-1.0 if t < 0.0 else 0.0)
        return sg * math.sqrt(abs(t) / k)
    return t / k


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

"""The thrust laws' scalar forms, in plain Python: what ``thrust_law.py`` compiles, and what a
scenario's validation evaluates (``thrusters.max_thrust``) without importing numba.

A law is carried in the kernels' flags as its index in ``LAWS``; a new law is one ``elif`` in each
of the two functions, its name in ``LAWS`` and its coefficient units in ``vessel_spec.K_UNITS``.
"""

from __future__ import annotations

import math

LAWS: tuple[str, ...] = ("linear", "quadratic")  # index = the code in the kernels' flags


def code(law: str) -> int:
    """The kernels' code of a thrust law name (ValueError naming the known ones)."""
    try:
        return LAWS.index(law)
    except ValueError:
        raise ValueError(f"unknown thrust law '{law}' (known: {', '.join(LAWS)})") from None


def thrust_of(k: float, n: float, law: int) -> float:
    """Thrust at shaft speed n with coefficient k (k_forward for n >= 0, else k_reverse)."""
    if law == 1:
        return k * n * abs(n)
    return k * n


def speed_of(k: float, t: float, law: int) -> float:
    """Shaft speed giving thrust t with coefficient k (k_forward for t >= 0, else k_reverse)."""
    if law == 1:
        sg = 1.0 if t > 0.0 else (-1.0 if t < 0.0 else 0.0)
        return sg * math.sqrt(abs(t) / k)
    return t / k

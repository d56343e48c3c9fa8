"""Kinematics in Fossen's (SNAME) notation: rotations, J(eta), skew matrices, Coriolis from mass.

The formulas live in ``components.dynamics`` (one module for rotations, Coriolis and restoring
forces); this module keeps the names it always offered, for the code and tests that import them
from here.
"""

from __future__ import annotations

from .dynamics import J, m2c, rot2, rpsi, rzyx, smtrx, tzyx, tzyx_inv, wrap_angle

__all__ = ["J", "m2c", "rot2", "rpsi", "rzyx", "smtrx", "tzyx", "tzyx_inv", "wrap_angle"]

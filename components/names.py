"""A hint for a mistyped name in an error message: every layer names things a user types (vessels,
profiles, scenarios, FMU variables), so the hint lives at the bottom, where all of them can use it."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


def did_you_mean(name: str, choices: Iterable[object]) -> str:
    """'; did you mean 'x'?' for the closest of ``choices`` to a mistyped ``name``, else ''."""
    close = difflib.get_close_matches(str(name), [str(c) for c in choices], n=1, cutoff=0.75)
    return f"; did you mean '{close[0]}'?" if close else ""

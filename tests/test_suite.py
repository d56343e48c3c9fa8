"""The test suite's own bookkeeping: the `slow` list in conftest names tests that exist."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import SLOW

HERE = Path(__file__).parent


def test_every_test_marked_slow_exists() -> None:
    missing = []
    for file, names in SLOW.items():
        tree = ast.parse((HERE / file).read_text())
        defined = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
        missing += [f"{file}::{n}" for n in sorted(names - defined)]
    assert not missing, f"conftest.SLOW names tests that are gone: {missing}"

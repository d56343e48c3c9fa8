"""Shared fixtures: the FMUs are built once per test session (incrementally, like `seafmu build`)."""

from __future__ import annotations

import pytest

from seafmu.build import build_all


@pytest.fixture(scope="session")
def built_fmus() -> dict[tuple[str, str], object]:
    from seafmu.build import KINDS, VESSELS, fmu_path

    build_all()
    return {(v, k): fmu_path(v, k) for v in VESSELS for k in KINDS}

"""Shared fixtures: the vessels (one load per test module) and the FMUs (built once per session,
incrementally, like `seafmu build`)."""

from __future__ import annotations

import pytest

from seafmu.build import build_all
from seafmu.components.vessel_spec import VesselSpec, load_vessel


@pytest.fixture(scope="module")
def minerva() -> VesselSpec:
    return load_vessel("minerva2")


@pytest.fixture(scope="module")
def amv() -> VesselSpec:
    return load_vessel("amv_osf")


@pytest.fixture(scope="session")
def built_fmus() -> dict[tuple[str, str], object]:
    from seafmu.build import KINDS, VESSELS, fmu_path

    build_all()
    return {(v, k): fmu_path(v, k) for v in VESSELS for k in KINDS}

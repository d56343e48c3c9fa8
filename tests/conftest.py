"""Shared fixtures: the vessels (one load per test module) and the FMUs (built once per session,
incrementally, like `seafmu build`)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from hypothesis import settings

from seafmu.build import build_all
from seafmu.components.vessel_spec import VesselSpec, load_vessel

# Property tests draw the same examples on every run (CI must not go red on a new random draw);
# `pytest --hypothesis-profile=explore` draws new ones, as a search for cases worth pinning with @example.
settings.register_profile("seafmu", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile("seafmu")


@pytest.fixture(scope="session", autouse=True)
def _temp_folder_of_the_session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The temporary files of the tests and of the processes they start go under pytest's own base
    folder, which pytest prunes (it keeps the last three sessions), not into the machine's: fmpy's
    ``extract(path)``, which the FMI tests call as any fmpy user would, unpacks into a new temporary
    folder each time and leaves it (2 MB each, hundreds per session)."""
    before = os.environ.get("TMPDIR")
    os.environ["TMPDIR"] = str(tmp_path_factory.mktemp("tmp"))
    tempfile.tempdir = None  # gettempdir() reads TMPDIR again
    yield
    if before is None:
        os.environ.pop("TMPDIR", None)
    else:
        os.environ["TMPDIR"] = before
    tempfile.tempdir = None


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


@dataclass(frozen=True)
class Ports:
    profile: Path  # the bundled emulator_pty profile, on these ports
    serial: Path  # where the emulator links its NMEA pty (``--serial pty:PATH``)
    slcan: Path  # and its SLCAN pty (``--can slcan:pty:PATH``)


@pytest.fixture
def own_ports(tmp_path: Path) -> Ports:
    """The bundled ``emulator_pty`` profile on this test's own pseudo-terminal paths: the shared
    /tmp/seafmu-emulator paths are held by whichever emulator runs there (another test session, a
    user's), and a second emulator is refused."""
    from seafmu.scenario import REPO

    ports = tmp_path / "ports"
    ports.mkdir()
    doc = yaml.safe_load((REPO / "hardware" / "profiles" / "emulator_pty.yaml").read_text())
    doc["serial"]["url"], doc["can"]["channel"] = str(ports / "nmea"), str(ports / "slcan")
    profile = ports / "emulator_pty.yaml"
    profile.write_text(yaml.safe_dump(doc, sort_keys=False))
    return Ports(profile, ports / "nmea", ports / "slcan")


# Tests that take several seconds each (fresh processes, cross-process links, other engines, long
# identification logs), by file and name. They are marked `slow` here, in one list, so that
# `pytest -m "not slow"` gives a quick loop while editing; CI (`.ci/run`) runs everything.
SLOW = {
    "test_fmu_lifecycle.py": {"test_cli_run_exits_normally_every_time",
                              "test_300_valid_runs_in_fresh_processes",
                              "test_200_failed_initialisations_in_a_fresh_process"},
    "test_hw_loopback.py": {"test_dp_across_processes_holds_position_and_matches_simulation"},
    "test_hw_safety.py": {"test_sigkill_of_the_controller_process_stops_the_thrusters_within_the_timeout"},
    "test_ident_maneuver_diagnosis.py": {"test_constant_force_in_a_6dof_maneuver_log_is_named"},
    "test_ident_maneuver.py": {"test_output_error_beats_ls_under_sensor_noise"},
    "test_ident_robustness.py": {"test_output_error_scales_linearly_with_the_log_length"},
    "test_export.py": {"test_exported_files_run_alike_in_libcosim_and_ecos"},
    "test_coupling.py": {"test_seafmu_jacobi_libcosim_and_ecos_agree"},
    "test_libcosim_fmus.py": {"test_libcosim_runs_the_four_fmus_and_agrees_with_seafmu"},
    "test_testplan.py": {"test_hardware_yaw_trial_over_ptys", "test_supply_recovers_published_damping",
                         "test_minerva2_identification_on_short_trials"},
    "test_thruster_loss.py": {"test_lost_thruster_located_in_a_hardware_recording"},
    "test_sweep.py": {"test_resume_after_interrupt", "test_small_study_on_local_cluster",
                      "test_study_on_an_existing_scheduler",
                      "test_case_failing_validation_after_the_cluster_started"},
    "test_run_robustness.py": {
        "test_sigterm_of_a_hardware_run_stops_the_thrusters_and_finishes_the_recording"},
    "test_hw_recording_errors.py": {
        "test_a_hardware_run_whose_recording_outgrows_the_file_size_limit_runs_to_its_end"},
}


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: takes several seconds (quick loop: pytest -m 'not slow')")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        name = getattr(item, "originalname", None) or item.name
        if name in SLOW.get(item.path.name, ()):
            item.add_marker(pytest.mark.slow)

"""Each FMU runs its own bundled code, whatever else its host has loaded (issue 9).

Every case runs in a fresh host process, as a user's host would: only fmpy and what the FMU's
``resources/requirements.txt`` lists are needed there.
"""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from seafmu.build import KINDS, REQUIREMENTS, VESSELS, fmu_path


def _host(code: str, *args: str, cwd: Path | None = None,
          extra_path: str = "") -> subprocess.CompletedProcess:
    env = dict(os.environ)
    if extra_path:
        env["PYTHONPATH"] = extra_path + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd, env=env)


_SIMULATE_ALL = """
import sys
from fmpy import simulate_fmu
for path in sys.argv[1:]:
    res = simulate_fmu(path, stop_time=1.0, step_size=0.05, output_interval=0.05)
    assert len(res) == 21, (path, len(res))
print("ok", len(sys.argv) - 1)
"""


def test_every_fmu_one_after_another_with_simulate_fmu(built_fmus: dict) -> None:
    paths = [str(fmu_path(v, k)) for v in VESSELS for k in KINDS]
    proc = _host(_SIMULATE_ALL, *paths, *paths[:2])  # and the first two again after the rest
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert f"ok {len(paths) + 2}" in proc.stdout


_VESSEL_BY_NAME_AGAIN = """
import sys
from fmpy import simulate_fmu
plant = sys.argv[1]
simulate_fmu(plant, stop_time=0.5, output_interval=0.05)  # its folder is removed when it returns
res = simulate_fmu(plant, stop_time=0.5, output_interval=0.05, output=["north"],
                   start_values={"vessel_file": "minerva2_published_damping"})
print("ok", len(res))
"""


def test_a_bundled_vessel_by_name_after_the_first_fmus_folder_is_gone(built_fmus: dict) -> None:
    """``vessel_file`` naming a bundled vessel is found in this FMU's own resources, not in the
    folder of the FMU that first imported the code, which fmpy removed after that run."""
    proc = _host(_VESSEL_BY_NAME_AGAIN, str(fmu_path("minerva2", "plant")))
    assert proc.returncode == 0 and "ok 11" in proc.stdout, proc.stderr[-1500:]


_SIDE_BY_SIDE = """
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
units = []
for path in sys.argv[1:]:
    md = read_model_description(path)
    u = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=md.coSimulation.modelIdentifier)
    u.instantiate(); u.setupExperiment(startTime=0); u.enterInitializationMode(); u.exitInitializationMode()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    units.append((u, vr))
for k in range(20):
    for u, vr in units:
        u.setReal([vr["n_cmd_1"]], [5.0])
        u.doStep(k * 0.05, 0.05)
surge = [u.getReal([vr["u"]])[0] for u, vr in units]
print("surge", *surge)
for u, _ in units:
    u.terminate(); u.freeInstance()
"""


def test_two_vessels_plants_side_by_side(built_fmus: dict) -> None:
    proc = _host(_SIDE_BY_SIDE, str(fmu_path("minerva2", "plant")), str(fmu_path("amv_osf", "plant")))
    assert proc.returncode == 0, proc.stderr[-1500:]
    surge = [float(x) for x in proc.stdout.split()[1:]]
    # each plant is its own vessel: the same command gives different surge speeds, both forward
    assert all(s > 0 for s in surge) and abs(surge[0] - surge[1]) > 1e-6


def test_unrelated_packages_named_like_ours_come_first(built_fmus: dict, tmp_path: Path) -> None:
    for name in ("components", "fmus", "hardware"):
        pkg = tmp_path / name
        pkg.mkdir()
        (pkg / "__init__.py").write_text("MARK = 'not seafmu'\n")
        (pkg / "block.py").write_text("raise ImportError('the wrong block module was imported')\n")
    code = ("import components, fmus, hardware\n"  # already imported by the host, from elsewhere
            + _SIMULATE_ALL)
    paths = [str(fmu_path("minerva2", k)) for k in KINDS]
    proc = _host(code, *paths, extra_path=str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert "ok 4" in proc.stdout


def test_an_installed_seafmu_does_not_replace_the_bundled_code(built_fmus: dict) -> None:
    """The host imported seafmu's own components first: the FMU still runs its bundled copy."""
    code = ("import seafmu.components.plant, seafmu.fmus._slave\n"
            "from fmpy import extract\n"
            "import sys, glob\n"
            "d = extract(sys.argv[1])\n"
            + _SIMULATE_ALL.replace("for path in sys.argv[1:]:", "for path in sys.argv[1:2]:")
            + "bundled = [m for m in sys.modules if m.startswith('seafmu_fmu_')]\n"
            "assert any(m.endswith('.components.plant') for m in bundled), bundled\n")
    proc = _host(code, str(fmu_path("minerva2", "plant")))
    assert proc.returncode == 0, proc.stderr[-1500:]


def test_requirements_file_lists_what_each_kind_imports(built_fmus: dict) -> None:
    for kind in KINDS:
        with zipfile.ZipFile(fmu_path("minerva2", kind)) as z:
            lines = z.read("resources/requirements.txt").decode().split()
        assert lines == [f"{n}{s}" for n, s in REQUIREMENTS[kind].items()]
    assert "daqp" in REQUIREMENTS["allocator"] and "daqp" not in REQUIREMENTS["plant"]


_NO_DAQP = """
import sys
from importlib import metadata
real = metadata.version
def version(name):
    if name == "daqp":
        raise metadata.PackageNotFoundError(name)
    return real(name)
metadata.version = version
messages = []
def logger(env, instance, status, category, message):
    messages.append((status, message.decode()))
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave, fmi2CallbackLoggerTYPE
md = read_model_description(sys.argv[1])
u = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]),
              modelIdentifier=md.coSimulation.modelIdentifier, instanceName="a")
try:
    u.instantiate(loggingOn=True, callbacks=None)
except Exception as exc:
    print("refused:", exc)
"""


@pytest.mark.parametrize("kind", ["allocator", "plant"])
def test_a_host_without_daqp_gets_one_line_naming_it(built_fmus: dict, kind: str) -> None:
    proc = _host(_NO_DAQP, str(fmu_path("minerva2", kind)))
    assert proc.returncode == 0, proc.stderr[-1500:]
    if kind == "plant":  # the plant does not need daqp
        assert "refused" not in proc.stdout
        return
    assert "refused: Failed to instantiate model" in proc.stdout
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if "needs Python packages" in ln]
    assert len(lines) == 1, proc.stdout + proc.stderr
    assert "daqp>=0.11,<1 (not installed)" in lines[0]
    assert "pip install 'daqp>=0.11,<1'" in lines[0]

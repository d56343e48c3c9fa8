"""``seafmu build``: the four FMUs per vessel, rebuilt only when their sources changed.

For each vessel and FMU kind a two-line script (unique module name, pitfall 2) subclasses the
kind's slave and names the vessel; pythonfmu packs it with the ``components`` and ``fmus``
packages under a package name unique to the build, and ``resources/requirements.txt`` says
what the host's Python must have (``pythonfmu deploy`` installs it). The modelDescription
pythonfmu writes is then completed (units, min/max, start values, InitialUnknowns) so that
``fmpy.validation.validate_fmu`` finds no problem (pitfall 1).
"""

from __future__ import annotations

import compileall
import hashlib
import json
import os
import py_compile
import shutil
import sys
import tempfile
import uuid
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pythonfmu

from seafmu.components.vessel_spec import bundled_vessels, load_vessel
from seafmu.fmus.model_description import complete_model_description as _complete
from seafmu.unitdefs import base_unit

REPO = Path(__file__).resolve().parents[1]
KINDS = ("plant", "observer", "controller", "allocator")


class _VesselsWithFmus(Sequence[str]):
    """Every bundled vessel file gets its FMUs (a new vessel is data only), except a variant of
    another vessel (``extra.variant_of``), which is loaded into that vessel's FMUs by vessel_file.

    Read when first asked, each file at most once: ``name in VESSELS``, which every scenario
    asks, reads that vessel's file only (a vessel file takes ~30 ms to read; the list, all of them).
    """

    def __init__(self) -> None:
        self._has_fmus: dict[str, bool] = {}
        self._names: tuple[str, ...] | None = None

    def _check(self, name: str) -> bool:
        if name not in self._has_fmus:
            self._has_fmus[name] = not load_vessel(name).extra.get("variant_of")
        return self._has_fmus[name]

    def names(self) -> tuple[str, ...]:
        if self._names is None:
            self._names = tuple(v for v in bundled_vessels() if self._check(v))
        return self._names

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in bundled_vessels() and self._check(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def __getitem__(self, i: Any) -> Any:
        return self.names()[i]

    def __repr__(self) -> str:
        return repr(self.names())


VESSELS: Sequence[str] = _VesselsWithFmus()
SOURCE_PACKAGES = ("components", "fmus")
# Not copied into an FMU: caches, and the build tool that completes the modelDescription.
BUNDLE_IGNORE = ("__pycache__", "*.pyc", "model_description.py")


def build_dir() -> Path:
    return Path(os.environ.get("SEAFMU_BUILD_DIR", REPO / "build" / "fmus"))


def model_identifier(vessel: str, kind: str) -> str:
    return "".join(part.capitalize() for part in vessel.split("_")) + kind.capitalize()


def fmu_path(vessel: str, kind: str) -> Path:
    return build_dir() / f"{model_identifier(vessel, kind)}.fmu"


@dataclass
class BuildResult:
    path: Path
    rebuilt: bool


def _sources_digest(vessel: str, kind: str) -> str:
    h = hashlib.sha256()
    h.update(f"{vessel}/{kind}/{pythonfmu.__version__}".encode())
    for pkg in SOURCE_PACKAGES:
        for f in sorted((REPO / pkg).rglob("*")):
            if f.is_file() and "__pycache__" not in f.parts and f.suffix in (".py", ".yaml"):
                h.update(str(f.relative_to(REPO)).encode())
                h.update(f.read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()


def fmu_guid(vessel: str, kind: str, digest: str) -> str:
    """The FMU's GUID: a function of its sources, so a state serialised by one build is accepted
    by an identical build and refused by any other (fmus/_state.py)."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"seafmu/{vessel}/{kind}/{digest}"))


# What each FMU kind needs from its host's Python (the bundled packages import these). Ranges:
# the oldest versions tested here, below the next major release. The allocator alone needs daqp.
_COMMON = {"numpy": ">=1.26,<3", "pyyaml": ">=6,<7", "numba": ">=0.60,<1"}
REQUIREMENTS: dict[str, dict[str, str]] = {
    "plant": _COMMON,
    "observer": {**_COMMON, "scipy": ">=1.11,<2"},
    "controller": _COMMON,
    "allocator": {**_COMMON, "daqp": ">=0.11,<1"},
}


def bundle_name(digest: str) -> str:
    """The import name of an FMU's bundled copy of seafmu's components and fmus packages.

    Unique per build (a hash of the sources): every FMU runs its own code whatever else its host
    has loaded -- another seafmu FMU of another build, an installed seafmu, or an unrelated
    package called ``components`` or ``fmus`` (docs/fmi_hosts.md, "Isolation").
    """
    return f"seafmu_fmu_{digest[:16]}"


def requirements_text(kind: str) -> str:
    return "".join(f"{name}{spec}\n" for name, spec in REQUIREMENTS[kind].items())


def _script(vessel: str, kind: str, guid: str, bundle: str) -> str:
    cls = f"{kind.capitalize()}Slave"
    ident = model_identifier(vessel, kind)
    return (
        f'"""Generated by seafmu build: the {kind} FMU of vessel {vessel}."""\n\n'
        "import os as _os\n"
        "import sys as _sys\n"
        "from importlib import metadata as _metadata\n\n"
        f"_REQUIRES = {REQUIREMENTS[kind]!r}\n\n\n"
        "def _version(text):\n"
        "    return tuple(int(p) for p in (text.split('.') + ['0', '0'])[:3] if p.isdigit())\n\n\n"
        "def _fits(version, spec):\n"
        "    for part in spec.split(','):\n"
        "        op, ref = part[:2], _version(part[2:])\n"
        "        if (op == '>=' and version < ref) or (op[0] == '<' and version >= _version(part[1:])):\n"
        "            return False\n"
        "    return True\n\n\n"
        "def _check_requirements():\n"
        '    """A missing or too old package: one line naming it and the install command, before any\n'
        '    import of it fails deep inside the model (the host shows it as the instantiate error)."""\n'
        "    bad = []\n"
        "    for name, spec in _REQUIRES.items():\n"
        "        try:\n"
        "            have = _metadata.version(name)\n"
        "        except _metadata.PackageNotFoundError:\n"
        "            bad.append((name, spec, 'not installed'))\n"
        "            continue\n"
        "        if not _fits(_version(have), spec):\n"
        "            bad.append((name, spec, 'version ' + have))\n"
        "    if bad:\n"
        "        need = ', '.join(f'{n}{s} ({why})' for n, s, why in bad)\n"
        "        cmd = ' '.join(f\"'{n}{s}'\" for n, s, _ in bad)\n"
        f"        raise ImportError('seafmu FMU {ident} needs Python packages in the host environment: '\n"
        "                          + need + '; install with: pip install ' + cmd\n"
        f"                          + ' (or: pythonfmu deploy {ident}.fmu)')\n\n\n"
        "_check_requirements()\n\n"
        "# All FMUs in a process share sys.modules. When another FMU of this same build imported the\n"
        "# bundle first and its unpacked folder is gone (fmpy's simulate_fmu removes it), new submodules\n"
        "# would not be found: look for them in this FMU's copy as well.\n"
        f"for _pkg in {(bundle, bundle + '.components', bundle + '.fmus')!r}:\n"
        "    _mod = _sys.modules.get(_pkg)\n"
        "    _own = _os.path.join(_os.path.dirname(_os.path.abspath(__file__)), *_pkg.split('.'))\n"
        "    _dirs = list(getattr(_mod, '__path__', None) or [])\n"
        "    if _dirs and not any(_os.path.isdir(d) for d in _dirs) and _own not in _dirs:\n"
        "        _mod.__path__.append(_own)\n\n"
        f"from {bundle}.fmus.{kind}_fmu import {cls}  # noqa: E402\n\n\n"
        f"class {ident}({cls}):\n"
        f'    VESSEL = "{vessel}"\n'
        f'    GUID = "{guid}"  # written into modelDescription.xml by the slave (fmus/_slave.py)\n\n\n'
        "def _hold_globals() -> None:\n"
        '    """A function holds its module\'s globals: the reference the first instantiation'
        ' drops (see fmus/_slave.py)."""\n'
    )


def build_fmu(vessel: str, kind: str, force: bool = False) -> BuildResult:
    out = fmu_path(vessel, kind)
    stamp = out.with_suffix(".sha256")
    digest = _sources_digest(vessel, kind)
    if not force and out.is_file() and stamp.is_file() and stamp.read_text() == digest:
        return BuildResult(out, rebuilt=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="seafmu_build_") as tmp:
        bundle = bundle_name(digest)
        # The script's module name is unique per build too: pythonfmu imports it by name.
        script = Path(tmp) / f"{vessel}_{kind}_fmu_{digest[:8]}.py"
        script.write_text(_script(vessel, kind, fmu_guid(vessel, kind, digest), bundle))
        # Copy the packages without caches so stale bytecode never ships inside an FMU; they
        # import each other relatively, so they work under the bundle's name.
        root = Path(tmp) / "pkgs" / bundle
        for pkg in SOURCE_PACKAGES:
            shutil.copytree(REPO / pkg, root / pkg, ignore=shutil.ignore_patterns(*BUNDLE_IGNORE))
        (root / "__init__.py").write_text('"""seafmu packages bundled in an FMU (seafmu build)."""\n')
        requirements = Path(tmp) / "pkgs" / "requirements.txt"
        requirements.write_text(requirements_text(kind))
        project = [root, requirements]
        # Built and completed under a name of this process, then renamed: builds running at the
        # same time (two test sessions, `seafmu run` twice) never see or complete a half-made FMU.
        part = out.with_name(f".{out.stem}.{os.getpid()}.part.fmu")
        try:
            # pythonfmu imports the script to write the modelDescription: the bundle must be
            # importable here for that one import, and is forgotten again right after.
            sys.path.insert(0, str(root.parent))
            try:
                built = pythonfmu.FmuBuilder.build_FMU(
                    script, dest=part, project_files=project, canGetAndSetFMUstate=True,
                    canSerializeFMUstate=True,
                )
            finally:
                sys.path.remove(str(root.parent))
                for name in [m for m in sys.modules
                             if m in (bundle, script.stem) or m.startswith(bundle + ".")]:
                    del sys.modules[name]
            complete_model_description(Path(built), _signals_by_name(vessel, kind))
            add_bytecode(Path(built), Path(tmp) / "bytecode")
            os.replace(built, out)
        finally:
            part.unlink(missing_ok=True)
    part_stamp = stamp.with_name(f".{stamp.name}.{os.getpid()}.part")
    part_stamp.write_text(digest)
    os.replace(part_stamp, stamp)
    return BuildResult(out, rebuilt=True)


def add_bytecode(fmu: Path, work: Path) -> None:
    """Add this interpreter's compiled form of every Python file of the FMU, as checked-hash pycs.

    Why: an FMU is unpacked into a fresh folder by every process that loads it, so its ~90 modules
    were compiled from source on every load (~0.14 s of each ``seafmu run`` and each sweep worker).
    pythonfmu leaves ``__pycache__`` out of the FMU, so they are added here. A checked-hash pyc is
    used only while its source's hash matches (unpacking does not keep file times, so time-stamped
    ones would never match), and another interpreter ignores it (the file name carries its tag).
    """
    with zipfile.ZipFile(fmu) as z:
        sources = [n for n in z.namelist() if n.startswith("resources/") and n.endswith(".py")]
        z.extractall(work, members=sources)
    compileall.compile_dir(work, quiet=2, workers=1,
                           invalidation_mode=py_compile.PycInvalidationMode.CHECKED_HASH)
    with zipfile.ZipFile(fmu, "a", zipfile.ZIP_DEFLATED) as z:
        for pyc in sorted(work.rglob("*.pyc")):
            z.write(pyc, arcname=pyc.relative_to(work).as_posix())


def build_all(vessels: Sequence[str] = VESSELS, force: bool = False) -> list[BuildResult]:
    return [build_fmu(v, k, force) for v in vessels for k in KINDS]


# -- modelDescription completion (fmus/model_description.py) -----------------------------------

def _signals_by_name(vessel: str, kind: str) -> dict:
    from seafmu.fmus.registry import BLOCKS

    iface = BLOCKS[kind].interface(load_vessel(vessel))
    return {s.name: s for s in [*iface.inputs, *iface.outputs, *iface.parameters]}


def complete_model_description(fmu: Path, signals: dict, tool: str = "seafmu build") -> None:
    """``fmus.model_description.complete_model_description`` with seafmu's SI base units."""
    _complete(fmu, signals, base_unit, tool=tool)


def manifest() -> dict[str, str]:
    return {f"{v}/{k}": str(fmu_path(v, k)) for v in VESSELS for k in KINDS}


if __name__ == "__main__":  # pragma: no cover - convenience
    for r in build_all():
        print(json.dumps({"fmu": str(r.path), "rebuilt": r.rebuilt}))

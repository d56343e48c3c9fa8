"""The hardware link as an FMI 2.0 co-simulation FMU, so another FMI tool can drive a real vessel.

``build_link_fmu(profile, dest)`` packs a per-profile slave (unique module name) with the
``hardware`` and ``components`` packages; its variables are the link's (``HardwareLink.interface``):
inputs ``n_cmd_i``, outputs ``meas_*``, ``*_count``, ``n_i``, status. String parameters
``serial_url``, ``can_interface``, ``can_channel`` and ``record_dir`` override the profile's ports
without a rebuild. ``fmi2DoStep`` is paced to the wall clock (the vessel does not wait), so a host
must call it no faster than real time can follow. The host's Python needs pyserial, python-can,
cantools and pynmea2 (and numpy, numba, pyyaml, pydantic), as for seafmu's other FMUs.
"""

from __future__ import annotations

import hashlib
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real, String
from pythonfmu.enums import Fmi2Initial, Fmi2Status

from ..fmus._slave import _dedupe_sys_path, _Py_IncRef, _release_pystate
from ..fmus.model_description import BaseUnit, complete_model_description
from .link import HardwareLink
from .profile import HardwareProfile, load_profile

REPO = Path(__file__).resolve().parents[1]
STRING_PARAMS = {
    "serial_url": ("serial.url", "pyserial URL of the NMEA port (empty: the profile's)"),
    "can_interface": ("can.interface", "python-can interface (empty: the profile's)"),
    "can_channel": ("can.channel", "CAN channel (empty: the profile's)"),
    "record_dir": ("record.dir", "folder for a recording of the run (empty: the profile's, or none)"),
}

# pythonfmu 0.7.0 drops one reference to the slave module's globals per instantiation; as in
# fmus/_slave.py, each instance adds one back (and the generated script holds one more).
_GLOBALS_REFS: list[dict[str, Any]] = []


class LinkSlave(Fmi2Slave):
    """The link behind FMI: the generated script sets PROFILE (a bundled profile name)."""

    PROFILE: ClassVar[str] = ""
    author = "seafmu"
    license = "MIT"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if self.resources:
            _GLOBALS_REFS.append(vars(sys.modules[type(self).__module__]))
        self._profile = load_profile(self.PROFILE)
        iface = HardwareLink.interface(self._profile)
        self.description = (
            f"seafmu hardware link, profile '{self._profile.name}' (vessel {self._profile.vessel})"
        )
        self._in_names = iface.input_names()
        self._u = np.zeros(len(iface.inputs))
        self._y = np.full(len(iface.outputs), np.nan)
        self._strings = {k: "" for k in STRING_PARAMS}
        self._link: HardwareLink | None = None
        for i, s in enumerate(iface.inputs):
            self.register_variable(
                Real(
                    s.name,
                    causality=Fmi2Causality.input,
                    variability=Fmi2Variability.continuous,
                    description=s.description,
                    getter=lambda i=i: float(self._u[i]),
                    setter=lambda v, i=i: self._u.__setitem__(i, v),
                )
            )
        for i, s in enumerate(iface.outputs):
            self.register_variable(
                Real(
                    s.name,
                    causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous,
                    initial=Fmi2Initial.calculated,
                    description=s.description,
                    getter=lambda i=i: float(self._y[i]),
                )
            )
        for name, (_, desc) in STRING_PARAMS.items():
            self.register_variable(
                String(
                    name,
                    causality=Fmi2Causality.parameter,
                    variability=Fmi2Variability.fixed,
                    description=desc,
                    getter=lambda n=name: self._strings[n],
                    setter=lambda v, n=name: self._strings.__setitem__(n, v),
                )
            )

    # -- the boundary to pythonfmu's C++ wrapper (its defects: fmus/_slave.py) ------------------
    def _get_log_queue(self) -> list[Any]:
        """Called by the wrapper right after construction: from now on it holds this instance."""
        self._queue = self.log_queue
        try:
            if self.resources:
                self._hosted = True
                _dedupe_sys_path(self.resources)
                _release_pystate(self.resources, type(self).__name__)
        except Exception:  # nothing may escape here
            pass
        return self.log_queue

    def _give_back_references(self) -> None:
        """The wrapper releases class, instance and log queue once too often per escaped exception."""
        if getattr(self, "_hosted", False):
            _Py_IncRef(type(self))
            _Py_IncRef(self)
            _Py_IncRef(self._queue)

    def exit_initialization_mode(self) -> bool:
        over = {path: self._strings[k] for k, (path, _) in STRING_PARAMS.items() if self._strings[k]}
        try:
            profile = self._profile.with_overrides(**over) if over else self._profile
            self._link = HardwareLink(profile, name=self.instance_name or "link")
            self._y[:] = self._link.initialize(self._u.copy())
        except Exception as exc:  # the host gets an FMI error with the reason, not a traceback
            self.log(f"{self.instance_name}: {str(exc).splitlines()[0]}", Fmi2Status.error)
            self._give_back_references()
            raise
        return True

    def do_step(self, current_time: float, step_size: float) -> bool:
        link = self._link
        if link is None:
            self.log("do_step called before exit_initialization_mode", Fmi2Status.error)
            return False
        try:
            link.set_inputs(self._u)
            link.do_step(current_time, step_size)
            self._y[:] = link.get_outputs()
        except Exception as exc:  # fmi2Discard with the reason: never an exception into the wrapper
            self.log(f"{self.instance_name}: {' '.join(str(exc).split())}", Fmi2Status.error)
            return False
        return True

    def terminate(self) -> None:
        if self._link is not None:
            self._link.terminate()
            self._link = None


def _identifier(profile: str) -> str:
    return "".join(part.capitalize() for part in profile.replace("-", "_").split("_")) + "Link"


def build_link_fmu(profile: str | Path, dest: str | Path, base_unit: BaseUnit | None = None) -> Path:
    """Build the link FMU for ``profile`` (bundled name or YAML path) into folder or file ``dest``.

    ``base_unit`` (``seafmu.unitdefs.base_unit``, passed by ``seafmu build --link``) gives the
    units their SI base units in the modelDescription; without it they are declared by name only.
    """
    import pythonfmu

    prof = load_profile(profile)
    ident = _identifier(prof.name)
    dest = Path(dest)
    out = dest if dest.suffix == ".fmu" else dest / f"{ident}.fmu"
    out.parent.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha256(prof.name.encode())
    for pkg in ("hardware", "components", "fmus"):
        for f in sorted((REPO / pkg).rglob("*")):
            if f.is_file() and "__pycache__" not in f.parts:
                digest.update(str(f.relative_to(REPO)).encode() + f.read_bytes())
    # The packages go in under a name unique to this build (as in seafmu/build.py): the FMU runs
    # its own code whatever else its host has imported.
    bundle = f"seafmu_link_{digest.hexdigest()[:16]}"
    with tempfile.TemporaryDirectory(prefix="seafmu_link_build_") as tmp:
        pkgs = Path(tmp) / "pkgs"
        root = pkgs / bundle
        ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
        shutil.copytree(REPO / "hardware", root / "hardware", ignore=ignore)
        shutil.copytree(REPO / "components", root / "components", ignore=ignore)
        shutil.copytree(REPO / "fmus", root / "fmus", ignore=ignore)
        (root / "__init__.py").write_text('"""seafmu packages bundled in the hardware link FMU."""\n')
        src = Path(prof.source) if prof.source else None
        if src is not None and src.resolve().parent != (REPO / "hardware" / "profiles").resolve():
            shutil.copy(src, root / "hardware" / "profiles" / f"{prof.name}.yaml")  # a user's profile file
        script = Path(tmp) / f"{prof.name}_link_fmu_{digest.hexdigest()[:8]}.py"
        script.write_text(
            f'"""Generated by seafmu: the hardware link FMU of profile {prof.name}."""\n\n'
            f"from {bundle}.hardware.link_fmu import LinkSlave\n\n\n"
            f"class {ident}(LinkSlave):\n"
            f'    PROFILE = "{prof.name}"\n\n\n'
            "def _hold_globals() -> None:\n"
            '    """Holds this module\'s globals: the reference the first instantiation drops."""\n'
        )
        sys.path.insert(0, str(pkgs))  # pythonfmu imports the script once to describe it
        try:
            built = pythonfmu.FmuBuilder.build_FMU(script, dest=out.parent, project_files=[root])
        finally:
            sys.path.remove(str(pkgs))
            for name in [m for m in sys.modules if m in (bundle, script.stem) or m.startswith(bundle + ".")]:
                del sys.modules[name]
    # completed beside its final name, then renamed: a failure leaves no half-described FMU
    part = Path(built).with_name(f".{out.stem}.part.fmu")
    Path(built).replace(part)
    try:
        complete_link_model_description(part, prof, base_unit)
        part.replace(out)
    finally:
        part.unlink(missing_ok=True)
    return out


def complete_link_model_description(fmu: Path, profile: str | Path | HardwareProfile,
                                    base_unit: BaseUnit | None = None) -> None:
    """Units, min/max and InitialUnknowns, exactly as for seafmu's own FMUs."""
    iface = HardwareLink.interface(profile)
    signals = {s.name: s for s in [*iface.inputs, *iface.outputs]}
    complete_model_description(fmu, signals, base_unit or _no_base_unit, tool="seafmu hardware link")


def _no_base_unit(unit: str) -> None:
    return None

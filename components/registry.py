"""Named GNC variants: which controller, allocator and guidance a vessel uses, by name.

A vessel file names its variants (``gnc.controller``, ``gnc.allocator``, ``gnc.guidance``); nothing
in seafmu guesses them from the number of DOFs or thrusters. The FMU-facing blocks
(``ControllerBlock``, ``AllocatorBlock``) look the name up here and delegate to the variant;
scenarios may choose another registered variant through the blocks' string parameters
``controller_variant`` and ``allocator`` (see docs/architecture.md for what each may change).

The registries hold names, module paths and descriptions only, and import a variant when it is
first resolved: the vessel loader validates names without importing the GNC code (which imports
the loader), and an FMU imports only what its vessel uses.

Adding a variant: write the class (a ``ControllerBlock`` subclass, an ``AllocationLaw`` or a
guidance class), add one ``Variant`` line below, name it in a vessel file.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Variant:
    """One named variant: where its implementation lives and what design data it reads."""

    name: str
    module: str  # relative to this package, e.g. ".dp_pid"
    attr: str  # class (controllers, guidance) or law class (allocators) in that module
    summary: str
    tuning: tuple[str, ...] = ()  # keys allowed under the vessel file's gnc.tuning (controllers)


CONTROLLERS: dict[str, Variant] = {v.name: v for v in (
    Variant("dp_pid", ".dp_pid", "DPPidController",
            "nonlinear PID dynamic positioning in NED with a reference model and anti-windup, 3 or 6 DOF; "
            "modes DP, waypoint tracking (guidance), auto-depth, auto-heading, joystick",
            tuning=("omega", "zeta", "omega_min_attitude", "attitude_factor", "integral_ratio", "ref_omega",
                    "ref_zeta")),
    Variant("heading_autopilot", ".heading_autopilot", "HeadingAutopilot",
            "heading (course) autopilot with open-loop surge force, PID with yaw-rate feed-forward or "
            "linear backstepping; joystick and land mode of an amphibious vessel (AMV OSF)",
            tuning=("kp", "kd", "ki", "ref_omega", "ref_zeta", "bs_k1", "bs_k2", "bs_ki")),
    Variant("axis_trial", ".axis_trial", "AxisTrialController",
            "test-plan trials (seafmu testplan): dp_pid's interface; the DOF with zero gains is free "
            "under an open-loop joystick force, the others held at the starting pose",
            tuning=("omega", "zeta", "omega_min_attitude", "attitude_factor", "integral_ratio", "ref_omega",
                    "ref_zeta")),
)}

ALLOCATORS: dict[str, Variant] = {v.name: v for v in (
    Variant("pinv", ".allocation", "PseudoInverseLaw",
            "weighted pseudo-inverse (minimum thrust energy), then per-thruster limits (clip)"),
    Variant("pinv_camera", ".allocation", "CameraWeightedLaw",
            "pseudo-inverse with weight S on camera thrusters that would go negative (Minerva 2 thesis)"),
    Variant("qp", ".allocation", "QPLaw",
            "constrained QP (DAQP): thrust and rate limits, prioritised slack on the allocation error"),
    Variant("qp_camera", ".allocation", "CameraQPLaw",
            "constrained QP that also minimises the negative thrust of the camera thrusters"),
    Variant("two_screw", ".allocation", "TwoScrewLaw",
            "two fixed screws: surge and yaw rows solved exactly, saturated with heading priority"),
)}

GUIDANCE: dict[str, Variant] = {v.name: v for v in (
    Variant("none", "", "", "no guidance: setpoints only"),
    Variant("reference_point", ".guidance", "PathGuidance",
            "speed-limited reference point along straight lines between waypoints (lawnmower)"),
)}

REGISTRIES = {"controller": CONTROLLERS, "allocator": ALLOCATORS, "guidance": GUIDANCE}

# The allocator's integer selector (parameter ``method``: a number, so events and hosts without
# string parameters can switch laws): 0 = the variant named by ``allocator``, 1.. = these variants.
METHOD_VARIANTS: tuple[str | None, ...] = (None, "qp", "pinv_camera", "qp_camera")

_resolved: dict[tuple[str, str], Any] = {}


def check(kind: str, name: Any) -> str:
    """``name`` if it is a registered variant of ``kind``; ValueError listing the known ones."""
    reg = REGISTRIES[kind]
    if not isinstance(name, str) or name not in reg:
        raise ValueError(f"unknown {kind} variant {name!r}; known: {', '.join(reg)}")
    return name


def check_text_parameter(name: str, value: str, vessel: Any = None) -> None:
    """ValueError if a text parameter of seafmu's blocks holds what its block refuses when the FMU
    initialises (an unknown variant, one that cannot serve ``vessel`` (a VesselSpec) if given,
    waypoints that do not parse), so that a scenario is refused when it is checked, not when it runs
    (a sweep validates every case before any runs)."""
    if name == "allocator":
        if vessel is None:
            check("allocator", value)
        else:
            from .allocation import check_allocator

            check_allocator(value, vessel)
    elif name == "controller_variant":
        check("controller", value)
    elif name == "waypoints" and value.strip():
        from .guidance import parse_waypoints

        parse_waypoints(value)


def resolve(kind: str, name: str) -> Any:
    """The implementation (class) of a registered variant, imported on first use; None for 'none'."""
    key = (kind, name)
    if key not in _resolved:
        v = REGISTRIES[kind][check(kind, name)]
        _resolved[key] = getattr(importlib.import_module(v.module, __package__), v.attr) if v.module else None
    return _resolved[key]


def controller_class(name: str) -> Any:
    return resolve("controller", name)


def guidance_class(name: str) -> Any:
    return resolve("guidance", name)


_laws: dict[str, Any] = {}


def allocator_law(name: str) -> Any:
    """The (stateless) allocation law object of a registered allocator variant, one per name."""
    law = _laws.get(name)
    if law is None:
        law = _laws[name] = resolve("allocator", name)()
    return law

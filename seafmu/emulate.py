"""``python -m seafmu.emulate`` (= ``seafmu emulate``): the vessel emulator with ``--scenario``.

The emulator (``seafmu.hardware.emulator``) sits below the scenario layer; this module reads the
scenario and hands the emulator its plant parameters as plain data.
"""

from __future__ import annotations

import sys
from typing import Any


def scenario_plant_parameters(scenario: str) -> dict[str, Any]:
    """The plant instance's parameters of a scenario (seed, current, initial state), and its vessel
    as ``vessel_file`` (the emulator checks it is its own); none when the scenario has no seafmu
    plant."""
    from seafmu.scenario import load_scenario

    sc = load_scenario(scenario)
    plant = next((i for i in sc.instances if i.kind == "plant"), None)
    if plant is None:
        return {}
    return {"vessel_file": sc.vessel, **plant.parameters}  # the plant's own vessel file, if it names one


def plant_set_values(spec: Any, sets: list[str]) -> dict[str, Any]:
    """``--set NAME=VALUE`` for the emulator's plant, read as ``seafmu run --set plant.NAME=VALUE``
    reads it: a quantity in any unit of the table (``current_speed=0.4kn``, ``current_direction=45deg``)
    or a bare number in the parameter's SI unit, its name and range checked; a bad one is a one-line
    ValueError naming the item."""
    from seafmu.components.names import did_you_mean
    from seafmu.scenario import ScenarioError, convert_parameter, interface_variables, parse_override

    variables = {k: v for k, v in interface_variables(spec.name, "plant", spec).items()
                 if v.causality == "parameter" and k != "vessel_file"}  # the emulator's own vessel
    out: dict[str, Any] = {}
    for item in sets:
        try:
            if "=" not in item or not item.split("=", 1)[0].strip():
                raise ScenarioError(f"--set {item}: must read NAME=VALUE (e.g. current_speed=0.4kn)")
            text = item.strip()
            full = text if text.startswith("plant.") else f"plant.{text}"  # run's form, or the short one
            try:
                o = parse_override(full)
            except ScenarioError as exc:  # its reason, with the item as given
                why = str(exc).removeprefix(f"--set {full!r}: ").removeprefix(f"--set {full}: ")
                raise ScenarioError(f"--set {item}: {why}") from None
            if o.time is not None:
                raise ScenarioError(f"--set {item}: the emulator takes no timed values (NAME@TIME)")
            info = variables.get(o.variable)
            if o.variable == "vessel_file":
                raise ScenarioError(f"--set {item}: the emulator's vessel is its VESSEL argument")
            if info is None:
                raise ScenarioError(f"--set {item}: no plant parameter '{o.variable}'"
                                    f"{did_you_mean(o.variable, variables)}")
            out[o.variable] = convert_parameter(o.value, info, f"--set {item}")
        except ScenarioError as exc:
            raise ValueError(str(exc)) from None
    return out


def main(argv: list[str] | None = None) -> int:
    """``seafmu emulate ...`` itself, so that a bad argument is the same one line (seafmu.cli)."""
    from seafmu.cli import main as cli_main

    return cli_main(["emulate", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

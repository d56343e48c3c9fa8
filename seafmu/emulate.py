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


def main(argv: list[str] | None = None) -> int:
    """``seafmu emulate ...`` itself, so that a bad argument is the same one line (seafmu.cli)."""
    from seafmu.cli import main as cli_main

    return cli_main(["emulate", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

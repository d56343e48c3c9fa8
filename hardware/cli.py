"""The ``seafmu emulate`` subcommand; seafmu's CLI adds it with ``hardware.cli.register(sub, ...)``.

The layer that reads scenarios (``seafmu/``) lends a ``ScenarioReader`` (a scenario's plant parameters,
``--set`` values with units), which enables ``--scenario``; this layer never imports it.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the emulator (plant, CAN, serial) is imported when the subcommand is added
    from .emulator import ScenarioReader


def register(subparsers: argparse._SubParsersAction, reader: ScenarioReader | None = None) -> None:
    """Add ``emulate VESSEL --serial PORT --can INTERFACE:CHANNEL`` to seafmu's subcommands."""
    from .emulator import __doc__ as doc
    from .emulator import build_parser, run_args

    p = subparsers.add_parser(
        "emulate",
        help="run a vessel model in real time behind NMEA 0183 serial and CAN",
        description=(doc or "").split("\n\n", 1)[0],
    )
    build_parser(p, scenarios=reader is not None)
    p.set_defaults(fn=lambda args: run_args(args, reader))

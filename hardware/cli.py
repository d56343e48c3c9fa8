"""The ``seafmu emulate`` subcommand; seafmu's CLI adds it with ``hardware.cli.register(sub)``."""

from __future__ import annotations

import argparse


def _cmd_emulate(args: argparse.Namespace) -> int:
    from .emulator import run_args

    return run_args(args)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``emulate VESSEL --serial PORT --can INTERFACE:CHANNEL`` to seafmu's subcommands."""
    from .emulator import __doc__ as doc
    from .emulator import build_parser

    p = subparsers.add_parser(
        "emulate",
        help="run a vessel model in real time behind NMEA 0183 serial and CAN",
        description=(doc or "").split("\n\n", 1)[0],
    )
    build_parser(p)
    p.set_defaults(fn=_cmd_emulate)

"""Command line of ``resection``: parses arguments and calls the library, nothing else.

Each group of sub-commands lives in a ``_cli_*.py`` module with a ``register(subparsers)``
function; errors on bad input are printed as one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys

from ._cliutil import OneLineParser, run


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="resection",
        description="Camera resection for wind-tunnel optical measurements.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    from . import _cli_io, _cli_markers, _cli_pose, _cli_surface, _cli_track

    for module in (_cli_pose, _cli_track, _cli_surface, _cli_markers, _cli_io):
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""Command line of ``resection``: parses arguments and calls the library, nothing else.

Each group of sub-commands lives in a module of :mod:`resection.cli` with a ``register(subparsers)``
function; errors on bad input are printed as one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys

from resection.cli.util import OneLineParser, run


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="resection",
        description="Camera resection for wind-tunnel optical measurements.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    from resection.cli import io, markers, pose, surface, track

    for module in (pose, track, surface, markers, io):
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

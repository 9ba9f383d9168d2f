"""Command line of ``resection``: parses arguments and calls the library, nothing else.

Each group of sub-commands lives in a ``_cli_*.py`` module with a ``register(subparsers)``
function; errors on bad input are printed as one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys

from .errors import InputError, SolveError


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (``prog: error: message``, exit status 2), without the
    usage block; ``--help`` still shows it. Sub-command parsers inherit the class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="resection",
        description="Camera resection for wind-tunnel optical measurements.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    from . import _cli_markers, _cli_pose, _cli_surface, _cli_track

    for module in (_cli_pose, _cli_track, _cli_surface, _cli_markers):
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (InputError, SolveError, FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"resection {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""The ``selfillum`` command line: each command's parser and runner, nothing else."""

from __future__ import annotations

try:
    from selfillum.cli.main import main
except KeyboardInterrupt:  # Ctrl-C while the command line loads: a stop, not a traceback
    import sys

    print("selfillum: interrupted", file=sys.stderr)
    raise SystemExit(130) from None

__all__ = ["main"]

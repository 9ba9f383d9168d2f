"""The ``resection`` command line: each command's parser and runner, nothing else.

Every runner parses its arguments and calls the library; bad input is one line on stderr and
exit status 2 (:func:`~resection.cli.util.run`). :func:`main` is the console script."""

from __future__ import annotations

try:
    from resection.cli.main import main
except KeyboardInterrupt:  # Ctrl-C while the command line loads: a stop, not a traceback
    import sys

    print("resection: interrupted", file=sys.stderr)
    raise SystemExit(130) from None

__all__ = ["main"]

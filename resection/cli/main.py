"""Command line of ``resection``: parses arguments and calls the library, nothing else.

Each group of sub-commands lives in a module of :mod:`resection.cli` with a ``register(subparsers)``
function; errors on bad input are printed as one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import os
import sys

from resection.cli.util import OneLineParser, run


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="resection",
        description="Camera resection for wind-tunnel optical measurements.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    from resection.cli import compare, io, markers, pose, surface, track

    for module in (pose, compare, track, surface, markers, io):
        module.register(sub)
    return parser


#: commands whose process, run as the program, ends without the interpreter's finalization
#: (:func:`end_process`): every file they write is complete and closed when they return
FAST_EXIT = ("track",)


def main(argv: list[str] | None = None) -> int:
    """Run the command of ``argv`` (default: the program's arguments) and return its exit
    status. Run as the program (``argv`` None), a command of :data:`FAST_EXIT` ends the
    process at once instead (:func:`end_process`), and Ctrl-C is caught from the start
    (:func:`resection.cli.interrupts.install`)."""
    if argv is None:
        from resection.cli.interrupts import done, install

        install()
    try:
        rc = run(build_parser(), argv)
    except KeyboardInterrupt:  # while the parser is built (its imports) or parses
        print("resection: interrupted", file=sys.stderr)
        rc = 130
    if argv is None:
        done()  # the status is decided: a Ctrl-C while the interpreter ends is ignored
    if argv is None and sys.argv[1:2] and sys.argv[1] in FAST_EXIT:
        end_process(rc)
    return rc


def end_process(rc: int) -> None:
    """End the process with status ``rc`` without the interpreter's finalization: tearing
    down the 1,600 modules and the compiled code that ``track`` loads (NumPy, SciPy,
    numba and LLVM) takes 0.2 to 0.7 s, a fifth of a 200-frame run, and frees nothing that
    the operating system would not. The standard streams are flushed first. Returns (a
    normal exit follows) when a thread other than this one is still running."""
    import threading

    if threading.active_count() > 1:
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(rc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

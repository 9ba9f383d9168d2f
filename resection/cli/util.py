"""What the two command lines (``resection``, ``selfillum``) share: one-line errors.

Bad input (an :class:`~resection.errors.InputError`, an untrustworthy solve, a missing or
unwritable file, a bad argument, an output that is one of the inputs) is printed as one
line naming the problem, with exit status 2, never as a traceback; so is every error of the
operating system (a full disk, a read-only folder, a symlink loop: ``<file>: <reason>``), an
input nested too deeply to parse and a memory need that cannot be met. The paths of a command
line are checked before the command runs (:mod:`resection.cli.paths`): no output is written
when another cannot be. Ctrl-C prints one line and exits with status 130; the files being
written are removed (see :func:`resection.io.outputs.atomic_path`), complete ones stay. A
closed output pipe (``... | head``) ends quietly.
"""

from __future__ import annotations

import argparse
import os
import sys

from resection.errors import InputError, SolveError
from resection.io.outputs import check_command_outputs

#: Exceptions reported as one line with exit status 2.
USER_ERRORS = (
    InputError,
    SolveError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)


class OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line (``prog: error: message``, exit status 2), without the
    usage block; ``--help`` still shows it. Sub-command parsers inherit the class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


#: Longest error line printed: a value quoted from an input (a 10 MB ``$var`` expansion,
#: a line of a binary file) is cut in its middle.
MAX_MESSAGE = 600


def one_line(message: str, limit: int = MAX_MESSAGE) -> str:
    """The first line of ``message``, cut in the middle to at most ``limit`` characters
    (saying how many were left out)."""
    first = message.splitlines()[0] if message else ""
    if len(first) <= limit:
        return first
    cut = f" ... ({len(first) - limit} characters left out) ... "
    keep = max(limit - len(cut), 0)
    return first[:keep - keep // 3] + cut + first[len(first) - keep // 3:]


def run(parser: argparse.ArgumentParser, argv: list[str] | None) -> int:
    """Parse ``argv`` and call the chosen sub-command's ``func(args)``; return the exit
    status."""
    from resection._numba_cache import ensure_numba_cache
    from resection.cli.interrupts import interrupted
    from resection.cli.paths import check_command_paths
    from resection.io.paths import os_error_text

    args = parser.parse_args(argv)
    prog = f"{parser.prog} {args.command}"
    stopped = (f"{prog}: interrupted; files being written were removed, complete ones "
               "kept")
    try:
        check_command_paths(args)  # inputs readable, every output writable, before any work
        check_command_outputs(args)  # no output may be one of the inputs
        ensure_numba_cache()  # before any kernel is imported: a read-only install
        # numba's parallel kernels run on OpenMP (GNU libgomp, which reads this when the
        # first parallel kernel loads it): its threads spin while they wait, and on cores
        # shared with other work each launch then cost several times its work (the thermal
        # run's sampling, asv's bench_thermal.py); passive waiting, unless the user set it
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        status = int(args.func(args) or 0)
        if interrupted():  # a Ctrl-C that a library swallowed: still a stop
            print(stopped, file=sys.stderr)
            return 130
        return status
    except USER_ERRORS as exc:
        msg = one_line(str(exc)) if str(exc) else type(exc).__name__
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (e.g. `| head`): stop quietly, as Unix tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except OSError as exc:  # full disk, read-only file system, link loop, ...
        print(f"{prog}: error: {one_line(os_error_text(exc))}", file=sys.stderr)
        return 2
    except RecursionError:
        print(f"{prog}: error: an input is nested too deeply to read", file=sys.stderr)
        return 2
    except MemoryError as exc:
        why = one_line(str(exc), 200) if str(exc) else "an allocation failed"
        print(f"{prog}: error: not enough memory ({why})", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(stopped, file=sys.stderr)
        return 130


def add_acceptance_options(p: argparse.ArgumentParser) -> None:
    """``--marker-accuracy`` and ``--max-rms``: the acceptance rule's options, the same in
    every command that fits a camera to markers (see docs/acceptance.md)."""
    from resection.defaults import DEFAULT_MARKER_ACCURACY, DEFAULT_MAX_RMS

    p.add_argument("--marker-accuracy", type=float, default=DEFAULT_MARKER_ACCURACY,
                   metavar="PX",
                   help="stated accuracy of a marker position, survey + detection, px "
                   "(RMS length; default 1): residuals are judged against it and gross "
                   "outliers dropped")
    p.add_argument("--max-rms", type=float, default=DEFAULT_MAX_RMS, metavar="PX",
                   help="refuse a fit whose RMS residual exceeds this whatever the "
                   "accuracy, px (default 2)")


def add_mesh_format(parser: argparse.ArgumentParser) -> None:
    """``--format``: the mesh file's format when its extension does not say it (Plot3D is
    recognised by content; see :data:`resection.io.meshes.MESH_FORMATS`)."""
    from resection.defaults import MESH_FORMATS

    parser.add_argument("--format", dest="mesh_format", choices=MESH_FORMATS, default=None,
                        help="format of --mesh (default: from the extension; Plot3D by "
                        "content)")


def add_camera_check_options(parser: argparse.ArgumentParser) -> None:
    """``--markers`` and ``--polarity``: check that the camera fits the image (each target
    it should see lands on a spot; :mod:`resection.pose.camera_fit`)."""
    parser.add_argument("--markers", metavar="MARKERS", help="marker file (CSV or uPSP "
                        ".tgts): check that the camera fits each image, every target it "
                        "should see landing on a spot (window check); a camera that does "
                        "not fit is refused")
    parser.add_argument("--polarity", choices=("dark", "bright"), default="dark",
                        help="targets darker (default) or brighter than the paint, for "
                        "--markers")

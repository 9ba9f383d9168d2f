"""Exceptions raised on bad input.

Every function of the package checks what it is given and raises one of these with a
message that names the problem (which file, which key, which marker), so that the CLI
can print it on one line and a script can catch it.
"""

from __future__ import annotations


class InputError(ValueError):
    """Input that cannot be used: wrong shape, NaN, too few markers, unknown key, ..."""


class DegenerateError(InputError):
    """Geometrically degenerate input: collinear or coplanar markers, singular systems."""


class SolveError(RuntimeError):
    """A solver that ran but did not produce a trustworthy answer (no convergence,
    residual too large, ambiguous solution). The message says why."""

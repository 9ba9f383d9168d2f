"""The ``selfillum`` command line: each command's parser and runner, nothing else."""

from __future__ import annotations

from selfillum.cli.main import main

__all__ = ["main"]

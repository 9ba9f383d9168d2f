"""Checks of a parsed command line's paths, made by the common runner
(:func:`resection.cli.util.run`) before a command reads or writes anything.

* every input option naming a path: not a symlink loop, a FIFO, a device or a socket
  (:func:`resection.io.paths.check_input_path`);
* every output option: a file that can be written (folder present and writable, name not
  too long) or, for the commands whose ``--out`` is a folder (``track``, ``selfillum psp``,
  ``selfillum corner``), a folder that can be made and written, whose files the command
  writes are not the user's (:func:`resection.io.marks.claim_folder`) and are none of the
  inputs (``track --out seq --markers seq/markers.csv``);
* the temporary files a killed run left in those folders are removed
  (:func:`resection.io.paths.sweep_temporaries`).

A command declares a folder output with ``parser.set_defaults(out_folder=FolderOutput(...))``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from resection.io.outputs import OUTPUT_OPTIONS, as_paths, refuse_overwriting_inputs
from resection.io.paths import (
    check_input_path,
    check_output_folder,
    check_output_path,
    sweep_temporaries,
)

__all__ = ["FolderOutput", "check_command_paths"]

_NOT_PATHS = ("command", "func", "out_folder")


@dataclass(frozen=True)
class FolderOutput:
    """A command whose ``--out`` is a folder: the files it writes there (``names``, some
    as ``glob`` patterns resolved by the command), the manifest that marks the folder as
    its output, the producer named in it, and sub-folders it writes into."""

    names: tuple[str, ...]
    manifest: str
    producer: str
    subfolders: tuple[str, ...] = ()


def _outputs(args) -> dict[str, str]:
    return {k: os.fspath(v) for k, v in vars(args).items()
            if k in OUTPUT_OPTIONS and isinstance(v, (str, os.PathLike)) and os.fspath(v)}


def check_command_paths(args) -> None:
    """Check the paths of a parsed command line (see the module docstring); raise
    :class:`~resection.errors.InputError` naming the first bad one."""
    from resection.io.marks import claim_folder, existing

    opts = vars(args)
    outputs = _outputs(args)
    folder: FolderOutput | None = opts.get("out_folder")
    inputs = {f"input {k.replace('_', '-')}": as_paths(v) for k, v in opts.items()
              if k not in OUTPUT_OPTIONS + _NOT_PATHS}
    for k, v in opts.items():
        if k not in OUTPUT_OPTIONS + _NOT_PATHS:
            for p in as_paths(v):
                if p:
                    check_input_path(p, f"--{k.replace('_', '-')}")
    for key, value in outputs.items():
        option = f"--{key.replace('_', '-')}"
        if key == "out" and folder is not None:
            check_output_folder(value, option)
            out = Path(value)
            claim_folder(out, folder.names, folder.manifest, folder.producer)
            named = {f"{option} {out / n}": out / n for n in folder.names if "*" not in n}
            named.update({f"{option} {p}": p for p in existing(out, folder.names)})
            refuse_overwriting_inputs(named, inputs)
            for sub in ("", *folder.subfolders):
                sweep_temporaries(out / sub)
        else:
            check_output_path(value, option)
            sweep_temporaries(Path(value).parent)

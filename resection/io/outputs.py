"""Writing outputs safely: never over an input, never half a file.

Three rules every command follows (docs/design.md, "Outputs never overwrite an input"):

* an output that is one of the command's inputs (the same file, through any path, link or
  hard link) is refused before anything is computed: :func:`refuse_overwriting_inputs`,
  and :func:`check_command_outputs` which applies it to a parsed command line;
* every file is written to a temporary name in its own folder and renamed into place
  (``os.replace``, atomic on one file system), so a crash, a full disk or a bad value
  never leaves half a file nor destroys the previous one: :func:`atomic_path`,
  :func:`atomic_write`;
* a side file (a preview, a sidecar) is named from the output it goes with and never
  replaces a file the command did not make: :func:`side_path`. An output folder is
  created only by a run that succeeds (:func:`output_folder`).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import stat
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from resection.errors import InputError

__all__ = [
    "OUTPUT_OPTIONS",
    "atomic_path",
    "atomic_write",
    "check_command_outputs",
    "output_folder",
    "picture_format",
    "refuse_overwriting_inputs",
    "same_file",
    "side_path",
]

#: Command-line options (argparse ``dest``) that name files a command writes; every other
#: option whose value names an existing file is taken as an input.
OUTPUT_OPTIONS = ("out", "residuals", "png", "suggest", "pose", "surface", "plot",
                  "save_links")


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` are one file: ``os.path.samefile`` when both exist (links
    and hard links included), else the same absolute path with links resolved."""
    a, b = Path(a), Path(b)
    try:
        if os.path.exists(a) and os.path.exists(b):  # False, not an error, for a non-path
            return os.path.samefile(a, b)
    except OSError:
        pass
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError, ValueError):
        return False


def refuse_overwriting_inputs(outputs: Mapping[str, str | os.PathLike | None],
                              inputs: Mapping[str, Iterable[str | os.PathLike]]) -> None:
    """Raise :class:`InputError` when an output is one of the inputs, or two outputs are
    one file.

    Parameters
    ----------
    outputs : mapping of str to path or None
        Outputs by the name the user knows them under (e.g. ``"--out"``); None is skipped.
        An existing folder is not a file output and is skipped.
    inputs : mapping of str to iterable of paths
        Inputs by name (e.g. ``"--image"``); only existing files are compared.
    """
    outs = [(k, Path(v)) for k, v in outputs.items()
            if v is not None and str(v) != "" and not os.path.isdir(v)]
    existing = {}  # (device, inode) of the outputs that exist: only they can be inputs
    for i, (name, path) in enumerate(outs):
        for other_name, other in outs[:i]:
            if same_file(path, other):
                raise InputError(f"{name} {path}: same file as {other_name}; give each "
                                 "output its own name")
        st = _stat_or_none(path)
        if st is not None:
            existing.setdefault((st.st_dev, st.st_ino), (name, path))
    if not existing:
        return
    for in_name, paths in inputs.items():  # one stat an input (thousands of frames)
        for p in paths:
            st = _stat_or_none(p)  # None for a value that is no path (a JSON text)
            if st is None or not stat.S_ISREG(st.st_mode):
                continue
            hit = existing.get((st.st_dev, st.st_ino))  # the same file, links included
            if hit is not None:
                name, path = hit
                raise InputError(
                    f"{name} {path}: is an input of this command ({in_name} {p}); "
                    "refusing to overwrite it: write to another file")


def _stat_or_none(path):
    try:
        return os.stat(path)
    except (OSError, ValueError):
        return None


def as_paths(value) -> list[str]:
    """The file names a parsed option value may hold (a string, a list of them, or
    ``A:B`` pairs as in ``calibrate --views``)."""
    if isinstance(value, (str, os.PathLike)):
        text = os.fspath(value)
        return [text, *text.rsplit(":", 1)] if ":" in text else [text]
    if isinstance(value, (list, tuple)):
        return [p for v in value for p in as_paths(v)]
    return []


def check_command_outputs(args, output_options: Iterable[str] = OUTPUT_OPTIONS) -> None:
    """Apply :func:`refuse_overwriting_inputs` to a parsed command line: the options in
    ``output_options`` are the outputs, every other option naming an existing file an
    input. Called before the command runs, so nothing is computed in vain."""
    opts = vars(args)
    output_options = tuple(output_options)
    outputs = {f"--{k.replace('_', '-')}": v for k, v in opts.items()
               if k in output_options and isinstance(v, (str, os.PathLike))}
    inputs = {f"input {k.replace('_', '-')}": as_paths(v)
              for k, v in opts.items() if k not in output_options + ("command", "func")}
    refuse_overwriting_inputs(outputs, inputs)


def picture_format(fig, path: str | os.PathLike) -> str:
    """The picture format of ``path`` (its suffix, lower case) when ``fig``'s canvas can
    write it; a one-line :class:`InputError` naming the formats it can write otherwise."""
    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower().lstrip(".")
    formats = fig.canvas.get_supported_filetypes()
    if suffix not in formats:
        raise InputError(f"{path}: unknown picture format {suffix!r} (use one of "
                         f"{', '.join(sorted(formats))})")
    return suffix


def _temporary_name(path: Path) -> Path:
    """A fresh name next to ``path`` with the same extension (writers choose the format
    from it): ``folder/.name.<pid>-<random>.tmp<suffix>``."""
    tag = f"{os.getpid()}-{secrets.token_hex(4)}"
    return path.with_name(f".{path.stem}.{tag}.tmp{path.suffix}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike | None) -> Iterator[Path | None]:
    """Context manager: a temporary path to write ``path`` through.

    Write the file to the yielded path; when the block ends without an exception it is
    renamed to ``path`` (``os.replace``: readers see the old file or the new one, never a
    part); on an exception it is removed and ``path`` is left as it was. A ``None`` path
    yields None (an optional output not asked for).

    Raises
    ------
    InputError
        The folder of ``path`` does not exist, or ``path`` is a folder.
    """
    if path is None:
        yield None
        return
    final = Path(path)
    if final.is_dir():
        raise InputError(f"{final}: is a folder, expected a file name")
    folder = final.parent
    if not folder.is_dir():
        raise InputError(f"{final}: output folder {folder} does not exist")
    tmp = _temporary_name(final)
    try:
        yield tmp
        if not tmp.exists():
            raise InputError(f"{final}: nothing was written")
        os.replace(tmp, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        msg = str(exc)
        if tmp.name in msg and isinstance(exc, ValueError):
            # the writer's message names the temporary file: name the user's file
            raise type(exc)(msg.replace(str(tmp), str(final)).replace(tmp.name, final.name)) \
                from None
        raise


def atomic_write(path: str | os.PathLike, writer, *args, **kwargs):
    """``writer(tmp, *args, **kwargs)`` through :func:`atomic_path`; returns its result.

    E.g. ``atomic_write("out.tif", write_image, image)``.
    """
    with atomic_path(path) as tmp:
        return writer(tmp, *args, **kwargs)


def side_path(output: str | os.PathLike, tag: str, suffix: str) -> Path:
    """The name of a side file (preview, sidecar) of ``output``: ``<stem>.<tag><suffix>``
    in the same folder (``a.tif`` -> ``a.preview.png``).

    A side file never replaces a file the command did not make: an existing one is
    accepted only when it carries the mark of ``output``'s side file
    (:mod:`resection.io.marks`: the writer adds it), else it is refused.

    Raises
    ------
    InputError
        The side file exists without the mark, or is the output itself.
    """
    from resection.io.marks import claim_side_file

    output = Path(output)
    side = output.with_name(f"{output.stem}.{tag}{suffix}")
    if same_file(side, output):
        raise InputError(f"{output}: its {tag} would have the same name {side.name}")
    return claim_side_file(side, output, tag)


@contextlib.contextmanager
def output_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Context manager: the output folder ``path``, created if missing, and removed again
    (with what the block wrote into it) when the block fails and the folder was made here.
    An existing folder is never removed."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: exists and is not a folder")
    made = None  # the topmost folder this call creates
    for parent in (folder, *folder.parents):
        if parent.exists():
            break
        made = parent
    folder.mkdir(parents=True, exist_ok=True)
    try:
        yield folder
    except BaseException:
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)
        raise

"""The entry's datapoint index, in either schema (docs/entry.md):

* **the project's own** (YAML or JSON): ``entry`` (what is fixed for the entry: ``grid``,
  ``targets``, ``test_config``, ``camera_tunnel`` = {camera number: calibration file},
  optional ``paint_calibration``, ``steady``, ``reflectance``, ``options``) and
  ``datapoints`` = {id: {``wtd``, ``videos`` = {camera number: video}, optional ``steady``,
  ``kulites``, ``paint_calibration``}};
* **uPSP's datapoint index** (JSON, as ``upsp-make-processing-tree`` reads it): per
  datapoint ``camera_tunnel_calibration_dir``, ``camera_video_dir``, ``grid_file``,
  ``kulites_files_path``, ``paint_calibration_file``, ``steady_psp_file``, ``targets_file``,
  ``wtd_file`` (optional ``normals_file``, refused: not supported), the datapoints at the
  top level (uPSP's docs) or under ``datapoints`` (uPSP's ``tree.py``), ``__meta__``
  beside them. Videos are found as uPSP finds them: ``<id>NN.<ext>`` in
  ``camera_video_dir`` (``.cine``, ``.mraw``; camera ``NN``), calibrations as
  ``cameraNN.json`` in ``camera_tunnel_calibration_dir``.

Relative paths are taken from the index file's folder.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from resection.errors import InputError

__all__ = ["Datapoint", "EntryIndex", "read_index", "UPSP_KEYS", "find_videos",
           "find_camera_tunnel"]

#: the keys of a datapoint in uPSP's index.
UPSP_KEYS = ("camera_tunnel_calibration_dir", "camera_video_dir", "grid_file",
             "kulites_files_path", "paint_calibration_file", "steady_psp_file",
             "targets_file", "wtd_file", "normals_file")
_UPSP_REQUIRED = ("camera_tunnel_calibration_dir", "camera_video_dir", "grid_file",
                  "targets_file", "wtd_file", "steady_psp_file")
_ENTRY_KEYS = ("name", "grid", "targets", "test_config", "camera_tunnel",
               "paint_calibration", "steady", "reflectance", "options")
_DP_KEYS = ("wtd", "videos", "steady", "kulites", "paint_calibration")
#: video files uPSP's tree looks for in ``camera_video_dir`` (``.dyn`` named as unsupported)
VIDEO_EXTS = (".cine", ".mraw", ".dyn")


@dataclass(frozen=True)
class Datapoint:
    """One datapoint: its files (absolute paths) and its index entries.

    ``videos`` / ``camera_tunnel``: {camera number: path}, or None when they are found in
    ``video_dir`` / ``calibration_dir`` (uPSP's index: :func:`find_videos`,
    :func:`find_camera_tunnel`). ``entries``: the index's values under uPSP's names, which
    the processing overlays match."""

    id: str
    wtd: Path
    grid: Path
    targets: Path
    steady: Path | None
    paint_calibration: Path | None
    kulites: Path | None
    videos: dict | None = None
    camera_tunnel: dict | None = None
    video_dir: Path | None = None
    calibration_dir: Path | None = None
    entries: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EntryIndex:
    """The index read: ``datapoints`` in file order, ``schema`` (``"project"`` or
    ``"upsp"``), ``test_config`` (path or None), ``reflectance``, ``options`` (the deck
    options of the project's schema), ``name`` and ``source``."""

    datapoints: tuple
    schema: str
    source: str
    test_config: Path | None = None
    reflectance: object = 0.6
    options: dict = field(default_factory=dict)
    name: str = ""


def _load(p: str):
    try:
        text = Path(p).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read ({e})") from None
    if p.lower().endswith(".json") or text.lstrip().startswith("{"):
        try:
            return json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(f"{p}: not JSON ({e.msg}, line {e.lineno})") from None
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"{p}: not YAML ({getattr(e, 'problem', e)}{where})") from None


def _path(base: Path, v, what: str) -> Path:
    if not isinstance(v, str) or not v:
        raise InputError(f"{what}: expected a path, got {v!r}")
    q = Path(os.path.expanduser(v))
    return q if q.is_absolute() else base / q


def _cameras(base: Path, d, what: str) -> dict:
    if not isinstance(d, dict) or not d:
        raise InputError(f"{what}: expected {{camera number: file}}, got {d!r}")
    out = {}
    for k, v in d.items():
        try:
            n = int(k)
        except (TypeError, ValueError):
            raise InputError(f"{what}: camera {k!r} is not a number") from None
        if n < 1:
            raise InputError(f"{what}: camera numbers count from 1, got {n}")
        out[n] = _path(base, v, f"{what}[{k}]")
    return dict(sorted(out.items()))


def _unknown(d: dict, known, what: str) -> None:
    import difflib

    for k in d:
        if k not in known:
            near = difflib.get_close_matches(str(k), known, n=1, cutoff=0.7)
            hint = f" (did you mean {near[0]!r}?)" if near else \
                f" (known: {', '.join(known)})"
            raise InputError(f"{what}: unknown key {k!r}{hint}")


def _project(d: dict, p: str, base: Path) -> EntryIndex:
    _unknown(d, ("entry", "datapoints"), p)
    e = d.get("entry")
    if not isinstance(e, dict):
        raise InputError(f"{p}: 'entry' must be an object (grid, targets, test_config, "
                         "camera_tunnel, ...)")
    _unknown(e, _ENTRY_KEYS, f"{p}: entry")
    for k in ("grid", "targets", "test_config", "camera_tunnel"):
        if k not in e:
            raise InputError(f"{p}: entry: missing {k!r}")
    cams = _cameras(base, e["camera_tunnel"], f"{p}: entry: camera_tunnel")
    dps = d.get("datapoints")
    if not isinstance(dps, dict) or not dps:
        raise InputError(f"{p}: 'datapoints' must be an object {{id: {{wtd, videos, ...}}}}")
    opts = e.get("options", {}) or {}
    if not isinstance(opts, dict):
        raise InputError(f"{p}: entry: options must be an object (the deck's @options)")
    out = []
    for dp, v in dps.items():
        w = f"{p}: datapoint {dp}"
        if not isinstance(v, dict):
            raise InputError(f"{w}: expected an object {{wtd, videos, ...}}")
        _unknown(v, _DP_KEYS, w)
        for k in ("wtd", "videos"):
            if k not in v:
                raise InputError(f"{w}: missing {k!r}")
        videos = _cameras(base, v["videos"], f"{w}: videos")
        missing = sorted(set(videos) - set(cams))
        if missing:
            raise InputError(f"{w}: camera {missing[0]} has a video but no camera_tunnel "
                             "calibration in 'entry'")
        g = {k: _path(base, e[k], f"{p}: entry: {k}") for k in ("grid", "targets")}
        opt = {k: (_path(base, v[k], f"{w}: {k}") if v.get(k) is not None else
                   _path(base, e[k], f"{p}: entry: {k}") if e.get(k) is not None else None)
               for k in ("steady", "paint_calibration")}
        kul = _path(base, v["kulites"], f"{w}: kulites") if v.get("kulites") else None
        wtd = _path(base, v["wtd"], f"{w}: wtd")
        entries = {"grid_file": e["grid"], "targets_file": e["targets"], "wtd_file": v["wtd"],
                   "steady_psp_file": v.get("steady", e.get("steady", "")) or "",
                   "paint_calibration_file":
                       v.get("paint_calibration", e.get("paint_calibration", "")) or "",
                   "kulites_files_path": v.get("kulites", "") or ""}
        out.append(Datapoint(str(dp), wtd, g["grid"], g["targets"], opt["steady"],
                             opt["paint_calibration"], kul, videos,
                             {n: cams[n] for n in videos}, entries=entries))
    return EntryIndex(tuple(out), "project", p, _path(base, e["test_config"],
                                                      f"{p}: entry: test_config"),
                      e.get("reflectance", 0.6), dict(opts), str(e.get("name", "")))


def _upsp(d: dict, p: str, base: Path) -> EntryIndex:
    meta = d.get("__meta__", {})
    dps = d["datapoints"] if isinstance(d.get("datapoints"), dict) else \
        {k: v for k, v in d.items() if k != "__meta__"}
    if not dps:
        raise InputError(f"{p}: no datapoint")
    out = []
    for dp, v in dps.items():
        w = f"{p}: datapoint {dp}"
        if not isinstance(v, dict):
            raise InputError(f"{w}: expected an object (uPSP's index: grid_file, wtd_file, "
                             "...)")
        _unknown(v, UPSP_KEYS, w)
        for k in _UPSP_REQUIRED:
            if k not in v:
                raise InputError(f"{w}: missing {k!r}")
        if v.get("normals_file"):
            raise InputError(f"{w}: normals_file is not supported (the grid's own normals "
                             "are used)")
        for k, x in v.items():
            if not isinstance(x, str):
                raise InputError(f"{w}: {k} must be a path, got {x!r}")

        def q(k, v=v, w=w):
            return _path(base, v[k], f"{w}: {k}") if v.get(k) else None

        out.append(Datapoint(str(dp), q("wtd_file"), q("grid_file"), q("targets_file"),
                             q("steady_psp_file"), q("paint_calibration_file"),
                             q("kulites_files_path"), video_dir=q("camera_video_dir"),
                             calibration_dir=q("camera_tunnel_calibration_dir"),
                             entries=dict(v)))
    name = meta.get("test_name", "") if isinstance(meta, dict) else ""
    return EntryIndex(tuple(out), "upsp", p, name=str(name))


def read_index(path: str | os.PathLike) -> EntryIndex:
    """Read a datapoint index in either schema (module notes)."""
    p = os.fspath(path)
    d = _load(p)
    if not isinstance(d, dict):
        raise InputError(f"{p}: expected an object (the project's 'entry' and 'datapoints', "
                         "or uPSP's datapoint index)")
    base = Path(p).resolve().parent
    if "entry" in d:
        return _project(d, p, base)
    return _upsp(d, p, base)


def find_videos(dp: Datapoint) -> dict:
    """{camera number: video} of a datapoint: as given, or uPSP's ``<id>NN.<ext>`` in
    its ``camera_video_dir`` (:class:`InputError` naming the datapoint and folder when
    there is none, or a camera has two)."""
    if dp.videos is not None:
        return dict(dp.videos)
    d = dp.video_dir
    if d is None or not d.is_dir():
        raise InputError(f"datapoint {dp.id}: camera_video_dir {d}: not a folder")
    found: dict = {}
    pat = re.compile(re.escape(dp.id) + r"(\d+)$")
    for f in sorted(d.iterdir()):  # a folder of videos
        m = pat.match(f.stem)
        if m and f.suffix.lower() in VIDEO_EXTS:
            found.setdefault(int(m.group(1)), []).append(f)
    if not found:
        raise InputError(f"datapoint {dp.id}: no video {dp.id}NN.cine/.mraw in {d}")
    for n, fs in found.items():
        if len(fs) > 1:
            raise InputError(f"datapoint {dp.id}: camera {n} has {len(fs)} videos in {d} "
                             f"({', '.join(f.name for f in fs)})")
        if fs[0].suffix.lower() == ".dyn":
            raise InputError(f"datapoint {dp.id}: {fs[0]}: .dyn videos are not supported")
    return {n: fs[0] for n, fs in sorted(found.items())}


def find_camera_tunnel(dp: Datapoint, numbers) -> dict:
    """{camera number: camera-to-tunnel calibration} for ``numbers``: as given, or
    uPSP's ``cameraNN.json`` in ``camera_tunnel_calibration_dir``."""
    if dp.camera_tunnel is not None:
        out = {n: dp.camera_tunnel[n] for n in numbers if n in dp.camera_tunnel}
    else:
        out = {n: dp.calibration_dir / f"camera{n:02d}.json" for n in numbers}
    for n in numbers:
        if n not in out or not out[n].is_file():
            raise InputError(f"datapoint {dp.id}: camera {n}: no camera-to-tunnel "
                             f"calibration {out.get(n, 'given')}")
    return out

"""uPSP's processing parameters file read as it is: the parameter sets, the ``defaults``,
and the ``__overlays__`` matched by regular expression on each datapoint's index entries
(``docs/sphinx/file-formats.rst``, "Processing pipeline configuration parameters").

``{"processing": {"defaults": {APP: {...}}, NAME: {APP: {...}}, "__overlays__": [[NAME,
{KEY_RE: VALUE_RE, ...}], ...]}}``: for each overlay in order, a datapoint matches when,
for every ``KEY_RE``, some index entry whose name fully matches ``KEY_RE`` has a value
fully matching ``VALUE_RE``; the parameter set ``NAME`` is then merged into the datapoint's
parameters (nested dictionaries merged key by key, the later overlay winning). The
applications read here are ``psp_process`` (:func:`psp_options`) and
``external-calibration`` (the tunnel, :func:`selfillum.entry.tunnel.tunnel_config`).
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings

from resection.errors import InputError

__all__ = ["read_processing", "resolve_overlays", "psp_options", "PSP_KEYS"]

#: ``psp_process`` parameters honoured, and how each maps onto ``UnsteadyConfig``.
PSP_KEYS = ("target_patcher", "registration", "overlap", "filter", "filter_size",
            "oblique_angle", "number_frames", "pixel_interpolation", "cutoff_x_max")
_REGISTRATION = {"pixel": "first-frame", "none": "none", "track": "track",
                 "first-frame": "first-frame"}


def read_processing(path: str | os.PathLike) -> dict:
    """The ``processing`` object of a uPSP processing parameters file, checked: each
    overlay a ``[name, {pattern: pattern}]`` pair naming a parameter set, each pattern a
    valid regular expression."""
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8-sig") as fh:
            d = json.load(fh)
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read ({e})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not JSON ({e.msg}, line {e.lineno})") from None
    if not isinstance(d, dict) or not isinstance(d.get("processing"), dict):
        raise InputError(f"{p}: no 'processing' object (uPSP's processing parameters file)")
    proc = d["processing"]
    sets = {k for k in proc if k != "__overlays__"}
    for k in sets:
        if not isinstance(proc[k], dict):
            raise InputError(f"{p}: parameter set {k!r} is not an object")
    ovs = proc.get("__overlays__", [])
    if not isinstance(ovs, list):
        raise InputError(f"{p}: __overlays__ must be a list of [name, {{key: value}}] pairs")
    for i, ov in enumerate(ovs):
        if not (isinstance(ov, list | tuple) and len(ov) == 2 and isinstance(ov[0], str)
                and isinstance(ov[1], dict)):
            raise InputError(f"{p}: __overlays__[{i}] must be [name, {{key: value}}], got "
                             f"{ov!r}")
        if ov[0] not in sets:
            raise InputError(f"{p}: __overlays__[{i}] names {ov[0]!r}, not a parameter set "
                             f"(sets: {', '.join(sorted(sets))})")
        for a in (x for kv in ov[1].items() for x in kv):
            if not isinstance(a, str):
                raise InputError(f"{p}: __overlays__[{i}]: pattern {a!r} is not text")
            try:
                re.compile(a)
            except re.error as e:
                raise InputError(f"{p}: __overlays__[{i}]: invalid regular expression "
                                 f"{a!r} ({e})") from None
    return {"sets": {k: proc[k] for k in sets}, "overlays": [tuple(o) for o in ovs],
            "source": p}


def _merge(d: dict, u: dict) -> dict:
    for k, v in u.items():
        d[k] = _merge(dict(d.get(k, {})), v) if isinstance(v, dict) else v
    return d


def _matches(patterns: dict, entries: dict) -> bool:
    for kre, vre in patterns.items():
        hit = False
        for k, v in entries.items():
            if re.fullmatch(kre, k) and re.fullmatch(vre, str(v)):
                hit = True
                break
        if not hit:
            return False
    return True


def resolve_overlays(processing: dict, datapoints: dict) -> dict:
    """Each datapoint's parameters: ``{id: {app: {key: value}}}`` from
    :func:`read_processing`'s result and ``{id: {entry name: value}}`` (the index's
    entries, uPSP's names: ``grid_file``, ``wtd_file``, ...). An overlay that matches no
    datapoint is reported in a warning, as uPSP does."""
    out = {k: {} for k in datapoints}
    for name, patterns in processing["overlays"]:
        hit = False
        for dp, entries in datapoints.items():
            if _matches(patterns, entries):
                out[dp] = _merge(out[dp], processing["sets"][name])
                hit = True
        if not hit:
            warnings.warn(f"{processing['source']}: overlay {name!r} {patterns} matches no "
                          "datapoint", stacklevel=2)
    return out


def psp_options(params: dict, where: str) -> dict:
    """``UnsteadyConfig`` keyword arguments from a datapoint's ``psp_process`` parameters;
    a parameter this package does not honour is refused by name."""
    kw = {}
    for k, v in params.items():
        if k not in PSP_KEYS:
            raise InputError(f"{where}: psp_process parameter {k!r} is not supported (known: "
                             f"{', '.join(PSP_KEYS)})")
        if k == "registration":
            if v not in _REGISTRATION:
                raise InputError(f"{where}: registration {v!r} unknown (pixel, none, track)")
            kw[k] = _REGISTRATION[v]
        elif k == "pixel_interpolation":
            if v != "linear":
                raise InputError(f"{where}: pixel_interpolation {v!r}: only linear is "
                                 "supported")
        elif k in ("filter_size", "number_frames"):
            if isinstance(v, bool) or not isinstance(v, int | str) or \
                    not str(v).lstrip("-").isdigit():
                raise InputError(f"{where}: {k} must be an integer, got {v!r}")
            kw[k] = int(v)
        elif k in ("oblique_angle", "cutoff_x_max"):
            # uPSP's tree writes cutoff_x_max onto psp_process's command line as it is
            # (-cutoff_x_max=120): a number, in the grid's units
            try:
                if isinstance(v, bool):
                    raise TypeError
                kw[k] = float(v)
            except (TypeError, ValueError):
                raise InputError(f"{where}: {k} must be a number, got {v!r}") from None
            if not math.isfinite(kw[k]):
                raise InputError(f"{where}: {k} must be a finite number, got {v!r}")
        else:
            kw[k] = str(v)
    return kw

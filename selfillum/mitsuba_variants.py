"""Which Mitsuba variant this machine runs, and Mitsuba imported so that Dr.Jit finds a
libLLVM.

Shared by the renders (:mod:`selfillum.rendering`) and the Mitsuba ray tracer of the view
factors (:mod:`selfillum.transport.mitsuba_rays`): ``cuda_ad_rgb`` with a working GPU,
``llvm_ad_rgb`` when a libLLVM >= 16 loads, else ``scalar_rgb``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

from resection.errors import InputError

__all__ = ["available_variants", "choose_variant", "import_mitsuba"]

_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")


def _find_libllvm() -> str | None:
    """Path of the newest libLLVM >= 16 the dynamic linker knows, or None."""
    try:
        out = subprocess.run(
            ["ldconfig", "-p"], capture_output=True, text=True, timeout=10, check=False
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    best, best_ver = None, 15
    for line in out.splitlines():
        m = re.search(r"libLLVM[-.](?:so\.)?(\d+)\S*\s.*=>\s*(\S+)", line)
        if m and int(m.group(1)) > best_ver and os.path.exists(m.group(2)):
            best, best_ver = m.group(2), int(m.group(1))
    return best


def import_mitsuba():
    """Import Mitsuba and Dr.Jit, pointing Dr.Jit at a libLLVM >= 16 when it would not
    find one by itself (``DRJIT_LIBLLVM_PATH``, read once when Dr.Jit first loads; a value
    the user set is kept)."""
    if "drjit" not in sys.modules and "DRJIT_LIBLLVM_PATH" not in os.environ:
        path = _find_libllvm()
        if path is not None:
            os.environ["DRJIT_LIBLLVM_PATH"] = path
    import drjit as dr
    import mitsuba as mi

    return mi, dr


def available_variants() -> list[str]:
    """The RGB variants this machine can run, fastest first.

    ``cuda_ad_rgb`` needs a working CUDA device, ``llvm_ad_rgb`` a loadable libLLVM (>= 16
    for Mitsuba 3.5+, e.g. Debian's ``libllvm19``), ``scalar_rgb`` nothing.
    """
    mi, dr = import_mitsuba()
    compiled = set(mi.variants())
    out = []
    if "cuda_ad_rgb" in compiled and dr.has_backend(dr.JitBackend.CUDA):
        out.append("cuda_ad_rgb")
    if "llvm_ad_rgb" in compiled and dr.has_backend(dr.JitBackend.LLVM):
        out.append("llvm_ad_rgb")
    if "scalar_rgb" in compiled:
        out.append("scalar_rgb")
    return out


def choose_variant(variant: str | None = None) -> str:
    """The Mitsuba variant to render with.

    Parameters
    ----------
    variant : str, optional
        ``None`` or ``"auto"``: the fastest available (cuda, then llvm, then scalar).
        Otherwise one of ``cuda_ad_rgb``, ``llvm_ad_rgb``, ``scalar_rgb`` (or the short
        names ``cuda``, ``llvm``, ``scalar``), which must be available here.

    Raises
    ------
    InputError
        Unknown variant, or one this machine cannot run.
    """
    avail = available_variants()
    if variant is None or variant == "auto":
        if not avail:
            raise InputError("render: this Mitsuba build has no RGB variant")
        return avail[0]
    name = {"cuda": "cuda_ad_rgb", "llvm": "llvm_ad_rgb", "scalar": "scalar_rgb"}.get(
        variant, variant
    )
    if name not in _VARIANTS:
        raise InputError(
            f"render: unknown Mitsuba variant {variant!r} (expected auto, cuda, llvm or scalar)"
        )
    if name not in avail:
        raise InputError(
            f"render: Mitsuba variant {name} is not available on this machine "
            f"(available: {', '.join(avail)})"
        )
    return name

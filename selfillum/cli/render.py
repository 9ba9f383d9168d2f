"""``selfillum render``: a synthetic validation image rendered with Mitsuba 3.

Only parses arguments, reads the inputs and calls :func:`selfillum.rendering.mitsuba_render.render`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from resection.cli.util import add_mesh_format
from resection.errors import InputError


def per_face_arg(text: str, name: str):
    """A number, or a file of per-face values (.npy, or text/CSV with one value a line)."""
    try:
        return float(text)
    except ValueError:
        pass
    path = Path(text)
    if not path.exists():
        raise InputError(f"{name}: {text!r} is neither a number nor an existing file")
    try:
        if path.suffix.lower() == ".npy":
            from resection.io.images import load_npy

            return load_npy(path)  # one-line errors, never advising allow_pickle
        return np.loadtxt(path, delimiter="," if path.suffix.lower() == ".csv" else None,
                          ndmin=1)
    except (ValueError, OSError) as exc:
        raise InputError(f"{name}: cannot read {path}: {exc}") from None


def preview(image: np.ndarray) -> np.ndarray:
    """8-bit preview: linear, 0 black, the 99.5th percentile of the model pixels white."""
    img = np.asarray(image, dtype=np.float64)
    pos = img[np.isfinite(img) & (img > 0)]
    top = float(np.percentile(pos, 99.5)) if pos.size else 1.0
    scaled = np.clip(np.nan_to_num(img / top), 0.0, 1.0)
    return np.rint(255.0 * scaled).astype(np.uint8)


def _cmd_render(args) -> int:
    from resection.io.cameras import read_camera
    from resection.io.images import write_image
    from resection.io.marks import mark_png
    from resection.io.meshes import load_mesh
    from resection.io.outputs import atomic_path, atomic_write, side_path
    from selfillum.rendering.mitsuba_render import render

    out = Path(args.out)
    if out.suffix.lower() not in (".tif", ".tiff", ".npy"):
        raise InputError(f"--out: expected a .tif, .tiff or .npy file, got {out.name!r}")
    if not out.parent.exists():
        raise InputError(f"--out: folder {out.parent} does not exist")
    png = side_path(out, "preview", ".png")  # a.tif -> a.preview.png, never an unrelated a.png
    mesh = load_mesh(args.mesh, format=args.mesh_format)
    camera = read_camera(args.camera)
    emission = per_face_arg(args.emission, "--emission")
    reflectance = per_face_arg(args.reflectance, "--reflectance")
    paint = None
    if args.specular_weight > 0:
        from selfillum.solve.brdf import GlossyPaint

        paint = GlossyPaint(args.specular_weight, args.roughness)
    t0 = time.perf_counter()
    res = render(mesh, emission, reflectance, camera, bounces=args.bounces, spp=args.spp,
                 seed=args.seed, variant=args.variant, paint=paint, two_sided=args.two_sided)
    seconds = time.perf_counter() - t0
    atomic_write(out, write_image, res.image)
    with atomic_path(png) as tmp:
        write_image(tmp, preview(res.image))
        mark_png(tmp, out, "selfillum render")  # ours: a later run into `out` may replace it
    print(f"variant   {res.variant}")
    print(f"image     {camera.width} x {camera.height}, {res.spp} spp, bounces {res.bounces}")
    if paint is not None:
        print(f"paint     glossy, specular weight {paint.specular_weight:g}, "
              f"GGX alpha {paint.roughness:g}")
    print(f"time      {seconds:.2f} s")
    print(f"wrote {out}")
    print(f"wrote {png}")
    return 0


def _bounces(text: str) -> int:
    try:
        b = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if b < 1 and b != -1:
        raise argparse.ArgumentTypeError(f"must be >= 1 or -1 (all), got {text}")
    return b


def _spp(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return v


def register(sub) -> None:
    """Add the ``render`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    p = sub.add_parser(
        "render",
        help="render a painted model with Mitsuba 3 (synthetic validation image)",
        description="Render the radiance image (B/pi on a Lambertian face of radiosity B) "
        "of a mesh with per-face emission and reflectance seen by a camera, with Mitsuba "
        "3's path tracer. Writes OUT (.tif float32 or .npy) and a PNG preview next to it.",
    )
    p.add_argument("--mesh", required=True, help="model surface (STL, OBJ, PLY, Plot3D, ...)")
    add_mesh_format(p)
    p.add_argument("--camera", required=True, help="camera JSON file (resection format)")
    p.add_argument("--emission", required=True,
                   help="emitted exitance: a number for every face, or a per-face file "
                   "(.npy, or text/CSV with one value a line)")
    p.add_argument("--reflectance", required=True,
                   help="diffuse reflectance in [0, 1): a number or a per-face file")
    p.add_argument("--bounces", type=_bounces, default=-1,
                   help="path length: 1 = emission only, 2 = one reflection, ..., "
                   "-1 = all (default)")
    p.add_argument("--spp", type=_spp, default=64, help="samples per pixel (default 64)")
    p.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    p.add_argument("--variant", default="auto", choices=("auto", "cuda", "llvm", "scalar"),
                   help="Mitsuba variant (default auto: cuda, else llvm, else scalar)")
    p.add_argument("--specular-weight", type=float, default=0.0,
                   help="glossy paint: share w of a GGX specular lobe in [0, 1) (default 0: "
                   "Lambertian); the reflectance is then that of the diffuse base")
    p.add_argument("--roughness", type=float, default=0.3,
                   help="glossy paint: GGX alpha in [0.2, 1] (default 0.3)")
    p.add_argument("--two-sided", action="store_true",
                   help="faces painted on both sides (thin sheets); default one-sided")
    p.add_argument("--out", required=True, help="output image, .tif or .npy")
    p.set_defaults(func=_cmd_render)

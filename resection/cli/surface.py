"""``resection map``, ``backproject``, ``align`` and ``view``: argument parsing only; the
work is in :mod:`resection.surface.surface_map`, :mod:`~resection.surface.align`,
:mod:`resection.io.meshes` and
:mod:`resection.surface.plots`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from resection.cli.util import add_camera_check_options, add_mesh_format
from resection.defaults import DEFAULT_MAX_OBLIQUENESS
from resection.errors import InputError
from resection.io.outputs import atomic_path, atomic_write


def register(sub) -> None:
    """Add the image <-> surface sub-commands to an argparse sub-parser set."""
    m = sub.add_parser(
        "map",
        help="camera image(s) -> per-face surface fields (PLY/VTK/CSV); several cameras "
        "merged onto one grid",
        description="Average every image's pixels onto the model faces they see (one Embree "
        "ray per pixel) and write, per image, the mean (field named after the image file), "
        "the pixel count (<name>_count) and whether the face was seen (<name>_seen). With "
        "several --camera, one --image per camera (in the same order): the images are merged "
        "(weights feathered by view angle and by distance to each image's edges and "
        "occlusion boundaries, a gain per camera matched on the overlaps) into the fields "
        "merged, merged_weight, merged_cameras and merged_seen, in the first camera's "
        "counts; gains and overlap statistics are printed.",
    )
    m.add_argument("--mesh", required=True, help="model grid (STL/OBJ/PLY/GLB/OFF, Plot3D, "
                   "Cart3D .tri)")
    add_mesh_format(m)
    m.add_argument("--camera", required=True, action="append",
                   help="camera JSON with the solved pose; repeat for several cameras")
    m.add_argument("--image", required=True, nargs="+", action="extend",
                   help="image(s) of that camera; with several cameras, one per camera")
    m.add_argument("--out", required=True, help="surface file: .vtk, .vtu, .xdmf, .ply, .csv, "
                   ".npy, or .f (Plot3D function file, per grid node, on a Plot3D grid); .h5: "
                   "a time history of a frame sequence (see below)")
    m.add_argument("--max-obliqueness", type=float, default=DEFAULT_MAX_OBLIQUENESS,
                   metavar="DEG", help="faces seen more obliquely than this (degrees between "
                   "line of sight and normal, default %(default)g as uPSP; 90: none) count as "
                   "unseen")
    m.add_argument("--feather", type=float, default=None, metavar="PX",
                   help="several cameras: width of the weight ramp from image edges and "
                   "occlusion boundaries, pixels (default 4 %% of the image's smaller side; "
                   "0: none)")
    m.add_argument("--no-gain-match", action="store_true",
                   help="several cameras: do not match the camera gains on the overlaps")
    add_camera_check_options(m)
    h = m.add_argument_group(
        "time histories (--out P.h5)",
        "--image is then a frame sequence (image files, a multi-page TIFF, a 3-D .npy, "
        ".cine, .mraw): every frame is mapped with its own pose and written, as it "
        "finishes, into one HDF5 file with an XDMF sidecar (P.xdmf) for ParaView")
    h.add_argument("--track", metavar="DIR", help="track output folder: the pose of every "
                   "frame it solved (the model moves; --camera gives the intrinsics)")
    h.add_argument("--per", choices=("node", "face"), default="node",
                   help="values per grid node or per face (default node)")
    h.add_argument("--fps", type=float, help="frame rate for the frame times (default: "
                   "the video's, else times are frame numbers)")
    h.add_argument("--resume", action="store_true",
                   help="continue the file of an interrupted run")
    m.add_argument("--keep-border", action="store_true",
                   help="map the frame's dark border too (default: rows and columns at "
                   "the edges that hold no light are masked as unknown and named)")
    m.add_argument("--saturation", type=float, default=None, metavar="LEVEL",
                   help="pixels at or above this are saturated: unknown, in no value, and "
                   "the faces they fall on unseen (default: the full scale of the file's "
                   "integer type or of the video's sensor bits; none for float images)")
    m.set_defaults(func=run_map)

    b = sub.add_parser(
        "backproject",
        help="per-face values -> camera image",
        description="Render per-face values into a camera's image, interpolated within "
        "faces; pixels off the model keep the background (NaN, a value or an image).",
    )
    b.add_argument("--mesh", required=True)
    add_mesh_format(b)
    b.add_argument("--camera", required=True)
    b.add_argument("--values", required=True, help="per-face values: any field file 'map' "
                   "writes (.vtk/.vtu/.xdmf/.ply/.csv) or a .npy with one value per face")
    b.add_argument("--field", help="field name in --values (default: the only/first field)")
    b.add_argument("--background", help="image or number for pixels off the model")
    b.add_argument("--interpolation", choices=("linear", "mean", "nearest"), default="linear")
    b.add_argument("--out", required=True, help="output image (.tif, .npy: float; .png: "
                   "integer values as they are, else with --png-range)")
    b.add_argument("--png-range", metavar="MIN,MAX|auto",
                   help="PNG output: map MIN..MAX linearly to counts 1..65535 (auto: the "
                   "image's finite range), NaN to 0; the map is printed")
    b.set_defaults(func=run_backproject)

    a = sub.add_parser(
        "align",
        help="warp an image of one camera into another camera's view through the model",
        description="For every pixel of the target camera: its model surface point, "
        "projected with the source camera, sampled in the source image (wind-on onto "
        "wind-off).",
    )
    a.add_argument("--mesh", required=True)
    add_mesh_format(a)
    a.add_argument("--source-camera", required=True, help="camera JSON of --image")
    a.add_argument("--target-camera", required=True, help="camera JSON of the output view")
    a.add_argument("--image", required=True)
    a.add_argument("--order", type=int, default=1, help="interpolation order (1 bilinear)")
    a.add_argument("--out", required=True, help="output image (.tif or .npy)")
    a.set_defaults(func=run_align)

    v = sub.add_parser(
        "view",
        help="picture of per-face data from any Point of View with a colour bar",
        description="Render per-face data through a camera JSON or a virtual camera "
        "(--azimuth/--elevation) with a colour map, a colour bar and the model's outline "
        "(silhouettes and creases, never grid-block interfaces); writes a PNG. --target "
        "with --zoom, or --box, frames a region of the same Point of View.",
    )
    v.add_argument("--mesh", required=True)
    add_mesh_format(v)
    v.add_argument("--values", required=True, help="per-face values (.vtk/.vtu/.xdmf/.ply/"
                   ".csv/.npy)")
    v.add_argument("--field", help="field name in --values")
    v.add_argument("--camera", help="camera JSON (default: a virtual camera)")
    v.add_argument("--azimuth", type=float, default=30.0, help="virtual camera, degrees")
    v.add_argument("--elevation", type=float, default=30.0, help="virtual camera, degrees")
    v.add_argument("--size", default="800x600", metavar="WxH", help="virtual camera image")
    v.add_argument("--method", choices=("raster", "polygons"), default="raster")
    v.add_argument("--cmap", default="viridis")
    v.add_argument("--vmin", type=float)
    v.add_argument("--vmax", type=float)
    v.add_argument("--label", default=None, help="colour bar label (default: field name)")
    v.add_argument("--target", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="model point put at the picture's centre")
    v.add_argument("--zoom", type=float, default=1.0,
                   help="magnification about --target (default %(default)g)")
    v.add_argument("--box", nargs=6, type=float,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="frame this box of the model (model units)")
    v.add_argument("--crease", type=float, default=30.0, metavar="DEG",
                   help="outline edges whose dihedral angle exceeds this (default %(default)g)")
    v.add_argument("--no-outline", action="store_true", help="do not draw the outline")
    v.add_argument("--out", required=True, help="PNG file")
    v.set_defaults(func=run_view)


def _field(path: str, name: str | None, n_faces: int) -> tuple[str, np.ndarray]:
    from resection.io.meshes import read_face_fields

    fields = read_face_fields(path, n_faces)
    if not fields:
        raise InputError(f"{path}: holds no per-face field")
    if name is None:
        name = next(iter(fields))
    if name not in fields:
        raise InputError(f"{path}: no field {name!r}; fields: {', '.join(fields)}")
    return name, fields[name]


def run_map(args: argparse.Namespace) -> int:
    from resection.border import border_report, mask_dark_border
    from resection.camera.units import require_seen
    from resection.io.cameras import read_camera_file
    from resection.io.images import read_native
    from resection.io.markers import read_markers
    from resection.io.meshes import load_mesh, write_surface
    from resection.pose.camera_fit import check_camera
    from resection.saturation import faces_touched, level_of, mask_saturated, report
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster

    if Path(args.out).suffix.lower() in (".h5", ".hdf5"):
        return _run_history(args)
    if args.track or args.resume:
        raise InputError("--track and --resume go with a time history (--out P.h5)")
    if Path(args.out).suffix.lower() == ".xdmf":  # its heavy data file: before any work
        from resection.io.fields import xdmf_data_path

        xdmf_data_path(args.out)
    names = [Path(p).stem for p in args.image]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"--image: several images named {repeated[0]!r} (the field names "
                         "come from the file names; rename or map them separately)")
    if len(args.camera) > 1:
        return _run_merge(args, names)
    def native(path):
        raw = read_native(path)
        if raw.ndim != 2:
            raise InputError(f"{path}: a stack of {raw.shape[0]} frames; map one image, or "
                             "the sequence into a time history (--out P.h5)")
        return raw

    mesh = load_mesh(args.mesh, format=args.mesh_format)
    first = native(args.image[0])  # read once: checked, then mapped
    cf = read_camera_file(args.camera[0], image_size=first.shape[::-1])
    camera = cf.camera
    caster = RayCaster(mesh)  # one Embree scene: the map and the footprint check
    smap = SurfaceMap(mesh, camera, max_obliqueness=args.max_obliqueness, caster=caster)
    markers = read_markers(args.markers) if args.markers else None
    for k, path in enumerate(args.image):  # units, image, markers: before any work
        raw = first if k == 0 else native(path)  # one more image in memory at a time
        line = check_camera(args.camera[0], cf, path, raw.astype(np.float32), mesh.vertices,
                            args.mesh, markers=markers, surface_map=smap,
                            polarity=args.polarity, caster=caster)
        if line:
            print(line)
    require_seen(smap.seen_faces.sum(), camera, mesh.vertices, "the mesh",
                 f"map: {args.camera} sees none of the {len(mesh.faces)} faces of {args.mesh}")
    fields = {}
    per_node = Path(args.out).suffix.lower() == ".f"  # Plot3D function file: node values
    n_sat = n_faces = 0
    level = None
    for k, path in enumerate(args.image):
        raw = first if k == 0 else native(path)
        first = None
        level = level_of(raw.dtype, args.saturation)
        img, sat = mask_saturated(raw, level)  # unknown: in no value
        if not args.keep_border:  # the frame's dark border: no light, in no value
            img, border = mask_dark_border(img, inplace=True)
            line = border_report(border, path)
            if line:
                print(f"map: {line}")
        touched = faces_touched(smap.face_index, smap.mask, sat, len(mesh.faces))
        n_sat, n_faces = n_sat + int(sat.sum()), n_faces + int(touched.sum())
        name = Path(path).stem
        if per_node:
            from resection.surface.node_values import image_node_fields

            fields.update(image_node_fields(smap, img, name))
            continue
        res = smap.to_surface(img)
        fields[name] = np.where(touched, np.nan, res.values)
        fields[f"{name}_count"] = res.counts
        fields[f"{name}_seen"] = ~res.unseen & ~touched
    if per_node:
        write_surface(args.out, mesh, None, node_fields=fields)  # atomic, with its .nam
    else:  # atomic itself: an .xdmf's data file named after the final name, not a temporary
        write_surface(args.out, mesh, fields)
    print(f"map: {int(smap.seen_faces.sum())} of {len(mesh.faces)} faces seen by "
          f"{int(smap.mask.sum())} pixels; written to {args.out}")
    line = report(n_sat, level, n_faces)
    if line:
        print(f"map: warning: {line}", file=sys.stderr)
    return 0


def _run_history(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera
    from resection.io.history import xdmf_path
    from resection.io.meshes import load_mesh
    from resection.io.video import open_frames
    from resection.saturation import level_of, report
    from resection.sequence import read_track
    from resection.sequence.mapping import map_to_history

    if len(args.camera) > 1:
        raise InputError("--out .h5: one --camera (a time history is one camera's sequence)")
    if args.markers:
        raise InputError("--markers checks single images; a sequence's poses are checked by "
                         "'resection track'")
    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        raise InputError(f"--fps: must be a positive finite frame rate, got {args.fps}")
    mesh = load_mesh(args.mesh, format=args.mesh_format)
    camera = read_camera(args.camera[0])
    src = open_frames(args.image if len(args.image) > 1 else args.image[0])
    with src:
        if args.track:
            tr = read_track(args.track)
            ok = np.flatnonzero(tr.status == "ok")
            numbers = tr.frame[ok]
            if numbers.size and numbers.max() >= len(src):
                raise InputError(f"--track: {args.track} has frame {numbers.max()}, the "
                                 f"sequence {len(src)} frames")
            cameras = [camera.with_pose(rvec=tr.rvec[i], t=tr.tvec[i]) for i in ok]
        else:
            numbers, cameras = np.arange(len(src)), camera
        fps = args.fps if args.fps is not None else src.frame_rate
        if fps is not None and not (np.isfinite(fps) and fps > 0):
            raise InputError(f"{src.path}: its header's frame rate {fps} is not a positive "
                             "finite number; give --fps")
        times = numbers / fps if fps else numbers.astype(float)
        sources = _ImageIdentities(args.image, numbers)  # a resume maps the same images
        level = level_of(np.float32, args.saturation, bits=src.bits)
        if level is None and args.saturation is None and src.bits is None:
            from resection.io.images import image_info  # image files: their type's scale

            level = image_info(args.image[0])["saturation"]
        frames = _Saturated(src, level, keep_border=args.keep_border)
        n = map_to_history(args.out, mesh, cameras, frames, frame_numbers=numbers, times=times,
                           per=args.per, resume=args.resume,
                           max_obliqueness=args.max_obliqueness, sources=sources)
    print(f"map: {n} frames mapped per {args.per} ({len(numbers)} in the history); "
          f"written to {args.out} and {xdmf_path(args.out)}")
    line = report(frames.count, frames.level)
    if line:
        print(f"map: warning: {line} in the frames mapped now", file=sys.stderr)
    from resection.border import border_report

    line = border_report(frames.border, "frames (the widest)")
    if line:
        print(f"map: {line}")
    return 0


class _Saturated:
    """Frames of a source with their saturated pixels NaN (:mod:`resection.saturation`)
    and, unless ``keep_border``, their dark border NaN (:mod:`resection.border`), counted
    as they are read (``border``: the largest border met)."""

    def __init__(self, src, level, keep_border: bool = False):
        self.src, self.level, self.count = src, level, 0
        self.keep_border, self.border = keep_border, (0, 0, 0, 0)

    def __len__(self):
        return len(self.src)

    def __getitem__(self, i):
        from resection.border import mask_dark_border
        from resection.saturation import mask_saturated

        img, sat = mask_saturated(self.src[i], self.level)
        self.count += int(sat.sum())
        if not self.keep_border:
            img, b = mask_dark_border(img, inplace=True)
            self.border = tuple(max(x, y) for x, y in zip(self.border, b, strict=True))
        return img


class _ImageIdentities:
    """What each frame of a time history is read from: ``name|digest`` of its image file
    (:func:`resection.sequence.frames.content_digest`: size and a sample of the content),
    or ``name#k|digest`` for frame k of a file holding many. Lazy: a frame's digest is
    taken when the resume check or the writer asks for it (12 KiB read), not for every
    frame up front."""

    def __init__(self, paths: list[str], numbers):
        self.paths, self.numbers = [Path(p) for p in paths], np.asarray(numbers, int)
        self._video = None

    def __len__(self) -> int:
        return len(self.numbers)

    @staticmethod
    def _digest(q: Path) -> str:
        from resection.sequence.frames import content_digest

        return content_digest(q) if q.is_file() else ""

    def __getitem__(self, i) -> str:
        k = int(self.numbers[i])
        if len(self.paths) == 1:
            if self._video is None:
                self._video = self._digest(self.paths[0])
            return f"{self.paths[0].name}#{k}|{self._video}"
        return f"{self.paths[k].name}|{self._digest(self.paths[k])}"


def _run_merge(args: argparse.Namespace, names: list) -> int:
    from resection.border import border_report, mask_dark_border
    from resection.io.cameras import read_camera_file
    from resection.io.images import read_native
    from resection.io.markers import read_markers
    from resection.io.meshes import load_mesh, write_surface
    from resection.pose.camera_fit import check_camera
    from resection.saturation import level_of, mask_saturated, report
    from resection.surface.merge import merge_views
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster

    if len(args.image) != len(args.camera):
        raise InputError(f"--image: {len(args.image)} images for {len(args.camera)} cameras "
                         "(give one image per camera, in camera order)")
    mesh = load_mesh(args.mesh, format=args.mesh_format)
    images, n_sat, level = [], 0, None
    for p in args.image:  # saturated pixels unknown (NaN): in no camera's values
        raw = read_native(p)
        if raw.ndim != 2:
            raise InputError(f"{p}: a stack of {raw.shape[0]} frames; give one image per "
                             "camera")
        level = level_of(raw.dtype, args.saturation)
        img, sat = mask_saturated(raw, level)
        if not args.keep_border:  # the frame's dark border: no light, in no value
            img, border = mask_dark_border(img, inplace=True)
            line = border_report(border, p)
            if line:
                print(f"map: {line}")
        images.append(img)
        n_sat += int(sat.sum())
    files = [read_camera_file(p, image_size=img.shape[::-1])
             for p, img in zip(args.camera, images, strict=True)]
    caster = RayCaster(mesh)  # one Embree scene for every camera and the checks
    maps = [SurfaceMap(mesh, cf.camera, max_obliqueness=args.max_obliqueness, caster=caster)
            for cf in files]
    markers = read_markers(args.markers) if args.markers else None
    for cpath, cf, ipath, img, smap in zip(args.camera, files, args.image, images, maps,
                                           strict=True):
        line = check_camera(cpath, cf, ipath, img, mesh.vertices, args.mesh, markers=markers,
                            surface_map=smap, polarity=args.polarity, caster=caster)
        if line:
            print(line)
    mv = merge_views(maps, images, feather_px=args.feather, match_gain=not args.no_gain_match)
    if Path(args.out).suffix.lower() == ".f":  # Plot3D function file: node values
        from resection.surface.node_values import merged_node_fields

        write_surface(args.out, mesh, None,
                      node_fields=merged_node_fields(maps, images, mv, names))
    else:
        fields = {"merged": mv.values, "merged_weight": mv.weight,
                  "merged_cameras": mv.n_cameras, "merged_seen": mv.seen}
        for c, name in enumerate(names):
            fields[name] = mv.camera_values[c]
            fields[f"{name}_weight"] = mv.camera_weights[c]
        write_surface(args.out, mesh, fields)  # atomic itself (see map)
    print(mv.report())
    print(f"map: {int(mv.seen.sum())} of {len(mesh.faces)} faces seen by {len(maps)} "
          f"cameras ({int((mv.n_cameras > 1).sum())} by several); written to {args.out}")
    line = report(n_sat, level)
    if line:
        print(f"map: warning: {line}", file=sys.stderr)
    return 0


def run_backproject(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera
    from resection.io.images import read_image, write_image
    from resection.io.meshes import load_mesh
    from resection.surface.surface_map import SurfaceMap

    mesh = load_mesh(args.mesh, format=args.mesh_format)
    camera = read_camera(args.camera)
    _, values = _field(args.values, args.field, len(mesh.faces))
    background = None
    if args.background is not None:
        try:
            background = float(args.background)
        except ValueError:
            background = read_image(args.background)
    from resection.io.png_range import parse_png_range, png_counts

    png_range = parse_png_range(args.png_range)
    png = Path(args.out).suffix.lower() == ".png"
    if png_range is not None and not png:
        raise InputError("--png-range is for a .png output")
    img = SurfaceMap(mesh, camera).to_image(values, background=background,
                                            interpolation=args.interpolation)
    if png:
        counts, how = png_counts(img, png_range, args.out)
        atomic_write(args.out, write_image, counts, dtype=np.uint16)
        print(f"backproject: {how}")
    else:
        atomic_write(args.out, write_image, img.astype(np.float32))
    print(f"backproject: image written to {args.out}")
    return 0


def run_align(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera
    from resection.io.images import read_image, write_image
    from resection.io.meshes import load_mesh
    from resection.surface.align import ViewWarp

    mesh = load_mesh(args.mesh, format=args.mesh_format)
    warp = ViewWarp(mesh, read_camera(args.source_camera), read_camera(args.target_camera))
    out = warp(read_image(args.image), order=args.order)
    atomic_write(args.out, write_image, out.astype(np.float32))
    print(f"align: {int(warp.valid.sum())} pixels aligned; written to {args.out}")
    return 0


def run_view(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera
    from resection.io.meshes import load_mesh
    from resection.surface.plots import frame_camera, plot_surface, virtual_camera

    mesh = load_mesh(args.mesh, format=args.mesh_format)
    name, values = _field(args.values, args.field, len(mesh.faces))
    if args.camera:
        camera = read_camera(args.camera)
    else:
        try:
            w, h = (int(x) for x in args.size.lower().split("x"))
        except ValueError:
            raise InputError(f"--size: expected WxH, got {args.size!r}") from None
        camera = virtual_camera(mesh, args.azimuth, args.elevation, width=w, height=h)
    box = None if args.box is None else np.reshape(args.box, (2, 3))
    if box is not None:
        lo, hi = np.asarray(mesh.bounds)
        if np.any(box[0] > hi) or np.any(box[1] < lo):
            raise InputError(f"--box: {args.box} holds no part of {args.mesh} (its bounds "
                             f"{lo.tolist()} to {hi.tolist()})")
    camera = frame_camera(camera, target=args.target, zoom=args.zoom, box=box)
    with atomic_path(args.out) as tmp:
        plot_surface(mesh, values, camera, method=args.method, cmap=args.cmap, vmin=args.vmin,
                     vmax=args.vmax, label=name if args.label is None else args.label,
                     outline=not args.no_outline, crease_deg=args.crease, path=tmp)
    print(f"view: {args.out}")
    return 0

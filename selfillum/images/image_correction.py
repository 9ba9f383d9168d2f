"""Self-illumination correction of a camera image of a painted model.

The image is mapped onto the faces (:class:`~resection.surface.SurfaceMap`: per-face mean of
the pixels that see each face), the per-face emission is recovered with
:func:`selfillum.correct` (faces the camera does not see are handled by its
partial-observation model), and the correction is brought back to *every pixel*,
interpolated over the surface (face values -> vertex values -> barycentric interpolation at
each pixel's hit point), so that face edges do not show:

* ``mode="subtract"`` (default): the self-illumination ``B - E`` of the faces is
  interpolated and subtracted from each pixel. Exact for the physics (what a pixel records
  is its own emission plus reflected light, and the reflected light is a smooth field), and
  it keeps features finer than a face (markers, shocks) untouched.
* ``mode="ratio"``: each pixel is multiplied by the interpolated ``E / B``. Insensitive to
  a smooth gain or vignetting across the image, but it scales sub-face contrast too.

Assumptions: the image is proportional to the radiance of the model (dark level already
subtracted), faces are Lambertian and painted on the side their normals point to.
"""

from __future__ import annotations

import csv
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.io.images import write_image
from resection.surface.surface_map import DEFAULT_MAX_OBLIQUENESS
from selfillum.images.output_dtype import output_dtype
from selfillum.mesh import check_mesh, face_areas
from selfillum.solve.fields import check_reflectance
from selfillum.solve.unseen import describe_unseen, read_unpainted, read_unseen, unseen_warning
from selfillum.transport.coupling import coupled_view_factors

if TYPE_CHECKING:
    import scipy.sparse as sp
    import trimesh

    from selfillum.solve.radiosity import SolveInfo

__all__ = ["ImageCorrection", "correct_image", "read_reflectance", "correct_image_file",
           "UnseenFacesWarning", "DEFAULT_MAX_OBLIQUENESS"]


@dataclass(frozen=True)
class ImageCorrection:
    """Result of :func:`correct_image`.

    Attributes
    ----------
    image : (H, W) or (T, H, W) ndarray
        Corrected image(s), same shape and dtype as the input; pixels off the model
        unchanged.
    correction : (H, W) or (T, H, W) float64 ndarray
        What was applied per pixel: the self-illumination subtracted (``"subtract"``) or
        the factor applied (``"ratio"``); 0 or 1 off the model.
    radiosity : (N,) or (T, N) ndarray
        Per-face mean of the image (NaN on faces not seen).
    emission : (N,) or (T, N) ndarray
        Per-face emission recovered (estimated on faces not seen).
    seen : (N,) or (T, N) bool ndarray
        Faces seen by at least one finite pixel.
    mode : str
        ``"subtract"`` or ``"ratio"``.
    info : SolveInfo or tuple of SolveInfo
        How the inverse was solved (one per frame for a stack).
    unseen_share : (N,) or (T, N) float64 ndarray
        Share of each seen face's correction that comes from faces the camera does not
        see (NaN on those), see :attr:`selfillum.SolveInfo.unseen_share`.
    assumption : str
        What unseen and unpainted faces were taken to emit, in words
        (:func:`selfillum.solve.unseen.describe_unseen`).
    warnings : tuple of str
        Warnings on the result (:func:`selfillum.solve.unseen.unseen_warning`, one per frame
        at most).
    grazing : (N,) bool ndarray
        Faces the camera sees beyond ``max_obliqueness`` (counted as unseen).
    unpainted : (N,) bool ndarray
        Faces taken to emit nothing (all False when none was given).
    """

    image: np.ndarray
    correction: np.ndarray
    radiosity: np.ndarray
    emission: np.ndarray
    seen: np.ndarray
    mode: str
    info: SolveInfo | tuple
    unseen_share: np.ndarray | None = None
    assumption: str = ""
    warnings: tuple = ()
    grazing: np.ndarray | None = None
    unpainted: np.ndarray | None = None
    saturated: int = 0
    saturated_faces: int = 0
    saturation: float | None = None


def correct_image(
    image,
    mesh: trimesh.Trimesh,
    camera: Camera,
    reflectance,
    *,
    F=None,
    rays_per_face: int = 256,
    seed: int = 0,
    mode: str = "subtract",
    surface_map=None,
    unseen="continue",
    unpainted=None,
    max_obliqueness: float = DEFAULT_MAX_OBLIQUENESS,
    progress: bool = False,
    saturation: float | None = None,
    caster=None,
) -> ImageCorrection:
    """Remove self-illumination from a camera image of a painted model.

    Parameters
    ----------
    image : (H, W) or (T, H, W) array_like
        Camera image, or a stack of ``T`` frames of the same camera (any real dtype),
        proportional to radiance, ``img[v, u]``. NaN pixels are ignored and left NaN.
    mesh : trimesh.Trimesh
        Model surface; faces are the radiosity elements, painted on their normal side.
    camera : resection.Camera
        Calibrated camera with its pose; its size must match the image.
    reflectance : float or (N,) array_like
        Paint reflectance per face, in ``[0, 1)``.
    F : (N, N) sparse matrix, optional
        Form factors of ``mesh``. When not given, only the rows the correction needs are
        computed (:func:`selfillum.transport.coupling.coupled_view_factors`: the seen faces and the
        hidden faces coupled to them), with ``rays_per_face`` and ``seed``.
    rays_per_face, seed : int
        View-factor parameters when ``F`` is computed here.
    mode : {"subtract", "ratio"}
        How the per-face correction is applied to pixels (see the module notes).
    surface_map : resection.surface.surface_map.SurfaceMap, optional
        A map of this mesh and camera already built (reused across frames).
    unseen : {"continue", "none"} or (N,) array_like
        What faces the camera does not see emit (see :func:`selfillum.correct`).
    unpainted : (N,) array_like of bool, optional
        Faces that emit nothing, seen or not (see :func:`selfillum.correct`).
    max_obliqueness : float
        Faces whose centroid the camera sees at more than this angle (degrees, between
        the line of sight and the normal) count as unseen: their few, smeared pixels are
        not a measurement (default 70, as :class:`~resection.surface.SurfaceMap`). Their
        pixels are left uncorrected.
    progress : bool
        Progress bar on the ray casting.
    saturation : float, optional
        Pixels at or above this level are saturated (default: the full scale of an integer
        image, 255 or 65535; none for a float image): their true value is unknown, so they
        take no part in the faces' values, the faces they fall on count as unseen, and
        they come out as they came in (NaN in a float image), uncorrected
        (:mod:`resection.saturation`). Counted in ``saturated``, ``saturated_faces``.
    caster : resection.surface.visibility.RayCaster, optional
        The Embree scene of ``mesh`` (e.g. the one ``surface_map`` was built with): the
        surface map, when built here, and the view factors trace in it, so the scene is
        built once (or not at all). Built here when not given.

    Returns
    -------
    ImageCorrection
        For a stack, every array gains a leading frame axis and ``info`` is a tuple.

    Raises
    ------
    InputError
        Image size not that of the camera, non-numeric image, reflectance outside
        ``[0, 1)``, invalid mesh, a camera that sees the model mostly from behind (the
        normals do not point to the painted side), a camera that sees no face.
    """
    from resection.surface.surface_map import SurfaceMap, oblique_faces

    check_mesh(mesh)
    if mode not in ("subtract", "ratio"):
        raise InputError(f"mode must be 'subtract' or 'ratio', got {mode!r}")
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise InputError(f"image: expected a 2-D image or a (T, H, W) stack, got shape {img.shape}")
    if img.dtype.kind not in "uif":
        raise InputError(f"image: expected real pixel values, got dtype {img.dtype}")
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    colour = img.ndim == 3 and img.shape[2] in (3, 4)
    if colour and img.shape[:2] == (camera.height, camera.width):
        raise InputError(
            f"image: shape {img.shape} is a colour image; give one channel (H, W) or a "
            "(T, H, W) stack of frames"
        )
    if img.shape[-2:] != (camera.height, camera.width):
        raise InputError(
            f"image: shape {img.shape} does not match the camera's (height, width) = "
            f"({camera.height}, {camera.width})"
        )
    single = img.ndim == 2
    stack = img[None] if single else img
    n = len(mesh.faces)
    rho = check_reflectance(reflectance, n)
    lim = float(max_obliqueness)
    if not 0.0 < lim <= 90.0:
        raise InputError(f"max_obliqueness: must be in (0, 90] degrees, got {max_obliqueness}")
    source = ""
    if unpainted is not None:
        unpainted, source = read_unpainted(unpainted, mesh)
    if isinstance(unseen, str | os.PathLike) and unseen not in ("continue", "none"):
        unseen = read_unseen(unseen, n)
    if caster is not None and caster.n_faces != n:
        raise InputError(f"caster: built for {caster.n_faces} faces, the mesh has {n}")
    if surface_map is None:
        from resection.surface.visibility import RayCaster

        caster = RayCaster(mesh) if caster is None else caster
        smap = SurfaceMap(mesh, camera, max_obliqueness=lim, caster=caster)
    else:
        smap = surface_map
    if smap.shape != stack.shape[1:] or smap.n_faces != n:
        raise InputError("surface_map: made for another camera size or mesh")
    _check_painted_side(smap, mesh, camera, None if caster is None else caster.normals)

    from resection.saturation import faces_touched, level_of

    level = level_of(img.dtype, saturation)
    sat = np.zeros(stack.shape, bool) if level is None else stack >= level
    x = stack.astype(np.float64)
    x[sat] = np.nan  # unknown: in no face's value
    sample = smap.to_surface(x)
    B = sample.values  # (T, N)
    same_view = smap.max_obliqueness == lim and np.array_equal(
        np.asarray(smap.camera.center), np.asarray(camera.center))
    grazing = smap.oblique if same_view else oblique_faces(mesh, camera.center, lim)
    sat_faces = faces_touched(smap.face_index, smap.mask, sat, n)
    seen = ~sample.unseen & ~grazing[None] & ~sat_faces
    if not seen.any(axis=1).all():
        t = int(np.flatnonzero(~seen.any(axis=1))[0])
        if (~sample.unseen[t] & ~grazing & ~sat_faces[t]).sum() == 0 and sat_faces[t].any():
            raise InputError(f"image: every face the camera sees has saturated pixels (at "
                             f"or above {level:g}) in frame {t}: their values are unknown, "
                             "nothing to correct")
        from resection.camera.units import nothing_seen_causes

        why = " (check the pose)" if smap.seen_faces.any() else \
            ": likely causes: " + nothing_seen_causes(camera, mesh.vertices, "the mesh")
        raise InputError(f"image: the camera sees no face of the model in frame {t}{why}")
    if F is None:
        F = _view_factors_and_fit(mesh, seen, B, mode, smap, unseen,
                                  rays_per_face=rays_per_face, seed=seed, progress=progress,
                                  caster=caster)
    else:
        import scipy.sparse as sp

        if not sp.issparse(F) or F.shape != (n, n):
            raise InputError(f"F: expected a sparse ({n}, {n}) matrix")
    from selfillum.solve.radiosity import correct  # imported while the rays ran

    E = np.empty_like(B)
    share = np.full_like(B, np.nan)
    infos = []
    for t in range(len(B)):  # frame by frame (the seen faces may differ), reusing F
        E[t], info = correct(
            F, np.where(seen[t], B[t], np.nan), rho, seen[t], mesh=mesh, unseen=unseen,
            unpainted=unpainted, return_info=True,
        )
        if info.unseen_share is not None:
            share[t] = info.unseen_share
        else:
            share[t][seen[t]] = 0.0
        infos.append(info)
    areas = face_areas(mesh) if caster is None else caster.areas
    with np.errstate(divide="ignore", invalid="ignore"):
        si = np.where(seen & (B != 0), (B - E) / B, np.nan)
    warns = []
    painted = np.ones(n, bool) if unpainted is None else ~np.asarray(unpainted, bool)
    for t in range(len(B)):  # unpainted faces have no emission to recover: left out
        w = unseen_warning(share[t], si[t], seen[t] & painted, areas)
        if w is not None:
            warns.append(w if single else f"frame {t}: {w}")
    for w in warns:
        warnings.warn(w, UnseenFacesWarning, stacklevel=2)
    said = describe_unseen(unseen, unpainted, source)

    on = smap.mask[None] & np.isfinite(x)
    out = x.copy()
    if mode == "subtract":
        corr = smap.to_image(np.where(seen, B - E, np.nan), background=0.0)
        corr = np.where(on & np.isfinite(corr), corr, 0.0)
        out[on] = x[on] - corr[on]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(seen & (B != 0), E / B, np.nan)
        corr = smap.to_image(ratio, background=1.0)
        corr = np.where(on & np.isfinite(corr), corr, 1.0)
        out[on] = x[on] * corr[on]
    out = _as_dtype(np.where(sat, 0.0, out), img.dtype)
    # saturated pixels come out unknown: NaN in a float image, else at their full scale
    out[sat] = np.nan if out.dtype.kind == "f" else stack[sat]
    counts = {"saturated": int(sat.sum()), "saturated_faces": int(sat_faces.any(axis=0).sum()),
              "saturation": level}
    if single:
        return ImageCorrection(out[0], corr[0], B[0], E[0], seen[0], mode, infos[0],
                               share[0], said, tuple(warns), grazing, ~painted, **counts)
    return ImageCorrection(out, corr, B, E, seen, mode, tuple(infos), share, said,
                           tuple(warns), grazing, ~painted, **counts)


def _view_factors_and_fit(mesh, seen, B, mode, smap, unseen, **kw) -> sp.csr_matrix:
    """The coupled rows of ``F``, and what comes after them made ready meanwhile.

    The rays run on numba's threads without Python's lock, and the main thread just waits
    for them. A thread uses that time for work the rays do not need: it imports the solve
    (SciPy's sparse solvers, which the steps before the rays do not import) and loads its
    compiled kernels (:func:`selfillum.solve.radiosity.load_kernels`), then, for one frame,
    builds the surface map's vertex fit of the faces the correction will have a value on
    (:meth:`SurfaceMap.prepare <resection.surface.surface_map.SurfaceMap.prepare>`: it
    needs the seen faces only). On 2 cores that thread takes CPU from the rays; with more
    cores it takes the work off the command's serial path."""
    kind = unseen if isinstance(unseen, str) else "none"  # the kernels of given values
    with ThreadPoolExecutor(1) as pool:
        ready = pool.submit(_load_solve, kind)
        fit = None
        if len(seen) == 1:
            valued = seen[0] if mode == "subtract" else seen[0] & (B[0] != 0)  # where E/B is
            fit = pool.submit(smap.prepare, valued)
        F, _ = coupled_view_factors(mesh, seen.any(axis=0), checked=True, **kw)
    ready.result()  # their errors, if any, here
    if fit is not None:
        fit.result()
    return F


def _load_solve(unseen: str) -> None:
    """Import the solve and load its compiled kernels (see :func:`_view_factors_and_fit`)."""
    from selfillum.solve.radiosity import load_kernels

    load_kernels(unseen)


class UnseenFacesWarning(UserWarning):
    """The correction rests on faces no camera sees over a meaningful area."""


def _check_painted_side(smap, mesh, camera, normals=None) -> None:
    """Refuse a model whose seen pixels mostly land on the back of faces (``normals``:
    the faces' unit normals when at hand)."""
    f = smap.face_index[smap.mask]
    if f.size == 0:
        return
    # a pixel sees the back of its face when the camera is behind the face's plane: one
    # sign per face (centre minus any point of the plane, along the normal), gathered
    tri0 = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)[:, 0]]
    normals = np.asarray(mesh.face_normals if normals is None else normals, dtype=np.float64)
    behind = np.einsum("ij,ij->i", np.asarray(camera.center, dtype=np.float64) - tri0,
                       normals) < 0
    back = behind[f]
    if back.mean() > 0.5:
        from resection.camera.units import camera_scale_hint

        hint = camera_scale_hint(camera, mesh.vertices, "the mesh")  # camera inside it?
        raise InputError(
            f"mesh: {100 * back.mean():.0f}% of the pixels on the model see the back of "
            "their face: " + (hint or "face normals must point to the painted side (fix "
                              "the winding)")
        )


def _as_dtype(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Back to the input's dtype: integers are rounded and clipped to their range."""
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        return np.clip(np.rint(values), info.min, info.max).astype(dtype)
    return values.astype(dtype)


def read_reflectance(spec, n_faces: int) -> np.ndarray:
    """Reflectance from a number, or a per-face file.

    Parameters
    ----------
    spec : float, str or path-like
        A number (``0.6`` or ``"0.6"``), a ``.npy`` file with ``n_faces`` values, or a
        ``.csv``/``.txt`` file with one value per face in face order (one column, or a
        column named ``reflectance`` under a header).
    n_faces : int
        Faces of the mesh.

    Returns
    -------
    (n_faces,) float64 ndarray in ``[0, 1)``.
    """
    if isinstance(spec, int | float | np.floating | np.integer):
        return check_reflectance(float(spec), n_faces)
    text = os.fspath(spec)
    try:
        number = float(text)
    except ValueError:
        number = None
    if number is not None:
        return check_reflectance(number, n_faces)
    path = Path(text)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such reflectance file (nor a number)")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        from resection.io.images import load_npy

        values = load_npy(path)  # one-line errors, never advising allow_pickle
    elif suffix in (".csv", ".txt"):
        values = _read_column(path)
    else:
        raise InputError(f"{path}: unknown reflectance file type {suffix!r} (use .npy or .csv)")
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if values.size != n_faces:
        raise InputError(f"{path}: {values.size} reflectance values for {n_faces} faces")
    try:
        return check_reflectance(values, n_faces)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def _read_column(path: Path) -> np.ndarray:
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    if not rows:
        raise InputError(f"{path}: empty reflectance file")
    col = 0
    try:
        float(rows[0][0])
    except ValueError:
        header = [h.strip().lower() for h in rows[0]]
        rows = rows[1:]
        if "reflectance" in header:
            col = header.index("reflectance")
        elif len(header) != 1:
            raise InputError(
                f"{path}: no 'reflectance' column in header {rows and header}"
            ) from None
    try:
        return np.array([float(r[col]) for r in rows])
    except (ValueError, IndexError):
        raise InputError(f"{path}: non-numeric or missing reflectance values") from None


def correct_image_file(
    mesh_path,
    camera_path,
    image_path,
    reflectance,
    out_path,
    *,
    rays_per_face: int = 256,
    seed: int = 0,
    mode: str = "subtract",
    surface_out=None,
    unseen="continue",
    unpainted=None,
    max_obliqueness: float = DEFAULT_MAX_OBLIQUENESS,
    progress: bool = False,
    mesh_format: str | None = None,
    dtype: str | None = None,
    markers=None,
    polarity: str = "dark",
    saturation: float | None = None,
) -> ImageCorrection:
    """File-level :func:`correct_image`: read the mesh (any format of
    :func:`resection.io.meshes.read_surface`), the camera JSON and the image (TIFF or NPY),
    correct, write the corrected image (TIFF, PNG or NPY, from ``out_path``'s suffix) as
    float32 for an 8-bit image and with the input's type otherwise, or as ``dtype``
    (``"float32"``, ``"uint16"``, ``"uint8"``) when asked (:mod:`selfillum.images.output_dtype`),
    the summary with the assumption for unseen faces
    (:func:`selfillum.summary.write_summary`) to ``out_path`` + ``".json"``, and
    optionally the per-face fields (``radiosity``, ``emission``, ``seen``,
    ``unseen_share``, ``grazing``, ``unpainted``) to ``surface_out`` (.ply, .vtk or .csv).

    The camera is checked against the image first (:func:`resection.pose.camera_fit.check_camera`):
    a warning when it was solved on another image, a refusal on a units mismatch with the
    mesh and, with ``markers`` (a marker file), when its targets do not land on spots of
    the image (``polarity``).

    ``unseen`` is ``"continue"``, ``"none"`` or a per-face file of emission values;
    ``unpainted`` a per-face 0/1 file or Plot3D block numbers
    (:func:`selfillum.solve.unseen.read_unpainted`); ``saturation`` as in
    :func:`correct_image`."""
    from resection.io.cameras import read_camera_file
    from resection.io.markers import read_markers
    from resection.io.marks import claim_side_file, mark
    from resection.io.meshes import read_surface, write_surface
    from resection.io.outputs import atomic_path, refuse_overwriting_inputs
    from resection.pose.camera_fit import check_camera
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster
    from selfillum.summary import summarize, write_summary

    image_path, out_path = Path(image_path), Path(out_path)
    for p in (image_path, out_path):  # the one image reader's formats (resection.io.images)
        if p.suffix.lower() not in (".tif", ".tiff", ".npy", ".png"):
            raise InputError(f"{p}: images must be TIFF (.tif, .tiff), PNG or NPY (.npy)")
    if not image_path.exists():
        raise FileNotFoundError(f"{image_path}: no such image file")
    if not out_path.parent.exists():
        raise FileNotFoundError(f"{out_path.parent}: output directory does not exist")
    summary_path = claim_side_file(out_path.with_name(out_path.name + ".json"), out_path,
                                   "summary")  # never a .json of the user's
    refuse_overwriting_inputs(
        {"--out": out_path, "--surface": surface_out, "summary": summary_path},
        {"--image": [image_path], "--mesh": [mesh_path], "--camera": [camera_path],
         "--reflectance": [reflectance] if isinstance(reflectance, str | os.PathLike) else [],
         "--unseen": [unseen] if isinstance(unseen, str | os.PathLike) else [],
         "--unpainted": [unpainted] if isinstance(unpainted, str | os.PathLike) else [],
         "--markers": [markers] if markers else []})
    mesh = read_surface(mesh_path, format=mesh_format)
    image = _read_native(image_path)
    target = output_dtype(image.dtype, out_path, dtype)  # refused before the work
    cf = read_camera_file(camera_path, image_size=image.shape[::-1][:2])
    camera = cf.camera
    caster = RayCaster(mesh)  # one Embree scene: the surface map's and the view factors'
    smap = SurfaceMap(mesh, camera, max_obliqueness=max_obliqueness, caster=caster)
    for frame in (image if image.ndim == 3 else image[None])[:1]:  # the first frame
        line = check_camera(camera_path, cf, image_path, frame, mesh.vertices, mesh_path,
                            markers=read_markers(markers) if markers else None,
                            surface_map=smap, polarity=polarity)
        if line and progress:
            print(line)
    from resection.saturation import level_of

    level = level_of(image.dtype, saturation)  # the file's full scale, or the level stated
    saturated = None if level is None else image >= level
    if image.dtype.kind in "uib":  # correct in float, then write the type chosen
        image = image.astype(np.float32)
    n = len(mesh.faces)
    rho = read_reflectance(reflectance, n)
    unpainted_mask, source = (None, "") if unpainted is None else \
        read_unpainted(unpainted, mesh)
    unseen_value = read_unseen(unseen, n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnseenFacesWarning)  # returned in the result
        result = correct_image(
            image,
            mesh,
            camera,
            rho,
            rays_per_face=rays_per_face,
            seed=seed,
            mode=mode,
            unseen=unseen_value,
            unpainted=unpainted_mask,
            max_obliqueness=max_obliqueness,
            progress=progress,
            surface_map=smap,
            saturation=level,
            caster=caster,
        )
    said = describe_unseen(unseen_value, unpainted_mask, source)
    corrected = _as_dtype(result.image if saturated is None
                          else np.where(saturated, 0.0, result.image), target)
    if saturated is not None:  # unknown: NaN in a float file, full scale in an integer one
        corrected[saturated] = np.nan if corrected.dtype.kind == "f" else \
            np.iinfo(corrected.dtype).max
    result = replace(result, assumption=said, image=corrected)
    said_file = f"{said}: {unseen}" if isinstance(unseen_value, np.ndarray) else said
    # every file through a temporary name, renamed into place only when all are written
    with atomic_path(out_path) as tmp, atomic_path(surface_out) as tmp_surface, \
            atomic_path(summary_path) as tmp_summary:
        if out_path.suffix.lower() == ".npy":
            np.save(tmp, result.image, allow_pickle=False)
        elif out_path.suffix.lower() == ".png":
            if result.image.ndim != 2 or result.image.dtype not in (np.uint8, np.uint16):
                raise InputError(f"{out_path}: PNG holds one 8/16-bit image; the corrected "
                                 f"image is {result.image.dtype} {result.image.shape} (write "
                                 ".tif or .npy)")
            write_image(tmp, result.image)
        else:
            import tifffile

            tifffile.imwrite(tmp, result.image)
        write_summary(tmp_summary, summarize(result), **mark(out_path, "selfillum correct"),
                      assumption_detail=said_file,
                      max_obliqueness_deg=float(max_obliqueness),
                      saturated_pixels=result.saturated, saturated_faces=result.saturated_faces,
                      saturation=result.saturation,
                      rays_per_face=rays_per_face, image=str(image_path),
                      mesh=str(mesh_path))
        if surface_out is not None:
            fields = {  # (N,) or, for a stack, (N, T): one column per frame
                "radiosity": result.radiosity.T,
                "emission": result.emission.T,
                "seen": result.seen.astype(np.uint8).T,
                "unseen_share": result.unseen_share.T,
                "grazing": result.grazing.astype(np.uint8),
                "unpainted": (np.zeros(n, np.uint8) if unpainted_mask is None
                              else unpainted_mask.astype(np.uint8)),
            }
            write_surface(tmp_surface, mesh, fields)
    return result


def _read_native(path: Path) -> np.ndarray:
    """The image with its own dtype (not converted to float): PNG, TIFF (a multi-page TIFF
    is a (T, H, W) stack) or NPY, through the package's one image reader."""
    from resection.io.images import read_native

    return read_native(path)

"""Linking by clicking: what the page of ``resection link --serve`` asks, answered.

A :class:`LinkSession` holds one frame, its candidates, the marker file and the camera
(intrinsics, and maybe an approximate pose), all read from the files named on the command
line (:func:`open_session`). The page sends only links, ``[(marker id, candidate number),
...]``; the session answers with plain dictionaries (JSON-ready):

* :meth:`LinkSession.plan`: the targets as seen from the camera's side (through the camera
  when it has a pose, else along the targets' mean normal or their flattest direction), so
  that a person can tell which target is which;
* :meth:`LinkSession.solve`: from four links (three with an approximate pose) the pose, solved
  by :func:`resection.pose.solve.solve_pose` and judged by the acceptance rule
  (:mod:`resection.pose.acceptance`); each link's residual, the links the rule rejects, every
  other target predicted in view, and the candidates within the rule's outlier gate of a
  prediction, offered as links;
* :meth:`LinkSession.save`: the linking CSV ``id,candidate`` (what ``pose --links`` and
  ``track --link`` read), the solved camera (JSON) and, if asked, the candidates with their
  ids (what ``pose --candidates`` reads), each written to a temporary name and renamed.

Candidate numbers are the row indices (from 0) of the candidate list, as in
:mod:`resection.markers.link`: detected with the default options and the given diameter, they are
the numbers ``pose --image --diameter D --links`` and ``track --diameter D --link`` find.
Conventions: docs/design.md (pixel centres at integer ``(u, v)``, ``x_cam = R X + t``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from resection.camera.model import Camera
from resection.errors import DegenerateError, InputError, SolveError
from resection.markers.detect import Candidates
from resection.pose.acceptance import (
    DEFAULT_MARKER_ACCURACY,
    DEFAULT_MAX_RMS,
    judge,
    outlier_gate,
)

__all__ = ["LinkSession", "open_session", "plan_axes"]

#: Fewest links for a pose without (with) an approximate pose.
MIN_LINKS, MIN_LINKS_APPROX = 4, 3


def plan_axes(xyz: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """Right and down axes ``(2, 3)`` of a plan of points seen from outside a surface.

    The viewer looks along ``-n``: ``n`` is the mean of the given unit normals when they
    agree (mean length over 0.5), else the points' flattest direction (smallest principal
    axis) with its largest component made positive. ``right`` is the principal direction of
    the points across ``n``; ``down = (-n) x right``, so that ``right x down = -n`` is the
    viewing direction (a camera's ``x``, ``y``, ``z``): the plan is never mirrored when
    the normals are known.
    """
    X = np.asarray(xyz, float).reshape(-1, 3)
    c = X - X.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False) if len(X) >= 3 else (None, None,
                                                                           np.eye(3))
    n = None
    if normals is not None:
        N = np.asarray(normals, float).reshape(-1, 3)
        N = N[np.isfinite(N).all(axis=1)]
        if len(N):
            m = N.mean(axis=0)
            if np.linalg.norm(m) > 0.5:
                n = m / np.linalg.norm(m)
    if n is None:
        n = vt[-1] if len(vt) == 3 else np.array([0.0, 0.0, 1.0])
        n = n * (1.0 if n[np.argmax(np.abs(n))] > 0 else -1.0)
    right = vt[0] - np.dot(vt[0], n) * n
    if np.linalg.norm(right) < 1e-9:  # points along n: any axis across it
        right = np.eye(3)[np.argmin(np.abs(n))] - n * n[np.argmin(np.abs(n))]
    right /= np.linalg.norm(right)
    down = np.cross(-n, right)
    return np.vstack([right, down])


@dataclass
class LinkSession:
    """One frame to link by hand, and the files its links are saved to.

    Attributes
    ----------
    image : (H, W) float array
        The frame (NaN where saturated).
    candidates : Candidates
        The numbered candidates.
    markers : MarkerSet
        The targets (taps excluded).
    camera : Camera
        Intrinsics, and an approximate pose when ``has_pose``.
    has_pose : bool
        False for an intrinsics-only camera file (e.g. uPSP's internal calibration).
    diameter : float
        Marker diameter in pixels the candidates were detected with (NaN when read).
    mesh : trimesh.Trimesh, optional
        Model surface: targets it hides are not predicted.
    save_links, save_camera, save_linked : path or None
        Outputs of :meth:`save` (links CSV, camera JSON, candidates with ids).
    inputs : dict of str to path
        The input files (never overwritten).
    initial_links : list of (str, int)
        Links read from a linking CSV to start from.
    marker_accuracy, max_rms : float
        The acceptance rule's options, px.
    """

    image: np.ndarray
    candidates: Candidates
    markers: object
    camera: Camera
    has_pose: bool = False
    diameter: float = float("nan")
    mesh: object = None
    save_links: str | None = None
    save_camera: str | None = None
    save_linked: str | None = None
    inputs: dict = field(default_factory=dict)
    initial_links: list = field(default_factory=list)
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY
    max_rms: float | None = DEFAULT_MAX_RMS

    # ------------------------------------------------------------------ static data
    def info(self) -> dict:
        """Frame size, counts, options and output names (basenames only) for the page."""
        return {
            "width": int(self.camera.width), "height": int(self.camera.height),
            "n_candidates": len(self.candidates), "n_targets": len(self.markers.ids),
            "has_pose": bool(self.has_pose),
            "diameter": None if not math.isfinite(self.diameter) else float(self.diameter),
            "min_links": MIN_LINKS_APPROX if self.has_pose else MIN_LINKS,
            "marker_accuracy": float(self.marker_accuracy),
            "outputs": [os.path.basename(p) for p in (self.save_links, self.save_camera,
                                                     self.save_linked) if p],
            "initial_links": [[k, int(c)] for k, c in self.initial_links],
            "image": os.path.basename(self.inputs.get("image", "")),
        }

    def frame_u16(self) -> tuple[bytes, float, float]:
        """The frame as little-endian uint16 bytes, row by row, mapped linearly from its
        finite range ``[lo, hi]`` to ``[1, 65535]`` (0 = masked); returns
        ``(bytes, lo, hi)``. The page stretches the contrast itself."""
        img = np.asarray(self.image, float)
        fin = np.isfinite(img)
        lo, hi = (float(img[fin].min()), float(img[fin].max())) if fin.any() else (0.0, 1.0)
        span = hi - lo if hi > lo else 1.0
        q = np.where(fin, 1.0 + np.clip((np.nan_to_num(img) - lo) / span, 0, 1) * 65534.0, 0)
        return np.rint(q).astype("<u2").tobytes(), lo, hi

    def candidates_json(self) -> dict:
        c = self.candidates
        return {"u": _list(c.u), "v": _list(c.v), "diameter": _list(c.diameter),
                "merit": _list(c.merit)}

    def plan(self, camera: Camera | None = None) -> dict:
        """The targets seen from the camera's side: normalised image coordinates
        ``x/z, y/z`` through ``camera`` (or the session's camera when it has a pose), else
        a plan along the targets' outward side (:func:`plan_axes`). Returns ``{"ids",
        "xy", "source"}`` (``xy`` rows of NaN for targets behind the camera)."""
        ms = self.markers
        if camera is None and self.has_pose:
            camera = self.camera
        if camera is not None:
            xc = camera.to_camera_frame(ms.xyz)
            with np.errstate(divide="ignore", invalid="ignore"):
                xy = np.where(xc[:, 2:3] > 0, xc[:, :2] / xc[:, 2:3], np.nan)
            src = "camera"
        else:
            xy = (ms.xyz - ms.xyz.mean(axis=0)) @ plan_axes(ms.xyz, ms.normals).T
            src = "normals" if np.isfinite(ms.normals).all() else "flattest direction"
        return {"ids": list(ms.ids), "xy": _list(xy), "source": src}

    # ------------------------------------------------------------------ links
    def _links(self, links) -> tuple[list, np.ndarray]:
        """Check the page's links: known ids, existing candidates, each used once."""
        pos = {k: i for i, k in enumerate(self.markers.ids)}
        ids, idx = [], []
        for item in links:
            if not (isinstance(item, list | tuple) and len(item) == 2):
                raise InputError("links: expected [id, candidate] pairs")
            k, c = str(item[0]), item[1]
            if k not in pos:
                raise InputError(f"links: unknown target {k!r}")
            if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c < len(
                    self.candidates):
                raise InputError(f"links: candidate {c!r} does not exist")
            ids.append(k)
            idx.append(c)
        if len(set(ids)) != len(ids) or len(set(idx)) != len(idx):
            raise InputError("links: a target or a candidate is linked twice")
        return ids, np.asarray(idx, dtype=int)

    def _fit(self, ids, idx):
        """Pose of the links: ``(camera, errors px, used, message)``; raises SolveError when
        the rule refuses it, DegenerateError when the links cannot determine one."""
        from scipy.spatial.transform import Rotation

        from resection.pose.solve import solve_pose
        from resection.pose.three_point import p3p

        X = self.markers.select(ids)
        uv = self.candidates.uv[idx]
        if len(ids) >= MIN_LINKS:
            res = solve_pose(self.camera, X, uv, ids=ids, marker_accuracy=self.marker_accuracy,
                             max_rms=self.max_rms)
            return res.camera, res.errors, res.used, res.message
        # three links: the P3P root nearest the approximate pose (in rotation), exact (dof 0)
        c0 = self.camera
        xy = c0.pixels_to_normalized(c0.undistort(uv))
        roots = p3p(X, np.column_stack([xy, np.ones(len(xy))])) if np.isfinite(xy).all() \
            else []
        if not roots:
            raise SolveError("3 links: no pose puts the three targets on their candidates")
        turn = [Rotation.from_matrix(R @ c0.R.T).magnitude() for R, _ in roots]  # <= 4
        R, t = roots[int(np.argmin(turn))]
        cam = c0.with_pose(R=R, t=t)
        err = np.hypot(*(cam.project(X) - uv).T)
        acc = judge(err, 6, self.marker_accuracy, self.max_rms)
        return cam, err, np.ones(len(ids), bool), (
            "3 links fitted exactly, the pose nearest the approximate one (no redundancy "
            f"to judge: {acc.describe()})")

    def solve(self, links) -> dict:
        """The live answer to a set of links (see the module docstring).

        Returns a dict: ``status`` (``"waiting"``, ``"accepted"`` or ``"refused"``),
        ``message``, ``links`` (per link: ``id``, ``candidate``, ``residual`` px or None,
        ``rejected``), ``predicted`` (per target not linked and expected in view: ``id``,
        ``u``, ``v``), ``offers`` (``id``, ``candidate``, ``distance`` px: the nearest free
        candidate within the outlier gate of a prediction, one-to-one), ``gate`` px,
        ``plan``.
        """
        ids, idx = self._links(links)
        need = MIN_LINKS_APPROX if self.has_pose else MIN_LINKS
        out = {"links": [{"id": k, "candidate": int(c), "residual": None, "rejected": False}
                         for k, c in zip(ids, idx, strict=True)],
               "predicted": [], "offers": [], "gate": None}
        if len(ids) < need:
            out.update(status="waiting", message=f"link {need - len(ids)} more for a pose",
                       plan=self.plan())
            return out
        try:
            cam, err, used, message = self._fit(ids, idx)
        except (SolveError, DegenerateError) as exc:  # e.g. links on one line
            out.update(status="refused", message=str(exc).splitlines()[0], plan=self.plan())
            bad = self._leave_one_out(ids, idx)
            if bad is not None:
                out["links"][bad]["rejected"] = True
                out["message"] += f" (without {ids[bad]} the rule accepts the pose)"
            return out
        for link, e, u in zip(out["links"], err, used, strict=True):
            link["residual"] = float(e)
            link["rejected"] = not bool(u)
        out.update(status="accepted", message=message, plan=self.plan(cam),
                   camera=cam.to_dict())
        out["predicted"], out["offers"], out["gate"] = self._predict(cam, ids, idx,
                                                                     int(used.sum()))
        return out

    def _leave_one_out(self, ids, idx):
        """The one link whose removal makes the rule accept the pose, if exactly one does
        (needs five links or more, so that four remain to be judged)."""
        if len(ids) <= MIN_LINKS:
            return None
        good = []
        for i in range(len(ids)):  # a handful of links
            keep = np.arange(len(ids)) != i
            try:
                self._fit([k for k, m in zip(ids, keep, strict=True) if m], idx[keep])
            except (SolveError, DegenerateError):
                continue
            good.append(i)
        return good[0] if len(good) == 1 else None

    def _expected(self, cam: Camera) -> np.ndarray:
        """Targets the pose says should be seen: in front, in the image, facing the camera
        and (with a mesh) not hidden."""
        ms = self.markers
        uv, valid = cam.project(ms.xyz, return_valid=True)
        ok = valid & cam.in_image(np.where(valid[:, None], uv, 0.0)) & ms.facing(cam.center)
        if self.mesh is not None and ok.any():
            from resection.markers.refind import occluded_targets

            d = self.diameter if math.isfinite(self.diameter) else 5.0
            z = np.maximum(cam.to_camera_frame(ms.xyz)[:, 2], 1e-12)
            sel = np.flatnonzero(ok)
            ok[sel] &= ~occluded_targets(self.mesh, cam, ms.xyz[sel], d * z[sel] / cam.K[0, 0])
        return ok

    def _predict(self, cam: Camera, ids, idx, n_used: int):
        from scipy.spatial import cKDTree

        from resection.markers.match import assign_nearest

        ms = self.markers
        linked = np.isin(np.asarray(ms.ids, dtype=object), np.asarray(ids, dtype=object))
        look = np.flatnonzero(self._expected(cam) & ~linked)
        uv = cam.project(ms.xyz[look]) if look.size else np.zeros((0, 2))
        predicted = [{"id": ms.ids[i], "u": float(p[0]), "v": float(p[1])}
                     for i, p in zip(look, uv, strict=True)]
        gate = outlier_gate(n_used + 1, self.marker_accuracy)
        free = np.setdiff1d(np.arange(len(self.candidates)), idx)
        offers = []
        if look.size and free.size:
            j, dist = assign_nearest(uv, cKDTree(self.candidates.uv[free]), gate)
            offers = [{"id": ms.ids[look[i]], "candidate": int(free[j[i]]),
                       "distance": float(dist[i])} for i in np.flatnonzero(j >= 0)]
        return predicted, offers, float(gate)

    # ------------------------------------------------------------------ saving
    def save(self, links) -> dict:
        """Solve the links again and, when the rule accepts the pose, write the outputs.

        Returns ``{"written": [basenames], "message"}``; raises :class:`SolveError` (nothing
        written) when the pose is refused or not yet determined, :class:`InputError` when
        no output is named or one would overwrite an input."""
        from resection.io.cameras import write_camera
        from resection.io.outputs import atomic_write, refuse_overwriting_inputs
        from resection.markers.link import write_links

        res = self.solve(links)
        if res["status"] != "accepted":
            raise SolveError(f"nothing saved: {res['message']}")
        outs = {"links CSV": self.save_links, "camera": self.save_camera,
                "linked candidates": self.save_linked}
        if not any(outs.values()):
            raise InputError("nothing to save to: no output file was named")
        refuse_overwriting_inputs(outs, {k: [v] for k, v in self.inputs.items() if v})
        keep = [lk for lk in res["links"] if not lk["rejected"]]
        ids = [lk["id"] for lk in keep]
        idx = [lk["candidate"] for lk in keep]
        written = []
        if self.save_links:
            atomic_write(self.save_links, write_links, ids, idx)
            written.append(self.save_links)
        if self.save_camera:
            cam = Camera.from_dict(res["camera"], source="solved camera")
            write_camera(self.save_camera, cam, format="json")
            written.append(self.save_camera)
        if self.save_linked:
            from resection.markers.detect import write_candidates

            labels = [None] * len(self.candidates)
            for k, c in zip(ids, idx, strict=True):
                labels[c] = k
            atomic_write(self.save_linked, write_candidates, self.candidates, ids=labels)
            written.append(self.save_linked)
        names = [os.path.basename(p) for p in written]
        return {"written": names, "message": f"{len(ids)} links and the pose saved: "
                + ", ".join(names)}


def _list(a) -> list:
    """A float array as nested lists with NaN as None (JSON has no NaN)."""
    arr = np.asarray(a, float)
    return np.where(np.isfinite(arr), arr, None).tolist()


def open_session(
    image: str | os.PathLike,
    markers: str | os.PathLike,
    camera: str | os.PathLike,
    *,
    mesh: str | os.PathLike | None = None,
    mesh_format: str | None = None,
    candidates: str | os.PathLike | None = None,
    links: str | os.PathLike | None = None,
    diameter: float | None = None,
    polarity: str = "dark",
    save_links: str | os.PathLike | None = None,
    save_camera: str | os.PathLike | None = None,
    save_linked: str | os.PathLike | None = None,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    max_rms: float | None = DEFAULT_MAX_RMS,
) -> LinkSession:
    """Read the files named on the command line into a :class:`LinkSession`.

    Candidates come from ``candidates`` (a candidate CSV) or are detected on the image with
    the default options of ``resection detect`` and ``diameter`` px (default: from the
    marker file's diameters through the camera's approximate pose; an intrinsics-only
    camera needs ``diameter``). ``links``: a linking CSV to start from. The outputs are
    checked against the inputs here, before anything is served.
    """
    from resection.io.cameras import read_camera_file
    from resection.io.images import read_image
    from resection.io.markers import read_markers
    from resection.io.outputs import refuse_overwriting_inputs
    from resection.markers.detect import read_candidates
    from resection.markers.in_image import detect_in_image, expected_diameter
    from resection.pose.pose_needed import has_usable_pose

    inputs = {"image": image, "markers": markers, "camera": camera, "mesh": mesh,
              "candidates": candidates, "links": links}
    inputs = {k: os.fspath(v) for k, v in inputs.items() if v is not None}
    outputs = {"--save-links": save_links, "--pose": save_camera, "--out": save_linked}
    refuse_overwriting_inputs(outputs, {k: [v] for k, v in inputs.items()})
    img = read_image(image, mask_saturated=True)
    cf = read_camera_file(camera, image_size=img.shape[::-1])  # for a uPSP file without one
    cam = cf.camera
    if img.shape != (cam.height, cam.width):
        raise InputError(f"{image}: {img.shape[1]}x{img.shape[0]} pixels, but the camera "
                         f"{camera} is {cam.width}x{cam.height} (wrong image or camera file?)")
    surface = None
    if mesh is not None:
        from resection.io.meshes import load_mesh

        surface = load_mesh(mesh, format=mesh_format)
    ms = read_markers(markers, mesh=surface).targets
    has_pose = has_usable_pose(cam, ms.xyz, cf.has_pose)
    d = float("nan")
    if candidates is not None:
        cand = read_candidates(candidates)[0]
    else:
        if diameter is None:
            if not has_pose:
                raise InputError(f"{camera}: the camera has no pose, so the marker size in "
                                 "the image is unknown: give --diameter PX (or --candidates)")
            # rounded, so that the value printed for pose and track detects the same
            diameter = round(expected_diameter(cam, ms), 2)
        d = float(diameter)
        cand = detect_in_image(img, d, polarity)
    if len(cand) == 0:
        raise InputError(f"{image}: no candidates found (check --diameter/--polarity)")
    init = []
    if links is not None:
        from resection.markers.link import read_links

        lids, _, lidx = read_links(links, cand, ms)
        init = [(k, int(c)) for k, c in zip(lids, lidx, strict=True)]
    return LinkSession(img, cand, ms, cam, has_pose, d, surface,
                       None if save_links is None else os.fspath(save_links),
                       None if save_camera is None else os.fspath(save_camera),
                       None if save_linked is None else os.fspath(save_linked),
                       inputs, init, marker_accuracy, max_rms)

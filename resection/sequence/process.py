"""One frame: detection, matching from a reference frame, pose; chunks of consecutive
frames and the repair pass."""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError, SolveError
from resection.sequence.frames import failure_reason, fingerprint, frame_name, load_image
from resection.sequence.outputs import try_write_frame
from resection.sequence.predict import track_predicted
from resection.sequence.results import DEFERRED, FrameResult


@dataclass(frozen=True)
class Setup:
    """Everything a worker needs to process frames (picklable, sent once)."""

    camera: Camera
    ids: np.ndarray
    points3d: np.ndarray
    diameter: float
    polarity: str
    detect_kw: dict
    match_kw: dict
    pose_kw: dict
    min_markers: int
    roi_margin: float | None = None
    #: (N, 3) outward unit normals at the markers (NaN rows where unknown), or None
    normals: np.ndarray | None = None
    #: threads of a frame's marker fits: 1 where processes share the cores (the pool, a
    #: cluster, this process beside them), None (every core) where this process tracks
    #: alone (:func:`resection.sequence.execute.execute`)
    fit_workers: int | None = 1

def _search_roi(setup: Setup, reference: FrameResult | None, shape) -> tuple | None:
    """Bounding box ``(u_min, v_min, u_max, v_max)`` of all the markers projected with the
    reference pose (or the approximate camera), widened by ``roi_margin`` pixels: markers
    cannot be elsewhere, and detection costs grow with the searched area. None: search the
    whole image."""
    if setup.roi_margin is None or "roi" in setup.detect_kw:
        return None
    cam = setup.camera if reference is None else reference.camera(setup.camera)
    uv = cam.project(setup.points3d)
    uv = uv[np.isfinite(uv).all(axis=1)]
    if len(uv) == 0:
        return None
    m = float(setup.roi_margin)
    H, W = shape
    u0, v0 = np.floor(uv.min(axis=0) - m)
    u1, v1 = np.ceil(uv.max(axis=0) + m)
    u0, v0, u1, v1 = max(int(u0), 0), max(int(v0), 0), min(int(u1), W - 1), min(int(v1), H - 1)
    if u1 - u0 < 2 * m or v1 - v0 < 2 * m:  # markers predicted (nearly) off the image
        return None
    return (u0, v0, u1, v1)


def _detect(img: np.ndarray, setup: Setup, roi=None, shape: str | None = None):
    """``detect_markers`` with the setup's options, its model the tracker's (``shape``
    None) unless the options name one."""
    from resection.markers.detect import detect_markers
    from resection.sequence.predict import marker_shape

    kw = {**setup.detect_kw,
          "shape": marker_shape(setup.detect_kw, setup.diameter) if shape is None else shape}
    if roi is not None:
        kw["roi"] = roi
    return detect_markers(img, setup.diameter, polarity=setup.polarity, **kw)


def _match(candidates, setup: Setup, reference: FrameResult | None):
    """Match the candidates to the 3-D markers, from the reference frame's markers (their
    pixel positions) or, without a reference, from the approximate camera. Returns the
    matched ``(ids, uv)`` and the matcher's pose solve (a ``PoseResult``)."""
    from resection.markers.match import match_markers

    markers3d = (setup.ids, setup.points3d)
    ref = setup.camera if reference is None else (tuple(reference.ids), reference.uv)
    kw = {**setup.match_kw, "pose_kw": setup.pose_kw}
    try:
        m = match_markers(candidates, markers3d, ref, camera=setup.camera, **kw)
    except SolveError as first:
        # The matcher's hypotheses are 2-D similarities: a pitch of a degree or two between
        # the reference and this frame (a chunk's first frame is matched from frame 0) bends
        # the marker pattern by more than the landing tolerance. One retry with twice the
        # tolerance; the matcher's pose verification and residual test still guard it.
        default = inspect.signature(match_markers).parameters["tolerance"].default
        kw["tolerance"] = 2.0 * float(kw.get("tolerance", default))
        try:
            m = match_markers(candidates, markers3d, ref, camera=setup.camera, **kw)
        except SolveError:
            raise SolveError(f"{first} (also with tolerance {kw['tolerance']:g} px)") from None
    return np.asarray(m.marker_ids).astype(str), np.asarray(m.uv, float).reshape(-1, 2), m.pose


def _solve(ids: np.ndarray, uv: np.ndarray, setup: Setup, frame: int, file: str,
           pose=None, method: str = "matched") -> FrameResult:
    """The frame's pose from matched markers (``pose``: the matcher's ``PoseResult`` for
    exactly these markers, solved with ``pose_kw``, reused)."""
    from resection.pose.solve import solve_pose

    index = {k: i for i, k in enumerate(setup.ids)}
    unknown = [i for i in ids if i not in index]
    if unknown:
        raise InputError(f"matched marker id(s) {unknown[:3]} are not in the marker file")
    if len(ids) < setup.min_markers:
        raise SolveError(f"only {len(ids)} markers matched, at least {setup.min_markers} "
                         "needed")
    if pose is None:
        X = setup.points3d[[index[i] for i in ids]]
        pose = solve_pose(setup.camera, X, uv, **setup.pose_kw)
    res = np.asarray(pose.residuals, float)
    if pose.used is not None and not pose.used.all():  # outliers dropped by the rule
        ids, uv, res = np.asarray(ids)[pose.used], np.asarray(uv)[pose.used], res[pose.used]
    return FrameResult(frame=frame, file=file, status="ok", rvec=np.asarray(pose.camera.rvec),
                       tvec=np.asarray(pose.camera.t, float), rms=float(pose.rms),
                       ids=np.asarray(ids, dtype=str), uv=np.asarray(uv, float),
                       residuals=res, method=method)


def process_frame(frame_data, index: int, setup: Setup, reference: FrameResult | None,
                   previous: FrameResult | None = None, sources: dict | None = None,
                   match: bool = True, digests: dict | None = None) -> FrameResult:
    """Read one frame, track its markers by prediction from ``reference`` (and the good
    frame before it, ``previous``) or, when the prediction's gate fails, detect and match
    them from ``reference`` with the statistical matcher (unless ``match`` is false: the
    frame then fails); solve the pose. Never raises for a bad frame: the failure is
    returned with its reason. ``sources``: multi-frame files kept open between frames
    (see :func:`resection.sequence.frames.load_image`); ``digests``: the files' content
    digests taken so far (:func:`~resection.sequence.frames.fingerprint`)."""
    source = fingerprint(frame_data, digests)  # before reading: a change is seen next time
    res = _process_frame_unlabelled(frame_data, index, setup, reference, previous, sources,
                                    match)
    return dataclasses.replace(res, matched_from=-1 if reference is None else reference.frame,
                               source=source,
                               ref_source=None if reference is None else reference.source)


def _process_frame_unlabelled(frame_data, index: int, setup: Setup,
                              reference: FrameResult | None,
                              previous: FrameResult | None, sources,
                              match: bool = True) -> FrameResult:
    name = frame_name(frame_data)
    try:
        img = load_image(frame_data, sources)
        if img.shape != (setup.camera.height, setup.camera.width):
            raise InputError(f"image is {img.shape[1]}x{img.shape[0]} px, the camera "
                             f"{setup.camera.width}x{setup.camera.height}")
        if reference is not None:
            res = track_predicted(img, setup, reference, previous, index, name)
            if res is not None:
                return res
            if not match:
                raise SolveError(f"the prediction from frame {reference.frame} failed")
        if not np.isfinite(img).any():
            raise InputError("image has no finite pixel (all NaN or infinite)")
        cands = _detect(img, setup, _search_roi(setup, reference, img.shape))
        if len(cands) < setup.min_markers:
            raise SolveError(f"only {len(cands)} marker candidates detected")
        ids, uv, pose = _match(cands, setup, reference)
        return _solve(ids, uv, setup, index, name, pose)
    except Exception as exc:  # noqa: BLE001 - any failure of one frame must not stop the run
        return FrameResult(frame=index, file=name, status="failed",
                           reason=failure_reason(exc, name))


def process_linked(frame_data, index: int, setup: Setup, link: dict) -> FrameResult:
    """The reference frame through a linking by hand: marker id -> candidate number, the
    candidates being those of ``detect_markers`` on the whole frame (as ``resection detect``
    numbers them). A linking that does not fit the candidates raises InputError."""
    source = fingerprint(frame_data)
    return dataclasses.replace(_process_linked_unlabelled(frame_data, index, setup, link),
                               source=source)


def _process_linked_unlabelled(frame_data, index: int, setup: Setup,
                               link: dict) -> FrameResult:
    name = frame_name(frame_data)
    try:
        img = load_image(frame_data)
        if img.shape != (setup.camera.height, setup.camera.width):
            raise InputError(f"image is {img.shape[1]}x{img.shape[0]} px, the camera "
                             f"{setup.camera.width}x{setup.camera.height}")
        # numbered as ``resection detect`` numbers them (the disk model), then the linked
        # markers fitted again with the tracker's model, as in the frames it tracks
        cands = _detect(img, setup, shape="disk")
    except Exception as exc:  # noqa: BLE001 - recorded, the run goes on
        return FrameResult(frame=index, file=name, status="failed",
                           reason=failure_reason(exc, name))
    ids, uv = _apply_link(cands, link, setup)
    uv = _refit(img, setup, uv)
    try:
        return _solve(ids, uv, setup, index, name, method="linked")
    except Exception as exc:  # noqa: BLE001
        return FrameResult(frame=index, file=name, status="failed",
                           reason=failure_reason(exc, name))


def _refit(img: np.ndarray, setup: Setup, uv: np.ndarray) -> np.ndarray:
    """The markers at ``uv`` fitted with the tracker's model where it is not the disk
    (see :func:`resection.sequence.predict.marker_shape`); a fit that fails, or moves more
    than half a diameter, keeps its position."""
    from resection.markers.refine import refine_markers
    from resection.sequence.predict import marker_shape

    kw = setup.detect_kw
    shape = marker_shape(kw, setup.diameter)
    if shape == "disk" or len(uv) == 0:
        return uv
    signal = np.asarray(img, float)
    signal = -signal if setup.polarity == "dark" else signal
    bad = None if kw.get("mask") is None else np.asarray(kw["mask"], bool)
    fit = refine_markers(signal, uv, setup.diameter, bad=bad, blur=float(kw.get("blur", 0.6)),
                         shape=shape)
    new = np.column_stack([fit["u"], fit["v"]])
    with np.errstate(invalid="ignore"):
        keep = fit["ok"] & (np.hypot(*(new - uv).T) <= 0.5 * setup.diameter)
    return np.where(keep[:, None], new, uv)


def _apply_link(candidates, link: dict, setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    markers = (setup.ids, setup.points3d)
    if link["path"] is not None:
        from resection.markers.link import read_links

        ids, uv, _ = read_links(link["path"], candidates, markers)
        return np.asarray(ids).astype(str), np.asarray(uv, float).reshape(-1, 2)
    pairs = link["pairs"]
    known = set(setup.ids)
    unknown = [k for k in pairs if k not in known]
    if unknown:
        raise InputError(f"link: id(s) not in the marker file: {', '.join(unknown[:10])}")
    idx = np.array([pairs[k] for k in pairs], int)
    if idx.size and (idx.min() < 0 or idx.max() >= len(candidates)):
        raise InputError(f"link: candidate numbers must lie in 0..{len(candidates) - 1} "
                         f"(the first frame has {len(candidates)} candidates)")
    if len(set(idx.tolist())) != idx.size:
        raise InputError("link: a candidate is linked twice")
    return np.array(list(pairs), dtype=str), candidates.uv[idx].reshape(-1, 2)




def run_chunk(setup: Setup, items: list, seed: FrameResult | None,
               done: dict | None = None,
               on_frame: Callable[[FrameResult], None] | None = None,
               frames_dir: str | None = None,
               previous: FrameResult | None = None) -> list[dict]:
    """Process consecutive frames ``items = [(index, frame), ...]``, each matched from the
    previous good one (the first from ``seed``, and ``previous``, the good frame before it,
    when known). Frames already in ``done`` (index -> dict) are not recomputed but serve as
    references. With ``frames_dir`` (a Dask task) every frame's result file is written
    there as soon as the frame is finished, so that an interruption loses at most the
    frame in progress. Returns the frames' dictionaries.

    A chunk seeded from a frame other than the one just before it (frame 0, for chunks run
    in parallel) whose first frame is not tracked by prediction from the seed computes no
    more (the statistical matcher is not tried there): the model moved too far since the
    seed, and every frame would fail alike, each at the price of a detection and a
    statistical match. Its frames are recorded as failed with ``matched_from = DEFERRED``;
    the chunk is started again from the chunk before it once that is done
    (:mod:`resection.sequence.chain`), or the sequential pass (:func:`repair`) computes
    them from the good frame before them."""
    done = done or {}
    ref, prev = seed, previous
    out = []
    sources: dict = {}  # multi-frame files, opened once for the chunk
    digests: dict = {}  # and their content digests, taken once while unchanged
    far_seed = seed is not None and bool(items) and seed.frame < items[0][0] - 1
    deferred = None
    try:
        for index, frame in items:
            if index in done:
                res = FrameResult.from_dict(done[index])
            elif deferred is not None:
                res = FrameResult(frame=index, file=frame_name(frame), status="failed",
                                  reason=deferred, matched_from=DEFERRED,
                                  source=fingerprint(frame, digests))
                if frames_dir is not None:
                    try_write_frame(Path(frames_dir), res)
                if on_frame is not None:
                    on_frame(res)
            else:
                first_far = far_seed and ref is seed
                res = process_frame(frame, index, setup, ref, prev, sources=sources,
                                    match=not first_far, digests=digests)
                if first_far and not res.ok:
                    deferred = (f"not computed in its chunk: frame {index} failed from "
                                f"frame {seed.frame}")
                if frames_dir is not None:
                    try_write_frame(Path(frames_dir), res)
                if on_frame is not None:
                    on_frame(res)
            if res.ok:
                ref, prev = res, ref
            out.append(res.to_dict())
    finally:
        for src in sources.values():
            src.close()
    return out


def repair(frames: list, setup: Setup, done: dict, record, frames_dir: Path) -> None:
    """Second, sequential pass over the frames that failed while matched from a frame other
    than the last good one before them (a chunk's first frames are matched from frame 0:
    after a large excursion that can fail where matching from the previous frame works).
    Such a frame is processed again from the last good frame; a frame that failed although
    matched from it (a corrupt frame) is left as it is, so the pass is cheap and a resumed
    run does not redo it. Deterministic: it depends only on the first pass' results.
    ``done``: index -> ``(ok, matched_from)``; the last good frame is read from its file."""
    from resection.sequence.outputs import frame_path, read_frame

    last_good = None
    for i in range(len(frames)):
        ok, matched_from = done[i]
        if ok:
            last_good = i
            continue
        if last_good is None or (matched_from == last_good and matched_from != DEFERRED):
            continue
        ref = FrameResult.from_dict(read_frame(frame_path(frames_dir, last_good)))
        res = process_frame(frames[i], i, setup, ref)
        record(res)
        if res.ok:
            last_good = i

"""Per-frame mapping of a moving model (resection.sequence.mapping) against the truth: frames
rendered by closed-form ray/box casting of a painted model pitching 2 degrees
(scenes.moving_surface), node values compared with the paint field at the nodes."""

import numpy as np
import pytest

from resection import InputError
from resection.sequence.mapping import map_frames
from scenes.moving_model import pitch_oscillation
from scenes.moving_surface import edge_nodes, model_surface, paint_field, render_surface

FRAMES = [0, 12, 37]  # rest, +2 degrees, -2 degrees of pitch (50 frames/s, 1 Hz)


@pytest.fixture(scope="module")
def run():
    model = pitch_oscillation(50, shape=(192, 192))
    mesh = model_surface(face_size=0.015)
    cams = [model.camera_at(k) for k in FRAMES]
    frames = [render_surface(model, k) for k in FRAMES]
    return model, mesh, cams, frames


def _errors(results, truth):
    return np.array([r.values - truth for r in results])


def test_per_frame_map_matches_the_truth_at_the_edges(run):
    model, mesh, cams, frames = run
    truth = paint_field(mesh.vertices)
    edge = edge_nodes(mesh, width=0.016)
    res = list(map_frames(mesh, cams, frames, per="node"))
    assert [r.index for r in res] == [0, 1, 2]
    err = _errors(res, truth)
    seen = np.isfinite(err)
    assert seen[:, edge].sum(axis=1).min() > 200  # edge nodes seen in every frame
    # first-order bound of the node estimate: |grad f| <= 5,100 counts/m times the distance
    # from a node to the weighted centre of its pixels (< a face size, 0.015 m)
    assert np.nanmax(np.abs(err)) < 5100 * 0.015
    assert np.nanpercentile(np.abs(err[:, edge]), 95) < 35
    # the frame-0 map kept for the moved frames (what a map not rebuilt does) puts
    # background and other points of the model on the edge nodes
    stale = _errors(map_frames(mesh, cams[0], frames, per="node"), truth)
    assert np.nanmax(np.abs(stale[1:, edge])) > 300
    # per face: the same map, face means; the faces seen match the frame's own map
    faces = list(map_frames(mesh, cams, frames, per="face"))
    assert faces[1].values.shape == (len(mesh.faces),)
    assert faces[1].seen.sum() > 200 and faces[1].seen.sum() != faces[0].seen.sum()


def test_map_frames_errors(run):
    model, mesh, cams, frames = run
    with pytest.raises(InputError, match="2 cameras for more frames"):
        list(map_frames(mesh, cams[:2], frames))
    with pytest.raises(InputError, match="frame 1: shape"):
        list(map_frames(mesh, cams, [frames[0], frames[1][:-1]]))
    other = cams[1].replace(K=np.array(cams[1].K) * [[1.01], [1.01], [1]])
    with pytest.raises(InputError, match="other intrinsics"):
        list(map_frames(mesh, [cams[0], other], frames[:2]))
    with pytest.raises(InputError, match="per must be"):
        list(map_frames(mesh, cams, frames, per="pixel"))

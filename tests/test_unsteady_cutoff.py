"""uPSP's ``cutoff_x_max`` (``psp_process -cutoff_x_max=X``) in ``selfillum unsteady``,
checked against uPSP's own logic, written out here from its source
(``cpp/exec/psp_process.cpp``, ``cpp/include/Model.h``):

* ``phase1()``: before anything else, ``if (xs[i] > sett.x_max) model.set_node_nondata(i)``
  for every node ``i`` of the grid, ``xs = model.get_x()`` (the grid's own coordinates:
  "model isn't transformed anymore");
* ``create_projection_mat()``: ``if (!n.is_datanode()) continue;`` -- a non-data node gets
  no row of the projection (every triangle stays in the ray-tracing scene: ``createBVH``
  extracts them all, so the cut part still hides what is behind it);
* ``identify_skipped_nodes`` then ``sol1[skipped[i]] = qNAN``: a node no camera projects
  is NaN in every frame; the weights of ``average_view`` are per node, so the data nodes
  are as without the option.

So, on the same run: the nodes with ``x > X`` (strictly) are NaN everywhere, every other
node is what the run without the option gives (to the work file's rounding).
"""

from __future__ import annotations

import json

import h5py
import numpy as np
from unsteady_cases import args, copy_run, refused, run_cli, small_run  # noqa: F401


def upsp_nondata(xs: np.ndarray, x_max: float) -> np.ndarray:
    """psp_process's marking, node by node as it is written there (a loop, on purpose)."""
    data = [True] * len(xs)  # Model::is_datanode defaults to true
    for i in range(len(xs)):
        if xs[i] > x_max:
            data[i] = False  # model.set_node_nondata(i)
    return ~np.array(data)


def upsp_solution(sol_without: np.ndarray, nondata: np.ndarray) -> np.ndarray:
    """The solution psp_process gives with the cut-off: a non-data node has no projection
    row, so it is among the skipped nodes and NaN; the rest as without."""
    out = np.array(sol_without, dtype=np.float64, copy=True)
    out[..., nondata] = np.nan
    return out


def _run(case, capsys, *extra, out):
    rc, _, err = run_cli(args(case, *extra, out=out), capsys)
    assert rc == 0, err
    with h5py.File(case / out, "r") as f:
        return (f["dcp"][()], f["stats/dcp_rms"][()], f["grid/points"][()],
                json.loads(f.attrs["options"]))


def test_cutoff_x_max_as_psp_process(small_run, tmp_path, capsys):  # noqa: F811
    case = copy_run(small_run, tmp_path / "case")
    d0, rms0, pts, _ = _run(case, capsys, out="all.h5")
    xs = pts[:, 0]
    seen0 = np.isfinite(rms0)
    # X at a seen node's own x, near the middle of the seen nodes' range: seen nodes on
    # both sides, and that node (x == X) must stay
    cand = np.sort(np.unique(xs[seen0]))
    X = float(cand[len(cand) // 2])
    nondata = upsp_nondata(xs, X)
    assert (seen0 & nondata).sum() > 20 and (seen0 & ~nondata).sum() > 20
    d1, rms1, _, opts = _run(case, capsys, "--cutoff-x-max", repr(X), out="cut.h5")
    assert opts["cutoff_x_max"] == X
    want = upsp_solution(d0, nondata)
    # the non-data nodes: NaN in every frame, no statistics
    assert np.isnan(d1[:, nondata]).all() and np.isnan(rms1[nondata]).all()
    # the data nodes, (x == X) among them: as without the option
    at_x = np.flatnonzero((xs == X) & seen0)
    assert at_x.size and np.isfinite(d1[:, at_x]).all()
    keep = ~nondata
    np.testing.assert_array_equal(np.isfinite(d1[:, keep]), np.isfinite(want[:, keep]))
    scale = np.nanmax(np.abs(d0))
    np.testing.assert_allclose(d1[:, keep], want[:, keep], rtol=0, atol=1e-3 * scale,
                               equal_nan=True)
    np.testing.assert_allclose(rms1[keep], rms0[keep], rtol=1e-3, equal_nan=True)


def test_cutoff_x_max_refused(small_run, tmp_path, capsys):  # noqa: F811
    case = copy_run(small_run, tmp_path / "case")
    err = refused(case, capsys, "--cutoff-x-max=-1e9")
    assert "cutoff_x_max -1e+09: every node of " in err and "no node would get data" in err
    err = refused(case, capsys, "--cutoff-x-max", "nan")
    assert "cutoff_x_max nan: out of range" in err

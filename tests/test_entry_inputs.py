"""The entry's inputs: the datapoint index in both schemas (uPSP's docs put the datapoints
at the top level, its tree.py under 'datapoints'), uPSP's processing overlays against its
own resolution logic (written out below from python/upsp/processing/tree.py), uPSP's
Kulite files against its kulite_utilities reading logic (written out below, with pandas as
uPSP uses it), the plain Kulite tables, and the batch clusters' job scripts."""

from __future__ import annotations

import collections.abc
import json
import re

import numpy as np
import pytest

from resection import InputError
from scenes.entry import write_kulite_files
from selfillum.entry.index import find_videos, read_index
from selfillum.entry.kulites import read_kulite_table, read_kulites, read_upsp_kulites
from selfillum.entry.processing import psp_options, read_processing, resolve_overlays

DP = {"camera_tunnel_calibration_dir": "cal", "camera_video_dir": "videos",
      "grid_file": "in/config1.grid", "kulites_files_path": "kul",
      "paint_calibration_file": "in/paint.txt", "steady_psp_file": "in/steady.f",
      "targets_file": "in/model.tgts", "wtd_file": "wtd/{}.wtd"}


def _upsp_index(ids, nested: bool):
    dps = {i: {k: v.format(i) for k, v in DP.items()} for i in ids}
    meta = {"config_name": "default", "test_name": "t"}
    return {"__meta__": meta, "datapoints": dps} if nested else {"__meta__": meta, **dps}


@pytest.mark.parametrize("nested", [False, True])
def test_upsp_index_both_layouts(tmp_path, nested):
    p = tmp_path / "index.json"
    p.write_text(json.dumps(_upsp_index(["301101", "301102"], nested)))
    idx = read_index(p)
    assert idx.schema == "upsp" and [d.id for d in idx.datapoints] == ["301101", "301102"]
    d = idx.datapoints[1]
    assert d.wtd == tmp_path / "wtd" / "301102.wtd"
    assert d.grid == tmp_path / "in" / "config1.grid" and d.kulites == tmp_path / "kul"
    assert d.calibration_dir == tmp_path / "cal" and d.entries["grid_file"] == \
        "in/config1.grid"
    # videos as uPSP's tree finds them: <id>NN.<ext>, camera NN
    (tmp_path / "videos").mkdir()
    for n in ("30110201.mraw", "30110202.cine", "30110101.mraw", "30110201.cih"):
        (tmp_path / "videos" / n).write_bytes(b"")
    assert find_videos(d) == {1: tmp_path / "videos" / "30110201.mraw",
                              2: tmp_path / "videos" / "30110202.cine"}


def test_upsp_index_refusals(tmp_path):
    p = tmp_path / "index.json"
    bad = _upsp_index(["301101"], True)
    bad["datapoints"]["301101"]["grid_flie"] = "x"
    p.write_text(json.dumps(bad))
    with pytest.raises(InputError, match=r"datapoint 301101: unknown key 'grid_flie' "
                                         r"\(did you mean 'grid_file'\?\)"):
        read_index(p)
    bad = _upsp_index(["301101"], True)
    del bad["datapoints"]["301101"]["wtd_file"]
    p.write_text(json.dumps(bad))
    with pytest.raises(InputError, match=r"index.json: datapoint 301101: missing 'wtd_file'"):
        read_index(p)
    bad = _upsp_index(["301101"], True)
    bad["datapoints"]["301101"]["normals_file"] = "n.dat"
    p.write_text(json.dumps(bad))
    with pytest.raises(InputError, match="normals_file is not supported"):
        read_index(p)
    p.write_text("{ not json")
    with pytest.raises(InputError, match="index.json: not JSON"):
        read_index(p)


def test_project_yaml_index(tmp_path):
    p = tmp_path / "entry.yaml"
    p.write_text("entry:\n  grid: m.grid\n  targets: m.tgts\n  test_config: tc.json\n"
                 "  steady: s.f\n  camera_tunnel:\n    1: c1.json\n    2: c2.json\n"
                 "  options:\n    target_patcher: polynomial\n"
                 "datapoints:\n  '7':\n    wtd: a.wtd\n    videos: {1: v1.cine, 2: v2.cine}\n"
                 "    steady: s7.f\n  '8':\n    wtd: b.wtd\n    videos: {2: w2.cine}\n")
    idx = read_index(p)
    assert idx.schema == "project" and idx.test_config == tmp_path / "tc.json"
    a, b = idx.datapoints
    assert a.videos == {1: tmp_path / "v1.cine", 2: tmp_path / "v2.cine"}
    assert a.steady == tmp_path / "s7.f" and b.steady == tmp_path / "s.f"
    assert b.camera_tunnel == {2: tmp_path / "c2.json"} and b.kulites is None
    assert idx.options == {"target_patcher": "polynomial"}
    p.write_text(p.read_text().replace("{2: w2.cine}", "{3: w3.cine}"))
    with pytest.raises(InputError, match="datapoint 8: camera 3 has a video but no "
                                         "camera_tunnel"):
        read_index(p)


# ------------------------------------------------------------ processing overlays
def _upsp_resolve(processing, datapoints):
    """uPSP tree._resolve_parameter_overlays, written out."""
    def match_all(patterns, dp):
        def one(d, pk, pv):
            for dk, dv in d.items():
                if re.fullmatch(pk, dk) and re.fullmatch(pv, dv):
                    return True
            return False
        return all(one(dp, *it) for it in patterns.items())

    def update(d, u):
        for k, v in u.items():
            d[k] = update(d.get(k, {}), v) if isinstance(v, collections.abc.Mapping) else v
        return d

    sets = {k: v for k, v in processing.items() if k != "__overlays__"}
    out = {k: {} for k in datapoints}
    for name, patterns in processing.get("__overlays__", []):
        for dp_name, dp in datapoints.items():
            if match_all(patterns, dp):
                out[dp_name] = update(out[dp_name], json.loads(json.dumps(sets[name])))
    return out


def test_processing_overlays_as_upsp_resolves_them(tmp_path):
    proc = {"defaults": {"psp_process": {"filter": "none", "filter_size": 1,
                                         "number_frames": 20, "registration": "pixel"},
                         "external-calibration": {"max_dist": 6,
                                                  "tunnel-cor_to_tgts_tvec": [0, 0, 0]}},
            "geom2": {"external-calibration": {"tunnel-cor_to_tgts_tvec": [-195.5, 0, 0]}},
            "long": {"psp_process": {"number_frames": -1, "filter": "gaussian"}},
            "__overlays__": [["defaults", {".*": ".*"}],
                             ["geom2", {"grid_file": ".*config2.*"}],
                             ["long", {"wtd_.*": ".*30110[23].wtd", "grid_file": ".*"}]]}
    dps = {}
    for i, g in (("301101", "config1"), ("301102", "config2"), ("301103", "config1")):
        dps[i] = {k: v.format(i) for k, v in DP.items()}
        dps[i]["grid_file"] = f"in/{g}.grid"
    p = tmp_path / "proc.json"
    p.write_text(json.dumps({"__meta__": {"name": "x"}, "processing": proc}))
    got = resolve_overlays(read_processing(p), dps)
    assert got == _upsp_resolve(proc, dps)
    assert got["301102"]["external-calibration"]["tunnel-cor_to_tgts_tvec"] == [-195.5, 0, 0]
    assert got["301102"]["external-calibration"]["max_dist"] == 6
    assert got["301101"]["psp_process"]["number_frames"] == 20
    assert got["301103"]["psp_process"]["filter"] == "gaussian"
    assert psp_options(got["301103"]["psp_process"], "w") == {
        "filter": "gaussian", "filter_size": 1, "number_frames": -1,
        "registration": "first-frame"}
    # uPSP's tree puts cutoff_x_max on psp_process's command line as it is: a number
    assert psp_options({"cutoff_x_max": 120}, "w") == {"cutoff_x_max": 120.0}
    assert psp_options({"cutoff_x_max": "-1.5"}, "w") == {"cutoff_x_max": -1.5}
    for bad_x in ("abc", None, True, "nan"):
        with pytest.raises(InputError, match="w: cutoff_x_max must be a "):
            psp_options({"cutoff_x_max": bad_x}, "w")
    with pytest.raises(InputError, match="w: psp_process parameter 'target_diam_sf' is not "
                                         "supported"):
        psp_options({"target_diam_sf": 1.2}, "w")
    proc["__overlays__"].append(["nope", {".*": ".*"}])
    p.write_text(json.dumps({"processing": proc}))
    with pytest.raises(InputError, match=r"__overlays__\[3\] names 'nope', not a parameter"):
        read_processing(p)
    proc["__overlays__"][-1] = ["long", {"grid_file": "(["}]
    p.write_text(json.dumps({"processing": proc}))
    with pytest.raises(InputError, match=r"invalid regular expression '\(\['"):
        read_processing(p)


# ------------------------------------------------------------ Kulites
def _numeric(col):
    """pandas.to_numeric(errors="ignore") as uPSP calls it (removed from pandas 3)."""
    import pandas as pd

    try:
        return pd.to_numeric(col)
    except (ValueError, TypeError):
        return col


def _upsp_kulites(data_dir, run, seq, f_type):
    """uPSP kulite_utilities.Kulites, written out (pandas as uPSP uses it)."""
    import glob
    import os

    import pandas as pd

    fnames = glob.glob(os.path.join(data_dir, "*.info"))
    pat = r"T(?P<run>\d+)p(?P<seq>\d+)t\d+$"
    infos = [f for f in fnames
             if (m := re.search(pat, os.path.splitext(os.path.basename(f))[0]))
             and (int(m["run"]), int(m["seq"])) == (run, seq)]
    data, rate = {}, None
    for info in sorted(infos):
        with open(info) as fh:
            d = [r.rstrip("\n").split("\t") for r in fh]
        groups = []
        for _ in range(4):
            n = int(d[0][1])
            groups.append([d.pop(0)[2:] for _ in range(n + 1)])
        fp = pd.DataFrame(groups[0][1:], columns=groups[0][0])
        st = pd.DataFrame(groups[1][1:], columns=groups[1][0]).apply(_numeric)
        ch = pd.DataFrame(groups[3][1:], columns=groups[3][0]).set_index("User Name")
        ch = ch.apply(_numeric)
        assert len(ch.columns) == 18  # version 4
        row = 1 if f_type == "fast" else 2
        fn = os.path.join(os.path.dirname(info), fp["File Name"][row])
        fid = 0 if f_type == "fast" else 1
        nch, ns = st.loc[fid, "Number Channels"], st.loc[fid, "Samples Acquired"]
        b = np.fromfile(fn, dtype=np.dtype("(1,)i4")).reshape(ns, nch)
        for i, name in enumerate(ch.index):
            if "K" not in name:
                continue
            v = b[:, i] * ch["Coeff k1"].iloc[i] + ch["Coeff k0"].iloc[i]
            data[name] = v * ch["EU C1"].iloc[i] / (10 ** (ch["EU Gain (dB)"].iloc[i] / 20)) \
                + ch["EU C0"].iloc[i]
        rate = st["Sampling Rate"][0 if f_type == "fast" else 1]
    return data, rate


def test_kulite_files_as_upsp_reads_them(tmp_path):
    rng = np.random.default_rng(3)
    psi = 10.0 + 0.01 * rng.standard_normal((2, 400))
    write_kulite_files(tmp_path, "T3011p2t1", ("K02", "K01"), psi, 5000.0)
    write_kulite_files(tmp_path, "T3011p3t1", ("K01",), psi[:1] + 1.0, 5000.0)
    ks = read_upsp_kulites(tmp_path, 3011, 2)
    ref, rate = _upsp_kulites(str(tmp_path), 3011, 2, "fast")
    assert ks.names == ("K01", "K02") and rate == ks.rate == 5000.0
    for k, name in enumerate(ks.names):
        np.testing.assert_allclose(ks.data[k], ref[name], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ks.data[0], psi[1], atol=1e-5)  # counts of 1e-5 psi
    # the slow stream when there is no fast one
    (tmp_path / "T3011p2t1.fast").unlink()
    slow = read_upsp_kulites(tmp_path, 3011, 2)
    ref, rate = _upsp_kulites(str(tmp_path), 3011, 2, "slow")
    assert slow.rate == rate == 1250.0
    np.testing.assert_allclose(slow.data[1], ref["K02"], atol=1e-12)
    with pytest.raises(InputError, match="no Kulite .info file of run 3011 point 9"):
        read_kulites(tmp_path, 3011, 9)
    info = tmp_path / "T3011p3t1.info"
    lines = info.read_text().splitlines()
    lines = [ln.rsplit("\t", 1)[0] if ln.startswith("4\t") else ln for ln in lines]
    info.write_text("\n".join(lines) + "\n")  # 17 columns: version 3
    with pytest.raises(InputError, match="T3011p3t1.info: channel block layout version 3"):
        read_upsp_kulites(tmp_path, 3011, 3)


def test_kulite_tables(tmp_path):
    import h5py

    t = 0.002 + np.arange(50) / 2000.0
    a, b = 10 + np.sin(t * 300), 10.5 + np.cos(t * 200)
    (tmp_path / "k.csv").write_text("time,K01,K02\n" + "".join(
        f"{x:.17g},{y:.17g},{z:.17g}\n" for x, y, z in zip(t, a, b, strict=True)))
    arr = np.zeros(50, dtype=[("time", "f8"), ("K01", "f8"), ("K02", "f8")])
    arr["time"], arr["K01"], arr["K02"] = t, a, b
    np.save(tmp_path / "k.npy", arr)
    with h5py.File(tmp_path / "k.h5", "w") as f:
        f["time"] = t
        f["kulites/K01"] = a
        f["kulites/K02"] = b
    for name in ("k.csv", "k.npy", "k.h5"):
        ks = read_kulite_table(tmp_path / name)
        assert ks.names == ("K01", "K02") and ks.rate == pytest.approx(2000.0)
        assert ks.t0 == pytest.approx(0.002)
        np.testing.assert_allclose(ks.data, [a, b], rtol=1e-15)
    (tmp_path / "k2.csv").write_text("time,K01\n0,1\n0.001,2\n0.003,3\n")
    with pytest.raises(InputError, match="k2.csv: 'time' is not evenly sampled"):
        read_kulite_table(tmp_path / "k2.csv")


# ------------------------------------------------------------ batch clusters
@pytest.mark.parametrize("kind,marks", [
    ("pbs", ["#PBS -q normal", "#PBS -A g1234", "#PBS -l walltime=01:30:00",
             "#PBS -l select=1:model=cas_ait"]),
    ("slurm", ["#SBATCH -p normal", "#SBATCH -A g1234", "#SBATCH -t 01:30:00",
               "#SBATCH --constraint=cas_ait"]),
])
def test_jobqueue_job_scripts(tmp_path, kind, marks):
    from selfillum.entry.jobqueue import make_jobqueue_cluster, read_jobqueue

    extra = "-l select=1:model=cas_ait" if kind == "pbs" else "--constraint=cas_ait"
    p = tmp_path / "cluster.yaml"
    p.write_text(f"kind: {kind}\njobs: 4\ncores: 40\nmemory: 180GB\nwalltime: '01:30:00'\n"
                 f"queue: normal\naccount: g1234\njob_extra_directives: ['{extra}']\n"
                 "job_script_prologue: ['source /usr/local/lib/global.profile']\n")
    conf = read_jobqueue(p)
    assert conf["jobs"] == 4
    cluster = make_jobqueue_cluster(conf)
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    for m in marks:
        assert m in script
    assert "source /usr/local/lib/global.profile" in script
    assert "--nthreads 40" in script or "--nworkers 1 --nthreads 40" in script
    p.write_text(f"kind: {kind}\ncores: 4\nmemory: 4GB\nqueu: x\n")
    with pytest.raises(InputError, match="cluster.yaml: unknown key 'queu'"):
        read_jobqueue(p)
    p.write_text("kind: sge\ncores: 4\nmemory: 4GB\n")
    with pytest.raises(InputError, match="kind must be one of pbs, slurm"):
        read_jobqueue(p)

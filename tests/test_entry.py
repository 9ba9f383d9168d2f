"""``selfillum entry`` on a synthetic entry written in the real files' layouts
(:mod:`scenes.entry`: uPSP's index, processing parameters, camera-to-tunnel JSON, 12-bit
``.mraw``, NASA's ``.wtd``, uPSP's Kulite files): a polar from -5 to +15 deg of alpha with
a sting deflection the ``.wtd`` does not know, a wind-off point and a datapoint whose video
is cut short. The calibrations are checked against the scene's true cameras, the Kulite
comparison against the Kulites' known signals, the page in headless Chromium.

A whole entry takes a minute or more on two cores: these tests are marked slow; the
default run has the fast ones (tests/test_entry_fast.py, test_entry_inputs.py,
test_entry_compare.py, test_upsp_real_files.py)."""

from __future__ import annotations

import csv
import json
import re
import shutil

import numpy as np
import pytest

from resection.io.cameras import read_camera, read_camera_file
from scenes.entry import COR, STRUTZ, make_entry
from selfillum.cli import main
from selfillum.entry.tunnel import Attitude, TunnelConfig, camera_to_model

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def entry(tmp_path_factory):
    return make_entry(tmp_path_factory.mktemp("entry"), alphas=(-5.0, 15.0), faces=600,
                      frames=16)


@pytest.fixture(scope="module")
def done(entry, tmp_path_factory):
    """The entry run once through the command (a Dask local cluster, the uPSP index and
    processing file as they are)."""
    out = tmp_path_factory.mktemp("products") / "out"
    status = main(["entry", str(entry.index), "--processing", str(entry.processing),
                   "--out", str(out), "--rays", "16", "--quiet", "--workers", "2"])
    return out, status


def _rows(out):
    with open(out / "summary.csv", newline="") as fh:
        return {r["datapoint"]: r for r in csv.DictReader(fh)}


def _px(cam, X):
    return cam.project(X)


def test_entry_statuses_and_products(entry, done):
    out, status = done
    assert status == 1  # one datapoint failed: its video is cut short
    rows = _rows(out)
    assert list(rows) == list(entry.ids)
    on = [d for d in entry.ids if d not in (entry.wind_off, entry.corrupt)]
    for d in on:
        assert rows[d]["status"] == "ok"
        for f in ("unsteady.h5", "unsteady.xdmf", "cam01-to-model.json", "cam01-pose.png",
                  "kulites/kulites.csv", "kulites/K01_psd.png"):
            assert (out / d / f).is_file(), f
        assert float(rows[d]["alpha"]) == entry.alphas[d] and float(rows[d]["q"]) == 600.0
    assert rows[entry.wind_off]["status"] == "wind-off"
    assert not (out / entry.wind_off / "unsteady.h5").exists()  # never run as wind-on
    assert (out / entry.wind_off / "cam01-to-model.json").is_file()
    bad = rows[entry.corrupt]["status"]
    assert bad.startswith(f"failed: datapoint {entry.corrupt}: ") and \
        f"{entry.corrupt}01.mraw: truncated" in bad
    # the products: uPSP's camera-to-model layout, and the unsteady run's own layout
    cf = read_camera_file(out / on[0] / "cam01-to-model.json")
    assert cf.format == "upsp-model"
    import h5py

    with h5py.File(out / on[0] / "unsteady.h5", "r") as f:
        assert f["dcp"].shape == (16, len(f["grid/points"]))
        opts = json.loads(f.attrs["options"])
        prov = json.loads(f.attrs["provenance"])
    # the processing file's defaults and its overlay (oblique_angle 75 for this grid)
    assert opts["target_patcher"] == "polynomial" and opts["registration"] == "first-frame"
    assert opts["overlap"] == "average_view" and opts["oblique_angle"] == 75.0
    # the view factors computed once for the entry, given to every run
    ff = list((out / "_entry").glob("F-*.npz"))
    assert len(ff) == 1
    assert prov["files"]["form_factors"][0]["path"] == str(ff[0].resolve())


def test_calibrated_from_the_tunnel_across_the_polar(entry, done):
    out, _ = done
    from resection.io.tgts import read_tgts

    X = read_tgts(entry.folder / "inputs" / "model.tgts").targets.xyz
    cfg = TunnelConfig(COR)
    for d, a in entry.alphas.items():
        if d == entry.corrupt:
            continue
        truth = entry.cameras[d]
        got = read_camera(out / d / "cam01-to-model.json")
        err = np.linalg.norm(_px(got, X) - _px(truth, X), axis=1)
        assert np.max(err) < 0.3, (d, err)
        # the tunnel's prediction alone misses by the sting's deflection (> 1 px) ...
        pred = camera_to_model(entry.camera_tunnel, Attitude(a, 0, 0, STRUTZ), cfg)
        assert np.median(np.linalg.norm(_px(pred, X) - _px(truth, X), axis=1)) > 1.0
    # ... and without the attitude, by up to tens of pixels at 15 deg
    d15 = [d for d, a in entry.alphas.items() if a == 15.0][0]
    still = camera_to_model(entry.camera_tunnel, Attitude(0, 0, 0, STRUTZ), cfg)
    miss = np.linalg.norm(_px(still, X) - _px(entry.cameras[d15], X), axis=1)
    assert np.median(miss) > 10.0 and np.max(miss) > 20.0


def test_kulites_agree(tmp_path):
    """128 frames at 1 kHz: the plate's 120 Hz tone and 70 Hz wave at each Kulite, the PSP
    on the ring around its spot against the Kulite's known signal. The ring spans about
    +-3 cm on this grid, a tenth of the wave's 30 cm length: the ring's average keeps most
    of the wave and all of the tone."""
    e = make_entry(tmp_path / "e", alphas=(0.0,), wind_off=False, corrupt=False, faces=2500,
                   frames=128)
    out = tmp_path / "out"
    assert main(["entry", str(e.yaml), "--out", str(out), "--rays", "16", "--quiet",
                 "--workers", "0"]) == 0
    d = e.ids[0]
    with open(out / d / "kulites" / "kulites.csv", newline="") as fh:
        rows = {r["kulite"]: r for r in csv.DictReader(fh)}
    assert set(rows) == {"K01", "K02"}
    for r in rows.values():
        assert 0.8 < float(r["rms_ratio"]) < 1.2, r
        lo, hi = float(r["band_lo_hz"]), float(r["band_hi_hz"])
        assert lo <= 120.0 <= hi, r  # the tone within 1 dB
        assert float(r["coherence_in_band"]) > 0.95, r
        assert int(r["nodes"]) >= 3


def test_summary_page(entry, done):
    out, _ = done
    page = (out / "index.html").read_text()
    links = re.findall(r'(?:href|src)="([^"]+)"', page)
    assert any(x.endswith("cam01-pose.png") for x in links)
    assert any(x.endswith("unsteady_rms.png") for x in links)
    assert any(x.endswith("K01_psd.png") for x in links)
    for x in links:
        assert (out / x).is_file(), x
    assert f'id="dp-{entry.corrupt}"' in page and "truncated" in page


def test_summary_page_in_chromium(entry, done, tmp_path):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    out, _ = done
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
              "--window-size=1600,1000", "--allow-file-access-from-files"):
        opts.add_argument(a)
    drv = webdriver.Chrome(options=opts, service=Service(shutil.which("chromedriver")
                                                         or "/usr/bin/chromedriver"))
    try:
        drv.get((out / "index.html").as_uri())
        imgs = drv.find_elements(By.TAG_NAME, "img")
        assert len(imgs) >= 5
        for im in imgs:  # every thumbnail loaded (a broken link has no natural width)
            assert drv.execute_script("return arguments[0].complete && "
                                      "arguments[0].naturalWidth > 0", im), \
                im.get_attribute("src")
        rows = drv.find_elements(By.CSS_SELECTOR, "tbody tr")
        assert len(rows) == len(entry.ids)
        assert "failed" in rows[-1].get_attribute("class")
        shot = tmp_path / "entry.png"
        drv.save_screenshot(str(shot))
        from PIL import Image

        im = np.asarray(Image.open(shot).convert("L"), float)
        assert im.shape[0] > 500 and im.std() > 10  # a page was drawn, not a blank
    finally:
        drv.quit()


def test_resume(entry, done, tmp_path):
    """--resume skips what is done with the same inputs, carries a half-done datapoint on
    (its calibration kept), does again what changed or failed, and touches no other
    datapoint's products; here on a running Dask scheduler (--scheduler ADDRESS)."""
    from dask.distributed import LocalCluster

    out, _ = done
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    on = [d for d in entry.ids if d not in (entry.wind_off, entry.corrupt)]
    off = copy / entry.wind_off
    before = {p: p.stat().st_mtime_ns for p in off.rglob("*") if p.is_file()}
    # the first wind-on datapoint was cut short after its calibration
    half = copy / on[0]
    for n in ("done.json", "row.json", "unsteady.h5", "unsteady.xdmf", "unsteady_rms.png"):
        (half / n).unlink()
    shutil.rmtree(half / "kulites")
    cal_time = (half / "cam01-to-model.json").stat().st_mtime_ns
    # the last wind-on datapoint's .wtd changes: it is stale
    w = entry.folder / "wtd" / f"{on[-1]}.wtd"
    text = w.read_text()
    w.write_text(text.replace("\t600.000000\t", "\t601.000000\t"))
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=":0")
    try:
        argv = ["entry", str(entry.index), "--processing", str(entry.processing), "--out",
                str(copy), "--rays", "16", "--quiet", "--resume", "--scheduler",
                cluster.scheduler_address]
        assert main(argv) == 1
        rows = _rows(copy)
        assert float(rows[on[-1]]["q"]) == 601.0 and rows[on[-1]]["status"] == "ok"
        assert rows[on[0]]["status"] == "ok" and (half / "unsteady.h5").is_file()
        assert (half / "cam01-to-model.json").stat().st_mtime_ns == cal_time  # kept
        assert "targets, RMS" in rows[on[0]]["cameras"]
        assert rows[entry.corrupt]["status"].startswith("failed")
        after = {p: p.stat().st_mtime_ns for p in off.rglob("*") if p.is_file()}
        assert after == before  # the wind-off point: done before, untouched
    finally:
        w.write_text(text)
        cluster.close()
    # without --resume, existing products are refused before any work
    rc = main(["entry", str(entry.index), "--processing", str(entry.processing), "--out",
               str(copy), "--quiet"])
    assert rc == 2

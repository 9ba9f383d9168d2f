"""Linking by clicking (``resection link --serve``), tested in a real browser.

Debian's chromium, headless, driven by selenium through chromium-driver (``tools/setup.sh``
installs both, so ``.ci/run`` runs this test). The frame is the real-looking one of
:mod:`scenes.real_traits` (camera 0), the camera file an intrinsics-only uPSP file (an
internal calibration: no pose). The truth is the scene's: true target positions in the
image and the true camera.
"""

from __future__ import annotations

import csv
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from resection.io.cameras import read_camera, write_camera
from resection.markers.link_server import serve_links
from resection.markers.link_session import open_session
from scenes.real_traits import real_traits, write_scene

LINKED = ("T01", "T04", "T09", "T14", "T07")  # spread over the frame: a well-posed start


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    s = real_traits(scale=1.0)
    folder = tmp_path_factory.mktemp("link_page")
    paths = write_scene(s, folder)
    paths["intrinsics"] = str(folder / "internal.json")
    write_camera(paths["intrinsics"], s.cameras[0], format="upsp", intrinsics_only=True)
    return s, paths, folder


def _browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
              "--window-size=1400,900", "--no-first-run", "--disable-extensions"):
        opts.add_argument(a)
    service = Service(shutil.which("chromedriver") or "/usr/bin/chromedriver")
    return webdriver.Chrome(options=opts, service=service)


def _truth_candidates(session, scene_):
    """Candidate number of each target seen by camera 0 (nearest to its true position)."""
    uv = scene_.uv[0]
    d, j = cKDTree(session.candidates.uv).query(np.nan_to_num(uv, nan=-1e6))
    return {k: int(j[i]) for i, k in enumerate(scene_.marker_ids) if d[i] < 1.0}


@pytest.mark.slow  # 9 s; the page's plan test in Chromium stays in the default run
def test_link_page_in_chromium(scene, tmp_path):
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    s, paths, _ = scene
    out_links, out_cam, out_linked = (tmp_path / "links.csv", tmp_path / "camera.json",
                                      tmp_path / "linked.csv")
    session = open_session(paths["image0"], paths["markers"], paths["intrinsics"],
                           diameter=5.0, save_links=out_links, save_camera=out_cam,
                           save_linked=out_linked)
    assert not session.has_pose
    truth = _truth_candidates(session, s)
    assert set(LINKED) <= set(truth)
    server = serve_links(session)
    driver = _browser()
    # the page redraws its marks after each solve: an element found just before may be gone
    wait = WebDriverWait(driver, 20, ignored_exceptions=(StaleElementReferenceException,))
    clicks = 0
    try:
        driver.get(server.url)
        wait.until(lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-ready"))

        def settled(_d):
            return driver.find_element(By.TAG_NAME, "body").get_attribute("data-pending") == "0"

        def click(css):
            nonlocal clicks
            for attempt in range(3):  # found, then redrawn before the pointer got there
                try:
                    ActionChains(driver).move_to_element(
                        driver.find_element(By.CSS_SELECTOR, css)).click().perform()
                    break
                except StaleElementReferenceException:
                    if attempt == 2:
                        raise
            clicks += 1

        def read(css, what="class"):
            """An attribute (or the text) of the element now on the page."""
            def get(d):
                e = d.find_element(By.CSS_SELECTOR, css)
                return (e.text if what == "text" else e.get_dom_attribute(what)) or ""
            return wait.until(lambda d: (get(d),))[0]

        status = driver.find_element(By.ID, "status")
        for n, k in enumerate(LINKED, start=1):
            click(f'circle.cand[data-index="{truth[k]}"]')  # the candidate ...
            click(f'#targets li[data-id="{k}"]')  # ... then its target
            wait.until(settled)
            wait.until(lambda _d, n=n: status.text.startswith(f"{n} link(s)"))
            if n < 4:  # no pose before four links (no approximate pose here)
                assert "more for a pose" in status.text
                assert not driver.find_elements(By.CSS_SELECTOR, "#preds g.pred")
        assert "accepted" in status.get_attribute("class"), status.text
        assert not driver.find_element(By.ID, "save").get_attribute("disabled")
        # every other target in view is drawn where the pose predicts it
        preds = wait.until(lambda d: {e.get_attribute("data-id") for e in
                                      d.find_elements(By.CSS_SELECTOR, "#preds g.pred")})
        in_view = set(truth) - set(LINKED)
        assert in_view <= set(preds), sorted(in_view - set(preds))
        # each link shows its residual, none is rejected
        for k in LINKED:
            assert "linked" in read(f'#targets li[data-id="{k}"]')
            res = read(f'#targets li[data-id="{k}"] .res', "text")
            assert res.endswith(" px") and float(res.split()[0]) < 2.0
        # an offered candidate is linked with one click, and undone from the keyboard
        offered = driver.find_elements(By.CSS_SELECTOR, "#offers circle.offer-hit")
        assert len(offered) >= len(in_view) - 2
        k6 = next(iter(sorted(in_view)))
        click(f'#offers circle.offer-hit[data-offer="{k6}"]')
        wait.until(settled)
        assert "linked" in read(f'#targets li[data-id="{k6}"]')
        assert read(f'#targets li[data-id="{k6}"] .state', "text") == f"#{truth[k6]}"
        ActionChains(driver).send_keys("u").perform()
        wait.until(settled)
        wait.until(lambda _d: status.text.startswith(f"{len(LINKED)} link(s)"))
        wait.until(lambda d: "linked" not in d.find_element(
            By.CSS_SELECTOR, f'#targets li[data-id="{k6}"]').get_attribute("class"))
        # next target from the keyboard, then its candidate; delete it from the keyboard
        first_free = next(k for k in s.marker_ids if k not in LINKED)
        ActionChains(driver).send_keys("n").perform()
        wait.until(lambda d: "selected" in d.find_element(
            By.CSS_SELECTOR, f'#targets li[data-id="{first_free}"]').get_attribute("class"))
        click(f'circle.cand[data-index="{truth[first_free]}"]')
        wait.until(settled)
        wait.until(lambda _d: status.text.startswith(f"{len(LINKED) + 1} link(s)"))
        click(f'#targets li[data-id="{first_free}"]')
        ActionChains(driver).send_keys("\ue017").perform()  # the Delete key
        wait.until(settled)
        wait.until(lambda _d: status.text.startswith(f"{len(LINKED)} link(s)"))
        shot = tmp_path / "link_page.png"
        driver.save_screenshot(str(shot))
        # zoom (wheel), pan (drag) and the contrast stretch; then fit the frame again
        from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
        from selenium.webdriver.common.keys import Keys

        def view_box():
            return [float(x) for x in read("#frame", "viewBox").split()]

        vb0 = view_box()
        assert vb0 == [-0.5, -0.5, 320.0, 240.0]
        frame = driver.find_element(By.ID, "frame")
        ActionChains(driver).scroll_from_origin(ScrollOrigin.from_element(frame), 0, -300) \
            .perform()
        wait.until(lambda _d: view_box()[2] < 0.9 * vb0[2])
        vb1 = view_box()
        assert vb1[3] / vb1[2] == pytest.approx(0.75)  # the aspect kept
        ActionChains(driver).move_to_element(frame).click_and_hold().move_by_offset(120, 0) \
            .release().perform()
        wait.until(lambda _d: view_box()[0] < vb1[0] - 1.0)  # dragged right: view moves left
        assert view_box()[1] == pytest.approx(vb1[1]) and view_box()[2] == vb1[2]
        href = read("#img", "href")
        driver.find_element(By.ID, "lo").send_keys(Keys.ARROW_RIGHT * 20)
        wait.until(lambda _d: read("#img", "href") != href)
        click("#status")  # away from the slider, so that the keys reach the page
        ActionChains(driver).send_keys("f").perform()
        wait.until(lambda _d: view_box() == vb0)
        click("#save")
        wait.until(lambda d: "saved" in d.find_element(By.ID, "saved").text)
    finally:
        driver.quit()
        server.shutdown()
        server.server_close()
    # + one offer, next target's candidate, its target (to delete), the status line, save
    assert clicks == 2 * len(LINKED) + 5
    # the screenshot is kept as an artifact (pytest's tmp folder, and out/ when it exists)
    assert shot.stat().st_size > 10_000 and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    keep = Path(os.environ.get("LINK_PAGE_SCREENSHOT_DIR", "out"))
    if keep.is_dir():
        shutil.copy(shot, keep / "link_page.png")
    # the files pose --links and track read, against the truth
    with open(out_links, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["id", "candidate"]
    assert {(k, int(c)) for k, c in rows[1:]} == {(k, truth[k]) for k in LINKED}
    cam, true = read_camera(out_cam), s.cameras[0]
    angle = np.degrees(Rotation.from_matrix(cam.R @ true.R.T).magnitude())
    assert angle < 0.5
    dist = np.linalg.norm(true.center - s.markers.mean(axis=0))
    assert np.linalg.norm(cam.center - true.center) < 0.02 * dist
    seen = np.array([s.marker_ids.index(k) for k in truth])
    err = np.linalg.norm(cam.project(s.markers[seen]) - s.uv[0][seen], axis=1)
    assert err.max() < 2.5, err  # survey errors are 0.5 to 1.5 px
    with open(out_linked, newline="") as fh:
        lk = {r["id"]: (float(r["u"]), float(r["v"])) for r in csv.DictReader(fh) if r["id"]}
    assert set(lk) == set(LINKED)


def _labels_cut(driver) -> list:
    """Labels of the frame that reach past the frame's area (under the side bar or off its
    left edge) while part of them is in it."""
    return driver.execute_script("""
        const v = document.getElementById('view').getBoundingClientRect();
        const cut = [];
        for (const t of document.querySelectorAll('#frame text.label')) {
          const r = t.getBoundingClientRect();
          if (r.width === 0 || r.right < v.left || r.left > v.right || r.bottom < v.top
              || r.top > v.bottom) continue;  // wholly outside: its point is not in view
          if (r.right > v.right + 0.5 || r.left < v.left - 0.5) cut.push(t.textContent);
        }
        return cut;""")


@pytest.mark.parametrize("size", [(1600, 1000), pytest.param((1366, 768),
                                                               marks=pytest.mark.slow)])
def test_link_page_plan_labels_status_and_save_and_quit(scene, tmp_path, size):
    """Issue 34 item 10: a plan turned before the pose stayed turned under 'as the camera
    sees them'; labels at the right edge were cut off by the side bar; the status line
    scrolled out of view with the target list; the server ran on after Save."""
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    s, paths, _ = scene
    session = open_session(paths["image0"], paths["markers"], paths["intrinsics"],
                           diameter=5.0, save_links=tmp_path / "links.csv",
                           save_camera=tmp_path / "camera.json")
    truth = _truth_candidates(session, s)
    server = serve_links(session)
    driver = _browser()
    wait = WebDriverWait(driver, 20, ignored_exceptions=(StaleElementReferenceException,))
    try:
        driver.set_window_size(*size)
        driver.get(server.url)
        wait.until(lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-ready"))
        src = driver.find_element(By.ID, "plan-source")
        for _ in range(2):  # the plan turned by 180 degrees before the pose
            driver.find_element(By.ID, "rotate").click()
        assert "turned by 180 deg" in src.text

        def settled(d):
            return d.find_element(By.TAG_NAME, "body").get_attribute("data-pending") == "0"

        def click(css):
            for attempt in range(5):  # found, then redrawn before the pointer got there
                try:
                    ActionChains(driver).move_to_element(
                        driver.find_element(By.CSS_SELECTOR, css)).click().perform()
                    return
                except StaleElementReferenceException:
                    if attempt == 4:
                        raise

        for k in LINKED:
            click(f'circle.cand[data-index="{truth[k]}"]')
            click(f'#targets li[data-id="{k}"]')
            wait.until(settled)
        status = driver.find_element(By.ID, "status")
        wait.until(lambda _d: "accepted" in status.get_attribute("class"))
        # the plan as the camera sees it, not turned: its dots in the order of the
        # targets' true image positions
        assert src.text == "as the camera sees them"
        dots = {e.get_attribute("data-id"): (float(e.get_attribute("cx")),
                                             float(e.get_attribute("cy")))
                for e in driver.find_elements(By.CSS_SELECTOR, "#plan circle.plan-dot")}
        ids = [k for k in truth if k in dots]
        uv = np.array([s.uv[0][s.marker_ids.index(k)] for k in ids])
        xy = np.array([dots[k] for k in ids])
        assert np.corrcoef(xy[:, 0], uv[:, 0])[0, 1] > 0.95
        assert np.corrcoef(xy[:, 1], uv[:, 1])[0, 1] > 0.95
        # a linked candidate dragged to the right edge of the frame's area: its label
        # turns to its left, inside; so do the others
        view = driver.find_element(By.ID, "view").rect
        k = max(LINKED, key=lambda j: s.uv[0][s.marker_ids.index(j)][0])
        circ = driver.find_element(By.CSS_SELECTOR, f'circle.cand[data-index="{truth[k]}"]')
        cx = circ.rect["x"] + circ.rect["width"] / 2
        dx = int(view["x"] + view["width"] - 12 - cx)
        frame = driver.find_element(By.ID, "frame")
        ActionChains(driver).move_to_element(frame).click_and_hold().move_by_offset(dx, 0) \
            .release().perform()
        wait.until(lambda d: abs(d.find_element(
            By.CSS_SELECTOR, f'circle.cand[data-index="{truth[k]}"]').rect["x"] - cx - dx)
            < 20)
        assert _labels_cut(driver) == []
        # the status line stays in view when the list is scrolled to its last target
        click("#targets li:last-child")
        aside = driver.execute_script("return document.querySelector('aside').scrollTop")
        assert aside > 0  # the list did scroll
        top = driver.execute_script(
            "return document.getElementById('status').getBoundingClientRect().top")
        assert 0 <= top < 40
        # Save and quit: the files are written and the server stops
        driver.execute_script("document.querySelector('aside').scrollTop = 0")
        wait.until(lambda d: d.find_element(By.ID, "save-quit").is_enabled())
        driver.find_element(By.ID, "save-quit").click()
        wait.until(lambda d: "the server has stopped" in d.find_element(By.ID, "saved").text)
        assert driver.find_element(By.ID, "save").get_attribute("disabled")
        WebDriverWait(driver, 10).until(lambda _d: server.saved_and_quit)
    finally:
        driver.quit()
        server.shutdown()
        server.server_close()
    assert (tmp_path / "links.csv").is_file() and (tmp_path / "camera.json").is_file()

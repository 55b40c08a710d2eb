"""A real browser on the annotate page: headless Chromium from the system's packages, driven by playwright.

It clicks the synthetic vehicle's parts where they appear on its rendered image (named ones by hotkey, then
unnamed ones left to auto-naming), and checks the cuboid and the saved file; on a sequence, it confirms a track's
predicted cuboid and draws another's box. Skipped, saying why, where
playwright or the browser is missing (``pip install '.[browser]'`` and ``apt-get install chromium``).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.web.conftest import make_session
from tests.web.synthetic import NAMED, R_CAM_VEHICLE, UNNAMED, clicks, sequence_pose, write_sequence
from toosicubix.annotations.convert import load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.geometry import geodesic_angle
from toosicubix.parts.synthesis import PartSpec
from toosicubix.web.server import serve_in_thread
from toosicubix.web.session import Session, load_cameras

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]
#: The hotkey the page gives each part the test names (app.js HOTKEYS).
KEYS = {"wheel-front-left": "1", "wheel-rear-left": "3", "front": "l", "edge-front-left": "5", "front-center": "c",
        "wheel-front-right": "2"}


@pytest.fixture
def page():
    playwright_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed "
                                         "(pip install '.[browser]'): the browser test is skipped")
    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (apt-get install chromium): the browser test is skipped")
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1700, "height": 700})
        try:
            yield page
        finally:
            browser.close()


def _screen(page, uv: list[float]) -> tuple[float, float]:
    """Page coordinates of an image pixel, from the page's own zoom and pan."""
    zoom, pan_x, pan_y = page.evaluate("[state.zoom, state.panX, state.panY]")
    box = page.locator("#canvas").bounding_box()
    return box["x"] + pan_x + uv[0] * zoom, box["y"] + pan_y + uv[1] * zoom


def _wait_revision(page, revision: int) -> None:
    page.wait_for_function(f"state.revision >= {revision}", timeout=20000)


def _choose_and_click(page, c, revision: int) -> None:
    """Choose the name of ``c`` first (Esc: no click being named, then its key), click its points, wait for
    ``revision``."""
    page.keyboard.press("Escape")
    page.keyboard.press(KEYS[c.name])
    for uv in c.uv:
        page.mouse.click(*_screen(page, uv))
    _wait_revision(page, revision)


def _open_zoomed_in(page, url: str) -> None:
    """Open the page and zoom in on the synthetic vehicle (the page's mouse wheel does this; set here exactly):
    mouse positions are whole CSS pixels, so at zoom 3 a click lands within 0.17 image pixels of the part."""
    page.goto(url)
    page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
    page.evaluate("() => { const r = canvas.getBoundingClientRect(); state.zoom = 3; "
                  "state.panX = r.width / 2 - 3 * 700; state.panY = r.height / 2 - 3 * 270; render(); }")


def test_click_a_vehicle_in_the_browser(page, scene, tmp_path: Path):
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        # Six named parts: with the minimal five (six constraints) clicks half a pixel off leave the fit degenerate.
        named, unnamed = clicks(NAMED) + clicks(UNNAMED)[:1], clicks(UNNAMED)[1:]
        revision = 0
        for c in named:
            page.keyboard.press(KEYS[c.name])
            for uv in c.uv:
                page.mouse.click(*_screen(page, uv))
            revision += 1 + (revision == 0)  # the first click also adds the vehicle
            _wait_revision(page, revision)
        assert "yaw" in page.locator("#fit").inner_text(), page.locator("#fit").inner_text()
        for c in unnamed:
            page.keyboard.press("Escape")
            page.mouse.click(*_screen(page, c.uv[0]))
            revision += 1
            _wait_revision(page, revision)
            assert f"the page named it {c.name}, from the fit" in page.locator("#message").inner_text()
        page.wait_for_timeout(200)
        page.screenshot(path=str(tmp_path / "annotate.png"))
        if os.environ.get("TOOSICUBIX_SCREENSHOT"):  # to look at: where to copy the screenshot
            shutil.copy(tmp_path / "annotate.png", os.environ["TOOSICUBIX_SCREENSHOT"])
        assert "well determined" in page.locator("#fit").inner_text()
        # The file the page saved: every part named as clicked, and `fit` reads it.
        vehicle = load_images(out)[0].vehicles[0]
        assert [p.name for p in vehicle.parts] == [c.name for c in named + unnamed]
        view = session.image_view(0)["vehicles"][0]["fit"]
        assert np.rad2deg(geodesic_angle(np.array(view["R_cam_vehicle"]), R_CAM_VEHICLE)) < 1.0
        # Undo by key takes the last click back, in the file too.
        page.keyboard.press("u")
        _wait_revision(page, revision + 1)
        assert len(load_images(out)[0].vehicles[0].parts) == len(NAMED) + len(UNNAMED) - 1
        # Drag the first click 12 screen pixels right: at zoom 3 it moves 4 image pixels, in the file too.
        x, y = _screen(page, named[0].uv[0])
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 6, y, steps=3)
        page.mouse.move(x + 12, y, steps=3)
        page.mouse.up()
        _wait_revision(page, revision + 2)
        moved = load_images(out)[0].vehicles[0].parts[0].uv[0]
        assert abs(moved[0] - named[0].uv[0][0] - 4.0) < 0.5 and abs(moved[1] - named[0].uv[0][1]) < 0.5
    finally:
        server.shutdown()
        server.server_close()


def test_a_click_waiting_for_a_name_is_asked_again_after_a_reload(page, scene, tmp_path: Path):
    """Issue 33 follow-up, friction 1: a click the page could not name, then the page reloaded. The page asks again
    for that click's name (the server keeps the unnamed click), and the key pressed next names it, not the next
    click (before, the prompt was gone and the key armed the next click)."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        first = clicks(NAMED)[0]
        page.mouse.click(*_screen(page, first.uv[0]))
        _wait_revision(page, 2)  # the vehicle, and its click
        assert page.evaluate("state.view.vehicles[0].parts[0].name") is None
        page.reload()
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.locator("#next-click").inner_text().startswith("Naming click 1:")
        assert page.locator("#message").inner_text().startswith("which part is click 1?")
        assert page.locator("#clicks li.naming").count() == 1
        page.keyboard.press(KEYS[first.name])
        _wait_revision(page, 3)
        assert page.evaluate("state.armed") is None
        (named,) = load_images(out)[0].vehicles[0].parts
        assert named.name == first.name and np.allclose(named.uv, first.uv, atol=0.5)
        assert page.locator("#message").inner_text() == f"click 1 named {first.name}"
    finally:
        server.shutdown()
        server.server_close()


def test_a_reload_opens_on_the_image_the_person_was_on(page, tmp_path: Path):
    """A newcomer reloaded on image 12 of 14 and the page opened on image 1, with nothing saying where their waiting
    click was. The tab now remembers its image across a reload."""
    paths, cameras = write_sequence(tmp_path, frames=3)
    session = Session(paths, tmp_path / "annotations.json", load_cameras(cameras, [p.stem for p in paths]),
                      load_priors())
    server = serve_in_thread(session)
    try:
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.evaluate("state.index") == 0
        page.keyboard.press("]")
        page.keyboard.press("]")
        page.wait_for_function("state.index === 2 && state.view !== null", timeout=20000)
        page.reload()
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.evaluate("state.index") == 2
        assert page.locator("#image-name").inner_text().startswith(paths[2].stem)
    finally:
        server.shutdown()
        server.server_close()


def test_a_named_click_on_top_of_another_is_added_not_taken_for_a_selection(page, scene, tmp_path: Path):
    """A newcomer pressed a part's key and clicked 3 px from a click already there: the press selected that click
    and the named click was lost, silently. With a name chosen first the press is that name's click; without one it
    selects, and says how to click beside it."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        first, second = clicks(NAMED)[0], clicks(NAMED)[1]
        page.keyboard.press(KEYS[first.name])
        page.mouse.click(*_screen(page, first.uv[0]))
        _wait_revision(page, 2)
        page.mouse.click(*_screen(page, first.uv[0]))  # nothing chosen: a selection, said so
        page.wait_for_timeout(200)
        assert page.evaluate("state.revision") == 2
        assert page.locator("#message").inner_text().startswith("click 1 selected: drag it to move it")
        page.keyboard.press(KEYS[second.name])
        x, y = _screen(page, first.uv[0])
        page.mouse.click(x + 2, y + 1)  # within the 7 px that select a click
        _wait_revision(page, 3)
        names = [p.name for p in load_images(out)[0].vehicles[0].parts]
        assert names == [first.name, second.name]
    finally:
        server.shutdown()
        server.server_close()


def test_selecting_and_renaming_a_click_say_what_is_happening_to_which_click(page, scene, tmp_path: Path):
    """A newcomer selected click 2 in the Clicks list while the message still spoke of click 6's name; in rename
    mode the message said Esc keeps the name while the Naming box said Esc names the next click."""
    out = tmp_path / "annotations.json"
    session = _session_with_named_clicks(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        page.locator("#clicks li").nth(1).click()
        assert page.locator("#message").inner_text().startswith("click 2 selected")
        page.keyboard.press("r")
        assert page.locator("#message").inner_text().startswith("rename click 2:")
        assert page.locator("#next-click").inner_text() == ("Renaming click 2: press a part's key, or choose below or "
                                                              "in the palette. Esc: keep its name.")
    finally:
        server.shutdown()
        server.server_close()


def test_clicks_the_page_names_on_the_way_are_said(page, scene, tmp_path: Path):
    """A newcomer's named click let the page place the vehicle and name a click that had waited, and the message
    said only "click 2 named rear-center". What the page named in the same edit is now said too."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        wheel, rear_wheel, lights, edge = (clicks(NAMED)[k] for k in (0, 1, 2, 3))
        for c, revision in ((wheel, 2), (edge, 3)):  # two clicks the page cannot name yet: both wait
            page.keyboard.press("Escape")
            page.mouse.click(*_screen(page, c.uv[0]))
            _wait_revision(page, revision)
        _choose_and_click(page, rear_wheel, 4)
        _choose_and_click(page, lights, 5)
        message = page.locator("#message").inner_text()
        assert message.startswith("symmetry front added (you chose the name first)"), message
        assert f"; the page named click 1 {wheel.name}" in message
        assert f"; the page named click 2 {edge.name}" in message
    finally:
        server.shutdown()
        server.server_close()


def _session_with_named_clicks(scene, out: Path) -> Session:
    """A session on the scene whose first image has vehicle 1 with every part of NAMED clicked and named."""
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    for c in clicks(NAMED):
        session.edit(0, {"revision": session.revision, "op": "add_click", "vehicle": "1", "kind": c.kind,
                         "name": c.name, "uv": c.uv})
    return session


def test_wheels_named_on_the_wrong_axles_get_their_banner(page, scene, tmp_path: Path):
    """Rule 29, the second newcomer session's first leftover: a car seen from its side with its front and rear wheels
    named the other way round. The page's banner says the wheels look named on the wrong axles, what front and rear
    are, and how to rename; the fit says implausible. Renaming one wheel to the other's name (r, then its key: the two
    names swap) takes the banner away."""
    from tests.scenes import random_scene

    scene_car = random_scene(np.random.default_rng(1), "side")  # the scenes' camera is the synthetic image's
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    swapped = {"wheel-front-right": "wheel-rear-right", "wheel-rear-right": "wheel-front-right"}
    for p in scene_car.parts:
        session.edit(0, {"revision": session.revision, "op": "add_click", "vehicle": "1", "kind": p.kind,
                         "name": swapped.get(p.name, p.name), "uv": p.uv.tolist()})
    server = serve_in_thread(session)
    try:
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.locator("#banner").is_visible()
        text = page.locator("#banner").inner_text()
        assert text.startswith("The wheels look named on the wrong axles (the front axle comes out behind the rear "
                               "one: front and rear wheels look swapped).")
        assert "Front = the vehicle's own front, where its headlights are" in text
        assert "implausible" in page.locator("#fit").inner_text()
        page.screenshot(path=str(tmp_path / "axles.png"))
        if os.environ.get("TOOSICUBIX_SCREENSHOT"):
            shutil.copy(tmp_path / "axles.png", os.environ["TOOSICUBIX_SCREENSHOT"])
        page.locator("#clicks li").nth(0).click()  # the first click, named wheel-rear-right: give it its own name
        page.keyboard.press("r")
        page.keyboard.press("2")  # wheel-front-right, which the other wheel has: the names swap
        page.wait_for_function("!document.getElementById('banner').checkVisibility()", timeout=20000)
        assert [p.name for p in load_images(out)[0].vehicles[0].parts][:2] == ["wheel-front-right",
                                                                              "wheel-rear-right"]
    finally:
        server.shutdown()
        server.server_close()


def test_two_clicks_with_each_other_s_names_are_swapped_in_one_step(page, scene, tmp_path: Path):
    """Issue 33 follow-up, friction 2: the front wheels clicked with each other's names. Select one, r, the other's
    key: the two names swap in one edit (before, the name was refused as taken: four steps), and u swaps them
    back."""
    out = tmp_path / "annotations.json"
    session = _session_with_named_clicks(scene, out)
    names = [c.name for c in clicks(NAMED)]
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        revision = page.evaluate("state.revision")
        page.locator("#clicks li").nth(0).click()
        page.keyboard.press("r")
        page.keyboard.press(KEYS["wheel-rear-left"])
        _wait_revision(page, revision + 1)
        saved = [p.name for p in load_images(out)[0].vehicles[0].parts]
        assert saved == [names[1], names[0], *names[2:]]
        message = page.locator("#message").inner_text()
        assert message == (f"click 1 named {names[1]}; click 2, which had it, is now {names[0]} (names swapped: u "
                           "undoes)")
        page.keyboard.press("u")
        _wait_revision(page, revision + 2)
        assert [p.name for p in load_images(out)[0].vehicles[0].parts] == names
    finally:
        server.shutdown()
        server.server_close()


def test_the_message_never_describes_a_state_that_is_gone(page, scene, tmp_path: Path):
    """Issue 33 follow-up, friction 3: the message at the top after an undo, a delete and a frame change says what
    happened, or nothing, never what it said about the state before (it kept "which part is this?" after the click
    was undone, "... added" after the click was deleted, and both on the next image)."""
    image, cameras = scene
    second = image.with_name("car2.png")
    shutil.copy(image, second)
    out = tmp_path / "annotations.json"
    session = Session([image, second], out, load_cameras(cameras, ["car", "car2"]), load_priors())
    server = serve_in_thread(session)
    message = page.locator("#message")
    try:
        _open_zoomed_in(page, server.url)
        first = clicks(NAMED)[0]
        page.mouse.click(*_screen(page, first.uv[0]))
        _wait_revision(page, 2)
        assert message.inner_text().startswith("which part is click 1?")
        page.keyboard.press("u")
        _wait_revision(page, 3)
        assert message.inner_text() == "undone: the last change on this image is taken back (u again: the one before)"
        page.keyboard.press(KEYS[first.name])
        page.mouse.click(*_screen(page, first.uv[0]))
        _wait_revision(page, 4)
        assert message.inner_text() == f"{first.name} added (you chose the name first)"
        page.keyboard.press("Delete")
        _wait_revision(page, 5)
        assert message.inner_text() == f"click 1 ({first.name}) deleted: u brings it back"
        page.keyboard.press("u")
        _wait_revision(page, 6)
        page.keyboard.press("]")
        page.wait_for_function("state.view.index === 1 && state.image.complete", timeout=20000)
        assert message.inner_text() == ""
    finally:
        server.shutdown()
        server.server_close()


def test_clicks_are_counted_one_way_and_numbered_from_one(page, scene, tmp_path: Path):
    """Issue 33 follow-up, friction 4: the page counts a vehicle's clicks one way, the entries of its Clicks list (a
    pair's two points are one click; before: "clicks" in the list, "clicked points" in the fit, "named parts" in
    the hint), and numbers them from 1 for people (before: from 0), wherever it names one."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    first, _, pair = clicks(NAMED)[:3]
    session.edit(0, {"revision": 1, "op": "add_click", "vehicle": "1", "uv": first.uv})
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        assert page.locator("#vehicles li").inner_text() == "1 Car: 1 click (1 waiting for a name), not fitted yet"
        assert page.locator("#next-click").inner_text().startswith("Naming click 1:")
        assert page.locator("#choices").inner_text().startswith("Click 1 may be:")
        assert page.evaluate("document.getElementById('clicks').start") == 1
        assert page.locator("#fit").inner_text().startswith("not fitted yet: 1 click waiting for a name")
        _choose_and_click(page, pair, 3)
        fit = page.locator("#fit").inner_text()
        assert re.search(r"[12] named clicks? cannot place a cuboid yet; click at least \d+ more \(the wheels",
                         fit), fit
        assert "point" not in fit and "part" not in fit, fit
        assert page.locator("#vehicles li").inner_text().startswith("1 Car: 2 clicks")
    finally:
        server.shutdown()
        server.server_close()


def test_the_message_keeps_room_to_be_read_on_a_narrow_window(page, scene, tmp_path: Path):
    """A newcomer's window 1000 px wide showed no message at all (the header's buttons left it 0 px), and at 1280 px
    with a sequence's buttons it was cut to a few words. The message now takes a row of its own where it would be
    narrower than 320 px, and the image below does not move when it changes."""
    out = tmp_path / "annotations.json"
    session = _session_with_named_clicks(scene, out)
    server = serve_in_thread(session)
    try:
        page.set_viewport_size({"width": 1000, "height": 700})
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        page.evaluate("say('short')")
        top = page.evaluate("canvas.getBoundingClientRect().top")
        page.evaluate("say('a long message about the click that waits for a name, which the person must read whole "
                      "to know what the next key does, and then some more words so that it needs two lines')")
        assert page.evaluate("document.getElementById('message').getBoundingClientRect().width") >= 320
        assert page.evaluate("canvas.getBoundingClientRect().top") == top
    finally:
        server.shutdown()
        server.server_close()


def test_a_wide_image_fills_the_canvas_width_and_labels_do_not_overlap(page, scene, tmp_path: Path):
    """Issue 33 follow-up, friction 5: a 1240 x 375 image fills the canvas's width when the page opens and again
    when the window changes size (before, it kept the zoom it opened with, a third of a larger window), until the
    person zooms. Every click of the selected vehicle is labelled with its name and no label overlaps another, a
    click's dot or a target's circle (before, the targets' labels were drawn first and hid the clicks' names)."""
    out = tmp_path / "annotations.json"
    session = _session_with_named_clicks(scene, out)
    server = serve_in_thread(session)
    fills = "Math.abs(state.zoom * state.view.size[0] - canvas.getBoundingClientRect().width) < 1"
    try:
        page.set_viewport_size({"width": 1000, "height": 700})
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.evaluate(fills)
        zoom = page.evaluate("state.zoom")
        page.set_viewport_size({"width": 1700, "height": 900})
        page.wait_for_function(fills, timeout=5000)
        assert page.evaluate("state.zoom") > 1.5 * zoom
        # Labels: zoomed in on the vehicle, where its clicks, targets and labels crowd.
        page.evaluate("() => { const r = canvas.getBoundingClientRect(); state.zoom = 1.5; state.fitted = false; "
                      "state.panX = r.width / 2 - 1.5 * 700; state.panY = r.height / 2 - 1.5 * 270; render(); }")
        vehicle = page.evaluate("state.view.vehicles[0]")
        assert vehicle["targets"], "the test needs targets beside the clicks"
        labels = page.evaluate("state.labels")
        texts = [entry["text"] for entry in labels]
        assert all((p["name"] if p["kind"] == "point" else f"{p['name']} {p['kind']}") in texts
                   for p in vehicle["parts"]), texts
        boxes = [entry["box"] for entry in labels]

        def overlap(a, b):
            return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]

        assert not any(overlap(a, b) for k, a in enumerate(boxes) for b in boxes[k + 1:]), labels
        zoom, pan_x, pan_y = page.evaluate("[state.zoom, state.panX, state.panY]")
        points = [uv for p in vehicle["parts"] for uv in p["uv"]] + [uv for t in vehicle["targets"] for uv in t["uv"]]
        for u, v in points:
            x, y = pan_x + u * zoom, pan_y + v * zoom
            assert not any(overlap(b, [x - 4, y - 4, 8, 8]) for b in boxes), (u, v, labels)
        # Zoomed by the person: the zoom stays when the window changes.
        page.set_viewport_size({"width": 1500, "height": 900})
        page.wait_for_timeout(200)
        assert page.evaluate("state.zoom") == 1.5
    finally:
        server.shutdown()
        server.server_close()


#: A car's rear seen from behind at 14 m, every rear part clicked: ten clicks within some 150 x 80 px at zoom 1.
_CROWDED_REAR = [PartSpec("point", name) for name in ("wheel-rear-left", "wheel-rear-right", "corner-top-rear-left",
                                                     "corner-top-rear-right", "corner-bottom-rear-left",
                                                     "corner-bottom-rear-right")] + [
    PartSpec("point", name, {"Z": 0.75}) for name in ("edge-rear-left", "edge-rear-right", "rear-center")] + [
    PartSpec("symmetry", "rear", {"Y": 0.65, "Z": 0.8})]


@pytest.mark.parametrize("zoom", [0.3, 0.8, 1.0, 1.5])
def test_a_crowded_rear_view_labels_every_click_beside_its_own_dot_or_joined_to_it(page, scene, tmp_path: Path,
                                                                                  zoom: float):
    """The last stops' leftover: on a crowded rear view, some clicks' names were left out (none of the four places
    beside the dot was free) and some sat nearer to another dot than to their own. Now every click of the selected
    vehicle is named; a name beside its dot has no other mark nearer to it, and a name placed farther out is joined to
    its own dot by a line; no name overlaps another or a mark. At zoom 0.3 (the clicks within some 45 x 25 px) some
    lines have to cross other dots (the test fails without that), never another name."""
    from toosicubix.geometry import R_cam_vehicle_from_ypr

    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    for c in clicks(_CROWDED_REAR, R_cam_vehicle_from_ypr(-np.pi / 2 + 0.25), np.array([0.5, 1.65, 14.0])):
        session.edit(0, {"revision": session.revision, "op": "add_click", "vehicle": "1", "kind": c.kind,
                         "name": c.name, "uv": c.uv})
    server = serve_in_thread(session)
    try:
        page.set_viewport_size({"width": 1400, "height": 800})
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        vehicle = page.evaluate("state.view.vehicles[0]")
        uv = np.array([u for p in vehicle["parts"] for u in p["uv"]])
        page.evaluate(f"() => {{ const r = canvas.getBoundingClientRect(); state.zoom = {zoom}; state.fitted = false; "
                      f"state.panX = r.width / 2 - {zoom * uv[:, 0].mean()}; "
                      f"state.panY = r.height / 2 - {zoom * uv[:, 1].mean()}; render(); }}")
        labels = {entry["text"]: entry for entry in page.evaluate("state.labels")}
        z, pan_x, pan_y = page.evaluate("[state.zoom, state.panX, state.panY]")
        marks = {(p["name"] if p["kind"] == "point" else f"{p['name']} {p['kind']}"):
                 [(pan_x + u * z, pan_y + v * z) for u, v in p["uv"]] for p in vehicle["parts"]}
        marks_all = [m for own in marks.values() for m in own] + [
            (pan_x + u * z, pan_y + v * z) for t in vehicle["targets"] for u, v in t["uv"]]

        def distance(box, x, y):
            return float(np.hypot(max(box[0] - x, 0, x - box[0] - box[2]), max(box[1] - y, 0, y - box[1] - box[3])))

        def overlap(a, b):
            return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]

        assert set(marks) <= set(labels), sorted(set(marks) - set(labels))
        joined = 0
        for text, own in marks.items():
            entry = labels[text]
            box, point = entry["box"], entry["point"]
            assert np.allclose(point, own[0], atol=1e-6), (text, point, own[0])
            if entry["leader"] is not None:  # farther out: the line ends on the name's box
                joined += 1
                assert distance(box, *entry["leader"]) < 1e-6, entry
                continue
            mine = distance(box, *own[0])
            others = [distance(box, x, y) for x, y in marks_all
                      if min(np.hypot(x - ox, y - oy) for ox, oy in own) > 0.5]
            assert mine < min(others), (text, mine, min(others))
        boxes = [entry["box"] for entry in labels.values()]
        assert not any(overlap(a, b) for k, a in enumerate(boxes) for b in boxes[k + 1:]), labels
        for x, y in marks_all:
            assert not any(overlap(b, [x - 4, y - 4, 8, 8]) for b in boxes), (x, y)
        if zoom < 1.5:
            assert joined, "at this zoom some names need a line (the test should crowd them)"
    finally:
        server.shutdown()
        server.server_close()


def test_a_lamp_named_alone_is_told_that_lights_are_a_pair(page, scene, tmp_path: Path):
    """Issue 33 follow-up: the vocabulary has no single lamp (lights are the symmetry pair). A click waiting for a
    name given the front lights' key is not renamed nor left: the page says lights are clicked as a pair, both
    lamps, and how (before, the key silently armed the next two clicks and the waiting click lost its prompt)."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    wheel, pair = clicks(NAMED)[0], clicks(NAMED)[2]
    session.edit(0, {"revision": 1, "op": "add_click", "vehicle": "1", "uv": wheel.uv})
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        page.keyboard.press(KEYS["front"])
        assert page.locator("#message").inner_text() == (
            "Lights are clicked as a pair, both lamps: press Esc, then l, and click the vehicle's left one, then its "
            "right. Click 1 still waits for a name of one click (its key), or Delete it.")
        assert page.evaluate("[state.armed, state.naming]") == [None, 0]
        assert "(both lights)" in page.locator("#palette").inner_text()
        page.keyboard.press("Escape")
        page.keyboard.press(KEYS["front"])
        for uv in pair.uv:
            page.mouse.click(*_screen(page, uv))
        _wait_revision(page, 3)
        assert ("symmetry", "front") in [(p.kind, p.name) for p in load_images(out)[0].vehicles[0].parts]
    finally:
        server.shutdown()
        server.server_close()


def test_two_pages_on_one_file_keep_every_click(page, scene, tmp_path: Path):
    """Page B clicks on a stale revision after page A: the server refuses, B reloads and adds its click again."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session)
    other = page.context.browser.new_page(viewport={"width": 1700, "height": 700})
    try:
        for p in (page, other):
            p.goto(server.url)
            p.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        a, b = clicks(NAMED)[:2]
        page.keyboard.press(KEYS[a.name])
        page.mouse.click(*_screen(page, a.uv[0]))
        _wait_revision(page, 2)  # vehicle added, click added
        other.keyboard.press(KEYS[b.name])  # page B still shows revision 0 and no vehicle
        other.mouse.click(*_screen(other, b.uv[0]))
        # B's click first adds a vehicle (it sees none): refused as stale, B reloads, now sees A's vehicle and
        # adds its click to it.
        _wait_revision(other, 3)
        names = [[p.name for p in v.parts] for v in load_images(out)[0].vehicles]
        assert names == [[a.name, b.name]]
        assert f"{b.name} added" in other.locator("#message").inner_text()
    finally:
        other.close()
        server.shutdown()
        server.server_close()


def test_a_click_beside_the_image_is_not_sent(page, scene, tmp_path: Path):
    """Issue 34: a click on the grey area below the image (the whole image shown, 1240 x 375 px in a taller view) was
    sent and saved; now the page says it is outside the image and sends nothing. A box dragged past the image's edge
    is cut at it."""
    out = tmp_path / "annotations.json"
    server = serve_in_thread(make_session(scene, out))
    try:
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        x, y = _screen(page, [600.0, 375.0])
        page.mouse.click(x, y + 40)
        page.wait_for_function("document.querySelector('#message').textContent.includes('outside the image')",
                               timeout=20000)
        assert page.evaluate("state.revision") == 0 and not out.exists()
        page.keyboard.press("b")
        page.mouse.move(*_screen(page, [1000.0, 200.0]))
        page.mouse.down()
        page.mouse.move(*_screen(page, [1200.0, 420.0]), steps=3)  # below the image, on the canvas
        page.mouse.up()
        _wait_revision(page, 1)
        assert load_images(out)[0].vehicles[0].box2d.tolist() == pytest.approx([1000.0, 200.0, 1200.0, 375.0],
                                                                                 abs=1.0)
    finally:
        server.shutdown()
        server.server_close()


def test_a_second_server_on_the_file_is_refused_and_its_page_reloads_from_the_file(page, scene, tmp_path: Path):
    """Issue 34: two servers on one file. Page B's change after page A's is refused (409, nothing written); B's page
    shows a reload button, which reads the files as A left them; B's next click joins A's."""
    out = tmp_path / "annotations.json"
    server_a = serve_in_thread(make_session(scene, out))
    server_b = serve_in_thread(make_session(scene, out))
    other = page.context.browser.new_page(viewport={"width": 1700, "height": 700})
    try:
        for p, server in ((page, server_a), (other, server_b)):
            p.goto(server.url)
            p.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        a, b = clicks(NAMED)[:2]
        page.keyboard.press(KEYS[a.name])
        page.mouse.click(*_screen(page, a.uv[0]))
        _wait_revision(page, 2)
        on_disk = out.read_bytes()
        other.keyboard.press(KEYS[b.name])
        other.mouse.click(*_screen(other, b.uv[0]))
        other.wait_for_selector("#reload:not([hidden])", timeout=20000)
        assert "changed on disk" in other.locator("#message").inner_text()
        assert out.read_bytes() == on_disk
        other.click("#reload")
        other.wait_for_function("state.view.vehicles.length === 1 && state.view.vehicles[0].parts.length === 1",
                                timeout=20000)
        assert other.locator("#reload").is_hidden()
        other.keyboard.press(KEYS[b.name])
        other.mouse.click(*_screen(other, b.uv[0]))
        other.wait_for_function("state.view.vehicles[0].parts.length === 2", timeout=20000)
        assert [[p.name for p in v.parts] for v in load_images(out)[0].vehicles] == [[a.name, b.name]]
    finally:
        other.close()
        for server in (server_a, server_b):
            server.shutdown()
            server.server_close()


def test_click_keypoints_of_a_mapping_in_the_browser(page, scene, tmp_path: Path):
    """With a mapping, a keypoint is named by typing in the filter box and pressing Enter; an unnamed click is
    then named the nearest of the mapping's keypoints, and x takes the runner-up (a keypoint too)."""
    from tests.web.test_mapping import NAMED as KEYPOINTS
    from tests.web.test_mapping import _session, _uv

    out = tmp_path / "annotations.json"
    session = _session(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        assert page.locator("#keypoint-section").is_visible()
        revision = 0
        for name in KEYPOINTS:
            page.fill("#keypoint-filter", name.replace("-", " "))
            page.press("#keypoint-filter", "Enter")
            assert f"next click: {name} (you chose the name first)" in page.locator("#message").inner_text()
            page.mouse.click(*_screen(page, _uv(name)[0]))
            revision += 1 + (revision == 0)
            _wait_revision(page, revision)
        page.keyboard.press("Escape")
        page.mouse.click(*_screen(page, _uv("sill-left")[0]))
        _wait_revision(page, revision + 1)
        assert "the page named it sill-left" in page.locator("#message").inner_text()
        runner_up = page.evaluate("state.lastAuto.runner_up")
        page.keyboard.press("x")
        _wait_revision(page, revision + 2)
        parts = load_images(out)[0].vehicles[0].parts
        assert [(p.kind, p.name) for p in parts] == [("keypoint", n) for n in (*KEYPOINTS, runner_up)]
        assert session.image_view(0)["vehicles"][0]["fit"]["status"] == "ok"
    finally:
        server.shutdown()
        server.server_close()


def test_confirm_and_box_predictions_of_a_sequence_in_the_browser(page, tmp_path: Path):
    """A sequence of three frames, the first clicked (through the API): on the next frame the track is a dashed,
    predicted cuboid, selected; Enter confirms it and it is drawn solid, a vehicle of that track without clicks in the
    file. On the third frame the box tool draws the prediction's box: a vehicle of that track with a box only."""
    paths, cameras = write_sequence(tmp_path, frames=3)
    out = tmp_path / "annotations.json"
    session = Session(paths, out, load_cameras(cameras, [p.stem for p in paths]), load_priors(), sequence="0003")
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    for c in clicks([*NAMED, *UNNAMED], *sequence_pose(0)):
        session.edit(0, {"revision": session.revision, "op": "add_click", "vehicle": "1", "kind": c.kind,
                         "name": c.name, "uv": c.uv})
    server = serve_in_thread(session)
    try:
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.locator("#image-name").inner_text() == "sequence 0003, frame 0 (1 of 3)"
        assert page.evaluate("state.drawn") == [{"track": "0003-1", "vehicle": "1", "style": "solid"}]
        page.keyboard.press("]")
        page.wait_for_function("state.view.frame === 1 && state.image.complete", timeout=20000)
        assert page.locator("#image-name").inner_text() == "sequence 0003, frame 1 (2 of 3)"
        assert page.evaluate("state.drawn") == [{"track": "0003-1", "vehicle": None, "style": "dashed"}]
        assert page.evaluate("state.prediction") == "0003-1"  # a frame opens on its first prediction
        assert page.locator("#tracks").inner_text() == "0003-1 predicted"
        # Held from the one placed frame, it stands where that frame put it: the box comes first in what it says.
        hint = page.locator("#fit").inner_text()
        assert "held where frame 0 placed it: if it has moved since, b draws its box" in hint
        page.screenshot(path=str(tmp_path / "predicted.png"))
        if os.environ.get("TOOSICUBIX_SCREENSHOT"):  # to look at: where to copy the screenshot
            shutil.copy(tmp_path / "predicted.png", os.environ["TOOSICUBIX_SCREENSHOT"])
        revision = page.evaluate("state.revision")
        page.keyboard.press("Enter")
        _wait_revision(page, revision + 1)
        assert page.evaluate("state.drawn") == [{"track": "0003-1", "vehicle": "1", "style": "solid"}]
        assert page.locator("#tracks").inner_text() == "0003-1 interpolated"
        (confirmed,) = load_images(out)[1].vehicles
        assert confirmed.track == "0003-1" and confirmed.parts == () and confirmed.box2d is None
        # Frame 2: b, then drag the prediction's box.
        page.keyboard.press("]")
        page.wait_for_function("state.view.frame === 2 && state.image.complete", timeout=20000)
        assert page.evaluate("state.drawn") == [{"track": "0003-1", "vehicle": None, "style": "dashed"}]
        corners = np.array(page.evaluate("state.view.predictions[0].fit.corners_uv"))
        page.keyboard.press("b")
        page.mouse.move(*_screen(page, corners.min(axis=0).tolist()))
        page.mouse.down()
        page.mouse.move(*_screen(page, corners.max(axis=0).tolist()), steps=4)
        page.mouse.up()
        _wait_revision(page, revision + 2)
        (boxed,) = load_images(out)[2].vehicles
        assert boxed.track == "0003-1" and boxed.parts == () and boxed.box2d is not None
        assert page.evaluate("state.view.vehicles[0].fit.pose_from") == "box"
        assert page.evaluate("state.drawn") == [{"track": "0003-1", "vehicle": "1", "style": "solid"}]
    finally:
        server.shutdown()
        server.server_close()


# -- the newcomer (issue 33, item 6) ------------------------------------------------------------------------------

#: The part's key on the page (app.js HOTKEYS), for naming a click the page asks about or named wrong.
NEWCOMER_KEYS = {"wheel-front-left": "1", "wheel-front-right": "2", "wheel-rear-left": "3", "wheel-rear-right": "4",
                 "edge-front-left": "5", "edge-front-right": "6", "edge-rear-left": "7", "edge-rear-right": "8",
                 "front-center": "c", "rear-center": "v", "top-center": "t"}
#: Where a newcomer clicks on each kind of part: edges at 60 % of the height, badges at 40 %, the roof's centre a
#: little behind the middle (as the vocabulary's typical places); wheels where they touch the road.
NEWCOMER_AUX = {"edge": {"Z": 0.6}, "end-center": {"Z": 0.4}, "top-center": {"X": -0.1}}
#: The line colours app.js draws a selected vehicle's cuboid in (RGB): its sides (a track-less vehicle's colour,
#: trackColour(null)) and its front face.
SIDE_RGB, FRONT_RGB = (0x38, 0xD9, 0xFF), (0xFF, 0x50, 0x50)


def _newcomer_scene(tmp_path: Path):
    """A KITTI image with its calib file and a car's ground truth (object benchmark image 000008, the car 7.9 m away
    facing the camera: its left is on the image's right), when the shared data is there; else the synthetic car's
    rendered image. Returns (image, cameras file, R_cam_vehicle, t_cam_vehicle, dimensions, what it is)."""
    from tests.conftest import shared_data_dir
    from tests.web.synthetic import DIMENSIONS, T_CAM_VEHICLE, write_scene
    from toosicubix.formats.kitti import read_label_file
    from toosicubix.geometry import R_cam_vehicle_from_ypr

    kitti = shared_data_dir() / "kitti"
    if (kitti / "image_2" / "000008.png").is_file():
        calib = kitti / "calib" / "000008.txt"
        camera = load_cameras(calib, ["000008"])["000008"]
        car = read_label_file(kitti / "label_2" / "000008.txt")[1]
        return (kitti / "image_2" / "000008.png", calib, R_cam_vehicle_from_ypr(car.rotation_y),
                car.t_cam_vehicle(camera.t_cam_rect), np.asarray(car.dimensions, dtype=float), "KITTI 000008")
    image, cameras = write_scene(tmp_path)
    return image, cameras, R_CAM_VEHICLE, T_CAM_VEHICLE, DIMENSIONS, "synthetic"


def _newcomer_clicks(camera, R, t, d) -> list:
    """The point parts on the faces turned to the camera, in the order a newcomer clicks them (wheels, then the
    front or rear badge, the edges, the roof), at their typical places on the true cuboid."""
    from toosicubix import vocabulary
    from toosicubix.parts.synthesis import PartSpec, render_parts

    seen = vocabulary.faces_seen_from(-R.T @ t, d)
    names = [n for n in NEWCOMER_KEYS if any(seen[f] for f in vocabulary.entry("point", n).faces)]
    specs = []
    for name in names:
        aux = NEWCOMER_AUX.get(vocabulary.entry("point", name).get("shape"), {})
        specs.append(PartSpec("point", name, {k: v * d[2 if k == "Z" else 0] for k, v in aux.items()}))
    return render_parts(specs, R, t, d, camera, (0.3 * d[0], -0.3 * d[0]))


def _cuboid_pixels(page, shot: Path, corners_uv: list, front_face: list) -> float:
    """The share of points along the cuboid's 12 edges (20 to 80 % of each, inside the canvas) at which the
    screenshot ``shot`` has the edge's colour within a 5 x 5 pixel window (each channel within 40 of it: the lines
    are anti-aliased and drawn over the photo)."""
    import cv2

    image = cv2.imread(str(shot))[..., ::-1].astype(int)  # RGB
    box = page.locator("#canvas").bounding_box()
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    hits = total = 0
    for i, j in edges:
        colour = np.array(FRONT_RGB if i in front_face and j in front_face else SIDE_RGB)
        for s in np.linspace(0.2, 0.8, 7):
            x, y = _screen(page, (1 - s) * np.asarray(corners_uv[i]) + s * np.asarray(corners_uv[j]))
            inside = (box["x"] + 3 <= x < box["x"] + box["width"] - 3
                      and box["y"] + 3 <= y < box["y"] + box["height"] - 3)
            if not inside:
                continue
            window = image[int(y) - 2:int(y) + 3, int(x) - 2:int(x) + 3]
            total += 1
            hits += bool(np.any(np.all(np.abs(window - colour) <= 40, axis=-1)))
    assert total >= 40, f"only {total} edge points inside the canvas"
    return hits / total


def test_a_newcomer_clicks_a_car_sees_its_cuboid_and_the_swapped_sides_banner(page, tmp_path: Path):
    """Issue 33 item 6. A newcomer opens the page on a KITTI image and clicks the car's parts without naming them
    first (the README: "about ten clicks on vehicle parts"): the page asks what the first click is (nothing places
    the car yet), the newcomer presses its key on the parts diagram, and the page names the later clicks itself (a
    wrong name is renamed: r, then the key). The cuboid is drawn, within 5 degrees and 10 % of the depth of KITTI's
    ground truth (the benchmark's "right"), and its edges are in the screenshot's pixels. Pressing s swaps left and
    right: the banner names the likely cause and the fix; u takes the swap back and the banner goes."""
    image, cameras, R, t, d, what = _newcomer_scene(tmp_path)
    camera = load_cameras(cameras, [image.stem])[image.stem]
    out = tmp_path / "annotations.json"
    session = Session([image], out, {image.stem: camera}, load_priors())
    server = serve_in_thread(session)
    try:
        page.goto(server.url)
        page.wait_for_function("state.view !== null && state.image.complete", timeout=20000)
        assert page.locator("#next-click").inner_text().startswith("Next click: click first, the page names it")
        assert "left = the vehicle's left, as its driver sees it" in page.locator("aside").inner_text()
        page.screenshot(path=str(tmp_path / "before.png"))
        parts = _newcomer_clicks(camera, R, t, d)
        revision, named_by_page, renamed = 0, 0, []
        for k, part in enumerate(parts):
            page.mouse.click(*_screen(page, part.uv[0]))
            revision += 1 + (revision == 0)  # the first click also adds the vehicle
            _wait_revision(page, revision)
            given = page.evaluate(f"state.view.vehicles[0].parts[{k}]")
            if k == 0:  # nothing places the car yet: the page asks, offering the wheels
                assert given["name"] is None
                assert page.locator("#message").inner_text().startswith(f"which part is click {k + 1}?")
                assert page.locator("#next-click").inner_text().startswith(f"Naming click {k + 1}:")
                offered = page.locator("#choices button").all_inner_texts()
                assert any(o.startswith(part.name) for o in offered), offered
            elif given["name"] is not None:
                named_by_page += 1
                if given["name"] == part.name:
                    continue
                renamed.append((part.name, given["name"]))
                page.keyboard.press("r")
            page.keyboard.press(NEWCOMER_KEYS[part.name])
            revision += 1
            _wait_revision(page, revision)
        names = [p["name"] for p in page.evaluate("state.view.vehicles[0].parts")]
        assert names == [p.name for p in parts]
        # The newcomer named the first click and at most two more (asked, or named wrong): the page named the others
        # itself, right (of the 7 clicks after the first: on KITTI 6 named right and 1 asked; on the synthetic car 7
        # named, 1 of them wrong).
        asked = len(parts) - named_by_page
        assert asked + len(renamed) <= 3 and len(renamed) <= 1, (asked, renamed)
        fit = page.evaluate("state.view.vehicles[0].fit")
        assert fit["status"] == "ok" and fit["implausible"] is None
        yaw_error = abs((fit["yaw_pitch_roll_deg"][0] - np.rad2deg(np.arctan2(-R[2, 0], R[0, 0])) + 180) % 360 - 180)
        assert yaw_error < 5.0 and abs(fit["t_cam_vehicle"][2] / t[2] - 1) < 0.10, (what, fit)
        page.wait_for_timeout(200)
        page.screenshot(path=str(tmp_path / "newcomer.png"))
        if os.environ.get("TOOSICUBIX_SCREENSHOT"):  # to look at: where to copy the screenshot
            shutil.copy(tmp_path / "newcomer.png", os.environ["TOOSICUBIX_SCREENSHOT"])
        drawn = _cuboid_pixels(page, tmp_path / "newcomer.png", fit["corners_uv"], fit["front_face"])
        before = _cuboid_pixels(page, tmp_path / "before.png", fit["corners_uv"], fit["front_face"])
        print(f"{what}: edge colour at {drawn:.0%} of the cuboid's edge points, {before:.0%} before; asked {asked}, "
              f"renamed {renamed}")
        # Labels and the targets' dashed lines cover up to a quarter of the edge points (81 to 94 % found on the KITTI
        # and the synthetic image); the photo alone has the colours at none of them.
        assert drawn >= 0.7 and before <= 0.1, (drawn, before)
        # s: left and right swapped, the banner says so and how to fix it; u: back.
        page.keyboard.press("s")
        _wait_revision(page, revision + 1)
        assert page.locator("#banner").is_visible()
        text = page.locator("#banner").inner_text()
        assert text.startswith("Left and right look swapped.") and "Swap left and right (or press s)" in text
        assert "implausible" in page.locator("#fit").inner_text()
        page.screenshot(path=str(tmp_path / "swapped.png"))
        page.keyboard.press("u")
        _wait_revision(page, revision + 2)
        assert not page.locator("#banner").is_visible()
        assert [p.name for p in load_images(out)[0].vehicles[0].parts] == [p.name for p in parts]
    finally:
        server.shutdown()
        server.server_close()


def test_a_pedestrian_is_offered_its_keypoints_not_a_car_s_parts(page, scene, tmp_path: Path):
    """A newcomer who picks the Pedestrian prototype sees COCO's person keypoints to name clicks with, not the car's
    diagram and parts (whose keys say so instead of naming a wheel on a person); the named clicks fit the person."""
    from tests.web.synthetic import CAMERA
    from toosicubix.geometry import R_cam_vehicle_from_ypr
    from toosicubix.vocabulary import CLASSES

    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session)
    try:
        _open_zoomed_in(page, server.url)
        assert page.locator("#palette-section").is_visible() and not page.locator("#keypoint-section").is_visible()
        page.select_option("#prototype", "Pedestrian")
        assert page.locator("#keypoint-section").is_visible()
        assert page.locator("#keypoint-section h2").inner_text() == "Keypoints of a Pedestrian"
        assert not page.locator("#palette-section").is_visible() and not page.locator("#parts-section").is_visible()
        page.keyboard.press("1")
        assert "a Pedestrian is clicked on its keypoints" in page.locator("#message").inner_text()
        page.keyboard.press("n")
        _wait_revision(page, 1)
        hint = page.locator("#fit").inner_text()
        assert "A fit needs about 5 of its 17 keypoints, spread over the pedestrian" in hint
        # A person 1.75 m tall 8 m ahead, beside the car: nine keypoints from head to ankles, each named first.
        dims, R, t = np.array([0.8, 0.66, 1.75]), R_cam_vehicle_from_ypr(0.4), np.array([1.5, 1.65, 8.0])
        names = ("nose", "left_shoulder", "right_shoulder", "left_hip", "right_hip", "left_knee", "right_knee",
                 "left_ankle", "right_ankle")

        def pixel(name: str) -> list[float]:
            at = np.array(CLASSES["Pedestrian"].keypoints[name].at)
            return CAMERA.project((R @ (at * dims) + t)[None])[0].tolist()

        # A first click without a name waits (the page names a road user's clicks once its named ones fit) and is
        # named from the keypoints' filter box.
        page.mouse.click(*_screen(page, pixel(names[0])))
        _wait_revision(page, 2)
        assert ("which keypoint is click 1? The page names a Pedestrian's clicks once its named ones fit: choose it "
                "under Keypoints") in page.locator("#message").inner_text()
        page.fill("#keypoint-filter", names[0])
        page.press("#keypoint-filter", "Enter")
        revision = 3
        _wait_revision(page, revision)
        for name in names[1:]:
            uv = pixel(name)
            page.fill("#keypoint-filter", name.replace("_", " "))
            page.press("#keypoint-filter", "Enter")
            assert f"next click: {name} (you chose the name first)" in page.locator("#message").inner_text()
            page.mouse.click(*_screen(page, uv))
            revision += 1
            _wait_revision(page, revision)
        (person,) = load_images(out)[0].vehicles
        assert person.prototype == "Pedestrian" and [(p.kind, p.name) for p in person.parts] == [
            ("keypoint", n) for n in names]
        fit = session.image_view(0)["vehicles"][0]["fit"]
        # Clicks within 0.17 px of exact at zoom 3, the size prior pulling the scale: 0.42 deg here.
        assert fit["status"] == "ok" and np.rad2deg(geodesic_angle(np.array(fit["R_cam_vehicle"]), R)) < 1.0
    finally:
        server.shutdown()
        server.server_close()

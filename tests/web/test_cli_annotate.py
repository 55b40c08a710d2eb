"""``toosicubix annotate`` on the command line: bad input exits 2 naming the file and JSON path; good input serves
the page on 127.0.0.1 and prints its address."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from tests.web.synthetic import K
from toosicubix.cli import main
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.web.client import Client


def _run(*args: str):
    return CliRunner().invoke(main, ["annotate", *args])


def test_missing_image(tmp_path):
    result = _run(str(tmp_path / "nothing.png"), "--cameras", str(tmp_path / "c.json"))
    assert result.exit_code == 2
    assert f"no such image or folder: {tmp_path / 'nothing.png'}" in result.output


def test_bad_cameras_file_names_the_json_path(scene, tmp_path):
    image, _ = scene
    cameras = tmp_path / "bad.json"
    cameras.write_text(json.dumps({"car": {"K": [[720, 0, 620], [0, 720, 180], [0, 0, 2]]}}))
    result = _run(str(image), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2
    assert f"{cameras}: $[\"car\"].K" in result.output


def test_camera_missing_for_an_image(scene, tmp_path):
    image, _ = scene
    cameras = tmp_path / "other.json"
    cameras.write_text(json.dumps({"elsewhere.png": {"K": K.tolist()}}))
    result = _run(str(image), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2 and "no camera for image 'car'" in result.output


def test_no_cameras_for_a_new_image(scene, tmp_path):
    image, _ = scene
    result = _run(str(image), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2 and "no camera for this image: give --cameras" in result.output


def test_broken_annotation_file_is_refused(scene, tmp_path):
    image, cameras = scene
    out = tmp_path / "a.json"
    out.write_text('{"toosicubix": 1, "images": [{"id": "car", "camera": {"K": 3}}]}')
    result = _run(str(image), "--cameras", str(cameras), "-o", str(out))
    assert result.exit_code == 2 and f"{out}: $.images[0].camera.K" in result.output


def test_unknown_prototype(scene, tmp_path):
    image, cameras = scene
    result = _run(str(image), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"), "--prototype", "Boat")
    assert result.exit_code == 2 and "unknown prototype 'Boat'" in result.output


def test_serves_on_loopback_and_prints_the_address(scene, tmp_path):
    image, cameras = scene
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-m", "toosicubix", "annotate", str(image), "--cameras", str(cameras),
               "-o", str(tmp_path / "a.json"), "--port", "0"]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env) as process:
        try:
            line = process.stdout.readline()
            match = re.search(r"open http://(127\.0\.0\.1):(\d+)/", line)
            assert match, line
            status, doc = Client(match.group(1), int(match.group(2))).request("GET", "/api/session")
            assert status == 200 and doc["images"][0]["id"] == "car"
        finally:
            process.terminate()
            process.wait(timeout=30)
    assert not (tmp_path / "a.json").exists()  # nothing changed, nothing written
    assert Path(image).exists()


def test_image_name_that_is_no_image_id(tmp_path):
    image = tmp_path / "my car.png"
    image.write_bytes(b"")
    result = _run(str(image), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2 and "must make valid image ids" in result.output and "my car.png" in result.output


def test_unknown_prototype_in_the_file(scene, tmp_path):
    image, _ = scene
    out = tmp_path / "a.json"
    out.write_text(json.dumps({"toosicubix": 1, "images": [{"id": "car", "camera": {"K": K.tolist()}, "vehicles": [
        {"id": "1", "prototype": "Boat", "parts": []}]}]}))
    result = _run(str(image), "-o", str(out))
    assert result.exit_code == 2
    assert f"{out}: $.images[0].vehicles[0].prototype: unknown prototype 'Boat'" in result.output


def _ground_given(monkeypatch, scene, tmp_path, *options: str):
    """The ground block `annotate` hands the session with ``options`` (the session stops the command)."""
    from toosicubix.web import session
    from toosicubix.web.request_fields import ApiError

    given = {}

    class Recording:
        def __init__(self, *args, ground=None, **kwargs):
            given["ground"] = ground
            raise ApiError("stop here")

    monkeypatch.setattr(session, "Session", Recording)
    image, cameras = scene
    result = _run(str(image), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"), *options)
    assert result.exit_code == 2 and "stop here" in result.output, result.output
    return given["ground"]


def test_road_normal_and_camera_height_make_the_new_images_ground(monkeypatch, scene, tmp_path):
    assert _ground_given(monkeypatch, scene, tmp_path) is None
    assert _ground_given(monkeypatch, scene, tmp_path, "--road-normal", "0.04,-0.99,0.15").to_json() == {
        "normal": [0.04, -0.99, 0.15]}
    assert _ground_given(monkeypatch, scene, tmp_path, "--road-normal", "0,-1,0.1", "--camera-height",
                         "1.4").to_json() == {"normal": [0.0, -1.0, 0.1], "camera_height": 1.4}
    kitti = _ground_given(monkeypatch, scene, tmp_path, "--kitti-ground", "--camera-height", "1.8")
    assert kitti.camera_height == 1.8 and kitti.camera_height_sigma == 0.1 and kitti.normal == (0.0, -1.0, 0.0)


def test_a_bad_road_normal_is_refused(scene, tmp_path):
    image, cameras = scene
    for value, expected in (("1,2", "expected three numbers x,y,z"), ("0,0,0", "non-zero road normal"),
                            ("nan,1,0", "ground options")):
        result = _run(str(image), "--cameras", str(cameras), "--road-normal", value)
        assert result.exit_code == 2 and expected in result.output, (value, result.output)


def _served_session(monkeypatch, *args: str):
    """The session `annotate` would serve with ``args``, and what it said (serving is stopped)."""
    from toosicubix.web import server

    served = {}

    def record(session, host, port):
        served["session"] = session
        raise OSError("stop here")

    monkeypatch.setattr(server, "serve", record)
    result = _run(*args)
    assert result.exit_code == 2 and "stop here" in result.output, result.output
    return served["session"], result.output


def test_the_page_fits_the_files_vehicles_as_fit_does(monkeypatch, tmp_path):
    """With vehicles in the file, the page fits with the click noise and road normal `fit` estimates for it."""
    import cv2
    import numpy as np

    from tests.pipeline.test_road_normal import _pitched_batch
    from toosicubix.annotations.convert import document_json
    from toosicubix.pipeline.batch import fit_file

    out = tmp_path / "pitched.json"
    out.write_text(json.dumps(document_json(_pitched_batch(40, np.random.default_rng(8)))))
    fit_file(out, tmp_path / "fitted", BatchSettings(estimate_click_sigma=True, estimate_road_normal=True))
    fitted = json.loads((tmp_path / "fitted" / "results.json").read_text())
    image = tmp_path / "im000.png"
    cv2.imwrite(str(image), np.zeros((375, 1242, 3), np.uint8))

    session, said = _served_session(monkeypatch, str(image), "-o", str(out), "--port", "0")
    assert "click noise:" in said and "estimated from the residuals of 40 vehicles" in said
    assert "road normal of camera" in said
    assert session.options.click_sigma == fitted["settings"]["click_sigma"]
    view = session.image_view(0)["vehicles"][0]["fit"]
    # The same fit_one with the same settings and ground: the same bits.
    np.testing.assert_array_equal(view["R_cam_vehicle"], fitted["images"][0]["vehicles"][0]["R_cam_vehicle"])
    assert view["road"] == "estimated" and view["click_sigma_px"] == fitted["settings"]["click_sigma"]  # the page says
    assert json.loads(out.read_text()) == json.loads(out.read_text()) and "ground" not in json.loads(
        out.read_text())["images"][0]  # the estimate is the page's, never written to the file

    session, said = _served_session(monkeypatch, str(image), "-o", str(out), "--port", "0", "--road-normal", "none",
                                    "--click-sigma", "2")
    assert "click noise: 2 px (given); no road normal estimated" in said and "estimating" not in said
    assert session.options.click_sigma == 2.0
    plain = session.image_view(0)["vehicles"][0]["fit"]
    assert not np.array_equal(plain["R_cam_vehicle"], view["R_cam_vehicle"])
    assert plain["road"] is None and plain["click_sigma_px"] == 2.0


def test_a_new_file_is_fitted_with_the_default_click_noise(monkeypatch, scene, tmp_path):
    image, cameras = scene
    session, said = _served_session(monkeypatch, str(image), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"))
    assert "click noise: 1.5 px (default: no file yet to estimate it from); no road normal estimated" in said
    assert session.options.click_sigma == 1.5


def test_a_ground_option_gives_the_road_and_nothing_is_said_of_estimating_it(monkeypatch, scene, tmp_path):
    # A newcomer with --kitti-ground read "no road normal estimated yet": the ground option gives every image its
    # road, as in fit, so the page does not estimate one.
    image, cameras = scene
    session, said = _served_session(monkeypatch, str(image), "--cameras", str(cameras), "--kitti-ground", "-o",
                                    str(tmp_path / "a.json"))
    assert "the road as the ground options give it" in said and "no road normal" not in said
    assert ("the page estimates the click noise (for cuboid parts with how far they sit from the cuboid model) as "
            "`fit` does") in said
    assert session.image_view(0)["vehicles"] == [] and session.images[0].ground is not None


def test_the_page_estimates_again_as_the_file_grows(monkeypatch, tmp_path):
    """A file of 20 vehicles gives no road normal (30 needed); once it has 40 (written by another program and
    reloaded), the page estimates again, in the background, and fits as `fit` fits the 40-vehicle file."""
    import cv2
    import numpy as np

    from tests.pipeline.test_road_normal import _pitched_batch
    from toosicubix.annotations.convert import document_json
    from toosicubix.pipeline.batch import fit_file

    batch = _pitched_batch(40, np.random.default_rng(8))
    out = tmp_path / "pitched.json"
    out.write_text(json.dumps(document_json(batch[:20])))
    image = tmp_path / "im000.png"
    cv2.imwrite(str(image), np.zeros((375, 1242, 3), np.uint8))
    session, said = _served_session(monkeypatch, str(image), "-o", str(out), "--port", "0")
    assert "the pilot fitted at most 20 vehicles of each, 30 needed" in said
    assert session.image_view(0)["vehicles"][0]["fit"]["road"] is None

    out.write_text(json.dumps(document_json(batch)))
    fit_file(out, tmp_path / "fitted", BatchSettings(estimate_click_sigma=True, estimate_road_normal=True))
    fitted = json.loads((tmp_path / "fitted" / "results.json").read_text())
    session.reload()
    session.wait_for_estimates(60.0)
    view = session.image_view(0)["vehicles"][0]["fit"]
    assert view["road"] == "estimated" and view["click_sigma_px"] == fitted["settings"]["click_sigma"]
    np.testing.assert_array_equal(view["R_cam_vehicle"], fitted["images"][0]["vehicles"][0]["R_cam_vehicle"])
    assert session.estimate_again_if_grown() is False  # 40 is not twice 40


def test_the_page_estimates_again_when_the_vehicles_double(scene, tmp_path):
    """The rule, with a stand-in estimate: from 30 vehicles on, each time they double, up to the pilot's 400."""
    from dataclasses import replace

    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.solver.fit import SolverOptions
    from toosicubix.web.session import Session, load_cameras

    image, cameras = scene
    asked = []

    def estimate(path):
        asked.append(len(json.loads(path.read_text())["images"][0]["vehicles"]))  # the session's snapshot
        return replace(SolverOptions(), click_sigma=0.5 + len(asked)), None

    session = Session([image], tmp_path / "a.json", load_cameras(cameras, [image.stem]), load_priors(),
                      estimate=estimate)
    for _ in range(130):
        session.edit(0, {"revision": session.revision, "op": "add_vehicle"})
        session.wait_for_estimates(10.0)
    assert asked == [30, 60, 120]
    assert session.options.click_sigma == 3.5  # the last estimate's
    session._estimated_from = 400
    session.edit(0, {"revision": session.revision, "op": "add_vehicle"})
    assert session.estimate_again_if_grown() is False


def test_mapping_gives_the_page_its_keypoints(monkeypatch, scene, tmp_path):
    image, cameras = scene
    args = (str(image), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"))
    session, _ = _served_session(monkeypatch, *args, "--mapping", "apollocar3d-66")
    assert session.mapping.name == "apollocar3d-66" and len(session.summary()["keypoints"]) == 66
    result = _run(*args, "--mapping", "apollocar3d-66-paper")
    assert result.exit_code == 2
    assert "the mapping apollocar3d-66-paper has no keypoint parts" in result.output
    result = _run(*args, "--mapping", str(tmp_path / "none.json"))
    assert result.exit_code == 2 and "none.json" in result.output and "no such mapping file" in result.output


def _write_image(path: Path) -> None:
    cv2.imwrite(str(path), np.zeros((375, 1240, 3), np.uint8))


def test_a_folder_gives_its_images_sorted_and_a_calib_folder_their_cameras(monkeypatch, tmp_path):
    """Issue 33 item 5: ``annotate imgs/`` takes the folder's images (png, jpg, jpeg, bmp, webp in any case, not its
    subfolders, not other files) sorted by file name; ``--cameras calib/`` gives each its KITTI P2 by file stem."""
    from tests.formats.test_cameras import P2, _kitti_calib

    images, calib = tmp_path / "imgs", tmp_path / "calib"
    images.mkdir()
    calib.mkdir()
    (images / "sub").mkdir()
    for name in ("000010.jpeg", "000002.png", "000001.JPG", "sub/000003.png"):
        _write_image(images / name)
    (images / "readme.txt").write_text("not an image")
    for k, stem in enumerate(("000001", "000002", "000010")):
        P = P2.copy()
        P[0, 0] = P[1, 1] = 700.0 + k
        (calib / f"{stem}.txt").write_text(_kitti_calib(P))
    session, _ = _served_session(monkeypatch, str(images), "--cameras", str(calib), "-o", str(tmp_path / "a.json"))
    assert [im.path.name for im in session.images] == ["000001.JPG", "000002.png", "000010.jpeg"]
    assert [im.camera.K[0, 0] for im in session.images] == [700.0, 701.0, 702.0]
    # P2's fourth column: the camera 2 frame is 6 cm off KITTI's rectified camera 0, as fit reads it.
    assert abs(session.images[0].camera.t_cam_rect[0] - 721.5 * 0.06 / 700.0) < 1e-12


def test_a_calib_folder_without_an_images_file_names_it(tmp_path):
    from tests.formats.test_cameras import _kitti_calib

    _write_image(tmp_path / "000001.png")
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "000002.txt").write_text(_kitti_calib())
    result = _run(str(tmp_path / "000001.png"), "--cameras", str(tmp_path / "calib"), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2
    assert (f"no camera for image '000001': no KITTI calib file {tmp_path / 'calib' / '000001.txt'}"
            in result.output)


@pytest.mark.parametrize("form", ["kitti", "ros"])
def test_one_calib_file_or_camera_yaml_gives_every_image_its_camera(monkeypatch, tmp_path, form):
    from tests.formats.test_cameras import ROS, _kitti_calib

    for name in ("a.png", "b.png"):
        _write_image(tmp_path / name)
    cameras = tmp_path / ("calib.txt" if form == "kitti" else "camera.yaml")
    cameras.write_text(_kitti_calib() if form == "kitti" else ROS)
    session, _ = _served_session(monkeypatch, str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--cameras",
                                 str(cameras), "-o", str(tmp_path / "out.json"))
    for image in session.images:
        assert image.camera.K[0, 0] == 721.5 and image.camera.K[1, 2] == 172.9
        assert (image.camera.distortion is None) == (form == "kitti")


def test_a_folder_without_images_and_a_bad_calib_file_are_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("x")
    result = _run(str(tmp_path / "empty"), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2
    assert (f"{tmp_path / 'empty'}: a folder with no images in it (expected .png, .jpg, .jpeg, .bmp, .webp files; "
            "its subfolders are not searched)") in result.output
    _write_image(tmp_path / "a.png")
    (tmp_path / "calib.txt").write_text("P2: 721.5 0 609.6\n")
    result = _run(str(tmp_path / "a.png"), "--cameras", str(tmp_path / "calib.txt"), "-o", str(tmp_path / "a.json"))
    assert result.exit_code == 2
    assert f"{tmp_path / 'calib.txt'}: line 1: P2: expected 12 numbers" in result.output

"""`toosicubix render` over the fitted sample: files, messages, blank canvases, identical re-runs."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.camera import Camera
from toosicubix.cli import main
from toosicubix.formats.results import read_results
from toosicubix.pipeline.batch import fit_file
from toosicubix.render.folder import _fitted_uv, selected, vehicle_label
from toosicubix.render.overlay import BLANK_BGR
from toosicubix.solver.misfit import ResidualTest

SAMPLE_FILE = REPO / "samples" / "annotations.json"

SAMPLE = REPO / "samples" / "annotations.json"
PHOTO_BGR = (10, 200, 30)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> tuple[Path, Path]:
    """The sample fitted, with image 000001's file missing and 000002's a plain green photo."""
    root = tmp_path_factory.mktemp("render")
    doc = json.loads(SAMPLE.read_text())
    doc["images"][0]["file"] = "images/missing.png"
    doc["images"][1]["file"] = "images/000002.png"
    (root / "images").mkdir()
    w, h = doc["images"][1]["size"]
    photo = np.empty((h, w, 3), np.uint8)
    photo[:] = PHOTO_BGR
    cv2.imwrite(str(root / "images" / "000002.png"), photo)
    annotations = root / "annotations.json"
    annotations.write_text(json.dumps(doc))
    fit_file(annotations, root / "out")
    return root, annotations


def run(*args) -> object:
    return CliRunner().invoke(main, ["render", *[str(a) for a in args]])


def test_render_writes_one_png_per_image_missing_file_gives_message_and_blank_canvas(fitted):
    root, annotations = fitted
    result = run(root / "out", "--annotations", annotations, "-o", root / "pictures")
    assert result.exit_code == 0, result.output
    missing = root / "images" / "missing.png"
    assert f"warning: image 000001: {missing} not found ($.images[0].file in {annotations}); drawn on a blank " \
           "canvas" in result.stderr
    assert "rendered 3 images, 2 on a blank canvas" in result.stderr
    names = sorted(p.name for p in (root / "pictures").iterdir())
    assert names == ["000001.png", "000002.png", "000003.png"]  # and no temporary files left
    blank = cv2.imread(str(root / "pictures" / "000001.png"))
    photo = cv2.imread(str(root / "pictures" / "000002.png"))
    w, h = 1242, 375
    assert blank.shape[0] == h and blank.shape[1] > w  # the overlay and the bird's-eye view beside it
    assert tuple(blank[5, 5]) == BLANK_BGR
    assert tuple(photo[5, 5]) == PHOTO_BGR
    assert not np.all(photo[:, :w] == np.array(PHOTO_BGR, np.uint8))  # something was drawn on the photo


def test_rendering_twice_gives_identical_files(fitted, tmp_path):
    root, annotations = fitted
    for name in ("a", "b"):
        assert run(root / "out", "--annotations", annotations, "-o", tmp_path / name, "-q").exit_code == 0
    for path in (tmp_path / "a").iterdir():
        assert path.read_bytes() == (tmp_path / "b" / path.name).read_bytes(), path.name


def test_annotation_file_found_from_results_json_and_default_output(fitted, tmp_path, monkeypatch):
    root, _ = fitted
    out = tmp_path / "out"
    shutil.copytree(root / "out", out)
    monkeypatch.chdir(root)  # results.json names the annotation file as fit was given it (absolute here)
    result = run(out, "-q")
    assert result.exit_code == 0, result.output
    assert len(list((tmp_path / "out-render").glob("*.png"))) == 3
    assert not (out / "render").exists()  # never inside OUT: a later fit into OUT must not find foreign files


def test_fit_again_after_render(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    fit_file(SAMPLE_FILE, tmp_path / "toosicubix-out")
    assert run(tmp_path / "toosicubix-out", "-q").exit_code == 0
    summary = fit_file(SAMPLE_FILE, tmp_path / "toosicubix-out")  # refused before: render/ inside OUT
    assert summary.ok == 6 and len(list((tmp_path / "toosicubix-out-render").glob("*.png"))) == 3


def test_bad_inputs_exit_2_with_the_file_named(fitted, tmp_path):
    root, annotations = fitted
    result = run(tmp_path / "nothing")
    assert result.exit_code == 2
    assert f"Error: {tmp_path / 'nothing'}: no results.json" in result.stderr
    doc = json.loads((root / "out" / "results.json").read_text())
    doc["annotations"] = "gone.json"
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "results.json").write_text(json.dumps(doc))
    result = run(tmp_path / "out")
    assert result.exit_code == 2
    assert "results.json: $.annotations: annotation file gone.json not found; give it with --annotations" \
        in result.stderr
    result = run(root / "out", "--annotations", annotations, "--images", tmp_path / "no-such-dir")
    assert result.exit_code == 2 and "image folder not found" in result.stderr


def test_ground_truth_is_drawn_dashed_white(fitted, tmp_path):
    root, annotations = fitted
    args = (root / "out", "--annotations", annotations, "--no-birds-eye", "-q")
    assert run(*args, "-o", tmp_path / "plain").exit_code == 0
    result = run(*args, "-o", tmp_path / "gt", "--kitti", REPO / "samples" / "ground_truth")
    assert result.exit_code == 0, result.output
    plain = cv2.imread(str(tmp_path / "plain" / "000003.png"))
    with_gt = cv2.imread(str(tmp_path / "gt" / "000003.png"))
    added = np.any(with_gt != plain, axis=2)
    assert added.sum() > 200
    # What was added is white blended (1 px, anti-aliased) into the grey canvas: grey, brighter than the canvas;
    # where it runs under a fitted edge (the sample's fits are near exact) the edge's colour shows instead.
    spread = with_gt[added].max(axis=1).astype(int) - with_gt[added].min(axis=1)
    assert np.median(spread) < 10 and np.median(with_gt[added]) > 100


def test_only_keeps_images_with_failed_vehicles(fitted):
    root, _ = fitted
    results = read_results(root / "out" / "results.json")
    assert not any(selected(r, "failed") for r in results)  # every sample vehicle is fitted
    assert all(selected(r, None) for r in results)
    uncertain = [r.id for r in results if selected(r, "uncertain")]
    assert uncertain  # the sample has vehicles with yaw sigmas far above 5 degrees (see docs/uncertainty.md, validate)


def test_fitted_positions_round_trip_through_the_distortion():
    camera = Camera(K=np.array([[700.0, 0, 600], [0, 700, 200], [0, 0, 1]]),
                    distortion=np.array([-0.3, 0.1, 0.001, 0.002, 0.0]), image_size=(1200, 400))
    clicks = np.array([[100.0, 50.0], [600.0, 200.0], [1100.0, 380.0]])
    # Zero residuals: the fit puts each click where it was (1e-6 px: the iterative undistortion's tolerance).
    np.testing.assert_allclose(_fitted_uv(camera, clicks, np.zeros((3, 2))), clicks, atol=1e-6)
    assert _fitted_uv(camera, clicks, np.zeros((2, 2))) is None  # residuals that do not line up


def test_only_failed_renders_the_images_with_a_failed_vehicle_boxed_in_red(fitted, tmp_path):
    root, annotations = fitted
    out = tmp_path / "out"
    shutil.copytree(root / "out", out)
    doc = json.loads((out / "results.json").read_text())
    failed = doc["images"][2]["vehicles"][0]
    failed.update(status="failed", error="test: no lines", R_cam_vehicle=None, t_cam_vehicle=None, dimensions=None)
    (out / "results.json").write_text(json.dumps(doc))
    result = run(out, "--annotations", annotations, "--only", "failed", "-o", tmp_path / "r", "--no-birds-eye")
    assert result.exit_code == 0, result.output
    assert "rendered 1 images, 1 on a blank canvas -> " in result.stderr
    assert "(2 left out by --only failed)" in result.stderr
    assert [p.name for p in (tmp_path / "r").iterdir()] == [f"{doc['images'][2]['id']}.png"]
    picture = cv2.imread(str(next((tmp_path / "r").iterdir())))
    x1, y1, x2, _ = (round(v) for v in failed["box2d"])
    red = np.all(np.abs(picture.astype(int) - np.array([40, 40, 230])) < 30, axis=2)
    assert red[y1 - 1:y1 + 2, x1 + 5:x2 - 5].mean() > 0.5  # the box's top edge is red along its length


def test_the_label_says_misfit_when_the_residual_test_failed(fitted):
    v = next(v for im in read_results(fitted[0] / "out" / "results.json") for v in im.vehicles if v.ok)
    assert "MISFIT" not in vehicle_label(v)
    passed = replace(v, residual_test=ResidualTest(chi2=10.0, dof=10.0, level=0.99))
    failed = replace(v, residual_test=ResidualTest(chi2=100.0, dof=10.0, level=0.99))  # 0.99 quantile: 23.2
    assert "MISFIT" not in vehicle_label(passed)
    assert vehicle_label(failed).endswith("MISFIT")


def test_only_misfit_keeps_the_images_with_a_misfit(fitted):
    from toosicubix.cli.render import render_command as render
    from toosicubix.render.folder import ONLY_CHOICES

    results = read_results(fitted[0] / "out" / "results.json")
    assert not any(selected(r, "misfit") for r in results)  # fitted without the test
    first = results[0]
    v = next(k for k, v in enumerate(first.vehicles) if v.ok)
    vehicles = list(first.vehicles)
    vehicles[v] = replace(vehicles[v], residual_test=ResidualTest(chi2=100.0, dof=10.0, level=0.99))
    assert selected(replace(first, vehicles=tuple(vehicles)), "misfit")
    only = next(p for p in render.params if p.name == "only")
    assert tuple(only.type.choices) == ONLY_CHOICES  # the command offers what the folder renderer knows


def test_a_ground_truth_that_contradicts_its_clicks_is_noted_by_its_id():
    from dataclasses import replace

    from toosicubix.formats.ground_truth import GtObject
    from toosicubix.render.folder import ground_truth_note

    obj = GtObject(index=0, cls="Car", cuboid_rect=None, box2d=np.zeros(4), truncation=None, occlusion=None,
                   occlusion_fraction=None, track_id=1653, source="", keypoints=9, keypoints_hidden=4,
                   keypoints_off_rays_m=1.94)
    assert ground_truth_note(obj) == "GT 1653: hides 4 of its 9 keypoints; 1.9 m off their rays"
    assert ground_truth_note(replace(obj, keypoints_hidden=2)) == "GT 1653: 1.9 m off its keypoints' rays"
    assert ground_truth_note(replace(obj, keypoints_off_rays_m=0.3)) == "GT 1653: hides 4 of its 9 keypoints"
    assert ground_truth_note(replace(obj, keypoints_hidden=2, keypoints_off_rays_m=0.5)) == ""  # 0.5 m is not off
    assert ground_truth_note(replace(obj, keypoints=None, keypoints_hidden=None, keypoints_off_rays_m=None)) == ""


def test_a_frame_is_found_in_its_sequence_folder_or_in_the_folder_of_sequences(tmp_path):
    # --images may name the sequence's own folder of frames (KITTI's image_02/0001) or the folder of sequences
    # (image_02); a frame's file is <frame as 6 digits>.png either way. Another folder's 000007.png is not taken.
    from types import SimpleNamespace

    from toosicubix.render.folder import find_image_file

    (tmp_path / "clip").mkdir()
    (tmp_path / "clip" / "000007.png").write_bytes(b"")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "000007.png").write_bytes(b"")
    frame = SimpleNamespace(file=None, sequence="clip", frame=7, json_path="$.images[0]")
    assert find_image_file(frame, "clip-7", None, tmp_path / "clip") == (tmp_path / "clip" / "000007.png", None)
    assert find_image_file(frame, "clip-7", None, tmp_path) == (tmp_path / "clip" / "000007.png", None)
    path, message = find_image_file(frame, "clip-7", None, tmp_path / "other")
    assert path is None and "(looked for clip-7.png, clip-7.jpg, clip-7.jpeg, clip/000007.png)" in message
    # From results.json alone (no annotation file), a KITTI tracking id names its sequence and frame.
    (tmp_path / "0001").mkdir()
    (tmp_path / "0001" / "000015.png").write_bytes(b"")
    assert find_image_file(None, "0001_000015", None, tmp_path / "0001") == (tmp_path / "0001" / "000015.png", None)

"""The annotate page on a file of imported keypoints (``toosicubix import coco``): their typical positions
(``at``, ``spread``) and ``visible`` flags come from the mapping, the page fits with them and keeps them
through every edit."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.pipeline.test_road_normal import _pitched_batch
from toosicubix.annotations.convert import document_json, load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.web.request_fields import ApiError
from toosicubix.web.session import Session


@pytest.fixture
def keypoint_file(tmp_path: Path) -> tuple[Path, Path]:
    """A file of three images with one car of twelve keypoints each (the first one's third keypoint labelled
    but hidden), and the first image."""
    images = _pitched_batch(3, np.random.default_rng(3))
    vehicle = images[0].vehicles[0]
    parts = list(vehicle.parts)
    parts[2] = replace(parts[2], visible=False)
    images[0] = replace(images[0], vehicles=(replace(vehicle, parts=tuple(parts)),))
    out = tmp_path / "keypoints.json"
    out.write_text(json.dumps(document_json(images)))
    image = tmp_path / f"{images[0].id}.png"
    cv2.imwrite(str(image), np.zeros((375, 1240, 3), np.uint8))
    return out, image


def _parts(path: Path, image: int = 0) -> list[dict]:
    return json.loads(path.read_text())["images"][image]["vehicles"][0]["parts"]


def test_keypoint_vehicles_fit_on_the_page(keypoint_file):
    out, image = keypoint_file
    session = Session([image], out, {}, load_priors())
    fit = session.image_view(0)["vehicles"][0]["fit"]
    assert fit["status"] == "ok", fit
    # The page's fit is the batch's fit of that vehicle: the same function on the same parts.
    from toosicubix.pipeline.vehicle import fit_one
    from toosicubix.solver.fit import SolverOptions

    (loaded, *_) = load_images(out)
    expected = fit_one(loaded.vehicles[0], loaded.camera, load_priors()["Car"], SolverOptions())
    np.testing.assert_array_equal(fit["R_cam_vehicle"], expected.R_cam_vehicle)


def test_edits_keep_the_keypoints_positions_and_flags(keypoint_file):
    out, image = keypoint_file
    before = _parts(out)
    others = json.loads(out.read_text())["images"][1:]
    session = Session([image], out, {}, load_priors())
    vehicle = session.image_view(0)["vehicles"][0]["id"]
    moved = [before[0]["xy"][0] + 2.0, before[0]["xy"][1] - 1.0]
    session.edit(0, {"revision": session.revision, "op": "move_click", "vehicle": vehicle, "part": 0, "click": 0,
                     "uv": moved})
    session.edit(0, {"revision": session.revision, "op": "set_vehicle", "vehicle": vehicle, "done": True})
    after = _parts(out)
    assert after[0]["xy"] == moved
    assert [{k: v for k, v in p.items() if k != "xy"} for p in after] == [
        {k: v for k, v in p.items() if k != "xy"} for p in before]
    assert after[2]["visible"] is False and "visible" not in after[0]
    assert after[1:] == before[1:]
    assert json.loads(out.read_text())["images"][1:] == others


def test_the_page_makes_no_keypoint_and_renames_none_to_another(keypoint_file):
    out, image = keypoint_file
    session = Session([image], out, {}, load_priors())
    vehicle = session.image_view(0)["vehicles"][0]["id"]
    with pytest.raises(ApiError, match="typical position on the vehicle, which comes from a keypoint mapping"):
        session.edit(0, {"revision": session.revision, "op": "add_click", "vehicle": vehicle, "kind": "keypoint",
                         "name": "door-handle-left", "uv": [[10.0, 20.0]]})
    with pytest.raises(ApiError, match="typical position is its name's"):
        session.edit(0, {"revision": session.revision, "op": "rename", "vehicle": vehicle, "part": 0,
                         "kind": "keypoint", "name": "lamp-front-left"})
    # Renamed to its own name: nothing changes (the position stays).
    before = _parts(out)
    session.edit(0, {"revision": session.revision, "op": "rename", "vehicle": vehicle, "part": 0,
                     "kind": before[0]["kind"], "name": before[0]["name"]})
    assert _parts(out) == before
    # Renamed to a part of the cuboid model, it drops the keypoint's position.
    session.edit(0, {"revision": session.revision, "op": "rename", "vehicle": vehicle, "part": 0,
                     "kind": "point", "name": "edge-rear-left"})
    first = _parts(out)[0]
    assert first["kind"] == "point" and first["part"] == "edge-rear-left" and "at" not in first


def test_preview_of_a_keypoint_vehicle(keypoint_file):
    out, image = keypoint_file
    session = Session([image], out, {}, load_priors())
    vehicle = json.loads(out.read_text())["images"][0]["vehicles"][0]
    view = session.preview({"image": 0, "vehicle": vehicle})
    assert view["fit"]["status"] == "ok"
    np.testing.assert_array_equal(view["fit"]["R_cam_vehicle"],
                                  session.image_view(0)["vehicles"][0]["fit"]["R_cam_vehicle"])

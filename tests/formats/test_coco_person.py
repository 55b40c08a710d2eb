"""``import coco --mapping coco-person`` on a hand-made COCO person-keypoint file: v flags, crowd annotations skipped
with a count, and a person without ankles still fitted from the height prior and said so."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from toosicubix.annotations.mapping import load_mapping
from toosicubix.annotations.priors_file import load_priors
from toosicubix.camera import Camera
from toosicubix.cli import main
from toosicubix.formats.coco import coco_to_annotations
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.parts.road_users import COCO_PERSON_KEYPOINTS
from toosicubix.pipeline.batch import fit_file
from toosicubix.vocabulary import CLASSES

K = [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]]


def _person(t_cam: list[float], ry: float, flags: dict[str, int]) -> list[float]:
    """COCO ``keypoints`` (x, y, v for the 17 in COCO's order) of a pedestrian of the prior's mean size at ``t_cam``,
    every keypoint at the vocabulary's place; ``flags`` gives v by name (default 2); v = 0 writes x = y = 0."""
    d = load_priors()["Pedestrian"].mean
    R = R_cam_vehicle_from_ypr(ry)
    camera = Camera(K=np.array(K))
    out: list[float] = []
    for name in COCO_PERSON_KEYPOINTS:
        v = flags.get(name, 2)
        uv = camera.project((R @ (np.array(CLASSES["Pedestrian"].keypoints[name].at) * d) + np.array(t_cam))[None])[0]
        out += [0.0, 0.0, 0] if v == 0 else [round(float(uv[0]), 2), round(float(uv[1]), 2), v]
    return out


def coco_people() -> dict:
    no_ankles = {"left_ankle": 0, "right_ankle": 0}
    return {
        "images": [{"id": 1, "file_name": "street/000001.jpg", "width": 1280, "height": 720, "K": K}],
        "categories": [{"id": 1, "name": "person", "supercategory": "person", "keypoints": list(COCO_PERSON_KEYPOINTS),
                        "skeleton": [[16, 14], [14, 12]]}],
        "annotations": [
            {"id": 11, "image_id": 1, "category_id": 1, "iscrowd": 0, "bbox": [560, 200, 90, 260], "num_keypoints": 16,
             "keypoints": _person([-0.6, 1.6, 8.0], 0.4, {"right_ear": 1, "right_elbow": 1, "right_wrist": 0})},
            {"id": 12, "image_id": 1, "category_id": 1, "iscrowd": 1, "bbox": [0, 300, 300, 200], "num_keypoints": 0,
             "keypoints": [0] * 51},
            {"id": 13, "image_id": 1, "category_id": 1, "iscrowd": 0, "bbox": [800, 250, 60, 150], "num_keypoints": 15,
             "keypoints": _person([2.5, 1.6, 12.0], -2.0, no_ankles)},
        ],
    }


def test_coco_person_import_flags_crowds_and_ankles(tmp_path):
    path = tmp_path / "person_keypoints.json"
    path.write_text(json.dumps(coco_people()))
    mapping, _ = load_mapping("coco-person")
    document, summary = coco_to_annotations(path, mapping)
    (image,) = document["images"]
    assert image["id"] == "000001" and [v["id"] for v in image["vehicles"]] == ["11", "13"]  # the crowd left out
    walker, no_feet = image["vehicles"]
    assert walker["prototype"] == no_feet["prototype"] == "Pedestrian"
    names = [p["name"] for p in walker["parts"]]
    assert "right_wrist" not in names and len(names) == 16  # v = 0: not labelled
    hidden = {p["name"] for p in walker["parts"] if p.get("visible") is False}
    assert hidden == {"right_ear", "right_elbow"}  # v = 1: kept, labelled but not visible
    assert all(p["kind"] == "keypoint" and p["at"] == list(CLASSES["Pedestrian"].keypoints[p["name"]].at)
               for p in walker["parts"])
    assert not {"left_ankle", "right_ankle"} & {p["name"] for p in no_feet["parts"]}
    assert summary.crowd_skipped == 1 and summary.hidden_kept == 2 and summary.unlabelled == 1 + 2
    lines = summary.lines()
    assert "1 crowd annotations (iscrowd 1) skipped" in lines
    assert any(line.startswith("1 persons without a labelled ankle: fitted all the same") for line in lines)


def test_a_person_without_ankles_is_fitted_from_the_height_prior_and_said_so(tmp_path):
    coco = tmp_path / "person_keypoints.json"
    coco.write_text(json.dumps(coco_people()))
    out = tmp_path / "ann.json"
    result = CliRunner().invoke(main, ["import", "coco", str(coco), "--mapping", "coco-person", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "1 crowd annotations (iscrowd 1) skipped" in result.output
    fit_file(out, tmp_path / "fit")
    vehicles = json.loads((tmp_path / "fit" / "results.json").read_text())["images"][0]["vehicles"]
    walker, no_feet = vehicles
    assert walker["status"] == no_feet["status"] == "ok"
    assert not any(w.startswith("no ankle clicked") for w in walker["warnings"])
    (note,) = [w for w in no_feet["warnings"] if w.startswith("no ankle clicked")]
    assert "Pedestrian height prior (1.76 m)" in note
    # The clicks sit exactly where the vocabulary puts them on a box of the prior's size 12 m away (the height prior
    # is then exact too): the feet land on the truth within the rounding of the clicks to 0.01 px, ~1e-4 m at 12 m.
    np.testing.assert_allclose(no_feet["t_cam_vehicle"], [2.5, 1.6, 12.0], atol=0.01)


def test_the_coco_person_mapping_is_listed_in_the_import_help():
    result = CliRunner().invoke(main, ["import", "coco", "--help"])
    assert result.exit_code == 0 and "coco-person" in result.output and "two-wheeler" in result.output


def test_an_unknown_keypoint_name_of_a_person_file_names_its_json_path(tmp_path):
    doc = coco_people()
    doc["categories"][0]["keypoints"][3] = "left_earlobe"
    path = Path(tmp_path / "bad.json")
    path.write_text(json.dumps(doc))
    result = CliRunner().invoke(main, ["import", "coco", str(path), "--mapping", "coco-person", "-o",
                                       str(tmp_path / "a.json")])
    assert result.exit_code == 2
    assert "$.categories[0].keypoints[3]" in result.output and "'left_earlobe'" in result.output

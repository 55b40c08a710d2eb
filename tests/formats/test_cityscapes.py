"""Cityscapes 3D gtBbox3d reader: layout, frames (ego -> camera of K), errors.

The files are built in ``eval_scenes`` from camera-frame poses by the CONVENTIONS rules run backwards
(scipy quaternions), with a sensor rotation that is not the identity. Tolerance 1e-12 m / rad: a few
3x3 products in float64 at metre scale; pixels 1e-9 (values ~2000 px).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.eval_scenes import CITYSCAPES_SCENE, K_CS, R_SENSOR_EGO, M, cs_box_json, cs_document
from toosicubix.errors import FormatError
from toosicubix.formats.cityscapes import R_CAM_SENSOR, parse_gtbbox3d, quaternion_to_matrix, read_gtbbox3d
from toosicubix.geometry import box2d_of_points, cuboid_corners_cam, geodesic_angle, project_pinhole

BOXES = CITYSCAPES_SCENE["aachen_000000_000019"]


@pytest.fixture
def gt_file(tmp_path):
    path = tmp_path / "aachen_000000_000019_gtBbox3d.json"
    path.write_text(json.dumps(cs_document(BOXES)))
    return path


def test_quaternion_to_matrix_agrees_with_scipy(rng):
    for _ in range(10):
        q_xyzw = Rotation.random(random_state=rng).as_quat()
        q_wxyz = np.roll(q_xyzw, 1)
        np.testing.assert_allclose(quaternion_to_matrix(q_wxyz), Rotation.from_quat(q_xyzw).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(quaternion_to_matrix(-q_wxyz), quaternion_to_matrix(q_wxyz), atol=1e-12)


def test_axes_multiplier_is_the_conventions_M():
    np.testing.assert_array_equal(R_CAM_SENSOR, M)
    assert not np.allclose(R_SENSOR_EGO, np.eye(3))  # the test's sensor really rotates


def test_reads_layout_and_camera(gt_file):
    ann = read_gtbbox3d(gt_file)
    assert ann.image_size == (2048, 1024)
    np.testing.assert_allclose(ann.camera.K, K_CS, atol=0)
    assert ann.camera.baseline == pytest.approx(0.209313)
    assert [b.label for b in ann.objects] == ["car", "car", "truck", "car"]
    assert ann.objects[2].type == "Mini Truck" and ann.objects[2].instance_id == 27001
    assert ann.objects[1].occlusion == pytest.approx(0.3)
    assert len(ann.ignore) == 1
    np.testing.assert_allclose(ann.ignore[0].box2d, [10, 400, 70, 440])  # [x, y, w, h] -> (x1, y1, x2, y2)


def test_pose_in_the_camera_frame_round_trips(gt_file):
    """Box centre -> bottom centre, [l, w, h], scalar-first quaternion, full rotation with the sensor's."""
    ann = read_gtbbox3d(gt_file)
    for box, truth in zip(ann.objects, BOXES, strict=True):
        R, t = box.pose_cam(ann.camera)
        assert geodesic_angle(R, truth.R_cam_vehicle) < 1e-12
        np.testing.assert_allclose(t, truth.t_cam, atol=1e-12)
        np.testing.assert_allclose(box.dimensions, truth.lwh, atol=0)


def test_amodal_box_is_the_projection_of_our_cuboid(gt_file):
    """The stored amodal box (made from the vertices in the ego frame) equals our cuboid's projection."""
    ann = read_gtbbox3d(gt_file)
    for box in ann.objects:
        R, t = box.pose_cam(ann.camera)
        uv = project_pinhole(ann.camera.K, cuboid_corners_cam(R, t, box.dimensions))
        np.testing.assert_allclose(box.box2d_amodal, box2d_of_points(uv, ann.image_size), atol=1e-9)


def test_legacy_bbox_keys_and_optional_fields():
    doc = cs_document(BOXES[:1], ignore=False)
    obj = doc["objects"][0]
    obj["2d"] = {"bbox": [1, 2, 3, 4], "bboxVis": [1, 2, 2, 2]}
    for key in ("occlusion", "truncation", "instanceId", "score"):
        del obj[key]
    box = parse_gtbbox3d(doc).objects[0]
    np.testing.assert_allclose(box.box2d_amodal, [1, 2, 4, 6])
    np.testing.assert_allclose(box.box2d_modal, [1, 2, 3, 4])
    assert box.occlusion is None and box.instance_id is None


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["objects"][0]["3d"].pop("rotation"), r"\$\.objects\[0\]\.3d\.rotation: missing"),
    (lambda d: d["objects"][0]["3d"].update(dimensions=[4.0, 1.7]), r"\$\.objects\[0\]\.3d\.dimensions: expected"),
    (lambda d: d["objects"][0]["3d"].update(dimensions=[4.0, -1.7, 1.5]), "expected positive"),
    (lambda d: d["objects"][0]["3d"].update(rotation=[2.0, 0, 0, 0]), "unit quaternion"),
    (lambda d: d["objects"][0]["3d"].update(format="CRS_S"), "CRS_ISO8855"),
    (lambda d: d["sensor"].pop("fx"), r"\$\.sensor\.fx: missing"),
    (lambda d: d["objects"][0].update(label=3), r"\$\.objects\[0\]\.label: expected str"),
    (lambda d: d.pop("objects"), r"\$\.objects: missing"),
])
def test_malformed_files_name_file_and_json_path(tmp_path, edit, message):
    doc = cs_document(BOXES[:1])
    edit(doc)
    path = tmp_path / "x_gtBbox3d.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=message) as info:
        read_gtbbox3d(path)
    assert str(path) in str(info.value)


def test_invalid_json_names_the_line(tmp_path):
    path = tmp_path / "x_gtBbox3d.json"
    path.write_text('{\n "objects": [\n  oops\n ]}')
    with pytest.raises(FormatError, match=r"x_gtBbox3d\.json:3: not valid JSON"):
        read_gtbbox3d(path)


def test_box_json_helper_matches_public_sample_layout():
    """The test builder writes the keys cityscapesScripts reads (helpers/annotation.py, CsBbox3d)."""
    obj = cs_box_json(BOXES[0])
    assert set(obj) == {"2d", "3d", "occlusion", "truncation", "instanceId", "label", "score"}
    assert set(obj["2d"]) == {"modal", "amodal"}
    assert set(obj["3d"]) == {"center", "dimensions", "rotation", "type", "format"}

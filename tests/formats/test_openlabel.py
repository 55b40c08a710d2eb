"""OpenLABEL 1.0.0 export: valid against the official schema, a known cuboid's val number by number."""

import json
import math
from importlib.resources import files

import jsonschema
import numpy as np
import pytest

from tests.formats.tool_fixtures import sample_doc, write_json
from toosicubix.camera import Camera
from toosicubix.formats.fitted import FittedImage, FittedVehicle, load_fitted
from toosicubix.formats.openlabel import cuboid_val, openlabel_document
from toosicubix.formats.results import VehicleResult
from toosicubix.solver.uncertainty import Uncertainty

#: The official ASAM OpenLABEL 1.0.0 JSON Schema (draft-07, ``$id`` https://openlabel.asam.net/V1-0-0/schema#),
#: as the ``openlabel-checker`` package (MPL-2.0, the test extra) ships it, fetched unmodified from ASAM's site
#: (its PROVENANCE.md); not copied into this repository, whose licence cannot cover ASAM's file. Known quirk: its
#: ``stream_properties`` ``oneOf`` is malformed, so ``intrinsics_pinhole`` is not validated; the exporter writes
#: the ``camera_matrix_3x4`` / ``distortion_coeffs_1xN`` names of the standard's own example.
SCHEMA = json.loads((files("openlabel_checker") / "schema_data" / "openlabel_json_schema-v1.0.0.json").read_text())

# A car 10 m ahead, facing away from the camera: vehicle X (forward) = camera z, Y (left) = camera -x,
# Z (up) = camera -y.
R_AHEAD = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _known_image() -> FittedImage:
    ok = VehicleResult("3", "ok", None, "Car", R_AHEAD, np.array([1.0, 1.5, 10.0]), np.array([4.0, 1.8, 1.5]),
                       sigma=Uncertainty(yaw_deg=2.0, pitch_deg=math.inf, roll_deg=math.inf, depth_m=0.4,
                                         depth_rel=math.inf, dimensions=(0.2, 0.05, 0.04), position_m=(),
                                         scale_rel=math.inf),
                       confidence=0.8, ambiguous=False)
    failed = VehicleResult("4", "failed", "degenerate clicks", "Van")
    parts = [{"kind": "point", "part": "wheel-rear-left", "xy": [600.0, 400.0]},
             {"kind": "symmetry", "face": "rear", "left": [580.0, 330.0], "right": [660.0, 331.0]}]
    K = np.array([[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]])
    return FittedImage("000123", "frames/000123.png", (1280, 720), Camera(K, np.array([-0.1, 0.01, 0, 0, 0])),
                       [FittedVehicle(ok, parts, [550.0, 300.0, 700.0, 420.0]), FittedVehicle(failed, parts[:1])])


def test_known_cuboid_val_number_by_number():
    # Centre = t + R (0, 0, dz/2) = (1, 1.5 - 0.75, 10). R turns by 120 degrees about (1, -1, 1)/sqrt(3):
    # q = (cos 60, sin 60 (1, -1, 1)/sqrt(3)) = (w 0.5; x 0.5, y -0.5, z 0.5), written scalar last.
    val = cuboid_val(R_AHEAD, np.array([1.0, 1.5, 10.0]), np.array([4.0, 1.8, 1.5]))
    expected = [1.0, 0.75, 10.0, 0.5, -0.5, 0.5, 0.5, 4.0, 1.8, 1.5]
    assert len(val) == 10
    for got, want in zip(val, expected, strict=True):
        assert got == pytest.approx(want, abs=1e-12)  # algebra only


def test_quaternion_sign_is_canonical_and_rotation_round_trips(rng):
    from scipy.spatial.transform import Rotation

    for R in Rotation.random(20, random_state=rng.integers(1 << 30)).as_matrix():
        val = cuboid_val(R, np.zeros(3), np.ones(3))
        assert val[6] >= 0 and np.linalg.norm(val[3:7]) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(Rotation.from_quat(val[3:7]).as_matrix(), R, atol=1e-12)


def test_document_layout_and_schema():
    doc, warnings = openlabel_document([_known_image()], name="annotations.json")
    assert warnings == []
    jsonschema.Draft7Validator(SCHEMA).validate(doc)
    root = doc["openlabel"]
    assert root["metadata"]["schema_version"] == "1.0.0"
    pinhole = root["streams"]["camera1"]["stream_properties"]["intrinsics_pinhole"]
    assert pinhole["camera_matrix_3x4"] == [700.0, 0.0, 640.0, 0.0, 0.0, 700.0, 360.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert pinhole["distortion_coeffs_1xN"] == [-0.1, 0.01, 0.0, 0.0, 0.0]
    assert (pinhole["width_px"], pinhole["height_px"]) == (1280, 720)
    assert root["objects"]["0"] == {"name": "000123/3", "type": "Car", "coordinate_system": "camera1",
                                    "frame_intervals": [{"frame_start": 0, "frame_end": 0}]}
    frame = root["frames"]["0"]
    assert frame["frame_properties"]["streams"]["camera1"]["uri"] == "frames/000123.png"
    data = frame["objects"]["0"]["object_data"]
    cuboid = data["cuboid"][0]
    assert cuboid["val"] == pytest.approx([1.0, 0.75, 10.0, 0.5, -0.5, 0.5, 0.5, 4.0, 1.8, 1.5], abs=1e-12)
    assert {"name": "sigma_yaw_deg", "val": 2.0} in cuboid["attributes"]["num"]
    assert {"name": "confidence", "val": 0.8} in cuboid["attributes"]["num"]
    assert {"name": "sigma_dimensions_m", "val": [0.2, 0.05, 0.04]} in cuboid["attributes"]["vec"]
    assert not any(a["name"] == "sigma_pitch_deg" for a in cuboid["attributes"]["num"])  # null: not determined
    assert [p["name"] for p in data["point2d"]] == ["wheel-rear-left", "rear-pair1-left", "rear-pair1-right"]
    assert data["point2d"][1]["val"] == [580.0, 330.0]
    assert data["bbox"][0]["val"] == [625.0, 360.0, 150.0, 120.0]
    assert {"name": "status", "val": "ok"} in data["text"] and {"name": "prototype", "val": "Car"} in data["text"]
    failed = frame["objects"]["1"]["object_data"]
    assert "cuboid" not in failed
    assert {"name": "error", "val": "degenerate clicks"} in failed["text"]


def test_schema_rejects_what_the_standard_forbids():
    doc, _ = openlabel_document([_known_image()])
    doc["openlabel"]["objects"]["car-3"] = doc["openlabel"]["objects"].pop("0")  # uids are integers or UUIDs
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft7Validator(SCHEMA).validate(doc)


def test_sample_fit_exports_a_valid_file(tmp_path):
    from toosicubix.pipeline.batch import fit_file

    annotations = write_json(tmp_path / "sample.json", sample_doc())
    fit_file(annotations, tmp_path / "out")
    images, _ = load_fitted(tmp_path / "out")
    doc, warnings = openlabel_document(images)
    assert warnings == []
    jsonschema.Draft7Validator(SCHEMA).validate(doc)
    root = doc["openlabel"]
    assert len(root["frames"]) == 3 and len(root["objects"]) == 6
    assert len(root["streams"]) == 2  # images 2 and 3 share their camera: one stream
    # Every cuboid's centre projects inside its image and every fitted vehicle has one.
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    for f, image in enumerate(results["images"]):
        for v in image["vehicles"]:
            uid = next(k for k, o in root["objects"].items() if o["name"] == f"{image['id']}/{v['id']}")
            val = root["frames"][str(f)]["objects"][uid]["object_data"]["cuboid"][0]["val"]
            expected = cuboid_val(np.array(v["R_cam_vehicle"]), np.array(v["t_cam_vehicle"]),
                                  np.array(v["dimensions"]))
            assert val == expected

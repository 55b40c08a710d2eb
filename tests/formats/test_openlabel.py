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


# --- keypoints and plates (ApolloCar3D-style fits) -----------------------------------------------------------------

def _point2d(doc: dict, frame: int = 0) -> list[list[dict]]:
    """The point2d entries of each object of a frame, in object order."""
    objects = doc["openlabel"]["frames"][str(frame)].get("objects", {})
    return [o["object_data"].get("point2d", []) for o in objects.values()]


def test_keypoints_and_plates_are_named_points_with_their_attributes():
    image = _known_image()
    keypoint = {"kind": "keypoint", "name": "top_left_c_left_front_car_light", "xy": [610.0, 350.0],
                "at": [0.45, 0.4, 0.6], "spread": [0.01, 0.03, 0.04], "visible": False}
    plate = {"kind": "plate", "face": "rear", "a": [600.0, 380.0], "b": [640.0, 381.0], "metres": 0.44,
             "sigma": 0.01, "at": [-0.47, 0.0, 0.55], "spread": [0.006, 0.037, 0.036]}
    unknown = {"kind": "wheel-ellipse", "part": "wheel-front-left", "box": [1, 2, 3, 4]}  # no OpenLABEL form
    vehicles = [FittedVehicle(image.vehicles[0].result, [*image.vehicles[0].parts, keypoint, plate, unknown]),
                FittedVehicle(image.vehicles[1].result, [keypoint, unknown, unknown])]
    doc, warnings = openlabel_document([FittedImage(image.id, image.file, image.size, image.camera, vehicles)])
    jsonschema.Draft7Validator(SCHEMA).validate(doc)
    first, second = _point2d(doc)
    assert [p["name"] for p in first] == ["wheel-rear-left", "rear-pair1-left", "rear-pair1-right",
                                          "top_left_c_left_front_car_light", "plate-rear-a", "plate-rear-b"]
    assert first[3] == {"name": "top_left_c_left_front_car_light", "val": [610.0, 350.0],
                        "coordinate_system": "camera1", "attributes": {"vec": [{"name": "at", "val": [0.45, 0.4, 0.6]},
                                               {"name": "spread", "val": [0.01, 0.03, 0.04]}],
                                       "boolean": [{"name": "visible", "val": False}]}}
    assert first[5]["val"] == [640.0, 381.0]
    assert first[5]["attributes"]["num"] == [{"name": "metres", "val": 0.44}, {"name": "sigma", "val": 0.01}]
    assert [p["name"] for p in second] == ["top_left_c_left_front_car_light"]
    # Said once for the kind, with its count, not once per part or vehicle.
    assert warnings == ["part kind 'wheel-ellipse' has no OpenLABEL form here: 3 parts on 2 vehicles left out"]


def test_an_apollocar3d_keypoint_fit_exports_every_keypoint(tmp_path):
    # Real human keypoints (ApolloCar3D, the shared data) imported with the apollocar3d-66 mapping and its plates,
    # fitted, exported: a valid OpenLABEL file holding every click of every car, and no warning.
    from click.testing import CliRunner

    from tests.conftest import shared_data_dir
    from toosicubix.cli import main

    folder = shared_data_dir() / "apollocar3d"
    if not (folder / "apollocar3d_val_dev.json").is_file():
        pytest.skip(f"{folder} not found")
    coco = json.loads((folder / "apollocar3d_val_dev.json").read_text())
    ids = {im["id"] for im in coco["images"][:2]}
    coco["images"] = [im for im in coco["images"] if im["id"] in ids]
    coco["annotations"] = [a for a in coco["annotations"] if a["image_id"] in ids]
    keypoints = write_json(tmp_path / "apollo.json", coco)
    annotations = tmp_path / "annotations.json"
    runner = CliRunner()
    for args in (["import", "coco", str(keypoints), "--mapping", "apollocar3d-66", "--option", "plates", "--cameras",
                  str(folder / "cameras.json"), "-o", str(annotations), "-q"],
                 ["fit", str(annotations), "-o", str(tmp_path / "out"), "-q"]):
        result = runner.invoke(main, args)
        assert result.exit_code in (0, 1), result.output
    result = runner.invoke(main, ["export", "openlabel", str(tmp_path / "out"), "-o", str(tmp_path / "labels.json")])
    assert result.exit_code == 0, result.output
    assert "warning" not in result.output
    doc = json.loads((tmp_path / "labels.json").read_text())
    jsonschema.Draft7Validator(SCHEMA).validate(doc)
    written = {o["name"]: [] for o in doc["openlabel"]["objects"].values()}
    names = [o["name"] for o in doc["openlabel"]["objects"].values()]
    for f in range(len(doc["openlabel"]["frames"])):
        for uid, data in doc["openlabel"]["frames"][str(f)].get("objects", {}).items():
            written[names[int(uid)]] = [(p["name"], p["val"]) for p in data["object_data"].get("point2d", [])]
    expected, kinds = {}, set()
    for image in json.loads(annotations.read_text())["images"]:
        for v in image["vehicles"]:
            clicks = []
            for p in v["parts"]:
                kinds.add(p["kind"])
                if p["kind"] == "keypoint":
                    clicks.append((p["name"], p["xy"]))
                else:
                    clicks += [(f"plate-{p['face']}-{end}", p[end]) for end in ("a", "b")]
            expected[f"{image['id']}/{v['id']}"] = clicks
    assert kinds == {"keypoint", "plate"}
    assert sum(map(len, expected.values())) > 100
    assert {k: sorted(v) for k, v in written.items()} == {k: sorted(v) for k, v in expected.items()}


# --- sequences: one object per track ------------------------------------------------------------------------------

def _frame(image_id: str, frame: int | None, *vehicles: tuple[str, str | None, str | None]) -> FittedImage:
    """An image of sequence 's' (``frame`` given) or on its own, its vehicles ``(id, track, pose_from)`` fitted."""
    K = np.array([[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]])
    t = np.array([1.0, 1.5, 10.0 + (frame or 0)])
    fitted = [FittedVehicle(VehicleResult(vid, "ok", None, "Car", R_AHEAD, t, np.array([4.0, 1.8, 1.5]), track=track,
                                          pose_from=pose_from), [])
              for vid, track, pose_from in vehicles]
    return FittedImage(image_id, None, (1280, 720), Camera(K), fitted, None if frame is None else "s", frame)


def test_a_track_is_one_object_over_the_frames_that_hold_it():
    # Tracks s-1 and s-2 in frames 3-5 of sequence 's', with an image on its own between frames 3 and 4 and s-2
    # absent from frame 4: each track one object whose frame_intervals are the document's frames holding it, each
    # frame's pose under the track's uid; the image on its own keeps its object per vehicle.
    images = [_frame("s_3", 3, ("1", "s-1", "clicks"), ("2", "s-2", "box")), _frame("alone", None, ("a", None, None)),
              _frame("s_4", 4, ("1", "s-1", "interpolated")),
              _frame("s_5", 5, ("1", "s-1", "box"), ("7", "s-2", "clicks"))]
    doc, warnings = openlabel_document(images)
    assert warnings == []
    jsonschema.Draft7Validator(SCHEMA).validate(doc)
    from openlabel_checker.checkers import run_all

    raw = json.dumps(doc)
    assert [issue for outcome in run_all(doc, raw) for issue in outcome.issues] == []  # its semantic checks too
    root = doc["openlabel"]
    by_name = {o["name"]: uid for uid, o in root["objects"].items()}
    assert set(by_name) == {"s-1", "s-2", "alone/a"}
    assert root["objects"][by_name["s-1"]]["frame_intervals"] == [{"frame_start": 0, "frame_end": 0},
                                                                  {"frame_start": 2, "frame_end": 3}]
    assert root["objects"][by_name["s-2"]]["frame_intervals"] == [{"frame_start": 0, "frame_end": 0},
                                                                  {"frame_start": 3, "frame_end": 3}]
    assert root["frames"]["2"]["frame_properties"] == {"streams": {"camera1": {"uri": "s_4"}}, "sequence": "s",
                                                       "frame": 4}
    assert "sequence" not in root["frames"]["1"]["frame_properties"]
    for f, image in enumerate(images):
        for fv in image.vehicles:
            uid = by_name[fv.result.track or f"{image.id}/{fv.result.id}"]
            data = root["frames"][str(f)]["objects"][uid]["object_data"]
            assert data["cuboid"][0]["val"] == cuboid_val(fv.result.R_cam_vehicle, fv.result.t_cam_vehicle,
                                                         fv.result.dimensions)
            text = {t["name"]: t["val"] for t in data["text"]}
            if fv.result.track is None:
                assert set(text) == {"status", "prototype"}
            else:
                assert text["vehicle"] == fv.result.id and text["pose_from"] == fv.result.pose_from

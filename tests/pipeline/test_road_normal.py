"""The camera's road normal estimated from a batch's own fits (what ``fit`` does unless given a ground)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tests.parts.test_real_click_kinds import project
from tests.scenes import CAMERA
from tests.solver.test_robust import TWELVE
from toosicubix.annotations.convert import document_json
from toosicubix.camera import Camera
from toosicubix.cli import main
from toosicubix.formats.results import ImageResult, VehicleResult
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.model import GroundBlock, GroundPlane, Image, Part, Vehicle
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.pilot import on_estimated_roads
from toosicubix.pipeline.road_normal import (
    MAX_SPREAD_DEG,
    MIN_VEHICLES,
    RoadNormal,
    camera_key,
    describe_without_pilot,
    estimate_road_normals,
    without_pilot,
)
from toosicubix.pipeline.settings import BatchSettings

#: A camera looking 9 degrees down (ApolloCar3D's camera 5 looks about that much): R_cam_level.
PITCH = np.deg2rad(9.0)
R_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(PITCH), -np.sin(PITCH)], [0.0, np.sin(PITCH), np.cos(PITCH)]])
#: The road's normal in that camera's frame (up is the level camera's -y).
NORMAL = R_DOWN @ np.array([0.0, -1.0, 0.0])
OTHER = Camera(K=np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]]), image_size=(1280, 720))


def _up(rng, normal, sigma_deg) -> np.ndarray:
    v = normal + np.deg2rad(sigma_deg) * rng.normal(size=3)
    return v / np.linalg.norm(v)


def _result(ups) -> ImageResult:
    vehicles = [VehicleResult(id=str(i), status="ok", error=None, prototype="Car",
                              R_cam_vehicle=np.column_stack([np.cross([0.0, 0.0, 1.0], u), [0.0, 0.0, 1.0], u]),
                              t_cam_vehicle=np.array([0.0, 1.5, 20.0])) for i, u in enumerate(ups)]
    return ImageResult(id="im", K=CAMERA.K, t_cam_rect=np.zeros(3), image_size=None, vehicles=vehicles)


def _image(i, camera=CAMERA, ground=None) -> Image:
    """A pilot image: it holds the vehicles the pilot fitted (their results are given apart)."""
    vehicle = Vehicle(id="v", prototype="Car", box2d=None, parts=(), json_path=f"$.images[{i}].vehicles[0]")
    return Image(id=f"im{i}", file=None, camera=camera, vehicles=(vehicle,), json_path=f"$.images[{i}]",
                 ground=ground)


def test_each_camera_gets_the_median_up_axis_of_its_vehicles():
    rng = np.random.default_rng(3)
    level = np.array([0.0, -1.0, 0.0])
    pilot = [_image(0), _image(1, OTHER), _image(2, OTHER)]
    results = [_result([_up(rng, NORMAL, 2.0) for _ in range(60)]),
               _result([_up(rng, level, 2.0) for _ in range(20)]), _result([_up(rng, level, 2.0) for _ in range(20)])]
    normals = estimate_road_normals(pilot, results, {camera_key(CAMERA): 1, camera_key(OTHER): 2})
    first, other = normals[camera_key(CAMERA)], normals[camera_key(OTHER)]
    # 60 up axes spread 2 degrees per axis: the median's error is about 2 * 1.25 / sqrt(60) = 0.3 deg.
    assert first.reason is None and first.vehicles == 60 and first.images == 1
    assert np.rad2deg(np.arccos(np.dot(first.normal, NORMAL))) < 1.0
    assert 1.5 < first.spread_deg < 4.0  # the median angle of a 2-degree-per-axis spread: 2 * 1.18 deg
    assert other.images == 2 and other.vehicles == 40 and other.reason is None
    assert np.rad2deg(np.arccos(np.dot(other.normal, level))) < 1.0
    down = float(first.describe().split("the camera looking ")[1].split(" deg down")[0])
    assert abs(down - 9.0) < 1.0


def test_too_few_or_scattered_vehicles_give_no_normal_and_say_why():
    rng = np.random.default_rng(4)
    few = estimate_road_normals([_image(0)], [_result([_up(rng, NORMAL, 2.0) for _ in range(MIN_VEHICLES - 1)])],
                                {camera_key(CAMERA): 1})[camera_key(CAMERA)]
    assert few.normal is None and f"{MIN_VEHICLES} needed" in few.reason and "not estimated" in few.describe()
    scattered = estimate_road_normals([_image(0)], [_result([_up(rng, NORMAL, 30.0) for _ in range(100)])],
                                      {camera_key(CAMERA): 1})[camera_key(CAMERA)]
    assert scattered.normal is None and scattered.spread_deg > MAX_SPREAD_DEG
    assert "do not share one road" in scattered.reason


def test_images_with_their_own_ground_keep_it():
    rng = np.random.default_rng(5)
    own = GroundPlane(np.array([0.0, -1.0, 0.0]), 0.01, 1.65, 0.1, 0.03)
    pilot = [_image(0, ground=own), _image(1)]
    results = [_result([_up(rng, -NORMAL, 2.0) for _ in range(50)]),
               _result([_up(rng, NORMAL, 2.0) for _ in range(50)])]
    normals = estimate_road_normals(pilot, results, {camera_key(CAMERA): 1})
    n = normals[camera_key(CAMERA)]
    assert n.vehicles == 50 and np.dot(n.normal, NORMAL) > 0.999  # the first image's vehicles did not count
    out = list(on_estimated_roads([_image(0, ground=own), _image(1), _image(2, OTHER)], normals))
    assert out[0].ground is own
    np.testing.assert_allclose(out[1].ground.normal, n.normal, atol=1e-12)
    assert out[1].ground.from_batch and out[1].ground.camera_height is None
    assert np.isclose(np.rad2deg(out[1].ground.upright_sigma), 2.0)
    assert np.isclose(np.rad2deg(out[1].ground.normal_sigma), 3.0)
    assert out[2].ground is None  # a camera without an estimate


def _pitched_batch(n: int, rng) -> list[Image]:
    """``n`` images of one car each, seen from behind and left 25-45 m ahead by the camera looking 9 deg down;
    twelve keypoints 1 % of the dimensions off their positions, clicked with 1 px noise."""
    images = []
    d = np.array([4.2, 1.75, 1.5])
    for i in range(n):
        R_level = R_cam_vehicle_from_ypr(np.deg2rad(rng.uniform(-140, -100)), 0.0, 0.0)
        t_level = np.array([rng.uniform(-4, 4), 1.6, rng.uniform(25, 45)])
        R, t = R_DOWN @ R_level, R_DOWN @ t_level
        parts = []
        for k, (name, at) in enumerate(TWELVE.items()):
            X = (np.array(at) + rng.normal(0.0, 0.01, 3)) * d
            uv = project(X[None], R, t) + rng.normal(0.0, 1.0, 2)
            parts.append(Part("keypoint", name, uv, f"$.images[{i}].vehicles[0].parts[{k}]", None, np.array(at),
                              np.full(3, 0.01)))
        vehicle = Vehicle(id=f"v{i}", prototype="Car", box2d=None, parts=tuple(parts),
                          json_path=f"$.images[{i}].vehicles[0]")
        images.append(Image(id=f"im{i:03d}", file=None, camera=CAMERA, json_path=f"$.images[{i}]",
                            vehicles=(vehicle,)))
    return images


def test_fit_estimates_the_normal_and_fits_upright_on_it(tmp_path):
    images = _pitched_batch(40, np.random.default_rng(6))
    path = tmp_path / "pitched.json"
    path.write_text(json.dumps(document_json(images)))
    summary = fit_file(path, tmp_path / "estimated", BatchSettings(estimate_road_normal=True))
    fit_file(path, tmp_path / "none")
    estimated = json.loads((tmp_path / "estimated" / "results.json").read_text())
    plain = json.loads((tmp_path / "none" / "results.json").read_text())
    (block,) = estimated["road_normal"]
    assert block["vehicles"] == 40 and block["images"] == 40 and block["reason"] is None
    (normal,) = summary.pilot.road_normals.values()
    assert normal.normal == tuple(block["normal"])
    # 40 far cars whose own up axes scatter a few degrees: their median lies within 1 degree of the road's.
    assert np.rad2deg(np.arccos(np.dot(block["normal"], NORMAL))) < 1.0
    assert all(im["ground"]["estimated"] and im["ground"]["camera_height"] is None for im in estimated["images"])
    assert "road_normal" not in plain and all(im.get("ground") is None for im in plain["images"])

    tilt_with = np.array([np.arccos(np.clip(np.dot(np.array(v["R_cam_vehicle"])[:, 2], NORMAL), -1, 1))
                          for im in estimated["images"] for v in im["vehicles"]])
    tilt_without = np.array([np.arccos(np.clip(np.dot(np.array(v["R_cam_vehicle"])[:, 2], NORMAL), -1, 1))
                             for im in plain["images"] for v in im["vehicles"]])
    # Upright within 2 degrees on a normal known within 3: the fits' tilts from the true road shrink (here from
    # a median 1.7 to 0.9 degrees; these cars' clicks are good, so there is less to gain than on real ones).
    assert np.median(tilt_with) < 0.75 * np.median(tilt_without)
    assert np.rad2deg(np.median(tilt_with)) < 1.5


def test_cli_estimates_by_default_and_road_normal_none_turns_it_off(tmp_path):
    runner = CliRunner()
    out = tmp_path / "out"
    result = runner.invoke(main, ["fit", "samples/annotations.json", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "road normal: not estimated for 2 camera(s) (3 images): the pilot fitted at most 3 vehicles" in result.output
    assert "road_normal" in json.loads((out / "results.json").read_text())
    for extra in (["--road-normal", "none"], ["--road-normal", "0,-1,0"], ["--kitti-ground"]):
        result = runner.invoke(main, ["fit", "samples/annotations.json", "-o", str(tmp_path / "x"), *extra])
        assert result.exit_code == 0, result.output
        assert "road normal" not in result.output
        assert "road_normal" not in json.loads((tmp_path / "x" / "results.json").read_text())
    result = runner.invoke(main, ["fit", "samples/annotations.json", "-o", str(tmp_path / "y"),
                                  "--road-normal", "estimate", "--camera-height", "1.6"])
    assert result.exit_code == 2 and "--road-normal estimate goes without" in result.output


@pytest.mark.parametrize("value", ["1,2", "up", "1,2,x"])
def test_road_normal_option_says_what_it_expects(tmp_path, value):
    result = CliRunner().invoke(main, ["fit", "samples/annotations.json", "-o", str(tmp_path), "--road-normal", value])
    assert result.exit_code == 2 and "'estimate' or 'none'" in result.output


def test_road_normal_round_trips_to_json():
    n = RoadNormal((700.0, 700.0, 600.0, 180.0), 3, (0.0, -1.0, 0.0), 40, 2.0)
    assert n.to_json()["camera"] == {"fx": 700.0, "fy": 700.0, "cx": 600.0, "cy": 180.0}
    assert n.to_json()["normal_sigma_deg"] == 3.0 and "looking 0.0 deg up" in n.describe()


def test_cameras_the_pilot_has_no_vehicle_of_are_counted_not_listed():
    """A batch whose every image has its own intrinsics has as many cameras as images: the header lists only
    those the pilot saw (at most its 400 vehicles' cameras) and counts the rest."""
    rng = np.random.default_rng(7)
    cams = [Camera(K=np.array([[700.0 + i, 0, 600], [0, 700.0 + i, 180], [0, 0, 1]])) for i in range(50)]
    counts = {camera_key(c): 1 for c in cams}
    pilot = [_image(i, cams[i]) for i in range(0, 50, 10)]
    normals = estimate_road_normals(pilot, [_result([_up(rng, NORMAL, 2.0)]) for _ in pilot], counts)
    assert len(normals) == 5 and all(n.reason and n.vehicles == 1 for n in normals.values())
    assert without_pilot(counts, normals) == {"cameras": 45, "images": 45}
    assert "45 more camera(s) (45 images)" in describe_without_pilot(without_pilot(counts, normals))
    assert describe_without_pilot({"cameras": 0, "images": 0}) == ""


def test_validate_fits_as_fit_does_with_the_batch_estimates(tmp_path):
    """validate's fits are fit's: the same pilot, the same click noise and road normal, the same poses."""
    from toosicubix.pipeline.validation import validate_file

    path = tmp_path / "pitched.json"
    path.write_text(json.dumps(document_json(_pitched_batch(40, np.random.default_rng(8)))))
    fit_file(path, tmp_path / "out", BatchSettings(estimate_click_sigma=True, estimate_road_normal=True))
    fitted = json.loads((tmp_path / "out" / "results.json").read_text())
    report = validate_file(path, BatchSettings(next_clicks=3, estimate_click_sigma=True, estimate_road_normal=True))
    as_json = report.to_json()
    assert as_json["road_normal"] == fitted["road_normal"] and as_json["click_noise"] == fitted["click_noise"]
    assert as_json["click_sigma"] == fitted["settings"]["click_sigma"]
    poses = {v["id"]: v["R_cam_vehicle"] for im in fitted["images"] for v in im["vehicles"]}
    assert len(report.vehicles) == 40
    for check in report.vehicles:
        np.testing.assert_array_equal(check.result.R_cam_vehicle, poses[check.result.id])
    plain = validate_file(path, BatchSettings(next_clicks=3)).to_json()
    assert "road_normal" not in plain and "click_noise" not in plain


def test_validate_cli_says_what_the_pilot_estimated(tmp_path):
    result = CliRunner().invoke(main, ["validate", "samples/annotations.json"])
    # The sample's cuboid parts are too few to estimate the click noise and the parts' placement (rule 33): it says so.
    assert ("click noise and part placement: 1.5 px, parts 9 cm off the cuboid model (defaults: the pilot's cuboid "
            "parts give 19 degrees of freedom, 200 needed" in result.output)
    assert "road normal: not estimated for 2" in result.output
    result = CliRunner().invoke(main, ["validate", "samples/annotations.json", "--road-normal", "none",
                                       "--click-sigma", "1.5"])
    assert "road normal" not in result.output and "click noise: 1.5 px (given)" in result.output


def test_the_pilot_counts_each_cameras_images_from_the_index_and_reads_only_its_own(tmp_path, monkeypatch):
    """The cameras and their images without a ground block come from the index (K, P and distortion told apart as
    the images' own cameras are), and the pilot reads only the images that hold its vehicles: the same findings as
    reading every image."""
    from collections import Counter

    from toosicubix.annotations import stream
    from toosicubix.annotations.stream import index_annotations
    from toosicubix.model import GroundOverride
    from toosicubix.pipeline import click_noise, pilot
    from toosicubix.pipeline.fitting import stream_images

    rng = np.random.default_rng(9)
    images = _pitched_batch(60, rng)
    P = np.hstack([CAMERA.K, np.array([[40.0], [0.0], [0.0]])])
    cameras = [CAMERA, Camera(K=CAMERA.K, distortion=np.array([0.01, 0.0, 0.0, 0.0])), Camera.from_P(P)]
    block = GroundBlock(normal=(0.0, -1.0, 0.0))
    images = [replace(im, camera=cameras[i % 3], ground_block=block if i % 4 == 0 else None)
              for i, im in enumerate(images)]
    path = tmp_path / "mixed.json"
    path.write_text(json.dumps(document_json(images)))
    index = index_annotations(path)
    for override in (None, GroundOverride(camera_height=1.65)):
        every = Counter(camera_key(im.camera) for im in stream_images(index, override) if im.ground is None)
        assert pilot._without_ground(index, override) == every
    # Three camera blocks, two cameras: a P whose K is another block's K is that camera.
    assert len(index.cameras) == 3 and len(pilot._without_ground(index, None)) == 2

    monkeypatch.setattr(click_noise, "PILOT_VEHICLES", 12)  # every 5th of the 60 vehicles
    read = []
    real = stream.image_annotation
    monkeypatch.setattr(stream, "image_annotation", lambda text: read.append(text) or real(text))
    findings = pilot.run_pilot(index, BatchSettings(estimate_click_sigma=True, estimate_road_normal=True))
    assert len(read) == 12
    assert findings.road_normals is not None and sum(n.images for n in findings.road_normals.values()) == 45

"""render and export cvat, after a review: a real KITTI lens's fold, edges to the zone's edge, a road user's class
colour beside tracks, malformed files that must not stop a picture, ids XML cannot carry."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from tests.pipeline.test_tracks import tracked_file  # noqa: F401  (the fixture: a tracked car, 21 frames)
from tests.render.test_overlay import BLANK_BGR, vehicle
from toosicubix.camera import Camera, fold_radius, trusted_radius
from toosicubix.cli import main
from toosicubix.formats.results import read_results
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.pipeline.batch import fit_file
from toosicubix.render.folder import Tracks, drawn_vehicles
from toosicubix.render.overlay import blank_canvas, draw_overlay, project_polylines
from toosicubix.render.palette import CLASS_PALETTES_BGR

SAMPLE = REPO / "samples" / "annotations.json"
#: KITTI's raw camera 2 (2011_09_26): its model folds back at a normalized radius of about 1.21, while the image's
#: corners undistort to 1.3-1.4 (the model never reaches them).
KITTI_RAW = Camera(K=np.array([[721.5, 0.0, 609.6], [0.0, 721.5, 172.9], [0.0, 0.0, 1.0]]),
                   distortion=np.array([-0.3691481, 0.1968681, 0.001353473, 0.0005677587, -0.06770705]),
                   image_size=(1242, 375))


def test_the_trusted_zone_stops_before_the_lens_model_folds_back():
    fold = fold_radius(KITTI_RAW)
    assert 1.19 < fold < 1.23
    assert trusted_radius(KITTI_RAW, KITTI_RAW.image_size) <= 0.98 * fold
    assert fold_radius(replace(KITTI_RAW, distortion=None)) == np.inf


def test_a_car_beside_the_camera_is_not_drawn_across_the_image():
    """Every part of this car lies left of u = 300 in the image; the folded model put its far edges at u = 961."""
    canvas = blank_canvas(KITTI_RAW.image_size)
    draw_overlay(canvas, KITTI_RAW, [vehicle(R_cam_vehicle_from_ypr(np.pi / 2), [-4.0, 1.65, 4.5], [4.2, 1.8, 1.5],
                                             label="1")])
    painted = np.any(canvas != np.array(BLANK_BGR, dtype=np.uint8), axis=2)
    columns = np.nonzero(painted)[1]
    assert painted.sum() > 500 and columns.max() < 320


def test_an_edge_leaving_the_trusted_zone_runs_to_its_edge():
    radius = 0.9
    a, b = np.array([0.0, 0.0, 10.0]), np.array([20.0, 0.0, 10.0])  # leaves the zone at x/z = 0.9
    (polyline,) = project_polylines(KITTI_RAW, [(a, b)], 4, radius)  # 4 pieces: samples at x/z 0, 0.5, 1.0 ...
    end = KITTI_RAW.normalize(polyline[-1:])[0]
    assert abs(np.hypot(end[0], end[1]) - radius) < 1e-6


def test_the_cvat_export_leaves_out_a_cuboid_the_lens_model_cannot_draw():
    from toosicubix.formats.cvat_export import projected_shapes
    from toosicubix.formats.fitted import FittedImage, FittedVehicle
    from toosicubix.formats.results import VehicleResult

    def result(t):
        return VehicleResult(id="1", status="ok", error=None, prototype="Car",
                             R_cam_vehicle=R_cam_vehicle_from_ypr(np.pi / 2), t_cam_vehicle=np.array(t),
                             dimensions=np.array([4.2, 1.8, 1.5]))

    for t, kept in (([-4.5, 1.65, 3.5], False), ([1.0, 1.65, 15.0], True)):
        image = FittedImage("im", None, KITTI_RAW.image_size, KITTI_RAW, [FittedVehicle(result(t), None)])
        shapes, warnings = projected_shapes(image)
        assert (len(shapes), len(warnings)) == ((1, 0) if kept else (0, 1)), warnings
        assert kept or "not trusted" in warnings[0]


def test_a_pedestrian_keeps_its_class_colour_in_a_frame_with_a_tracked_car(tracked_file, tmp_path):  # noqa: F811
    fit_file(tracked_file, tmp_path / "out")
    results = read_results(tmp_path / "out" / "results.json")
    frame = results[5]
    frame = replace(frame, vehicles=[frame.vehicles[0], replace(frame.vehicles[1], prototype="Pedestrian")])
    camera = Camera(K=frame.K, image_size=frame.image_size)
    colours = [v.colour for v in drawn_vehicles(None, frame, camera, Tracks.of(results).colours)]
    assert colours[1] == CLASS_PALETTES_BGR["Pedestrian"][0] and colours[0] != colours[1]


@pytest.fixture
def fitted_sample(tmp_path):
    fit_file(SAMPLE, tmp_path / "out")
    return tmp_path / "out"


def test_malformed_next_clicks_do_not_stop_a_picture(fitted_sample, tmp_path):
    path = fitted_sample / "results.json"
    doc = json.loads(path.read_text())
    doc["images"][0]["vehicles"][0]["next_clicks"] = [{"name": "x", "uv": "ab"}, {"name": "y", "uv": [1, 2, 3]}]
    path.write_text(json.dumps(doc))
    result = CliRunner().invoke(main, ["render", str(fitted_sample), "-o", str(tmp_path / "r"), "--next-clicks",
                                       "-q"])
    assert result.exit_code == 0, result.output
    assert len(list((tmp_path / "r").glob("*.png"))) == len(doc["images"])


def test_an_absolute_image_path_with_images_folder_is_a_warning(tmp_path):
    doc = json.loads(SAMPLE.read_text())
    doc["images"][0]["file"] = "/nonexistent/000001.png"
    annotations = tmp_path / "a.json"
    annotations.write_text(json.dumps(doc))
    fit_file(annotations, tmp_path / "out")
    (tmp_path / "images").mkdir()
    result = CliRunner().invoke(main, ["render", str(tmp_path / "out"), "-o", str(tmp_path / "r"), "--images",
                                       str(tmp_path / "images")])
    assert result.exit_code == 0, result.output
    assert "/nonexistent/000001.png" in result.output


def test_one_malformed_ground_truth_label_leaves_the_other_pictures(fitted_sample, tmp_path):
    gt = tmp_path / "gt"
    shutil.copytree(REPO / "samples" / "ground_truth", gt)
    label = gt / "label_2" / "000002.txt"
    label.write_text(label.read_text() + "Car 0 0 garbage\n")
    result = CliRunner().invoke(main, ["render", str(fitted_sample), "-o", str(tmp_path / "r"), "--kitti", str(gt)])
    assert result.exit_code == 0, result.output
    assert "000002" in result.output and "ground truth not drawn" in result.output
    assert len(list((tmp_path / "r").glob("*.png"))) == 3


def test_an_id_xml_cannot_carry_is_left_out_of_the_cvat_export(tmp_path):
    doc = json.loads(SAMPLE.read_text())
    doc["images"][0]["vehicles"][0]["id"] = "car\uffff1"
    annotations = tmp_path / "a.json"
    annotations.write_text(json.dumps(doc))
    fit_file(annotations, tmp_path / "out")
    result = CliRunner().invoke(main, ["export", "cvat", str(tmp_path / "out"), "-o", str(tmp_path / "c.xml")])
    assert result.exit_code == 0, result.output
    assert "XML cannot carry" in result.output
    root = ET.parse(tmp_path / "c.xml").getroot()  # well-formed
    assert len(root.findall(".//polyline")) == sum(len(im["vehicles"]) for im in doc["images"]) - 1

"""CVAT for images 1.1 import (fixtures as CVAT's dumper writes them) and the review export."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from tests.formats.tool_fixtures import (
    cameras_doc,
    cvat_xml,
    file_name,
    fit_results,
    max_pose_difference,
    same_clicks,
    sample_doc,
    sample_fit,
    write_json,
)
from toosicubix.errors import FormatError
from toosicubix.formats.cameras import load_cameras
from toosicubix.formats.cvat import read_cvat
from toosicubix.formats.cvat_export import EDGE_WALK, review_xml
from toosicubix.formats.fitted import load_fitted
from toosicubix.geometry import cuboid_corners_cam

IMAGE = '<image id="0" name="frames/a.png" width="1000" height="500">'


def _cameras(tmp_path):
    return load_cameras(write_json(tmp_path / "cameras.json", cameras_doc(sample_doc())))


def _any_camera(tmp_path):
    return load_cameras(write_json(tmp_path / "any.json", {"cameras": [
        {"match": "*", "K": [[800, 0, 500], [0, 800, 250], [0, 0, 1]]}]}))


def _xml(tmp_path, body: str, name: str = "a.xml"):
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n  <version>1.1</version>\n{body}'
                    "\n</annotations>\n")
    return path


@pytest.mark.parametrize("project", [False, True])
def test_template_annotation_import_fit_gives_the_sample_cuboids(tmp_path, project):
    doc = sample_doc()
    path = tmp_path / "annotations.xml"
    path.write_text(cvat_xml(doc, project=project))
    imported, summary = read_cvat(path, _cameras(tmp_path))
    assert summary.warnings == []
    assert same_clicks(imported, doc)
    assert [im["file"] for im in imported["images"]] == [file_name(im) for im in doc["images"]]
    assert [im["id"] for im in imported["images"]] == [im["id"] for im in doc["images"]]
    # Two and three skeletons in one image stay separate vehicles.
    assert [len(im["vehicles"]) for im in imported["images"]] == [3, 2, 1]
    out = write_json(tmp_path / "imported.json", imported)
    # The parts come back in vocabulary order, not file order: the optimum moves by rounding only.
    assert max_pose_difference(json.loads(sample_fit()), fit_results(out)) < 1e-6


def test_outside_points_are_not_clicks_and_occluded_ones_are(tmp_path):
    path = _xml(tmp_path, f"""  {IMAGE}
    <skeleton label="vehicle" source="manual" z_order="0">
      <points label="wheel-front-left" source="manual" outside="0" occluded="1" points="100.00,200.00">
      </points>
      <points label="wheel-rear-left" source="manual" outside="1" occluded="0" points="300.00,200.00">
      </points>
      <points label="rear-center" source="manual" outside="0" occluded="0" points="150.50,120.25">
      </points>
      <attribute name="prototype">Van</attribute>
    </skeleton>
  </image>""")
    doc, summary = read_cvat(path, _any_camera(tmp_path))
    vehicle = doc["images"][0]["vehicles"][0]
    assert vehicle["prototype"] == "Van"
    assert vehicle["parts"] == [{"kind": "point", "part": "wheel-front-left", "xy": [100.0, 200.0]},
                                {"kind": "point", "part": "rear-center", "xy": [150.5, 120.25]}]
    assert summary.warnings == [] and summary.keypoints == 2


def test_loose_points_grouped_by_group_id_with_a_box(tmp_path):
    path = _xml(tmp_path, f"""  {IMAGE}
    <points label="rear-pair1-left" source="manual" occluded="0" points="10.00,20.00" z_order="0" group_id="2">
    </points>
    <box label="Truck" source="manual" occluded="0" xtl="5.00" ytl="6.00" xbr="70.00" ybr="80.00" z_order="0" \
group_id="2">
    </box>
    <points label="rear-pair1-right" source="manual" occluded="0" points="30.00,21.00" z_order="0" group_id="2">
    </points>
    <points label="wheel-rear-left" source="manual" occluded="0" points="400.00,300.00" z_order="0" group_id="5">
    </points>
  </image>""")
    doc, summary = read_cvat(path, _any_camera(tmp_path))
    first, second = doc["images"][0]["vehicles"]
    assert first == {"id": "1", "prototype": "Truck", "box2d": [5.0, 6.0, 70.0, 80.0],
                     "parts": [{"kind": "symmetry", "face": "rear", "left": [10.0, 20.0], "right": [30.0, 21.0]}]}
    assert second["prototype"] == "Car" and second["parts"][0]["part"] == "wheel-rear-left"
    assert summary.warnings == [f"{path}: image 'frames/a.png', group_id 5: no prototype: 'Car' assumed"]


def test_problems_are_warnings_naming_image_and_element(tmp_path):
    path = _xml(tmp_path, f"""  {IMAGE}
    <skeleton label="vehicle" source="manual" z_order="0">
      <points label="wheel-front-left" source="manual" outside="0" occluded="0" points="100.00,200.00">
      </points>
      <points label="side-mirror" source="manual" outside="0" occluded="0" points="110.00,150.00">
      </points>
      <points label="rear-center" source="manual" outside="0" occluded="0" points="1200.00,120.00">
      </points>
      <points label="rear-pair2-left" source="manual" outside="0" occluded="0" points="120.00,120.00">
      </points>
      <attribute name="prototype">Car</attribute>
    </skeleton>
    <points label="top-center" source="manual" occluded="0" points="5.00,5.00" z_order="0">
    </points>
  </image>""")
    doc, summary = read_cvat(path, _any_camera(tmp_path))
    assert doc["images"][0]["vehicles"][0]["parts"] == [
        {"kind": "point", "part": "wheel-front-left", "xy": [100.0, 200.0]}]
    text = "\n".join(summary.warnings)
    where = f"{path}: image 'frames/a.png', skeleton 1 (label 'vehicle')"
    assert f"{where}, points 'rear-center': (1200.0, 120.0) lies outside the 1000x500 image: left out" in text
    assert f"{where}, points 'side-mirror': keypoint 'side-mirror': not a toosicubix keypoint name" in text
    assert f"{where}, points 'rear-pair2-left': keypoint 'rear-pair2-left': needs rear-pair2-right too" in text
    assert "points 2 (label 'top-center'): cannot be grouped to a vehicle" in text
    assert summary.left_out == {"rear-center": 1, "side-mirror": 1, "rear-pair2-left": 1, "top-center": 1}


def test_errors_name_the_file_and_image(tmp_path):
    body = f"""  {IMAGE}
    <skeleton label="vehicle" source="manual" z_order="0">
      <points label="wheel-front-left" source="manual" outside="0" occluded="0" points="1.00;2.00">
      </points>
    </skeleton>
  </image>"""
    with pytest.raises(FormatError, match=r"<image id='0' name='frames/a.png'> skeleton 1 .*expected points="):
        read_cvat(_xml(tmp_path, body), _any_camera(tmp_path))
    good = body.replace("1.00;2.00", "1.00,2.00")
    with pytest.raises(FormatError, match=r"image 'frames/a.png': no camera \(give --cameras"):
        read_cvat(_xml(tmp_path, good), None)
    with pytest.raises(FormatError, match="CVAT for video"):
        read_cvat(_xml(tmp_path, '  <track id="0" label="vehicle" source="manual"></track>'), None)
    bad = tmp_path / "bad.xml"
    bad.write_text("<annotations><image></annotations>")
    with pytest.raises(FormatError, match=f"{bad}:1: not valid XML"):
        read_cvat(bad, None)


def test_review_export_projects_each_fitted_cuboid(tmp_path):
    doc = sample_doc()
    annotations = write_json(tmp_path / "sample.json", doc)
    from toosicubix.pipeline.batch import fit_file

    fit_file(annotations, tmp_path / "out")
    images, _ = load_fitted(tmp_path / "out")
    text, warnings = review_xml(images)
    assert warnings == []
    root = ET.fromstring(text)
    assert root.findtext("version") == "1.1"
    xml_images = root.findall("image")
    assert [im.get("name") for im in xml_images] == [im["id"] for im in doc["images"]]  # the sample has no files
    first = xml_images[0].findall("polyline")[0]
    uv = np.array([[float(v) for v in p.split(",")] for p in first.get("points").split(";")])
    v = images[0].vehicles[0].result
    corners_uv = images[0].camera.project(cuboid_corners_cam(v.R_cam_vehicle, v.t_cam_vehicle, v.dimensions))
    # Image 1 has no lens distortion: the polyline is the edge walk through the projected corners (2 decimals).
    np.testing.assert_allclose(uv, corners_uv[list(EDGE_WALK)], atol=0.006)
    assert [a.text for a in first.findall("attribute")] == ["1", "ok"]
    # Image 2 has distortion: each edge is sampled 8 times, 15 edges of the walk plus its end.
    distorted = xml_images[1].findall("polyline")[0].get("points").split(";")
    assert len(distorted) == 15 * 8 + 1
    assert sum(len(im.findall("polyline")) for im in xml_images) == 6
    assert sum(len(im.findall("polygon")) for im in xml_images) == 6

"""CVAT for images 1.1 and CVAT for video 1.1 import (fixtures as CVAT's dumpers write them) and the review
export."""

import json
import re
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import REPO
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
from tests.pipeline.test_tracks import FRAMES, tracked_file  # noqa: F401  (the fixture: a tracked car, 21 frames)
from toosicubix.annotations.convert import document_json, images_from_schema
from toosicubix.annotations.schema import parse_annotations
from toosicubix.annotations.stream import index_annotations
from toosicubix.cli import main
from toosicubix.errors import FormatError, InputFileError
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


# --- CVAT for video 1.1 ----------------------------------------------------------------------------------------

VIDEO = REPO / "tests" / "formats" / "fixtures" / "cvat-video-1.1.xml"
VIDEO_K = [[721.5, 0.0, 609.6], [0.0, 721.5, 172.9], [0.0, 0.0, 1.0]]


def _video_cameras(tmp_path):
    return write_json(tmp_path / "cameras.json", {"cameras": [{"match": "images/frame_*", "K": VIDEO_K}]})


def _video_variant(tmp_path, old: str, new: str):
    text = VIDEO.read_text()
    assert text.count(old) == 1, old
    path = tmp_path / "annotations.xml"
    path.write_text(text.replace(old, new))
    return path


def test_video_export_becomes_frames_of_one_sequence(tmp_path):
    # The fixture, as dump_as_cvat_interpolation writes it: task 'highway 0003', frames 0-5 of 1242x375.
    # Vehicle A: skeleton track 0 (keyframes 0 and 3, CVAT's interpolation on 1-2, outside from 4) and box track 1
    # (keyframes 0, 3, outside on 4, back on 5), linked by group_id 1. Vehicle B: box track 2 alone, every frame.
    # Vehicle C: skeleton track 3 alone, keyframes 1 and 3, copied to the task's end (4, 5) without keyframes.
    doc, summary = read_cvat(VIDEO, load_cameras(_video_cameras(tmp_path)))
    assert summary.warnings == []
    images = doc["images"]
    assert [im["id"] for im in images] == [f"highway_0003_{f:06d}" for f in range(6)]
    assert [im["file"] for im in images] == [f"images/frame_{f:06d}.PNG" for f in range(6)]
    assert {im["sequence"] for im in images} == {"highway_0003"}
    assert [im["frame"] for im in images] == list(range(6))
    assert all(im["size"] == [1242, 375] and im["camera"] == {"K": VIDEO_K} for im in images)
    assert [list(im) for im in images[:1]] == [["id", "file", "sequence", "frame", "size", "camera", "vehicles"]]
    on = {f: {v["id"]: v for v in im["vehicles"]} for f, im in enumerate(images)}
    # A is not in frame 4 (outside); B is in every frame; C from frame 1 on.
    assert [sorted(on[f]) for f in range(6)] == [["0", "2"], ["0", "2", "3"], ["0", "2", "3"], ["0", "2", "3"],
                                                 ["2", "3"], ["0", "2", "3"]]
    assert {v["track"] for f in on for v in on[f].values()} == {"highway_0003-0", "highway_0003-2", "highway_0003-3"}
    assert all(v["track"] == f"highway_0003-{v['id']}" for f in on for v in on[f].values())
    # Prototypes: A's skeleton attribute (also on frame 5, where only its box is), B's box label, C's attribute.
    assert {(v["id"], v["prototype"]) for f in on for v in on[f].values()} == {("0", "Van"), ("2", "Truck"),
                                                                               ("3", "Car")}
    # Clicks on keyframes only; at frame 3 A's rear-center was not set again (keyframe="0"): no click.
    parts = {(f, k): [p["part"] for p in v["parts"]] for f in on for k, v in on[f].items() if v["parts"]}
    assert parts == {(0, "0"): ["wheel-front-left", "wheel-rear-left", "rear-center"],
                     (3, "0"): ["wheel-front-left", "wheel-rear-left"],
                     (1, "3"): ["wheel-rear-left", "rear-center"], (3, "3"): ["wheel-rear-left", "rear-center"]}
    assert on[0]["0"]["parts"][0] == {"kind": "point", "part": "wheel-front-left", "xy": [400.0, 220.0]}
    assert on[3]["3"]["parts"][1] == {"kind": "point", "part": "rear-center", "xy": [1040.0, 202.0]}
    # Boxes on every frame their track is not outside, interpolated (keyframe="0") or not.
    assert [on[f]["0"].get("box2d") for f in (0, 1, 2, 3, 5)] == [
        [270.0, 150.0, 420.0, 225.0], [280.0, 151.0, 430.0, 226.0], [290.0, 152.0, 440.0, 227.0],
        [300.0, 153.0, 450.0, 228.0], [320.0, 155.0, 470.0, 230.0]]
    assert [on[f]["2"]["box2d"][0] for f in range(6)] == [700.0, 698.0, 696.0, 694.0, 692.0, 690.0]
    assert all("box2d" not in on[f]["3"] for f in range(1, 6))
    # C on frames 2, 4, 5: neither clicks nor box, for the solver to interpolate.
    assert [on[f]["3"] for f in (2, 4, 5)] == [{"id": "3", "prototype": "Car", "track": "highway_0003-3",
                                                "parts": []}] * 3
    assert summary.tracks == {"highway_0003-0", "highway_0003-2", "highway_0003-3"}
    assert dict(summary.tracked) == {"clicks": 4, "box only": 9, "neither": 3}
    assert summary.images == 6 and summary.vehicles == 16 and summary.keypoints == 9


def test_video_round_trip_through_the_schema_and_the_streaming_index(tmp_path):
    doc, _ = read_cvat(VIDEO, load_cameras(_video_cameras(tmp_path)), sequence="drive-3")
    parsed = parse_annotations(doc)
    assert [(im.sequence, im.frame) for im in parsed.images] == [("drive-3", f) for f in range(6)]
    assert parsed.images[4].vehicles[0].track == "drive-3-2"
    again = document_json(images_from_schema(parsed))
    assert again == doc  # nothing lost or added on the way through the numpy model
    path = write_json(tmp_path / "imported.json", doc)
    index = index_annotations(path)  # the TrackBook rules pass on the stream too
    assert index.sequences == tuple(("drive-3", f) for f in range(6)) and index.tracked == 16


def test_video_cli_names_the_sequence_and_reports_the_tracks(tmp_path):
    out = tmp_path / "drive.json"
    result = CliRunner().invoke(main, ["import", "cvat", str(VIDEO), "--cameras", str(_video_cameras(tmp_path)),
                                       "--sequence", "drive3", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert result.output == ("6 images, 16 vehicles, 9 keypoints used\n"
                             "3 tracks; their vehicle frames: 4 with clicks, 9 with a box only, 3 with neither "
                             "(the solver interpolates those)\n"
                             f"wrote {out}\n")
    written = json.loads(out.read_text())
    assert written["images"][0]["id"] == "drive3_000000" and written["images"][0]["vehicles"][0]["track"] == "drive3-0"
    result = CliRunner().invoke(main, ["import", "cvat", str(VIDEO), "--sequence", "drive 3", "-o", str(out)])
    assert result.exit_code == 2
    assert ("Invalid value for '--sequence': expected a sequence name of letters, digits and '_', '.', '-' inside, "
            "at most 120 characters, got 'drive 3' (e.g. 'drive_3')") in result.output


@pytest.mark.parametrize(("old", "new", "message"), [
    ('<box frame="2" keyframe="0" outside="0" occluded="0" xtl="696.00"',
     '<box frame="1.5" keyframe="0" outside="0" occluded="0" xtl="696.00"',
     "{xml}:162: <track id='2' label='Truck'> box 3 frame: expected a frame number written in digits from 0 to "
     "1000000, got '1.5'"),
    ('<box frame="2" keyframe="0" outside="0" occluded="0" xtl="696.00"',
     '<box frame="1" keyframe="0" outside="0" occluded="0" xtl="696.00"',
     "{xml}:162: <track id='2' label='Truck'> box 3 (frame 1): frame 1 is given twice in one track"),
    ('<skeleton frame="2" keyframe="0" z_order="0">\n      <points label="wheel-front-left" keyframe="0" outside="0"',
     '<skeleton frame="2" keyframe="no" z_order="0">\n      <points label="wheel-front-left" keyframe="0" outside="0"',
     "{xml}:115: <track id='0' label='vehicle'> skeleton 3 (frame 2): expected keyframe=\"0\" or \"1\", got 'no'"),
    ('<track id="2" label="Truck" source="manual">', '<track id="2" label="Truck" source="manual" group_id="1">',
     "{xml}:158: <track id='2' label='Truck'> box 1 (frame 0): group_id 1 (tracks 0, 1, 2) has a second box on frame 0 "
     "(also <track id='1' label='Car'> box 1 (frame 0)): one box per vehicle"),
    # The prototype attribute changes along track 0 (Van, then Car on frame 3): one prototype per track.
    ('keyframe="0" outside="0" occluded="1" points="310.00,193.00">\n      </points>\n      '
     '<attribute name="prototype">Van',
     'keyframe="0" outside="0" occluded="1" points="310.00,193.00">\n      </points>\n      '
     '<attribute name="prototype">Car',
     "{xml} (as imported): $.images[3].vehicles[0].track (image 'highway_0003_000003'): track 'highway_0003-0' has "
     "prototype 'Car' here and 'Van' at $.images[0].vehicles[0].track: one prototype (and one size) per track"),
])
def test_video_bad_input_exits_2_naming_the_file_and_where(tmp_path, old, new, message):
    xml = _video_variant(tmp_path, old, new)
    out = tmp_path / "out.json"
    result = CliRunner().invoke(main, ["import", "cvat", str(xml), "--cameras", str(_video_cameras(tmp_path)),
                                       "-o", str(out)])
    assert result.exit_code == 2
    assert result.output == f"Error: {message.format(xml=xml)}\n"
    assert not out.exists()


def test_video_refusals_name_the_file(tmp_path):
    cameras = load_cameras(_video_cameras(tmp_path))
    project = _video_variant(tmp_path, "<task>\n      <id>12</id>", "<project>\n      <id>12</id>")
    project.write_text(project.read_text().replace("</task>", "</project>"))
    with pytest.raises(FormatError, match=f"{project}: CVAT for video from a project export: export each task"):
        read_cvat(project, cameras)
    unnamed = _video_variant(tmp_path, "<name>highway 0003</name>", "<name>(((</name>")
    assert read_cvat(unnamed, cameras)[0]["images"][0]["sequence"] == "task_12"
    unnamed.write_text(unnamed.read_text().replace("<id>12</id>", "<id></id>"))
    with pytest.raises(FormatError, match=r"names no task or job: give the sequence a name \(--sequence NAME\)"):
        read_cvat(unnamed, cameras)
    assert read_cvat(unnamed, cameras, sequence="s1")[0]["images"][0]["id"] == "s1_000000"
    # A job export: no name, and (as JobData writes it) the frame size beside <job> rather than in it.
    size = "\n      <original_size>\n        <width>1242</width>\n        <height>375</height>\n      </original_size>"
    task = "<task>\n      <id>12</id>\n      <name>highway 0003</name>"
    job = _video_variant(tmp_path, task, "<job>\n      <id>41</id>")
    job.write_text(job.read_text().replace(size, "").replace("</task>", f"</job>{size}"))
    first = read_cvat(job, cameras)[0]["images"][0]
    assert (first["id"], first["size"]) == ("job_41_000000", [1242, 375])
    with pytest.raises(FormatError, match=r"this file has no <track> \(CVAT for images 1.1\)"):
        read_cvat(_xml(tmp_path, f"  {IMAGE}\n  </image>"), cameras, sequence="drive3")


def test_images_export_still_imports_byte_for_byte(tmp_path):
    # CVAT for images 1.1 writes no sequence, frame or track, in the key order it always had.
    path = _xml(tmp_path, f"""  {IMAGE}
    <skeleton label="vehicle" source="manual" z_order="0">
      <points label="wheel-front-left" source="manual" outside="0" occluded="0" points="100.00,200.00">
      </points>
      <attribute name="prototype">Van</attribute>
    </skeleton>
    <points label="rear-center" source="manual" occluded="0" points="30.00,21.00" z_order="0" group_id="2">
    </points>
    <box label="Truck" source="manual" occluded="0" xtl="5.00" ytl="6.00" xbr="70.00" ybr="80.00" z_order="0" \
group_id="2">
    </box>
  </image>""")
    out = tmp_path / "out.json"
    cameras = write_json(tmp_path / "c.json", {"cameras": [{"match": "*", "K": VIDEO_K}]})
    result = CliRunner().invoke(main, ["import", "cvat", str(path), "--cameras", str(cameras), "-o", str(out)])
    assert result.exit_code == 0, result.output
    first = {"kind": "point", "part": "wheel-front-left", "xy": [100.0, 200.0]}
    expected = {"toosicubix": 1, "images": [{
        "id": "a", "file": "frames/a.png", "size": [1000, 500], "camera": {"K": VIDEO_K}, "vehicles": [
            {"id": "1", "prototype": "Van", "parts": [first]},
            {"id": "2", "prototype": "Truck", "box2d": [5.0, 6.0, 70.0, 80.0],
             "parts": [{"kind": "point", "part": "rear-center", "xy": [30.0, 21.0]}]}]}]}
    assert out.read_text() == json.dumps(expected, indent=1) + "\n"


# --- the zip CVAT downloads ---------------------------------------------------------------------------------------
# CVAT's exporters (_export_task / _export_project in cvat/apps/dataset_manager/formats/cvat.py; the format pages
# of its documentation) write annotations.xml at the zip's root and, with "Save images", the frames under images/
# (a project's under images/<subset>/; a video's as images/frame_<N:06d>.PNG).

def _zip(path, members: dict[str, bytes | str]):
    import zipfile

    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return path


PNG = b"\x89PNG\r\n\x1a\n" + bytes(64)  # the images' bytes do not matter: only annotations.xml is read


@pytest.mark.parametrize("layout", ["task", "project", "video"])
def test_the_export_zip_imports_as_its_xml(tmp_path, layout):
    if layout == "video":
        xml, cameras = VIDEO.read_text(), write_json(tmp_path / "c.json", {"cameras": [{"match": "*", "K": VIDEO_K}]})
        images = {f"images/frame_{n:06d}.PNG": PNG for n in range(3)}
    else:
        doc = sample_doc()
        xml, cameras = cvat_xml(doc, project=layout == "project"), write_json(tmp_path / "c.json", cameras_doc(doc))
        folder = "images/default/" if layout == "project" else "images/"
        images = {folder + file_name(im): PNG for im in doc["images"]}
    (tmp_path / "annotations.xml").write_text(xml)
    archive = _zip(tmp_path / "export.zip", {"annotations.xml": xml, **images})
    outputs = []
    for source in ("annotations.xml", "export.zip"):
        out = tmp_path / f"{source}.json"
        result = CliRunner().invoke(main, ["import", "cvat", str(tmp_path / source), "--cameras", str(cameras), "-o",
                                           str(out)])
        assert result.exit_code == 0, result.output
        outputs.append(out.read_bytes())
    assert outputs[0] == outputs[1]  # byte for byte
    doc, _ = read_cvat(archive, load_cameras(cameras))
    assert doc["images"]


@pytest.mark.parametrize(("members", "message"), [
    ({"images/a.png": PNG},
     r"expected the zip CVAT downloads .* with one annotations.xml; found none \(images/a.png\)"),
    ({"annotations.xml": "<annotations/>", "old/annotations.xml": "<annotations/>"},
     r"found 2 of them \(annotations.xml, old/annotations.xml\)"),
    ({"annotations/person_keypoints_default.json": "{}"}, r"found none .*a COCO or Datumaro export\? unzip it"),
    ({}, r"found none \(nothing\)"),
])
def test_a_zip_without_one_annotations_xml_is_refused(tmp_path, members, message):
    archive = _zip(tmp_path / "export.zip", members)
    with pytest.raises(FormatError, match=message) as info:
        read_cvat(archive, None)
    assert str(info.value).startswith(f"{archive}: ")
    result = CliRunner().invoke(main, ["import", "cvat", str(archive), "-o", str(tmp_path / "o.json")])
    assert result.exit_code == 2 and "with one annotations.xml" in result.output


def test_zip_members_are_read_within_the_xml_limit(tmp_path, monkeypatch):
    import io

    from toosicubix.formats import cvat

    monkeypatch.setattr(cvat, "MAX_XML_BYTES", 10_000)
    big = "<annotations>" + " " * 20_000 + "</annotations>"
    archive = _zip(tmp_path / "bomb.zip", {"annotations.xml": big})  # 20 kB that deflate to a few dozen bytes
    assert archive.stat().st_size < 1_000
    with pytest.raises(FormatError, match=rf"{archive}/annotations.xml: 20027 bytes uncompressed: larger than the "
                                          "10000 bytes"):
        read_cvat(archive, None)
    # A member whose header understates its size is stopped while it is read.
    with pytest.raises(FormatError, match=r"x.xml: more than 10000 bytes of XML"):
        cvat._parse_stream(io.BytesIO(big.encode()), tmp_path / "x.xml")
    (tmp_path / "big.xml").write_text(big)
    with pytest.raises(FormatError, match=r"big.xml: 20027 bytes: larger than the 10000 bytes"):
        read_cvat(tmp_path / "big.xml", None)


def test_a_damaged_zip_or_a_doctype_inside_it_is_refused(tmp_path):
    archive = _zip(tmp_path / "export.zip", {"annotations.xml": cvat_xml(sample_doc())})
    (tmp_path / "cut.zip").write_bytes(archive.read_bytes()[:200])
    with pytest.raises(FormatError, match=r"cut.zip: a damaged zip archive"):
        read_cvat(tmp_path / "cut.zip", None)
    doctype = _zip(tmp_path / "doctype.zip", {"annotations.xml": '<!DOCTYPE a [<!ENTITY x "y">]><annotations/>'})
    with pytest.raises(FormatError, match=r"doctype.zip/annotations.xml:1: a DOCTYPE is not allowed"):
        read_cvat(doctype, None)
    broken = _zip(tmp_path / "broken.zip", {"annotations.xml": "<annotations><image></annotations>"})
    with pytest.raises(FormatError, match=r"broken.zip/annotations.xml:1: not valid XML"):
        read_cvat(broken, None)


# --- hostile XML (issue 34): declarations refused by the parser, numbers and ids by the field rules ---------------

SKELETON = """  <image id="0" name="frames/a.png" width="1000" height="500">
    <skeleton label="vehicle" source="manual" z_order="0">
      <points label="wheel-front-left" source="manual" outside="0" occluded="0" points="401.20,202.00">
      </points>
      <points label="wheel-rear-left" source="manual" outside="0" occluded="0" points="301.20,212.00">
      </points>
    </skeleton>
    <points label="top-center" source="manual" occluded="0" points="350.00,150.00" z_order="0" group_id="3"/>
    <box label="Car" source="manual" occluded="0" xtl="280" ytl="120" xbr="420" ybr="230" z_order="0" group_id="3"/>
  </image>"""
LAUGHS = ('<!DOCTYPE annotations [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
          '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]>\n')


def _hostile(text: str, encoding: str = "utf-8") -> bytes:
    return text.encode(encoding)


@pytest.mark.parametrize(("data", "message"), [
    # A DOCTYPE after a comment longer than any look-ahead, in UTF-8 and in UTF-16 (both with entity expansion).
    (_hostile(f'<?xml version="1.0" encoding="utf-8"?>\n<!--{"x" * 5000}-->\n{LAUGHS}<annotations><version>&c;'
              "</version></annotations>"), ":3: a DOCTYPE is not allowed"),
    (_hostile(f'<?xml version="1.0" encoding="utf-16"?>\n{LAUGHS}<annotations><version>&c;</version></annotations>',
              "utf-16"), ":2: a DOCTYPE is not allowed"),
    (_hostile('<!DOCTYPE a [<!ENTITY e SYSTEM "file:///etc/passwd">]>\n<annotations>&e;</annotations>'),
     ":1: a DOCTYPE is not allowed"),
    (_hostile('<!DOCTYPE a SYSTEM "http://127.0.0.1:9/a.dtd">\n<annotations/>'), ":1: a DOCTYPE is not allowed"),
    (_hostile("<annotations><version>&c;</version></annotations>"), ":1: not valid XML: undefined entity"),
    (_hostile(SKELETON.replace("401.20,202.00", "4_01.2,202.00")),
     ":6: <image id='0' name='frames/a.png'> skeleton 1 (label 'vehicle'), points 'wheel-front-left' points: expected "
     "a pixel coordinate written in decimals (e.g. 401.25) from -1000000 to 1000000, got '4_01.2'"),
    (_hostile(SKELETON.replace("401.20,202.00", "nan,202.00")), "got 'nan'"),
    (_hostile(SKELETON.replace('points="350.00,150.00"', 'points="1e999,150.00"')), "got '1e999'"),
    (_hostile(SKELETON.replace('group_id="3"/>\n    <box', f'group_id="{"9" * 5000}"/>\n    <box')),
     ":11: <image id='0' name='frames/a.png'> points 2 (label 'top-center') group_id: expected a group id (CVAT "
     "numbers groups) written in at most 18 digits, got '99999"),
    (_hostile(SKELETON.replace('group_id="3"/>\n    <box', 'group_id="\u00b2"/>\n    <box')), "got '\u00b2'"),
    (_hostile(SKELETON.replace('width="1000"', 'width="\u00b2"')),
     ":4: <image id='0' name='frames/a.png'> width: expected an image side in pixels written in digits from 1 to "
     "1000000, got '\u00b2'"),
    (_hostile(SKELETON.replace('width="1000"', 'width="4_000"')), "got '4_000'"),
    (_hostile(SKELETON.replace('xtl="280"', 'xtl="2.8e2.1"')), "box 3 (label 'Car', group_id 3) xtl: expected"),
])
def test_hostile_xml_is_refused_naming_the_file_and_line(tmp_path, data, message):
    if data.lstrip().startswith(b"<image"):  # a fragment: one image
        data = (b'<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n  <version>1.1</version>\n' + data
                + b"\n</annotations>\n")
    path = tmp_path / "hostile.xml"
    path.write_bytes(data)
    with pytest.raises((FormatError, InputFileError)) as info:
        read_cvat(path, _any_camera(tmp_path))
    assert str(info.value).startswith(str(path)) and message in str(info.value)
    out = tmp_path / "out.json"
    result = CliRunner().invoke(main, ["import", "cvat", str(path), "-o", str(out)])
    assert result.exit_code == 2 and result.output.startswith(f"Error: {path}") and not out.exists()


def test_the_unmodified_skeleton_imports(tmp_path):
    doc, _ = read_cvat(_xml(tmp_path, SKELETON), _any_camera(tmp_path))
    assert [len(v["parts"]) for v in doc["images"][0]["vehicles"]] == [2, 1]
    assert doc["images"][0]["vehicles"][1]["box2d"] == [280.0, 120.0, 420.0, 230.0]


def test_images_are_read_one_at_a_time(tmp_path):
    from toosicubix.formats import cvat

    seen = []

    def take(element, root, source):
        seen.append((element.tag, element.line, len(root)))
        return element.tag == "image"

    body = "\n".join(SKELETON.replace('id="0" name="frames/a.png"', f'id="{i}" name="frames/{i}.png"')
                     for i in range(3))
    root, _ = cvat._parse(_xml(tmp_path, body), take)
    assert [tag for tag, _, _ in seen] == ["version", "image", "image", "image"]
    assert [children for tag, _, children in seen if tag == "image"] == [2, 2, 2]  # version and the one image
    assert [child.tag for child in root] == ["version"]
    assert [line for tag, line, _ in seen if tag == "image"] == [4, 14, 24]


XML_TEXT = st.text(alphabet=st.characters(codec="utf-8"), max_size=12)


@settings(max_examples=150, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_mutation_imports_or_is_named(tmp_path, data):
    """A CVAT XML with an attribute value replaced by any text, or bytes cut, inserted or replaced: a valid
    annotation document, or a FormatError (InputFileError) naming the file; never another exception."""
    text = _xml(tmp_path, SKELETON).read_bytes()
    if data.draw(st.booleans()):
        values = [m for m in re.finditer(rb'="([^"]*)"', text)]
        found = data.draw(st.sampled_from(values))
        new = data.draw(XML_TEXT).replace("&", "&amp;").replace("<", "&lt;").replace('"', "&quot;")
        text = text[:found.start(1)] + new.encode() + text[found.end(1):]
    else:
        at = data.draw(st.integers(min_value=0, max_value=len(text)))
        cut = data.draw(st.integers(min_value=0, max_value=16))
        text = text[:at] + data.draw(st.binary(max_size=8)) + text[at + cut:]
    path = tmp_path / "fuzz.xml"
    path.write_bytes(text)
    try:
        doc, _ = read_cvat(path, _any_camera(tmp_path))
    except (FormatError, InputFileError) as exc:
        assert str(exc).startswith(str(path))
        return
    parse_annotations(doc)


def test_review_export_numbers_images_by_frame_or_puts_a_cvat_video_into_tracks():
    # A CVAT video task's frames (one sequence, files named as CVAT names its frames) have no <image>: CVAT reads an
    # image id as a frame counted from the task's start by its step, which the file does not know; the vehicles go
    # into tracks (the next test). Other frames of one sequence are numbered by frame: a sequence's file holds only
    # its frames with a vehicle, and where CVAT cannot match the name it takes the id as the frame. Images of their
    # own, or of two sequences, are numbered in file order.
    from toosicubix.camera import Camera
    from toosicubix.formats.fitted import FittedImage

    K = np.array(VIDEO_K)

    def frame(number, sequence="clip", file="images/frame_{:06d}.PNG"):
        return FittedImage(f"{sequence}-{number}", file.format(number), (1242, 375), Camera(K), [], sequence, number)

    def ids(images):
        return [im.get("id") for im in ET.fromstring(review_xml(images)[0]).findall("image")]

    assert ids([frame(3), frame(7), frame(12)]) == []
    assert ids([frame(3, file="{:06d}.png"), frame(7, file="{:06d}.png"), frame(12, file="{:06d}.png")]) == [
        "3", "7", "12"]
    assert ids([frame(3), frame(7, file="{:06d}.png")]) == ["3", "7"]
    alone = FittedImage("alone", "alone.png", (1242, 375), Camera(K), [])
    assert ids([frame(3), alone, frame(12)]) == ["0", "1", "2"]
    assert ids([frame(3), frame(12, "other")]) == ["0", "1"]


@pytest.mark.parametrize("step", [1, 5])
def test_review_export_of_one_video_makes_each_track_a_cvat_track(tracked_file, tmp_path, step):  # noqa: F811
    """In a file of a CVAT video task's frames a tracked vehicle is one CVAT object: a track of its cuboid's
    polylines and one of its front's polygons, a keyframe on each frame that holds it, in frame order whatever the
    file's order, and
    ``outside`` from the frame after each run of frames (a gap, its end) but never past the file's last frame;
    an untracked vehicle is a track of one frame on each of its frames. With a frame step (a CVAT task of every
    fifth frame numbers them 0, 5, 10, ...), the frame after is the next of the step: CVAT refuses a frame its step
    skips."""
    from toosicubix.pipeline.batch import fit_file

    path = tmp_path / "gap.json"
    doc = json.loads(tracked_file.read_text())
    gap = {7, 8}  # the tracked car leaves the view on frames 7 and 8, and the file lists the frames backwards
    for image in doc["images"]:
        if image["frame"] in gap:
            image["vehicles"] = [v for v in image["vehicles"] if "track" not in v]
        image["frame"] *= step
        image["file"] = f"images/frame_{image['frame']:06d}.PNG"  # as import cvat names a video task's frames
    doc["images"].reverse()
    path.write_text(json.dumps(doc))
    fit_file(path, tmp_path / "out")
    images, _ = load_fitted(tmp_path / "out")
    # Frames named otherwise (an image task matches them by name, and numbers them its own way): <image>s, as before.
    other = [replace(image, file=f"{image.frame:06d}.png") for image in images]
    elsewhere = ET.fromstring(review_xml(other)[0])
    assert elsewhere.findall("track") == [] and len(elsewhere.findall("image")) == FRAMES
    root = ET.fromstring(review_xml(images)[0])
    assert root.findall("image") == []
    tracks = root.findall("track")
    # The tracked car first (frame 0; its two tracks), then the untracked car's 21 frames, each two one-frame tracks.
    assert [t.get("id") for t in tracks] == [str(k) for k in range(2 + 2 * FRAMES)]
    assert [t.get("label") for t in tracks] == ["toosicubix-cuboid", "toosicubix-front"] * (1 + FRAMES)
    for track, tag in zip(tracks[:2], ("polyline", "polygon"), strict=True):
        shapes = [s for s in track if s.tag != "attribute"]
        assert {s.tag for s in shapes} == {tag} and all(s.get("keyframe") == "1" for s in shapes)
        held = [int(s.get("frame")) for s in shapes if s.get("outside") == "0"]
        outside = [int(s.get("frame")) for s in shapes if s.get("outside") == "1"]
        assert held == [step * f for f in range(FRAMES) if f not in gap] and outside == [7 * step]
        values = {a.get("name"): a.text for a in shapes[0].findall("attribute")}
        assert values["vehicle_id"] == "1" and (tag == "polygon" or values["status"] == "ok")
    # The untracked car: on each frame a polyline track and a polygon track of one keyframe, outside on the next
    # frame of the step but after the last frame, as CVAT writes a shape in its video format.
    for k, f in enumerate(range(FRAMES)):
        for track, tag in zip(tracks[2 + 2 * k: 4 + 2 * k], ("polyline", "polygon"), strict=True):
            shapes = [(s.tag, s.get("frame"), s.get("outside"), s.find("attribute").text) for s in track]
            assert shapes == [(tag, str(step * f), "0", "2")] + ([(tag, str(step * (f + 1)), "1", "2")]
                                                                 if f < FRAMES - 1 else [])


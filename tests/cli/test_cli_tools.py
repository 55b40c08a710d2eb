"""`toosicubix template`, `import cvat|label-studio` and `export openlabel|cvat`: exit codes and messages."""

import json
import xml.etree.ElementTree as ET

import jsonschema

from tests.cli.test_cli_fit import run
from tests.formats.test_openlabel import SCHEMA
from tests.formats.tool_fixtures import (
    cameras_doc,
    cvat_xml,
    label_studio_export,
    same_clicks,
    sample_doc,
    write_json,
)
from toosicubix.parts.keypoints import KEYPOINTS


def test_template_prints_each_tool_and_refuses_unknown_prototypes(tmp_path):
    result = run("template", "cvat", "--prototypes", "Car,Mid Size Car")
    assert result.exit_code == 0, result.output
    labels = json.loads(result.output)
    assert labels[0]["attributes"][0]["values"] == ["Car", "Mid Size Car"]
    result = run("template", "label-studio", "-o", str(tmp_path / "config.xml"))
    assert result.exit_code == 0
    assert ET.parse(tmp_path / "config.xml").getroot().find("KeyPointLabels") is not None
    result = run("template", "coco")
    assert json.loads(result.output)["categories"][0]["keypoints"] == list(KEYPOINTS)
    result = run("template", "cvat", "--prototypes", "Car,Hovercraft")
    assert result.exit_code == 2
    assert "--prototypes: unknown prototype 'Hovercraft'; known: " in result.output
    assert run("template", "kml").exit_code == 2


def test_import_cvat_writes_the_annotation_file(tmp_path):
    doc = sample_doc()
    (tmp_path / "annotations.xml").write_text(cvat_xml(doc))
    cameras = write_json(tmp_path / "cameras.json", cameras_doc(doc))
    out = tmp_path / "imported.json"
    result = run("import", "cvat", str(tmp_path / "annotations.xml"), "--cameras", str(cameras), "-o", str(out))
    assert result.exit_code == 0, result.output
    assert "3 images, 6 vehicles, 53 keypoints used" in result.output
    assert same_clicks(json.loads(out.read_text()), doc)


def test_import_label_studio_warns_and_strict_refuses(tmp_path):
    doc = sample_doc()
    export = label_studio_export(doc)
    export[0]["annotations"][0]["result"][1]["value"]["keypointlabels"] = ["side-mirror"]
    path = write_json(tmp_path / "export.json", export)
    cameras = write_json(tmp_path / "cameras.json", cameras_doc(doc))
    out = tmp_path / "imported.json"
    result = run("import", "label-studio", str(path), "--cameras", str(cameras), "-o", str(out))
    assert result.exit_code == 0, result.output
    assert "warning: " in result.output and "keypoint 'side-mirror': not a toosicubix keypoint name" in result.output
    assert "left out: side-mirror x1" in result.output
    out.unlink()
    result = run("import", "label-studio", str(path), "--cameras", str(cameras), "-o", str(out), "--strict")
    assert result.exit_code == 2
    assert "--strict: 1 warnings, nothing written" in result.output
    assert not out.exists()


def test_import_errors_exit_2_naming_the_file(tmp_path):
    doc = sample_doc()
    path = write_json(tmp_path / "export.json", label_studio_export(doc))
    out = tmp_path / "imported.json"
    result = run("import", "label-studio", str(path), "-o", str(out))
    assert result.exit_code == 2
    assert f"{path}: image '/data/upload/1/000001.png': no camera (give --cameras CAMERAS.json)" in result.output
    bad_cameras = write_json(tmp_path / "cameras.json", {"cameras": [{"match": "*"}]})
    result = run("import", "cvat", str(path), "--cameras", str(bad_cameras), "-o", str(out))
    assert result.exit_code == 2 and "$.cameras[0].K: missing" in result.output
    result = run("import", "label-studio", str(path), "--cameras", str(bad_cameras), "-o", str(out),
                 "--length", "wheelbase-left=two")
    assert result.exit_code == 2 and "--length" in result.output
    assert not out.exists()


def test_export_openlabel_and_cvat_from_a_fit(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    annotations = write_json(tmp_path / "sample.json", sample_doc())
    assert run("fit", str(annotations), "-q").exit_code == 0
    result = run("export", "openlabel", "toosicubix-out", "-o", "labels.json")
    assert result.exit_code == 0, result.output
    jsonschema.Draft7Validator(SCHEMA).validate(json.loads((tmp_path / "labels.json").read_text()))
    result = run("export", "cvat", "-o", "review.xml")  # OUT defaults to toosicubix-out
    assert result.exit_code == 0, result.output
    assert len(ET.parse(tmp_path / "review.xml").getroot().findall("image/polyline")) == 6
    # A changed annotation file no longer matches the fit: refused.
    annotations.write_text(annotations.read_text() + "\n")
    result = run("export", "openlabel", "toosicubix-out", "-o", "labels2.json")
    assert result.exit_code == 2 and "changed since the fit" in result.output
    result = run("export", "cvat", "nowhere", "-o", "review2.xml")
    assert result.exit_code == 2 and "results.json: missing" in result.output
    assert not (tmp_path / "labels2.json").exists() and not (tmp_path / "review2.xml").exists()


def _calib(P) -> str:
    rows = " ".join(f"{v:.12e}" for row in P for v in row)
    other = " ".join(f"{v:.12e}" for v in (1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0))
    return f"P0: {other}\nP1: {other}\nP2: {rows}\nP3: {other}\nR0_rect: 1 0 0 0 1 0 0 0 1\n"


def test_import_takes_a_folder_of_kitti_calib_files_or_a_camera_yaml(tmp_path):
    doc = sample_doc()
    (tmp_path / "annotations.xml").write_text(cvat_xml(doc))
    calib = tmp_path / "calib"
    calib.mkdir()
    for image in doc["images"][:2]:
        camera = image["camera"]
        P = camera.get("P") or [[*row, 0.0] for row in camera["K"]]
        (calib / f"{image['id']}.txt").write_text(_calib(P))
    out = tmp_path / "imported.json"
    result = run("import", "cvat", str(tmp_path / "annotations.xml"), "--cameras", str(calib), "-o", str(out))
    assert result.exit_code == 2
    assert f"image 'frames/000003.png': no camera (no KITTI calib file {calib / '000003.txt'})" in result.output
    (calib / "000003.txt").write_text(_calib([[*row, 0.0] for row in doc["images"][2]["camera"]["K"]]))
    result = run("import", "cvat", str(tmp_path / "annotations.xml"), "--cameras", str(calib), "-o", str(out))
    assert result.exit_code == 0, result.output
    imported = json.loads(out.read_text())
    assert imported["images"][0]["camera"] == {"P": doc["images"][0]["camera"]["P"]}
    assert same_clicks(imported, doc)
    yaml = tmp_path / "camera.yaml"
    yaml.write_text("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                    "   data: [ 1000., 0., 640., 0., 1000., 360., 0., 0., 1. ]\n")
    path = write_json(tmp_path / "export.json", label_studio_export(doc))
    result = run("import", "label-studio", str(path), "--cameras", str(yaml), "-o", str(out))
    assert result.exit_code == 0, result.output
    cameras = [im["camera"] for im in json.loads(out.read_text())["images"]]
    assert cameras == [{"K": [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]]}] * 3
    (tmp_path / "calib.bin").write_bytes(bytes(range(256)))
    result = run("import", "cvat", str(tmp_path / "annotations.xml"), "--cameras", str(tmp_path / "calib.bin"), "-o",
                 str(out))
    assert result.exit_code == 2
    assert "not a cameras file: expected a cameras JSON file" in result.output
    assert "a KITTI calib file (a line 'P2:' with 12 numbers)" in result.output

"""`fit` and `validate` on a labelling tool's file: one line naming the `toosicubix import` that reads it, exit 2."""

import json
import zipfile

import pytest

from tests.cli.test_cli_fit import run
from tests.formats.tool_fixtures import cvat_xml, label_studio_export, sample_doc, write_json

COCO = {"images": [{"id": 1, "file_name": "000001.png", "width": 1242, "height": 375}],
        "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "keypoints": [600, 200, 2], "num_keypoints": 1,
                         "bbox": [590, 190, 20, 20]}],
        "categories": [{"id": 1, "name": "car", "keypoints": ["wheel-front-left"], "skeleton": []}]}
KITTI = "Car 0.00 0 -1.58 587.01 173.33 614.12 200.12 1.65 1.67 3.64 -0.65 1.71 46.70 -1.59\n"
KITTI_TRACKING = "0 2 Car 0 0 -1.79 296.74 161.75 455.23 292.01 2.00 1.82 4.43 -4.55 1.65 13.85 -2.12\n"


def _files(tmp_path) -> dict[str, tuple[object, str]]:
    """Each tool's file, and the words of the line expected for it."""
    doc = sample_doc()
    (tmp_path / "annotations.xml").write_text(cvat_xml(doc))
    with zipfile.ZipFile(tmp_path / "task_7.zip", "w") as archive:
        archive.writestr("annotations.xml", cvat_xml(doc))
    (tmp_path / "000001.txt").write_text(KITTI)
    (tmp_path / "0002.txt").write_text(KITTI_TRACKING)
    return {
        "coco": (write_json(tmp_path / "keypoints.json", COCO),
                 "a COCO keypoint file, not an annotation file: turn it into one with `toosicubix import coco "),
        "label-studio": (write_json(tmp_path / "export.json", label_studio_export(doc)),
                         "a Label Studio JSON export, not an annotation file: turn it into one with `toosicubix "
                         "import label-studio "),
        "label-studio task": (write_json(tmp_path / "task.json", label_studio_export(doc)[0]),
                              "`toosicubix import label-studio "),
        "cvat": (tmp_path / "annotations.xml", "a CVAT for images or video 1.1 export, not an annotation file: turn "
                                               "it into one with `toosicubix import cvat "),
        "cvat zip": (tmp_path / "task_7.zip", "`toosicubix import cvat "),
        "kitti": (tmp_path / "000001.txt", "a KITTI label file (3D boxes, no clicks), not an annotation file: no "
                                           "`toosicubix import` reads it; `toosicubix simulate --kitti DIR"),
        "kitti tracking": (tmp_path / "0002.txt", "a KITTI tracking label file (3D boxes, no clicks), not an "
                                                  "annotation file: no `toosicubix import` reads it; `toosicubix "
                                                  "simulate --kitti-tracking DIR"),
    }


@pytest.mark.parametrize("command", ["fit", "validate"])
@pytest.mark.parametrize("tool", ["coco", "label-studio", "label-studio task", "cvat", "cvat zip", "kitti",
                                  "kitti tracking"])
def test_a_tool_file_is_named_with_its_import_command(tmp_path, command, tool):
    path, words = _files(tmp_path)[tool]
    out = tmp_path / "out"
    result = run(command, str(path), *(["-o", str(out)] if command == "fit" else []), "-q")
    assert result.exit_code == 2
    assert result.output.startswith(f"Error: {path}: ")
    assert words in result.output
    assert len(result.output.strip().splitlines()) == 1  # one line, not the schema's errors
    assert not out.exists()


def test_the_import_command_runs_as_given(tmp_path):
    path, _ = _files(tmp_path)["cvat"]
    line = run("fit", str(path), "-o", str(tmp_path / "out")).output
    command = line.split("`")[1].split()
    assert command[:4] == ["toosicubix", "import", "cvat", str(path)]


def test_an_annotation_file_with_errors_still_lists_them(tmp_path):
    doc = sample_doc()
    doc["images"][0]["vehicles"][0]["prototype"] = 7
    del doc["toosicubix"]
    path = write_json(tmp_path / "broken.json", doc)
    for args in (["fit", str(path), "-o", str(tmp_path / "out")], ["validate", str(path)]):
        result = run(*args)
        assert result.exit_code == 2
        assert "$.toosicubix: missing" in result.output and "import" not in result.output
    (tmp_path / "notes.txt").write_text("not a label\n")
    result = run("fit", str(tmp_path / "notes.txt"), "-o", str(tmp_path / "out"))
    assert result.exit_code == 2 and "import" not in result.output


def test_a_coco_file_is_not_mistaken_for_ours(tmp_path):
    doc = sample_doc()
    doc["annotations"] = []  # an unknown field of an annotation file is its schema error, not a COCO file
    result = run("validate", str(write_json(tmp_path / "a.json", doc)))
    assert result.exit_code == 2 and "unknown field" in result.output and "COCO" not in result.output
    assert json.loads((tmp_path / "a.json").read_text())["toosicubix"] == 1

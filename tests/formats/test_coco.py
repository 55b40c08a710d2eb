"""COCO keypoint import: names and index mappings, v flags, cameras, videos and tracks (TAO, BDD100K), and errors
naming file and JSON path."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from toosicubix.annotations.mapping import load_mapping, mapping_json_schema
from toosicubix.annotations.schema import parse_annotations
from toosicubix.annotations.stream import index_annotations
from toosicubix.cli import main
from toosicubix.errors import InputFileError
from toosicubix.fields import shown
from toosicubix.formats.cameras import load_cameras as read_cameras
from toosicubix.formats.coco import CocoImport, coco_to_annotations

REPO = Path(__file__).resolve().parents[2]
K = [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]]


def mapping_doc() -> dict:
    at = {"at": [0.0, 0.0, 0.5], "spread": [0.05, 0.05, 0.05]}
    return {"toosicubix_mapping": 1, "name": "tiny", "keypoints": ["lamp-l", "lamp-r", "hub", "handle", "aerial"],
            "unused": ["aerial"], "prototypes": {"7": "SUV"},
            "parts": [{"kind": "symmetry", "face": "rear", "left": "lamp-l", "right": "lamp-r"},
                      {"kind": "point", "part": "hub-rear-left", "xy": "hub"},
                      {"kind": "keypoint", "keypoint": "handle", "position": at},
                      {"kind": "keypoint", "keypoint": "lamp-l", "position": at}]}


def coco_doc(named: bool = True) -> dict:
    names = ["lamp-l", "lamp-r", "hub", "handle", "aerial"]
    return {"images": [{"id": 5, "file_name": "dir/frame_Camera_5.jpg", "width": 1280, "height": 720}],
            "categories": [{"id": 7, "name": "car", "keypoints": names if named else [""] * 5}],
            "annotations": [{"id": 42, "image_id": 5, "category_id": 7, "bbox": [10, 20, 100, 50],
                             "keypoints": [100, 200, 2, 140, 201, 2, 90, 230, 1, 120, 180, 0, 130, 150, 2]}]}


def write(tmp_path: Path, name: str, doc: dict) -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


@pytest.fixture
def files(tmp_path):
    mapping = write(tmp_path, "mapping.json", mapping_doc())
    cameras = write(tmp_path, "cameras.json", {"cameras": [{"match": "*Camera_6*", "K": K},
                                                           {"match": "*Camera_5*", "K": K}]})
    return tmp_path, mapping, cameras


@pytest.mark.parametrize("named", [True, False])
def test_import_by_names_and_by_index(files, named):
    tmp_path, mapping_path, cameras_path = files
    coco = write(tmp_path, "coco.json", coco_doc(named))
    mapping, _ = load_mapping(mapping_path)
    doc, summary = coco_to_annotations(coco, mapping, read_cameras(cameras_path))
    parse_annotations(doc)  # a valid annotation file v1
    image = doc["images"][0]
    assert image["id"] == "frame_Camera_5" and image["camera"] == {"K": K} and image["size"] == [1280, 720]
    vehicle = image["vehicles"][0]
    assert vehicle["id"] == "42" and vehicle["prototype"] == "SUV" and vehicle["box2d"] == [10, 20, 110, 70]
    # The symmetry took lamp-l first, so the keypoint part of lamp-l is not made; handle has v = 0.
    assert vehicle["parts"] == [
        {"kind": "symmetry", "face": "rear", "left": [100.0, 200.0], "right": [140.0, 201.0]},
        {"kind": "point", "part": "hub-rear-left", "xy": [90.0, 230.0]}]
    assert summary.hidden_kept == 1 and summary.unlabelled == 1
    assert dict(summary.unused) == {"aerial": 1}
    assert summary.clicks == 3


def test_hidden_keypoint_part_says_so(files):
    tmp_path, mapping_path, cameras_path = files
    coco = coco_doc()
    coco["annotations"][0]["keypoints"][11] = 1  # handle: labelled, not visible
    mapping, _ = load_mapping(mapping_path)
    doc, _ = coco_to_annotations(write(tmp_path, "coco.json", coco), mapping, read_cameras(cameras_path))
    handle = [p for p in doc["images"][0]["vehicles"][0]["parts"] if p["kind"] == "keypoint"]
    assert handle == [{"kind": "keypoint", "name": "handle", "xy": [120.0, 180.0], "at": [0.0, 0.0, 0.5],
                       "spread": [0.05, 0.05, 0.05], "visible": False}]


def test_per_image_K_needs_no_cameras_file(files):
    tmp_path, mapping_path, _ = files
    coco = coco_doc()
    coco["images"][0]["K"] = K
    mapping, _ = load_mapping(mapping_path)
    doc, _ = coco_to_annotations(write(tmp_path, "coco.json", coco), mapping, None)
    assert doc["images"][0]["camera"] == {"K": K}


def test_image_without_camera_is_named(files):
    tmp_path, mapping_path, _ = files
    cameras = write(tmp_path, "cams.json", {"cameras": [{"match": "*Camera_6*", "K": K}]})
    mapping, _ = load_mapping(mapping_path)
    with pytest.raises(InputFileError, match=r"coco.json: \$.images\[0\]: image 'dir/frame_Camera_5.jpg' has no "
                                             r"camera"):
        coco_to_annotations(write(tmp_path, "coco.json", coco_doc()), mapping, read_cameras(cameras))


def test_unknown_keypoint_name_is_named(files):
    tmp_path, mapping_path, cameras_path = files
    coco = coco_doc()
    coco["categories"][0]["keypoints"][3] = "wing-mirror"
    mapping, _ = load_mapping(mapping_path)
    with pytest.raises(InputFileError, match=r"\$.categories\[0\].keypoints\[3\]: keypoint 'wing-mirror' is not "
                                             r"known to the mapping 'tiny'"):
        coco_to_annotations(write(tmp_path, "coco.json", coco), mapping, read_cameras(cameras_path))


@pytest.mark.parametrize(("keypoints", "where"), [
    ([100, 200, 2] * 4, r"\$.annotations\[0\].keypoints: expected 15 numbers"),
    ([100, 200, 2, 140, 201, 3, 90, 230, 1, 120, 180, 0, 130, 150, 2], r"\$.annotations\[0\].keypoints\[3:6\]: "
                                                                        r"keypoint 1 \(lamp-r\)"),
    ([100, 200, 2, 140, None, 2, 90, 230, 1, 120, 180, 0, 130, 150, 2], r"\$.annotations\[0\].keypoints\[3:6\]"),
])
def test_bad_triplets_are_named(files, keypoints, where):
    tmp_path, mapping_path, cameras_path = files
    coco = coco_doc()
    coco["annotations"][0]["keypoints"] = keypoints
    mapping, _ = load_mapping(mapping_path)
    with pytest.raises(InputFileError, match=where):
        coco_to_annotations(write(tmp_path, "coco.json", coco), mapping, read_cameras(cameras_path))


#: Values a keypoint triplet's x, y or v may come as (JSON's, and a caller's numpy floats).
TRIPLET_VALUES = [0, 1, 2, 3, -1, 2.0, 1.0, 0.5, -0.0, True, False, 1e6, -1e6, 1e6 + 0.5, 10**6, 10**6 + 1, 10**400,
                  float("nan"), float("inf"), "3", None, [1], np.float64(2.0), np.float64(1e7)]


def _triplet_reference(x, y, v):
    """What a triplet is, as the field rules say it one value at a time: None (refused) or (x, y, visible), with
    ``False`` standing for an unlabelled keypoint (v 0)."""
    from toosicubix import fields

    if not (fields.passes(fields.pixel, x) and fields.passes(fields.pixel, y) and v in (0, 1, 2)) \
            or isinstance(v, bool):
        return None
    return False if v == 0 else (float(x), float(y), v == 2)


@given(st.lists(st.tuples(*[st.sampled_from(TRIPLET_VALUES)] * 3), min_size=4, max_size=4))
@settings(max_examples=300, deadline=None)
def test_triplets_take_what_the_field_rules_take(triplets):
    """The importer's quick test of plain numbers accepts and refuses exactly what the field rules do, and keeps
    the same values."""
    from toosicubix.formats.coco import ImportSummary, _triplets

    names = ["a", "b", "c", "d"]
    expected = [_triplet_reference(*t) for t in triplets]
    summary = ImportSummary()
    ann = {"keypoints": [value for t in triplets for value in t]}
    if any(e is None for e in expected):
        first = next(j for j, e in enumerate(expected) if e is None)
        with pytest.raises(InputFileError, match=rf"keypoints\[{3 * first}:{3 * first + 3}\]: keypoint {first} "):
            _triplets(ann, names, "coco.json", "$.annotations[0]", summary)
        return
    got = _triplets(ann, names, "coco.json", "$.annotations[0]", summary)
    assert got == {n: e for n, e in zip(names, expected, strict=True) if e is not False}
    assert summary.unlabelled == sum(e is False for e in expected)
    assert summary.hidden_kept == sum(e is not False and not e[2] for e in expected)


def test_cli_import_exit_codes_and_summary(files):
    tmp_path, mapping_path, cameras_path = files
    coco = write(tmp_path, "coco.json", coco_doc())
    out = tmp_path / "ann.json"
    result = CliRunner().invoke(main, ["import", "coco", str(coco), "--mapping", str(mapping_path), "--cameras",
                                       str(cameras_path), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "1 labelled keypoints no part used, by name: aerial 1" in result.output
    assert json.loads(out.read_text())["images"][0]["vehicles"][0]["id"] == "42"
    result = CliRunner().invoke(main, ["import", "coco", str(coco), "--mapping", str(mapping_path), "-o",
                                       str(tmp_path / "b.json")])
    assert result.exit_code == 2
    assert "has no camera" in result.output and not (tmp_path / "b.json").exists()
    result = CliRunner().invoke(main, ["import", "coco", str(coco), "--mapping", "no-such-mapping", "-o", str(out)])
    assert result.exit_code == 2 and "not a bundled mapping" in result.output


def test_bundled_mappings_load_and_schema_is_committed():
    for name in ("apollocar3d-66", "apollocar3d-66-paper", "toosicubix"):
        mapping, source = load_mapping(name)
        assert mapping.name == name and source == f"bundled mapping {name}"
    apollo, _ = load_mapping("apollocar3d-66")
    assert len(apollo.keypoints) == 66 and sum(p.kind == "keypoint" for p in apollo.parts) == 66
    committed = json.loads((REPO / "schemas" / "mapping.schema.json").read_text())
    assert committed == mapping_json_schema(), "regenerate schemas/mapping.schema.json"


def test_toosicubix_mapping_names_our_parts(tmp_path):
    mapping, _ = load_mapping("toosicubix")
    names = ["wheel-front-left", "rear-pair1-left", "rear-pair1-right", "arrow-forward-tail", "arrow-forward-head"]
    coco = {"images": [{"id": 1, "file_name": "a.png", "K": K}],
            "categories": [{"id": 1, "name": "car", "keypoints": names}],
            "annotations": [{"id": 3, "image_id": 1, "category_id": 1,
                             "keypoints": [1, 2, 2, 3, 4, 2, 5, 6, 2, 7, 8, 2, 9, 10, 2]}]}
    doc, summary = coco_to_annotations(write(tmp_path, "c.json", coco), mapping)
    kinds = [p["kind"] for p in doc["images"][0]["vehicles"][0]["parts"]]
    assert sorted(kinds) == ["direction", "point", "symmetry"] and not summary.unused


def test_toosicubix_mapping_is_the_tool_vocabulary():
    from toosicubix.parts.keypoints import KEYPOINTS, mapping_document

    mapping, _ = load_mapping("toosicubix")
    assert mapping.keypoints == list(KEYPOINTS)
    assert mapping.model_dump(mode="json", exclude_none=True, exclude_defaults=True)["parts"] == [
        {k: v for k, v in p.items()} for p in mapping_document()["parts"]]


# --- videos: TAO's and BDD100K's spellings ---------------------------------------------------------------------

KEYPOINTS = [100, 200, 2, 140, 201, 2, 90, 230, 1, 120, 180, 0, 130, 150, 2]


def video_doc(frame_key: str = "frame_index", track_key: str = "track_id") -> dict:
    """Two frames of one video (a keypoint frame, then a box-only frame of the same track) and a still image."""
    folder = "train/YFCC100M/v_f69e"
    return {"videos": [{"id": 3, "name": folder, "width": 1280, "height": 720}],
            "images": [{"id": 10, "video_id": 3, frame_key: 0, "file_name": f"{folder}/frame0001.jpg", "width": 1280,
                        "height": 720},
                       {"id": 11, "video_id": 3, frame_key: 5, "file_name": f"{folder}/frame0006.jpg", "width": 1280,
                        "height": 720},
                       {"id": 12, "file_name": "dir/still_Camera_5.jpg"}],
            "categories": [{"id": 7, "name": "car", "keypoints": ["lamp-l", "lamp-r", "hub", "handle", "aerial"]},
                           {"id": 8, "name": "van", "keypoints": ["lamp-l", "lamp-r", "hub", "handle", "aerial"]}],
            "annotations": [{"id": 1, "image_id": 10, "category_id": 7, "bbox": [10, 20, 100, 50],
                             "keypoints": KEYPOINTS, track_key: 4},
                            {"id": 2, "image_id": 11, "category_id": 7, "bbox": [14, 20, 100, 50], track_key: 4},
                            {"id": 3, "image_id": 12, "category_id": 7, "keypoints": KEYPOINTS}]}


@pytest.mark.parametrize(("frame_key", "track_key"), [("frame_index", "track_id"), ("frame_id", "instance_id")])
def test_video_frames_and_tracks(files, frame_key, track_key):
    tmp_path, mapping_path, _ = files
    cameras = write(tmp_path, "cams.json", {"cameras": [{"match": "*", "K": K}]})
    mapping, _ = load_mapping(mapping_path)
    coco = write(tmp_path, "video.json", video_doc(frame_key, track_key))
    doc, summary = coco_to_annotations(coco, mapping, read_cameras(cameras))
    first, second, still = doc["images"]
    assert [list(im) for im in (first, still)] == [["id", "file", "sequence", "frame", "camera", "vehicles", "size"],
                                                   ["id", "file", "camera", "vehicles"]]
    assert (first["id"], first["sequence"], first["frame"]) == ("train_YFCC100M_v_f69e_000000", "train_YFCC100M_v_f69e",
                                                                0)
    assert (second["id"], second["frame"], second["file"]) == ("train_YFCC100M_v_f69e_000005", 5,
                                                               "train/YFCC100M/v_f69e/frame0006.jpg")
    assert first["vehicles"][0]["track"] == second["vehicles"][0]["track"] == "train_YFCC100M_v_f69e-4"
    assert len(first["vehicles"][0]["parts"]) == 2
    # No keypoints on a tracked annotation: a frame with its box only.
    assert second["vehicles"][0] == {"id": "2", "prototype": "SUV", "track": "train_YFCC100M_v_f69e-4", "parts": [],
                                     "box2d": [14, 20, 114, 70]}
    assert still["id"] == "still_Camera_5" and "track" not in still["vehicles"][0]
    assert summary.tracks == {"train_YFCC100M_v_f69e-4"} and summary.tracked_without_parts == 1
    assert summary.vehicles_without_parts == 0
    # The document passes the rules across frames, as a whole and streamed.
    parse_annotations(doc)
    index = index_annotations(write(tmp_path, "ann.json", doc))
    assert index.sequences == (("train_YFCC100M_v_f69e", 0), ("train_YFCC100M_v_f69e", 5), None)


def test_video_named_on_the_image(files):
    tmp_path, mapping_path, _ = files
    coco = video_doc()
    del coco["videos"]
    for image in coco["images"][:2]:
        del image["video_id"]
        image["video_name"] = "b1c66a42-6f7d68ca"
    mapping, _ = load_mapping(mapping_path)
    doc, _ = coco_to_annotations(write(tmp_path, "v.json", coco), mapping,
                                 read_cameras(write(tmp_path, "c.json", {"cameras": [{"match": "*", "K": K}]})))
    assert [im.get("sequence") for im in doc["images"]] == ["b1c66a42-6f7d68ca", "b1c66a42-6f7d68ca", None]
    assert doc["images"][1]["vehicles"][0]["track"] == "b1c66a42-6f7d68ca-4"


def _bad_frame(coco):
    coco["images"][1]["frame_index"] = 1.5


def _frame_without_video(coco):
    del coco["images"][0]["video_id"]


def _track_on_a_still(coco):
    coco["annotations"][2]["track_id"] = 9


def _two_prototypes(coco):
    coco["annotations"][1]["category_id"] = 8  # 'van': the mapping's default prototype, not SUV


@pytest.mark.parametrize(("change", "message"), [
    (_bad_frame, "{coco}: $.images[1].frame_index: expected an integer frame number from 0 to 1000000, got 1.5"),
    (_frame_without_video, "{coco}: $.images[0].frame_index: expected a video (video_id, video_name, video) and a "
                           "frame number (frame_index, frame_id) together, found only 'frame_index'"),
    (_track_on_a_still, "{coco}: $.annotations[2].track_id: a track needs a frame of a video, but image "
                        "'dir/still_Camera_5.jpg' has no video_id or video_name or video with frame_index or frame_id"),
    (_two_prototypes, "{coco} (as imported): $.images[1].vehicles[0].track (image 'train_YFCC100M_v_f69e_000005'): "
                      "track 'train_YFCC100M_v_f69e-4' has prototype 'Car' here and 'SUV' at "
                      "$.images[0].vehicles[0].track: one prototype (and one size) per track"),
])
def test_video_bad_input_exits_2_naming_the_json_path(files, change, message):
    tmp_path, mapping_path, _ = files
    coco = video_doc()
    change(coco)
    path = write(tmp_path, "video.json", coco)
    cameras = write(tmp_path, "cams.json", {"cameras": [{"match": "*", "K": K}]})
    out = tmp_path / "ann.json"
    result = CliRunner().invoke(main, ["import", "coco", str(path), "--mapping", str(mapping_path), "--cameras",
                                       str(cameras), "-o", str(out)])
    assert result.exit_code == 2
    assert result.output == f"Error: {message.format(coco=path)}\n"
    assert not out.exists()


# --- hostile values (issue 34): the field rules name the file and the JSON path, exit 2, nothing written ---------

HUGE = 10**400


def _set_path(doc: dict, path: tuple, value) -> dict:
    target = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return doc


@pytest.mark.parametrize(("path", "value", "message"), [
    (("annotations", 0, "bbox", 0), HUGE, "$.annotations[0].bbox[0]: expected a pixel coordinate from -1000000 to "
                                          "1000000, got an integer of 401 digits"),
    (("annotations", 0, "bbox", 2), HUGE, "$.annotations[0].bbox[2]: expected a box side from 0 to 2000000, got an "
                                          "integer of 401 digits"),
    (("annotations", 0, "keypoints", 3), HUGE, "$.annotations[0].keypoints[3:6]: keypoint 1 (lamp-r): expected x, y "
                                               "pixel coordinates within +-1000000 and v in 0, 1, 2, got [an integer "
                                               "of 401 digits, 201, 2]"),
    (("images", 0, "width"), HUGE, "$.images[0].width: expected an image side in pixels from 1 to 1000000, got an "
                                   "integer of 401 digits"),
    (("images", 0, "height"), "720", "$.images[0].height: expected an image side in pixels from 1 to 1000000, got "
                                     "'720'"),
    (("categories", 0, "id"), [7], "$.categories[0].id: expected a category id: a string of 1 to 128 characters (no "
                                   "control characters) or an integer of at most 18 digits, got [7]"),
    (("annotations", 0, "category_id"), {"id": 7}, "$.annotations[0].category_id: expected a category id: a string "
                                                   "of 1 to 128 characters (no control characters) or an integer of "
                                                   "at most 18 digits, got {'id': 7}"),
    (("annotations", 0, "image_id"), [5], "$.annotations[0].image_id: expected an image id"),
    (("images", 0, "id"), 10**4000, "$.images[0].id: expected an image id: a string of 1 to 128 characters (no "
                                    "control characters) or an integer of at most 18 digits, got an integer of 4001 "
                                    "digits"),
    (("annotations", 0, "id"), "a\x00", "$.annotations[0].id: expected an annotation id"),
    (("images", 0, "K"), [[HUGE, 0, 1], [0, 1, 1], [0, 0, 1]], "$.images[0].K[0][0]: expected a finite number, got "
                                                               "an integer of 401 digits"),
], ids=lambda value: shown(value, 30))
def test_hostile_values_exit_2_naming_file_and_path(files, path, value, message):
    tmp_path, mapping_path, cameras_path = files
    coco = write(tmp_path, "coco.json", _set_path(coco_doc(), path, value))
    out = tmp_path / "ann.json"
    result = CliRunner().invoke(main, ["import", "coco", str(coco), "--mapping", str(mapping_path), "--cameras",
                                       str(cameras_path), "-o", str(out)])
    assert result.exit_code == 2
    assert result.output.startswith(f"Error: {coco}: {message}")
    assert not out.exists()


def test_an_integer_python_cannot_read_is_named_by_its_line(files):
    tmp_path, mapping_path, cameras_path = files
    coco = tmp_path / "coco.json"
    coco.write_text(json.dumps(coco_doc(), indent=1).replace('"width": 1280', '"width": ' + "9" * 5000))
    result = CliRunner().invoke(main, ["import", "coco", str(coco), "--mapping", str(mapping_path), "--cameras",
                                       str(cameras_path), "-o", str(tmp_path / "ann.json")])
    assert result.exit_code == 2
    assert result.output == f"Error: {coco}: $: not valid JSON: a number of 5000 digits at line 6 (expected at most " \
                            "4300)\n"


def test_two_images_with_one_id_are_named_both(files):
    tmp_path, mapping_path, cameras_path = files
    coco = coco_doc()
    coco["images"].append({**coco["images"][0], "id": 6, "file_name": "other/FRAME_Camera_5.jpg"})
    mapping, _ = load_mapping(mapping_path)
    with pytest.raises(InputFileError, match=r"coco.json: \$.images\[1\]: this image and the one at \$.images\[0\] "
                                             r"both get the image id 'FRAME_Camera_5'"):
        coco_to_annotations(write(tmp_path, "coco.json", coco), mapping, read_cameras(cameras_path))


def test_written_image_by_image_as_the_whole_document_would_be(files):
    tmp_path, mapping_path, _ = files
    cameras = read_cameras(write(tmp_path, "cams.json", {"cameras": [{"match": "*", "K": K}]}))
    mapping, _ = load_mapping(mapping_path)
    coco = write(tmp_path, "video.json", video_doc())
    imported = CocoImport(coco, mapping, cameras)
    assert imported.write(tmp_path / "ann.json") == 3
    document, summary = coco_to_annotations(coco, mapping, cameras)
    assert (tmp_path / "ann.json").read_text() == json.dumps(document, indent=1) + "\n"
    assert imported.summary == summary
    # Only the annotations' places in the text are kept between the passes, not the decoded annotations.
    assert all(isinstance(start, int) and isinstance(i, int) for spans in imported._spans.values()
               for start, i in spans)


def test_an_annotation_file_problem_found_while_writing_leaves_nothing(files):
    tmp_path, mapping_path, _ = files
    cameras = read_cameras(write(tmp_path, "cams.json", {"cameras": [{"match": "*", "K": K}]}))
    mapping, _ = load_mapping(mapping_path)
    coco = video_doc()
    coco["annotations"][1]["category_id"] = 8  # a second prototype on the track: found once every frame is read
    out = tmp_path / "ann.json"
    with pytest.raises(InputFileError, match="one prototype"):
        CocoImport(write(tmp_path, "video.json", coco), mapping, cameras).write(out)
    assert not out.exists() and list(tmp_path.glob(".ann.json*")) == []


COCO_VALUES = st.one_of(
    st.none(), st.booleans(), st.floats(), st.integers(min_value=-(10**500), max_value=10**500),
    st.text(max_size=20), st.lists(st.integers(min_value=-3, max_value=3), max_size=3),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


def _coco_paths(doc, path=()):
    out = [path]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _coco_paths(v, (*path, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _coco_paths(v, (*path, i))
    return out


@settings(max_examples=150, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_value_anywhere_imports_or_is_named(files, data):
    """One value of a video COCO file replaced by any JSON value: an annotation file v1, or an InputFileError
    naming the file and a JSON path; never another exception."""
    tmp_path, mapping_path, _ = files
    cameras = read_cameras(write(tmp_path, "cams.json", {"cameras": [{"match": "*", "K": K}]}))
    mapping, _ = load_mapping(mapping_path)
    doc = copy.deepcopy(video_doc())  # its keypoint lists are one shared list
    path = data.draw(st.sampled_from(_coco_paths(doc)[1:]))
    coco = write(tmp_path, "fuzz.json", _set_path(doc, path, data.draw(COCO_VALUES)))
    try:
        document, _ = coco_to_annotations(coco, mapping, cameras)
    except InputFileError as exc:
        assert str(exc).startswith(f"{coco}") and ": $" in str(exc)
        return
    parse_annotations(document)


def test_the_pixel_rule_s_quick_path_refuses_what_its_general_rule_refuses():
    """fields.pixel tells plain numbers at once (a COCO file's hundreds of thousands of coordinates) and hands anything
    else to fields.number with the pixel bounds: the same verdict and value for each."""
    import functools

    from toosicubix import fields

    general = functools.partial(fields.number, low=-fields.MAX_PIXEL, high=fields.MAX_PIXEL, what="a pixel coordinate")
    values = [0, 1, -1, 1e6, -1e6, 10 ** 6, 10 ** 6 + 1, -(10 ** 6) - 1, 1e6 + 1e-9, 999999.9999, 10 ** 400, 0.5,
              float("nan"), float("inf"), -float("inf"), True, False, None, "1", [1.0], 5e-324]
    for value in values:
        assert fields.passes(fields.pixel, value) == fields.passes(general, value), value
        if fields.passes(general, value):
            quick, slow = fields.pixel(value, None, None), general(value, None, None)
            assert type(quick) is float and quick == slow, value

"""Label Studio JSON export import (fixtures as Label Studio exports them)."""

import json
import math
from pathlib import Path
from urllib.parse import quote

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.formats.tool_fixtures import (
    cameras_doc,
    fit_results,
    label_studio_export,
    max_pose_difference,
    same_clicks,
    sample_doc,
    sample_fit,
    write_json,
)
from toosicubix.annotations.schema import parse_annotations
from toosicubix.cli import main
from toosicubix.errors import FormatError, InputFileError
from toosicubix.formats.cameras import load_cameras
from toosicubix.formats.labelstudio import read_label_studio


def _cameras(tmp_path):
    return load_cameras(write_json(tmp_path / "cameras.json", cameras_doc(sample_doc())))


def _task(result, annotations_key="annotations", cancelled=False):
    return {"id": 7, "data": {"image": "/data/upload/3/5f3a2b1c-a.png"},
            annotations_key: [{"id": 1, "result": result, "was_cancelled": cancelled}]}


def _kp(rid, name, x, y, parent=None, width=1000, height=500):
    region = {"original_width": width, "original_height": height, "image_rotation": 0,
              "value": {"x": x, "y": y, "width": 0.5, "keypointlabels": [name]}, "id": rid,
              "from_name": "keypoint", "to_name": "image", "type": "keypointlabels", "origin": "manual"}
    if parent:
        region["parentID"] = parent
    return region


def _box(rid, label, x, y, w, h, width=1000, height=500):
    return {"original_width": width, "original_height": height, "image_rotation": 0,
            "value": {"x": x, "y": y, "width": w, "height": h, "rotation": 0, "rectanglelabels": [label]},
            "id": rid, "from_name": "vehicle", "to_name": "image", "type": "rectanglelabels", "origin": "manual"}


def _any_camera(tmp_path):
    return load_cameras(write_json(tmp_path / "any.json", {"cameras": [
        {"match": "*", "K": [[800, 0, 500], [0, 800, 250], [0, 0, 1]]}]}))


@pytest.mark.parametrize("completions", [False, True])
def test_template_annotation_import_fit_gives_the_sample_cuboids(tmp_path, completions):
    doc = sample_doc()
    path = write_json(tmp_path / "export.json", label_studio_export(doc, parent_ids=True, completions=completions))
    imported, summary = read_label_studio(path, _cameras(tmp_path))
    assert summary.warnings == []
    assert same_clicks(imported, doc)
    boxes = [v["box2d"] for im in imported["images"] for v in im["vehicles"]]
    expected = [v["box2d"] for im in doc["images"] for v in im["vehicles"]]
    assert max(abs(a - b) for ba, bb in zip(boxes, expected, strict=True) for a, b in zip(ba, bb, strict=True)) < 1e-9
    out = write_json(tmp_path / "imported.json", imported)
    assert max_pose_difference(json.loads(sample_fit()), fit_results(out)) < 1e-6


def test_percent_become_pixels_of_the_original_size(tmp_path):
    path = write_json(tmp_path / "e.json", [_task([_box("b", "Van", 10, 20, 50, 60),
                                                   _kp("k", "top-center", 25, 50, parent="b")])])
    doc, _ = read_label_studio(path, _any_camera(tmp_path))
    image = doc["images"][0]
    assert image["id"] == "a" and image["file"] == "a.png"  # Label Studio's upload prefix 5f3a2b1c- stripped
    assert image["size"] == [1000, 500]
    assert image["vehicles"] == [{"id": "1", "prototype": "Van", "box2d": [100.0, 100.0, 600.0, 400.0],
                                  "parts": [{"kind": "point", "part": "top-center", "xy": [250.0, 250.0]}]}]


def test_without_parent_ids_keypoints_go_to_the_box_that_holds_them(tmp_path):
    result = [_box("b1", "Car", 10, 10, 20, 20), _box("b2", "Van", 60, 10, 20, 20),
              _kp("k1", "wheel-front-left", 15, 29), _kp("k2", "wheel-rear-left", 70, 29),
              _kp("k3", "rear-center", 50, 50)]
    doc, summary = read_label_studio(write_json(tmp_path / "e.json", [_task(result)]), _any_camera(tmp_path))
    car, van = doc["images"][0]["vehicles"]
    assert car["parts"][0]["part"] == "wheel-front-left" and van["parts"][0]["part"] == "wheel-rear-left"
    assert summary.warnings == [
        f"{tmp_path / 'e.json'}: image 'a.png', task 7, keypoint k3 'rear-center' "
        "($[0].annotations[0].result[4]): cannot be grouped to a vehicle (no parentID, no relation, inside no "
        "vehicle box): left out"]


def test_sample_without_parent_ids_groups_only_what_one_box_holds(tmp_path):
    doc = sample_doc()
    path = write_json(tmp_path / "export.json", label_studio_export(doc, parent_ids=False))
    imported, summary = read_label_studio(path, _cameras(tmp_path))
    # Image 3 has one vehicle: its box holds every click. In images 1 and 2 boxes overlap (and an arrow drawn on
    # the ground lies outside every box): those keypoints are reported, never guessed.
    assert same_clicks({"images": imported["images"][2:]}, {"images": doc["images"][2:]})
    assert summary.warnings
    assert all("000001.png" in w or "000002.png" in w for w in summary.warnings)
    assert sum("inside 2 vehicle boxes" in w for w in summary.warnings) == 9
    assert sum("inside no vehicle box" in w for w in summary.warnings) == 1


def test_relations_tie_keypoints_to_boxes(tmp_path):
    result = [_box("b1", "Car", 10, 10, 20, 20), _box("b2", "Van", 15, 15, 20, 20), _kp("k1", "top-center", 20, 20),
              {"type": "relation", "from_id": "k1", "to_id": "b2", "direction": "right"}]
    doc, summary = read_label_studio(write_json(tmp_path / "e.json", [_task(result)]), _any_camera(tmp_path))
    assert [v["prototype"] for v in doc["images"][0]["vehicles"]] == ["Van"]
    assert "task 7, box b1" in summary.warnings[0] and "no usable keypoints" in summary.warnings[0]


def test_cancelled_and_repeated_annotations(tmp_path):
    cancelled = _task([_box("b", "Car", 10, 10, 20, 20)], cancelled=True)
    twice = _task([_box("b", "Car", 10, 10, 20, 20), _kp("k", "top-center", 20, 20, parent="b")])
    twice["data"]["image"] = "b.png"
    twice["annotations"].insert(0, {"id": 0, "result": [], "was_cancelled": False})
    doc, summary = read_label_studio(write_json(tmp_path / "e.json", [cancelled, twice]), _any_camera(tmp_path))
    assert [im["id"] for im in doc["images"]] == ["b"]
    assert "no annotation that is not cancelled: image left out" in summary.warnings[0]
    assert "2 annotations: the last one (annotations[1]) is used" in summary.warnings[1]


def test_errors_name_the_file_and_json_path(tmp_path):
    bad = _task([_kp("k", "top-center", "left", 20)])
    with pytest.raises(FormatError, match=r"\$\[0\].annotations\[0\].result\[0\].value.x: expected a percentage"):
        read_label_studio(write_json(tmp_path / "e.json", [bad]), _any_camera(tmp_path))
    good = _task([_kp("k", "top-center", 20, 20)])
    with pytest.raises(FormatError, match=r"image 'a.png': no camera"):
        read_label_studio(write_json(tmp_path / "e.json", [good]), None)
    with pytest.raises(FormatError, match=r"\$: expected a list of tasks"):
        read_label_studio(write_json(tmp_path / "e.json", "tasks"), None)


def test_a_real_label_studio_export(tmp_path):
    # Exported by Label Studio 1.23.2 through its API (tests/integration/labelstudio_roundtrip.py) after a project
    # was made from `toosicubix template label-studio` and the sample's clicks were posted, nested in their boxes.
    path = Path(__file__).parent / "fixtures" / "labelstudio-1.23.2-export.json"
    imported, summary = read_label_studio(path, _cameras(tmp_path))
    assert summary.warnings == []
    assert [im["file"] for im in imported["images"]] == [f"/frames/{im['id']}.png" for im in sample_doc()["images"]]
    assert same_clicks(imported, sample_doc())


def test_an_image_without_vehicles_needs_no_camera(tmp_path):
    empty = _task([])
    labelled = _task([_box("b", "Car", 10, 10, 20, 20), _kp("k", "top-center", 20, 20, parent="b")])
    labelled["data"]["image"] = "frames/b.png"
    cameras = load_cameras(write_json(tmp_path / "c.json", {"cameras": [
        {"match": "frames/*", "K": [[800, 0, 500], [0, 800, 250], [0, 0, 1]]}]}))
    doc, summary = read_label_studio(write_json(tmp_path / "e.json", [empty, labelled]), cameras)
    assert [im["id"] for im in doc["images"]] == ["b"]
    assert summary.warnings == [f"{tmp_path / 'e.json'}: image 'a.png', image: no vehicles and "
                                f"no camera (no entry of {tmp_path / 'c.json'} matches it): image left out"]


# How Label Studio names an image in a task's data (and so in its export), from its code:
# - an upload: FileUpload's upload_name_generator (label_studio/data_import/models.py) stores
#   upload/<project id>/<str(uuid4())[0:8]>-<file name>, served at MEDIA_URL /data/ (a host before it when
#   HOSTNAME is set, a script name when FORCE_SCRIPT_NAME is);
# - a local-files storage: f"{HOSTNAME}/data/local-files/?d={quote(relative path)}" (io_storages/localfiles);
# - a cloud storage: f"{url_scheme}://{bucket}/{key}" with url_scheme s3, gs, azure-blob (io_storages/*/models.py).
def _as_label_studio_names(name: str) -> dict[str, tuple[str, str]]:
    """Each way Label Studio names the image ``frames/<name>``: its URL and the file name the import gives."""
    return {
        "upload": (f"/data/upload/1/9f834e14-{name}", name),
        "upload, hostname": (f"http://localhost:8080/data/upload/1/0a1b2c3d-{name}", name),
        "upload, script name": (f"/label-studio/data/upload/1/deadbeef-{name}", name),
        "local files": (f"/data/local-files/?d={quote('frames/' + name)}", f"frames/{name}"),
        "local files, hostname": (f"http://localhost:8080/data/local-files/?d={quote('frames/' + name)}",
                                  f"frames/{name}"),
        "s3": (f"s3://toosicubix-data/kitti/frames/{name}", name),
        "gs": (f"gs://toosicubix-data/frames/{name}", name),
        "azure-blob": (f"azure-blob://container/frames/{name}", name),
        "url": (f"https://example.invalid/frames/{name}", f"/frames/{name}"),  # as the fixture has them
    }


@pytest.mark.parametrize("how", list(_as_label_studio_names("x.png")))
def test_image_ids_are_the_original_file_names_of_a_real_export(tmp_path, how):
    # The real Label Studio 1.23.2 export, its image URLs rewritten as Label Studio writes each kind of source:
    # the same image ids (the files' stems, as KITTI's ground truth names them) and clicks come out of each.
    path = Path(__file__).parent / "fixtures" / "labelstudio-1.23.2-export.json"
    tasks = json.loads(path.read_text())
    expected = []
    for task in tasks:
        name = task["data"]["image"].rsplit("/", 1)[1]
        task["data"]["image"], file = _as_label_studio_names(name)[how]
        expected.append(file)
    imported, summary = read_label_studio(write_json(tmp_path / "export.json", tasks), _cameras(tmp_path))
    assert summary.warnings == []
    assert [im["file"] for im in imported["images"]] == expected
    assert [im["id"] for im in imported["images"]] == [im["id"] for im in sample_doc()["images"]]
    assert same_clicks(imported, sample_doc())


@pytest.mark.parametrize(("url", "file"), [
    ("/data/upload/3/5f3a2b1c-my_car.png", "my_car.png"),
    ("/data/upload/3/5f3a2b1c-9f834e14-a.png", "9f834e14-a.png"),  # one prefix only: the rest is the name
    ("/data/upload/3/5f3a2b1c-stra%C3%9Fe.png", "straße.png"),  # the URL is percent-encoded
    ("/data/upload/3/000001.png", "/data/upload/3/000001.png"),  # no prefix: kept as it is
    ("/data/upload/3/5F3A2B1C-a.png", "/data/upload/3/5F3A2B1C-a.png"),  # not what Label Studio writes
    ("/data/upload/3/5f3a2b1-a.png", "/data/upload/3/5f3a2b1-a.png"),  # 7 digits
    ("frames/5f3a2b1c-a.png", "frames/5f3a2b1c-a.png"),  # not an upload
    ("/data/local-files/?d=kitti%20set/image_2/000001.png", "kitti set/image_2/000001.png"),
    ("s3://bucket/a%20b.png", "a%20b.png"),  # an object key is the key, not URL-encoded
])
def test_the_file_name_rule(tmp_path, url, file):
    task = _task([_box("b", "Car", 10, 10, 20, 20), _kp("k", "top-center", 20, 20, parent="b")])
    task["data"]["image"] = url
    doc, _ = read_label_studio(write_json(tmp_path / "e.json", [task]), _any_camera(tmp_path))
    assert doc["images"][0]["file"] == file


@pytest.mark.parametrize("d", ["../../etc/x.png", "frames/../../x.png", "frames%2F..%2F..%2Fx.png", "..\\x.png"])
def test_a_local_files_path_that_climbs_is_refused(tmp_path, d):
    task = _task([_kp("k", "top-center", 20, 20)])
    task["data"]["image"] = f"/data/local-files/?d={d}"
    with pytest.raises(FormatError, match=r"\$\[0\]\.data\.image \(task 7\): the local-files path .* has a '\.\.' "
                                          r"component: refused"):
        read_label_studio(write_json(tmp_path / "e.json", [task]), _any_camera(tmp_path))


# --- hostile values (issue 34) ---------------------------------------------------------------------------------

def _with(task_change=None, region_change=None):
    task = _task([_box("b", "Car", 10, 10, 50, 50), _kp("k", "wheel-front-left", 20, 30, parent="b"),
                  _kp("l", "wheel-rear-left", 40, 30, parent="b")])
    if task_change:
        task_change(task)
    if region_change:
        region_change(task["annotations"][0]["result"])
    return task


def _image(url):
    return lambda task: task["data"].__setitem__("image", url)


def _width(value):
    return lambda result: [region.__setitem__("original_width", value) for region in result]


@pytest.mark.parametrize(("task", "message"), [
    (_with(_image("http://[abc/x.png")), "$[0].data.image (task 7): expected an image URL or file name, got "
                                         "'http://[abc/x.png': Invalid IPv6 URL"),
    (_with(_image("/data/local-files/?d=..%2F..%2F000001.png")),
     "$[0].data.image (task 7): the local-files path '../../000001.png' has a '..' component: refused"),
    (_with(_image("http://host/img/..%2F..%2Fetc%2Fx.png")),
     "$[0].data.image (task 7): the file name '/img/../../etc/x.png' (from 'http://host/img/..%2F..%2Fetc%2Fx.png') "
     "has a '..' component: refused"),
    (_with(_image("../../x.png")), "the file name '../../x.png' (from '../../x.png') has a '..' component"),
    (_with(region_change=_width(math.inf)), "$[0].annotations[0].result[0].original_width: expected an image side in "
                                            "pixels from 1 to 1000000, got inf"),
    (_with(region_change=_width(math.nan)), "original_width: expected an image side in pixels from 1 to 1000000, "
                                            "got nan"),
    (_with(region_change=_width(10**400)), "original_width: expected an image side in pixels from 1 to 1000000, got "
                                           "an integer of 401 digits"),
    (_with(region_change=lambda r: r[1]["value"].__setitem__("x", 1e300)),
     "$[0].annotations[0].result[1].value.x: expected a percentage of the image's size from -10000 to 10000, got "
     "1e+300"),
    (_with(region_change=lambda r: r[0].__setitem__("id", [1])), "$[0].annotations[0].result[0].id: expected a "
                                                                 "region id"),
    (_with(region_change=lambda r: r[1].__setitem__("parentID", {"b": 1})), "result[1].parentID: expected a region id"),
])
def test_hostile_values_exit_2_naming_file_and_path(tmp_path, task, message):
    path = write_json(tmp_path / "export.json", [task])
    out = tmp_path / "ann.json"
    result = CliRunner().invoke(main, ["import", "label-studio", str(path), "--cameras",
                                       str(write_json(tmp_path / "c.json", {"cameras": [{"match": "*", "K": [
                                           [800, 0, 500], [0, 800, 250], [0, 0, 1]]}]})), "-o", str(out)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"Error: {path}: ") and message in result.output
    assert not out.exists()


def test_huge_task_and_relation_ids_are_named_not_spelled(tmp_path):
    task = _with()
    task["id"] = 10**400
    task["annotations"].append(task["annotations"][0])  # two annotations: a warning names the task
    task["annotations"][0]["result"].append({"type": "relation", "from_id": 10**400, "to_id": [1]})
    _, summary = read_label_studio(write_json(tmp_path / "e.json", [task]), _any_camera(tmp_path))
    assert summary.warnings == [f"{tmp_path / 'e.json'}: image 'a.png', task an integer of 401 digits: 2 annotations: "
                                "the last one (annotations[1]) is used"]


LS_VALUES = st.one_of(
    st.none(), st.booleans(), st.floats(), st.integers(min_value=-(10**500), max_value=10**500), st.text(max_size=30),
    st.sampled_from(["http://[::1/x.png", "/data/local-files/?d=a%2F..%2Fb.png", "s3://b/..", "%zz", "\x00"]),
    st.lists(st.integers(min_value=-3, max_value=3), max_size=2), st.dictionaries(st.text(max_size=2), st.none()))


def _ls_paths(doc, path=()):
    out = [path]
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        out += _ls_paths(value, (*path, key))
    return out


@settings(max_examples=150, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_value_anywhere_imports_or_is_named(tmp_path, data):
    """One value of an export replaced by any JSON value: an annotation file v1, or an error naming the file and
    a JSON path; never another exception."""
    doc = [_with()]
    path = data.draw(st.sampled_from(_ls_paths(doc)[1:]))
    target = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = data.draw(LS_VALUES)
    export = write_json(tmp_path / "fuzz.json", doc)
    try:
        imported, _ = read_label_studio(export, _any_camera(tmp_path))
    except (FormatError, InputFileError) as exc:
        assert str(exc).startswith(f"{export}: $") or "(as imported)" in str(exc), str(exc)
        return
    parse_annotations(imported)

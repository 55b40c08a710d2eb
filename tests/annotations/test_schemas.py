import copy
import json

import pytest

from tests.conftest import REPO
from toosicubix.annotations.priors_file import load_priors_file
from toosicubix.annotations.schema import (
    MAX_CLICKS_PER_VEHICLE,
    AnnotationFile,
    json_schema,
    load_annotations,
    parse_annotations,
)
from toosicubix.errors import InputFileError
from toosicubix.vocabulary import DIRECTION_AXES, POINT_PARTS

# The example of DESIGN section 3, verbatim.
DESIGN_EXAMPLE = {
    "toosicubix": 1,
    "images": [{
        "id": "000123",
        "file": "image_2/000123.png",
        "size": [1242, 375],
        "camera": {"P": [[721.5, 0, 609.6, 44.9], [0, 721.5, 172.9, 0.2], [0, 0, 1, 0.003]]},
        "vehicles": [{
            "id": "3",
            "prototype": "Car",
            "box2d": [387.6, 181.5, 423.8, 203.1],
            "parts": [
                {"kind": "point", "part": "wheel-front-left", "xy": [401.2, 202.0]},
                {"kind": "symmetry", "face": "rear", "left": [390.1, 190.3], "right": [410.8, 190.6]},
                {"kind": "direction", "axis": "forward", "tail": [380.0, 215.0], "head": [420.0, 212.0]},
            ],
        }],
    }],
}


def problems_of(doc) -> list[tuple[str, str]]:
    with pytest.raises(InputFileError) as info:
        parse_annotations(doc, "bad.json")
    return info.value.problems


def test_design_example_parses():
    doc = parse_annotations(DESIGN_EXAMPLE)
    vehicle = doc.images[0].vehicles[0]
    assert [p.kind for p in vehicle.parts] == ["point", "symmetry", "direction"]
    assert doc.images[0].camera.P is not None and doc.images[0].camera.K is None


def test_every_part_name_and_axis_is_accepted():
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    parts = [{"kind": "point", "part": name, "xy": [10.0, 20.0]} for name in POINT_PARTS]
    parts += [{"kind": "symmetry", "face": f, "left": [1.0, 2.0], "right": [3.0, 4.0]}
              for f in ("front", "rear", "roof")]
    parts += [{"kind": "direction", "axis": a, "tail": [1.0, 2.0], "head": [9.0, 9.0]} for a in DIRECTION_AXES]
    doc["images"][0]["vehicles"][0]["parts"] = parts
    assert len(parse_annotations(doc).images[0].vehicles[0].parts) == 19 + 4 + 3 + 6  # 4 wheel hubs


def test_keypoint_and_plate_parts_are_typed():
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    keypoint = {"kind": "keypoint", "name": "door_handle", "xy": [10.0, 20.0], "at": [0.1, 0.45, 0.5],
                "spread": [0.05, 0.02, 0.04]}
    plate = {"kind": "plate", "face": "rear", "a": [1.0, 2.0], "b": [9.0, 2.0], "at": [-0.5, 0.0, 0.4],
             "spread": [0.01, 0.01, 0.05], "metres": 0.44, "sigma": 0.01}
    doc["images"][0]["vehicles"][0]["parts"] = [keypoint, plate]
    parts = parse_annotations(doc).images[0].vehicles[0].parts
    assert parts[0].visible and parts[1].metres == 0.44
    for bad, where in (({**keypoint, "name": ""}, "name"), ({**keypoint, "spread": [0.1, 0.0, 0.1]}, "spread"),
                       ({**plate, "face": "roof"}, "face"), ({**plate, "metres": 1000.0}, "metres")):
        doc["images"][0]["vehicles"][0]["parts"] = [bad]
        with pytest.raises(InputFileError, match=rf"parts\[0\]\.{where}"):
            parse_annotations(doc)


def test_camera_K_with_distortion():
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    doc["images"][0]["camera"] = {"K": [[700, 0, 600], [0, 700, 180], [0, 0, 1]], "distortion": [-0.1, 0.01, 0, 0, 0]}
    assert parse_annotations(doc).images[0].camera.distortion == [-0.1, 0.01, 0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    ("mutate", "path", "fragment"),
    [
        (lambda d: d["images"][0]["vehicles"][0].update(colour="red"),
         "$.images[0].vehicles[0].colour", "unknown field"),
        (lambda d: d["images"][0]["vehicles"][0].pop("prototype"),
         "$.images[0].vehicles[0].prototype", "missing required field"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][1]["left"].__setitem__(0, float("nan")),
         "$.images[0].vehicles[0].parts[1].left[0]", "finite number"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][2]["head"].__setitem__(1, float("inf")),
         "$.images[0].vehicles[0].parts[2].head[1]", "finite number"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][0].update(part="wheel-front"),
         "$.images[0].vehicles[0].parts[0].part", "'wheel-front-left'"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][1].update(face="side"),
         "$.images[0].vehicles[0].parts[1].face", "'roof'"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][2].update(axis="sideways"),
         "$.images[0].vehicles[0].parts[2].axis", "'leftward'"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][0].update(kind="circle"),
         "$.images[0].vehicles[0].parts[0]", "'point', 'symmetry', 'direction'"),
        (lambda d: d["images"][0]["vehicles"].append(copy.deepcopy(d["images"][0]["vehicles"][0])),
         "$.images[0].vehicles", "unique vehicle ids, got '3' at [0] and [1]"),
        (lambda d: d["images"].append(copy.deepcopy(d["images"][0])),
         "$.images", "unique image ids"),
        (lambda d: d["images"][0].update(camera={"K": [[700, 0, 600], [1400, 0, 1200], [0, 0, 1]]}),
         "$.images[0].camera.K", "invertible K"),
        (lambda d: d["images"][0].update(camera={"P": [[0, 0, 609.6, 44.9], [0, 0, 172.9, 0.2], [0, 0, 1, 0]]}),
         "$.images[0].camera.P", "invertible K"),
        (lambda d: d["images"][0].update(camera={"K": [[700, 0, 600], [0, 700, 180], [0, 0, 2]]}),
         "$.images[0].camera.K", "last row of K"),
        (lambda d: d["images"][0]["camera"].update(K=[[700, 0, 600], [0, 700, 180], [0, 0, 1]]),
         "$.images[0].camera", "exactly one of 'K'"),
        (lambda d: d["images"][0].update(camera={"K": [[700, 0, 600], [0, 700, 180], [0, 0, 1]], "distortion": [0.1]}),
         "$.images[0].camera.distortion", "4, 5, 8, 12 or 14"),
        (lambda d: d["images"][0]["vehicles"][0].update(box2d=[10, 10, 5, 20]),
         "$.images[0].vehicles[0].box2d", "x1 < x2"),
        (lambda d: d["images"][0].update(id="../etc"),
         "$.images[0].id", "pattern"),
        (lambda d: d.update(toosicubix=2),
         "$.toosicubix", "1"),
    ],
)
def test_bad_input_names_the_json_path(mutate, path, fragment):
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    mutate(doc)
    problems = problems_of(doc)
    assert any(p == path and fragment in m for p, m in problems), problems


def test_error_message_names_the_file(tmp_path):
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    doc["images"][0]["vehicles"][0]["parts"][0]["part"] = "mirror"
    path = tmp_path / "ann.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputFileError) as info:
        load_annotations(path)
    assert str(info.value).startswith(f"{path}: $.images[0].vehicles[0].parts[0].part: Input should be")
    assert 'got "mirror"' in str(info.value)


def test_json_syntax_error_has_line_and_column(tmp_path):
    path = tmp_path / "ann.json"
    path.write_text('{"toosicubix": 1,\n "images": [,]}')
    with pytest.raises(InputFileError, match=r"not valid JSON: .* at line 2 column 13"):
        load_annotations(path)


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="cannot read the file"):
        load_annotations(tmp_path / "nope.json")


def test_committed_schema_matches_the_models():
    committed = json.loads((REPO / "schemas" / "annotations.schema.json").read_text())
    assert committed == json_schema(), "run: toosicubix schema > schemas/annotations.schema.json"


def test_schema_lists_every_part_name():
    schema = json.dumps(json_schema())
    for name in (*POINT_PARTS, *DIRECTION_AXES):
        assert f'"{name}"' in schema


def test_models_are_frozen():
    doc = parse_annotations(DESIGN_EXAMPLE)
    with pytest.raises(ValueError, match="frozen"):
        doc.images[0].id = "x"  # type: ignore[misc]
    assert isinstance(doc, AnnotationFile)


def test_priors_file_rejects_non_spd_covariance(tmp_path):
    path = tmp_path / "priors.json"
    entry = {"mean": [4, 1.7, 1.5], "cov": [[1, 2, 0], [2, 1, 0], [0, 0, 1]], "kitti_type": "Car", "source": "test"}
    path.write_text(json.dumps({"toosicubix_priors": 1, "prototypes": {"Car": entry}}))
    with pytest.raises(InputFileError, match=r"\$\.prototypes\.Car\.cov: expected a positive definite"):
        load_priors_file(path)


def test_clicks_per_vehicle_are_limited():
    # At the limit a vehicle parses; one clicked point more is refused with its JSON path and the limit.
    def doc_with(n_pairs: int, n_points: int):
        doc = copy.deepcopy(DESIGN_EXAMPLE)
        pair = {"kind": "symmetry", "face": "rear", "left": [390.1, 190.3], "right": [410.8, 190.6]}
        point = {"kind": "point", "part": "wheel-front-left", "xy": [401.2, 202.0]}
        doc["images"][0]["vehicles"][0]["parts"] = [pair] * n_pairs + [point] * n_points
        return doc

    half = MAX_CLICKS_PER_VEHICLE // 2
    parse_annotations(doc_with(half, MAX_CLICKS_PER_VEHICLE - 2 * half))
    problems = problems_of(doc_with(half, MAX_CLICKS_PER_VEHICLE - 2 * half + 1))
    assert len(problems) == 1
    path, message = problems[0]
    assert path == "$.images[0].vehicles[0].parts"
    assert f"at most {MAX_CLICKS_PER_VEHICLE} clicked points" in message
    assert f"found {MAX_CLICKS_PER_VEHICLE + 1}" in message


def test_a_camera_shared_by_many_images_is_checked_once_and_a_bad_one_refused_each_time(monkeypatch):
    """The camera checks (a determinant, a condition number) run once per distinct K or P of a file; a camera they
    refuse is refused at every image that has it, each named with its own path."""
    from toosicubix.annotations import schema

    schema._checked_camera.cache_clear()
    calls = []
    real = schema.check_intrinsics
    monkeypatch.setattr(schema, "check_intrinsics", lambda K: calls.append(K.tolist()) or real(K))
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    image = doc["images"][0]
    doc["images"] = [{**copy.deepcopy(image), "id": f"im{i}", "camera": {"K": [[700.0 + i % 3, 0, 600],
                                                                           [0, 700, 180], [0, 0, 1]]}}
                     for i in range(30)]
    parse_annotations(doc, "good.json")
    assert len(calls) == 3  # three distinct cameras among 30 images
    bad = {"K": [[700, 0, 600], [1400, 0, 1200], [0, 0, 1]]}
    for i in (4, 17):
        doc["images"][i]["camera"] = bad
    problems = problems_of(doc)
    assert [p for p, m in problems if "invertible K" in m] == ["$.images[4].camera.K", "$.images[17].camera.K"]

"""The flat keypoint vocabulary: names, keypoints -> parts -> keypoints, the mapping document."""

import json

import pytest

from tests.formats.tool_fixtures import sample_doc
from toosicubix.annotations.schema import parse_annotations
from toosicubix.parts.keypoints import (
    KEYPOINTS,
    SLOTS,
    TOOL_POINT_PARTS,
    KeypointProblem,
    keypoints_from_parts,
    lengths_of_parts,
    mapping_document,
    parts_from_keypoints,
    skeleton_edges,
)
from toosicubix.vocabulary import DIRECTION_AXES, LENGTH_FEATURES, POINT_PARTS


def _canonical(parts):
    return sorted(json.dumps(p, sort_keys=True) for p in parts)


def test_vocabulary_names_every_click_once():
    # 19 point parts (the 4 wheel hubs of real clicks left out), 3 faces x 3 pairs x 2, 6 arrows x 2, 8 length
    # features x 2.
    assert len(POINT_PARTS) == 23 and len(TOOL_POINT_PARTS) == 19
    assert len(KEYPOINTS) == 19 + 18 + 2 * len(DIRECTION_AXES) + 2 * len(LENGTH_FEATURES) == 65
    assert len(set(KEYPOINTS)) == len(KEYPOINTS)
    for name in ("wheel-front-left", "rear-center", "edge-rear-left", "corner-top-rear-left", "rear-pair1-left",
                 "roof-pair2-right", "front-pair3-left", "arrow-forward-tail", "arrow-upward-head", "plate-rear-a",
                 "wheelbase-left-b", "tyre-front-right-a"):
        assert name in KEYPOINTS


def test_sample_parts_survive_keypoints_and_back():
    doc = sample_doc()
    for image in doc["images"]:
        for vehicle in image["vehicles"]:
            keypoints = keypoints_from_parts(vehicle["parts"])
            conversion = parts_from_keypoints(keypoints, lengths_of_parts(vehicle["parts"]))
            assert conversion.problems == []
            assert _canonical(conversion.parts) == _canonical(vehicle["parts"])


def test_length_parts_keep_their_size_through_the_caller():
    parts = [{"kind": "length", "feature": "wheelbase-left", "a": [10.0, 20.0], "b": [50.0, 21.0],
              "metres": 2.7, "sigma": 0.05}]
    keypoints = keypoints_from_parts(parts)
    assert keypoints == [("wheelbase-left-a", (10.0, 20.0)), ("wheelbase-left-b", (50.0, 21.0))]
    assert parts_from_keypoints(keypoints, lengths_of_parts(parts)).parts == parts
    # Without a size, a wheelbase cannot be used; a plate falls back to the EU width.
    unknown = parts_from_keypoints(keypoints)
    assert unknown.parts == [] and "size of wheelbase-left is not known" in unknown.problems[0][1]
    plate = parts_from_keypoints({"plate-rear-a": (1.0, 2.0), "plate-rear-b": (3.0, 2.0)})
    assert plate.parts[0]["metres"] == 0.52 and plate.parts[0]["sigma"] == 0.01


def test_problems_name_the_keypoint():
    conversion = parts_from_keypoints([("rear-pair1-left", (1.0, 2.0)), ("wheel-front-left", (3.0, 4.0)),
                                       ("wheel-front-left", (5.0, 6.0)), ("mirror-left", (7.0, 8.0))])
    assert conversion.parts == [{"kind": "point", "part": "wheel-front-left", "xy": [3.0, 4.0]}]
    assert ("rear-pair1-left", "needs rear-pair1-right too") in conversion.problems
    assert ("wheel-front-left", "given more than once") in conversion.problems
    assert ("mirror-left", "not a toosicubix keypoint name") in conversion.problems


def test_parts_the_vocabulary_cannot_hold_are_refused():
    pair = {"kind": "symmetry", "face": "rear", "left": [1.0, 1.0], "right": [2.0, 1.0]}
    keypoints = keypoints_from_parts([pair] * 3)
    assert [k for k, _ in keypoints][-2:] == ["rear-pair3-left", "rear-pair3-right"]
    with pytest.raises(KeypointProblem, match="more than 3 symmetric pairs on the rear face"):
        keypoints_from_parts([pair] * 4)
    arrow = {"kind": "direction", "axis": "forward", "tail": [1.0, 1.0], "head": [2.0, 1.0]}
    with pytest.raises(KeypointProblem, match="arrow-forward-tail given twice"):
        keypoints_from_parts([arrow, arrow])


def test_mapping_document_covers_the_vocabulary_and_makes_valid_parts():
    mapping = mapping_document()
    assert mapping["name"] == "toosicubix" and mapping["keypoints"] == list(KEYPOINTS)
    assert len(mapping["parts"]) == len(SLOTS)
    click_fields = {"xy", "left", "right", "tail", "head", "a", "b"}
    used = [value for part in mapping["parts"] for key, value in part.items() if key in click_fields]
    assert sorted(used) == sorted(KEYPOINTS)
    # Filling every click field with a pixel gives parts the annotation schema accepts (length: known sizes).
    parts = []
    for part in mapping["parts"]:
        filled = {k: ([1.0, 2.0] if k in click_fields else v) for k, v in part.items()}
        if filled["kind"] == "length":
            filled.setdefault("metres", 1.0)
            filled.setdefault("sigma", 0.1)
        parts.append(filled)
    parse_annotations({"toosicubix": 1, "images": [{"id": "a", "camera": {"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
                                                    "vehicles": [{"id": "1", "prototype": "Car", "parts": parts}]}]})


def test_skeleton_edges_join_known_keypoints():
    edges = skeleton_edges()
    assert ("rear-pair1-left", "rear-pair1-right") in edges and ("arrow-forward-tail", "arrow-forward-head") in edges
    assert all(a in KEYPOINTS and b in KEYPOINTS and a != b for a, b in edges)

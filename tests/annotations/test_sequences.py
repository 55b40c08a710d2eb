"""Sequences and tracks in the annotation file (issue 32): an image may be a frame of a sequence, a vehicle a track.

The rules that span images are checked both by the whole-file reader and by the streaming index ``fit`` uses, with
the JSON path of the offending field: a frame number once per sequence, a track in one sequence, one prototype per
track, one vehicle per track in a frame, ``sequence`` and ``frame`` together, and a track only on a frame.
"""

from __future__ import annotations

import copy
import json

import pytest

from toosicubix.annotations.convert import document_json, images_from_schema
from toosicubix.annotations.schema import parse_annotations
from toosicubix.annotations.stream import index_annotations
from toosicubix.errors import InputFileError

K = [[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]]


def _frame(index: int, sequence: str = "0003", frame: int | None = None, tracks=(("a", "Car"),)) -> dict:
    return {"id": f"{sequence}_{index:06d}", "sequence": sequence, "frame": index if frame is None else frame,
            "camera": {"K": K},
            "vehicles": [{"id": str(k), "prototype": prototype, "track": track, "box2d": [100.0, 100.0, 200.0, 180.0]}
                         for k, (track, prototype) in enumerate(tracks)]}


def _doc(*images: dict) -> dict:
    return {"toosicubix": 1, "images": list(images)}


def _problems(doc: dict, tmp_path) -> tuple[list, list]:
    """The problems of the whole-file reader and of the streaming index, both."""
    with pytest.raises(InputFileError) as whole:
        parse_annotations(doc, "bad.json")
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputFileError) as streamed:
        index_annotations(path)
    return whole.value.problems, streamed.value.problems


def test_sequences_and_tracks_round_trip(tmp_path):
    doc = _doc(_frame(0), _frame(1, tracks=()), _frame(2, tracks=(("a", "Car"), ("b", "Van"))),
               {"id": "still", "camera": {"K": K}, "vehicles": []})
    images = images_from_schema(parse_annotations(doc))
    assert [(im.sequence, im.frame) for im in images] == [("0003", 0), ("0003", 1), ("0003", 2), (None, None)]
    assert [v.track for v in images[2].vehicles] == ["a", "b"]
    again = document_json(images)
    assert document_json(images_from_schema(parse_annotations(again))) == again
    assert again["images"][2]["vehicles"][1]["track"] == "b" and again["images"][3].get("sequence") is None
    path = tmp_path / "ok.json"
    path.write_text(json.dumps(doc))
    index = index_annotations(path)
    assert index.sequences == (("0003", 0), ("0003", 1), ("0003", 2), None) and index.tracked == 3
    assert index.vehicles == 3 and index.clicked == 0  # boxes only: nothing a pilot could fit alone


@pytest.mark.parametrize(("images", "path", "message"), [
    ((_frame(0), _frame(1, frame=0)), "$.images[1].frame", "frame 0 of sequence '0003' is given twice"),
    ((_frame(0), _frame(1, sequence="0004", tracks=(("a", "Car"),))), "$.images[1].vehicles[0].track",
     "a track stays in one sequence"),
    ((_frame(0), _frame(1, tracks=(("a", "Van"),))), "$.images[1].vehicles[0].track",
     "one prototype (and one size) per track"),
    # A sequence names its label_02 file: 'Seq' and 'seq' would share one where the file system ignores case.
    ((_frame(0, sequence="Seq", tracks=()), _frame(1, sequence="seq", tracks=())), "$.images[1].sequence",
     "differs from 'Seq' (at $.images[0]) only in case"),
])
def test_rules_across_frames_name_the_json_path(tmp_path, images, path, message):
    whole, streamed = _problems(_doc(*copy.deepcopy(images)), tmp_path)
    assert any(where == path and message in text for where, text in streamed), streamed
    assert any(where == path and message in text for where, text in whole), whole


def test_rules_within_a_frame(tmp_path):
    two = _frame(0, tracks=(("a", "Car"), ("a", "Car")))
    _, streamed = _problems(_doc(two), tmp_path)
    assert streamed == [("$.images[0].vehicles", "expected one vehicle per track in a frame, got track 'a' at [0] "
                                                 "and [1]")]
    no_frame = _frame(0)
    del no_frame["frame"]
    assert "expected 'sequence' and 'frame' together" in _problems(_doc(no_frame), tmp_path)[1][0][1]
    loose = _frame(0)
    del loose["frame"], loose["sequence"]
    assert "on an image whose vehicles carry a 'track'" in _problems(_doc(loose), tmp_path)[1][0][1]
    bad_name = _frame(0)
    bad_name["sequence"] = "../x"
    assert [where for where, _ in _problems(_doc(bad_name), tmp_path)[1]] == ["$.images[0].sequence"]


def test_image_ids_that_differ_in_case_are_refused_by_the_stream_as_by_the_whole_file(tmp_path):
    # They name label_2 files; fit reads the file through the stream, which only refused exact duplicates.
    images = (_frame(0, tracks=()) | {"id": "Img"}, _frame(1, tracks=()) | {"id": "img"})
    whole, streamed = _problems(_doc(*images), tmp_path)
    assert streamed == [("$.images[1].id", "expected unique image (ignoring case: they name files) ids, got 'img' "
                                           "at [0] and [1]")]
    assert [m for _, m in whole] == [m for _, m in streamed]

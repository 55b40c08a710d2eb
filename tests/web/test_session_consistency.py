"""The page's session keeps the file readable and its fits true to the file (a review of toosicubix/web/session.py):
undo across a sequence's frames, the fit cache, a save that fails half way, previews, renames and the messages."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest

import toosicubix.formats.atomic as atomic
from tests.web.conftest import make_session
from tests.web.synthetic import NAMED, clicks, write_scene, write_sequence
from toosicubix.annotations.convert import load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.web.request_fields import ApiError
from toosicubix.web.session import Session, load_cameras


def _edit(session: Session, index: int, **change) -> dict:
    return session.edit(index, {"revision": session.revision, **change})


@pytest.fixture
def sequence(tmp_path: Path) -> Session:
    paths, cameras = write_sequence(tmp_path, 3)
    return Session(paths, tmp_path / "a.json", load_cameras(cameras, [p.stem for p in paths]), load_priors(),
                   sequence="0003")


@pytest.fixture
def single(tmp_path: Path) -> Session:
    session = make_session(write_scene(tmp_path), tmp_path / "a.json")
    _edit(session, 0, op="add_vehicle")
    for c in clicks(NAMED):
        _edit(session, 0, op="add_click", vehicle="1", kind=c.kind, name=c.name, uv=c.uv)
    return session


def test_a_deleted_track_s_name_is_not_given_again(sequence):
    # Before: the Van took the deleted Car's name, the undo brought the Car back, and the file held one track as a
    # Car and a Van, which fit and annotate then refused to read.
    assert _edit(sequence, 0, op="add_vehicle")["track"] == "0003-1"
    _edit(sequence, 0, op="delete_vehicle", vehicle="1")
    assert _edit(sequence, 1, op="add_vehicle", prototype="Van")["track"] == "0003-2"
    _edit(sequence, 0, op="undo")
    tracks = [[(v.track, v.prototype) for v in im.vehicles] for im in load_images(sequence.out)]
    assert tracks == [[("0003-1", "Car")], [("0003-2", "Van")], []]


def test_an_undo_that_would_split_a_track_s_prototype_is_refused(sequence):
    _edit(sequence, 0, op="add_vehicle")
    _edit(sequence, 1, op="add_vehicle", track="0003-1")
    _edit(sequence, 0, op="delete_vehicle", vehicle="1")
    _edit(sequence, 1, op="set_vehicle", vehicle="1", prototype="Van")  # the track is on this frame only now
    before = sequence.out.read_bytes()
    with pytest.raises(ApiError, match="a Car here and a Van on frame 1"):
        _edit(sequence, 0, op="undo")
    assert sequence.out.read_bytes() == before and load_images(sequence.out)[1].vehicles[0].prototype == "Van"


def test_a_dismissed_prediction_does_not_pass_to_a_new_track(sequence):
    _edit(sequence, 0, op="add_vehicle")
    _edit(sequence, 1, op="dismiss_prediction", track="0003-1")
    _edit(sequence, 0, op="delete_vehicle", vehicle="1")
    assert _edit(sequence, 2, op="add_vehicle", prototype="Bus")["track"] == "0003-2"
    view = sequence.image_view(1)
    assert [p["track"] for p in view["predictions"]] == ["0003-2"]


def test_joining_a_track_on_a_frame_clears_its_dismissal_there(sequence):
    _edit(sequence, 0, op="add_vehicle")
    _edit(sequence, 1, op="dismiss_prediction", track="0003-1")
    _edit(sequence, 1, op="add_vehicle", prototype="Car")  # a new track, 0003-2
    _edit(sequence, 1, op="set_vehicle", vehicle="1", track="0003-1")
    assert sequence.images[1].dismissed == []


def test_the_fit_shown_is_of_the_length_s_size_as_the_file_has_it(single):
    # Before: the fit cache knew a length's clicks but not its size, so the page kept showing the 2.4 m fit.
    wheels = clicks(NAMED)
    uv = [wheels[0].uv[0], wheels[1].uv[0]]
    depths = []
    for metres in (2.4, 4.0):
        doc = _edit(single, 0, op="add_click", vehicle="1", kind="length", name="wheelbase-left", uv=uv,
                    known=[metres, 0.01])
        depths.append(doc["vehicles"][0]["fit"]["depth_m"])
        _edit(single, 0, op="delete_click", vehicle="1", part=len(single.images[0].vehicles[0].parts) - 1)
    assert depths[1] > depths[0] * 1.1  # a longer wheelbase puts the same clicks farther away


def test_a_save_that_fails_half_way_changes_neither_file(single, monkeypatch):
    _edit(single, 0, op="set_vehicle", vehicle="1", done=True)  # the extras file holds the done mark
    files = {p: p.read_bytes() for p in (single.out, single.extras_path)}
    real = atomic.tempfile.mkstemp

    def full_disk(*args, **kwargs):
        if kwargs.get("prefix", "").startswith(f".{single.extras_path.name}."):
            raise OSError(errno.ENOSPC, "No space left on device", str(single.extras_path))
        return real(*args, **kwargs)

    monkeypatch.setattr(atomic.tempfile, "mkstemp", full_disk)
    with pytest.raises(ApiError, match="No space left on device"):
        _edit(single, 0, op="delete_click", vehicle="1", part=0)
    assert {p: p.read_bytes() for p in files} == files
    assert len(single.images[0].vehicles[0].parts) == len(clicks(NAMED))
    assert not [p for p in single.out.parent.iterdir() if p.name.endswith(".tmp")]


def test_a_preview_fits_with_the_known_dimensions_it_is_given(single):
    vehicle = json.loads(single.out.read_text())["images"][0]["vehicles"][0]
    plain = single.preview({"image": 0, "vehicle": vehicle})["fit"]["dimensions"]
    known = single.preview({"image": 0, "vehicle": {**vehicle, "known_dimensions": {
        "dx": {"metres": 6.0, "sigma": 0.01}}}})["fit"]["dimensions"]
    assert abs(known[0] - 6.0) < 0.01 and abs(plain[0] - 6.0) > 1.0


def test_a_length_renamed_to_another_feature_takes_that_feature_s_size(single):
    wheels = clicks(NAMED)
    uv = [wheels[0].uv[0], wheels[1].uv[0]]
    doc = _edit(single, 0, op="add_click", vehicle="1", kind="length", name="wheelbase-left", uv=uv,
                known=[2.7, 0.05])
    part = doc["part"]
    with pytest.raises(ApiError, match="needs that feature's own known size"):
        _edit(single, 0, op="rename", vehicle="1", part=part, kind="length", name="plate-front")
    _edit(single, 0, op="rename", vehicle="1", part=part, kind="length", name="plate-front", known=[0.52, 0.01])
    length = json.loads(single.out.read_text())["images"][0]["vehicles"][0]["parts"][part]
    assert (length["feature"], length["metres"], length["sigma"]) == ("plate-front", 0.52, 0.01)


@pytest.mark.parametrize(("call", "field"), [
    (lambda s: s.preview({"image": 0, "vehicle": {"id": "9", "prototype": "Nope"}}), "vehicle.prototype:"),
    (lambda s: s.preview({"image": 0, "vehicle": {"id": "9", "prototype": "Car", "box2d": [0, 0, 9000, 100]}}),
     "vehicle.box2d"),
    (lambda s: s.preview({"image": 0, "vehicle": {"id": "9", "prototype": "Car", "track": "t"}}), "vehicle:"),
    (lambda s: _edit(s, 0, op="move_click", vehicle="1", part=0, uv=[100, "a"]), "uv[1]:"),
    (lambda s: s.save({"revision": True}), "revision:"),
])
def test_messages_name_the_request_s_own_field(single, call, field):
    with pytest.raises(ApiError) as info:
        call(single)
    assert str(info.value).startswith(field), str(info.value)

"""``toosicubix annotate --sequence``: frames in frame order, vehicles as tracks, a track carried to the frames it is
not on yet as a predicted cuboid (confirm, box, click or dismiss it), saved as tracks that ``fit`` fits as tracks."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tests.web.conftest import serving
from tests.web.synthetic import CAMERA, DIMENSIONS, FRAMES, NAMED, UNNAMED, clicks, sequence_pose, write_sequence
from toosicubix.annotations.convert import load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.cli import main
from toosicubix.geometry import geodesic_angle
from toosicubix.web.client import Client
from toosicubix.web.request_fields import ApiError
from toosicubix.web.sequence import frame_numbers, frames_to_fit, new_track_name, track_sort_key
from toosicubix.web.session import Session, load_cameras

SEQUENCE = "0003"
TRACK = "0003-1"


@pytest.fixture
def frames(tmp_path: Path) -> tuple[list[Path], Path]:
    return write_sequence(tmp_path)


def _session(frames: tuple[list[Path], Path], out: Path, sequence: str | None = SEQUENCE) -> Session:
    paths, cameras = frames
    return Session(paths, out, load_cameras(cameras, [p.stem for p in paths]), load_priors(), sequence=sequence)


@pytest.fixture
def served(frames, tmp_path: Path) -> Iterator[tuple[Client, Session]]:
    session = _session(frames, tmp_path / "annotations.json")
    with serving(session) as client:
        yield client, session


def _ok(client: Client, change: dict, image: int) -> dict:
    status, doc = client.edit(change, image=image)
    assert status == 200, doc
    return doc


def _view(client: Client, image: int) -> dict:
    status, doc = client.request("GET", f"/api/images/{image}")
    assert status == 200, doc
    return doc


def _click_fully(client: Client, image: int, vehicle: str) -> dict:
    """Every part of the synthetic vehicle, named, where it is on frame ``image``."""
    for c in clicks([*NAMED, *UNNAMED], *sequence_pose(image)):
        doc = _ok(client, {"op": "add_click", "vehicle": vehicle, "kind": c.kind, "name": c.name, "uv": c.uv}, image)
    return doc


def _first_frame(client: Client) -> dict:
    doc = _ok(client, {"op": "add_vehicle"}, 0)
    assert doc["track"] == TRACK  # a new vehicle of a sequence is a new track
    return _click_fully(client, 0, doc["vehicle"])


# -- frame numbers, track names, the frames fitted together -----------------------------------------------------


def test_frame_numbers_are_the_file_names_last_digits_else_positions():
    assert frame_numbers(["000123.png", "000124.png", "000200.png"]) == ([123, 124, 200], True)
    assert frame_numbers(["drive_0005_frame_0007.png", "drive_0005_frame_0008.png"]) == ([7, 8], True)
    assert frame_numbers(["f_0007.v3.png", "f_0008.v3.png"]) == ([0, 1], False)  # the stem's last digits: 3, 3
    assert frame_numbers(["a.png", "b7.png"]) == ([0, 1], False)  # not every name has digits
    assert frame_numbers(["left_01.png", "right_01.png"]) == ([0, 1], False)  # two give the same number


def test_new_track_names_take_the_smallest_unused_number():
    assert new_track_name("0003", []) == "0003-1"
    assert new_track_name("0003", ["0003-1", "0003-3", "0004-2"]) == "0003-2"
    assert sorted(["0003-10", "0003-2", "0003-1"], key=track_sort_key) == ["0003-1", "0003-2", "0003-10"]


def test_the_frames_fitted_together_are_bounded_and_reach_a_clicked_frame():
    clicked = {0: True, **{f: False for f in range(1, 100)}, 100: True}
    # Frame 50: 30 on each side, none clicked, so the nearest clicked frame beyond each side too.
    assert frames_to_fit(50, clicked, window=30) == [0, *range(20, 50), *range(51, 81), 100]
    # Frame 10: frame 0 is clicked and near; on the far side none is within 30, so frame 100.
    assert frames_to_fit(10, clicked, window=30) == [*range(0, 10), *range(11, 41), 100]
    assert frames_to_fit(5, {}, window=30) == []


# -- the sequence on the page --------------------------------------------------------------------------------------


def test_images_are_frames_in_frame_order(tmp_path):
    paths, cameras = write_sequence(tmp_path, frames=3)
    given = [paths[2], paths[0], paths[1]]  # as a shell might list them
    session = _session((given, cameras), tmp_path / "a.json")
    assert session.frames_from_names
    summary = session.summary()
    assert [(im["id"], im["sequence"], im["frame"]) for im in summary["images"]] == [
        ("000002", SEQUENCE, 2), ("000000", SEQUENCE, 0), ("000001", SEQUENCE, 1)]
    assert summary["order"] == [1, 2, 0]  # the page steps through them in frame order
    view = session.image_view(1)
    assert (view["sequence"], view["frame"], view["predictions"], view["tracks"]) == (SEQUENCE, 0, [], [])


def test_without_a_sequence_nothing_changes(frames, tmp_path):
    session = _session(frames, tmp_path / "a.json", sequence=None)
    assert "sequence" not in session.summary()["images"][0]
    doc = session.edit(0, {"revision": 0, "op": "add_vehicle"})
    assert doc["track"] is None and doc["vehicles"][0]["track"] is None and doc["predictions"] == []
    with pytest.raises(ApiError, match="not a frame of a sequence"):
        session.edit(0, {"revision": 1, "op": "confirm_prediction", "track": TRACK})
    assert load_images(tmp_path / "a.json")[0].sequence is None


def test_a_clicked_frame_confirmed_predictions_and_a_clicked_last_frame_fit_as_one_track(served, tmp_path):
    """Frame 0 clicked fully, the track's prediction confirmed on frames 1 to 9, frame 10 clicked fully: saved as a
    track, which `fit` fits as one: every frame a pose (from clicks or interpolated), one size."""
    client, _ = served
    doc = _first_frame(client)
    assert doc["vehicles"][0]["fit"]["pose_from"] == "clicks"
    assert doc["tracks"] == [{"track": TRACK, "vehicle": "1", "pose_from": "clicks"}]
    for f in range(1, FRAMES - 1):
        view = _view(client, f)
        (prediction,) = view["predictions"]
        assert prediction["track"] == TRACK and prediction["source"] == "held"  # only earlier frames yet
        assert prediction["from_frames"] == [f - 1, None] and prediction["fit"]["status"] == "ok"
        assert len(prediction["fit"]["corners_uv"]) == 8 and prediction["fit"]["sigma"]["yaw_deg"] > 0
        assert view["tracks"] == [{"track": TRACK, "vehicle": None, "pose_from": "predicted"}]
        doc = _ok(client, {"op": "confirm_prediction", "track": TRACK}, f)
        (vehicle,) = doc["vehicles"]
        assert (vehicle["track"], vehicle["parts"], vehicle["fit"]["pose_from"]) == (TRACK, [], "interpolated")
        assert doc["predictions"] == [] and doc["vehicle"] == vehicle["id"]
    # On the last frame the person clicks the prediction's parts: a vehicle of that track, then its clicks.
    doc = _ok(client, {"op": "add_vehicle", "track": TRACK}, FRAMES - 1)
    doc = _click_fully(client, FRAMES - 1, doc["vehicle"])
    fit = doc["vehicles"][0]["fit"]
    assert fit["pose_from"] == "clicks" and fit["track_frames"] == list(range(FRAMES))

    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["fit", str(tmp_path / "annotations.json"), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "2 from their clicks, 0 from a box alone, 9 interpolated" in result.output
    images = json.loads((out / "results.json").read_text())["images"]
    assert [(im["sequence"], im["frame"]) for im in images] == [(SEQUENCE, f) for f in range(FRAMES)]
    vehicles = [im["vehicles"][0] for im in images]
    assert [v["pose_from"] for v in vehicles] == ["clicks"] + ["interpolated"] * (FRAMES - 2) + ["clicks"]
    assert {v["track"] for v in vehicles} == {TRACK} and all(v["status"] == "ok" for v in vehicles)
    assert len({tuple(v["dimensions"]) for v in vehicles}) == 1  # one size for the track
    # Exact clicks on a vehicle at constant velocity and turn rate: every frame's pose is the truth up to the size
    # prior's pull on the scale (a car of 4.0 m under a prior of 3.9 m: depth within 5 %), rotation within 1 degree.
    for f, v in enumerate(vehicles):
        R, t = sequence_pose(f)
        assert np.linalg.norm(np.array(v["t_cam_vehicle"]) - t) < 0.05 * np.linalg.norm(t), f
        assert np.rad2deg(geodesic_angle(np.array(v["R_cam_vehicle"]), R)) < 1.0, f
    assert np.allclose(vehicles[0]["dimensions"], DIMENSIONS, rtol=0.05)


def test_a_prediction_interpolates_between_the_tracks_frames(served):
    client, _ = served
    _first_frame(client)
    doc = _ok(client, {"op": "add_vehicle", "track": TRACK}, FRAMES - 1)
    _click_fully(client, FRAMES - 1, doc["vehicle"])
    view = _view(client, 5)
    (prediction,) = view["predictions"]
    assert prediction["source"] == "interpolated" and prediction["from_frames"] == [0, FRAMES - 1]
    # Exact clicks on frames 0 and 10 of a vehicle at constant velocity and turn rate: frame 5's pose is the truth's
    # up to the size prior's pull on the scale (depth within 5 %), which leaves the bottom centre's pixel in place
    # (it scales about the camera), and the axle prior's on the shape (the rear axle 0.30 of the length behind the
    # middle, a car's 0.282: rule 29): within 0.6 px (0.52 measured; 0.5 allowed before that prior); rotation within
    # 1 degree.
    R, t = sequence_pose(5)
    fit = prediction["fit"]
    assert abs(fit["t_cam_vehicle"][2] / t[2] - 1) < 0.05
    assert np.abs(CAMERA.project(np.array([fit["t_cam_vehicle"]])) - CAMERA.project(t[None])).max() < 0.6
    assert np.rad2deg(geodesic_angle(np.array(fit["R_cam_vehicle"]), R)) < 1.0
    assert len(fit["corners_uv"]) == 8


def test_a_box_drawn_for_a_prediction_gives_a_box_only_vehicle(served, tmp_path):
    client, _ = served
    _first_frame(client)
    box = [560.0, 180.0, 900.0, 330.0]
    doc = _ok(client, {"op": "add_vehicle", "track": TRACK, "box2d": box}, 3)
    (vehicle,) = doc["vehicles"]
    assert vehicle["box2d"] == box and vehicle["parts"] == [] and vehicle["fit"]["pose_from"] == "box"
    saved = load_images(tmp_path / "annotations.json")[3].vehicles[0]
    assert saved.track == TRACK and saved.box2d.tolist() == box and saved.parts == ()


def test_an_unnamed_click_on_a_prediction_is_named_from_the_predicted_cuboid(served):
    client, _ = served
    _first_frame(client)
    doc = _ok(client, {"op": "add_vehicle", "track": TRACK}, FRAMES - 1)
    _click_fully(client, FRAMES - 1, doc["vehicle"])
    doc = _ok(client, {"op": "add_vehicle", "track": TRACK}, 5)
    wheel = clicks([NAMED[1]], *sequence_pose(5))[0]  # the rear left wheel, where it is on frame 5
    doc = _ok(client, {"op": "add_click", "vehicle": doc["vehicle"], "uv": wheel.uv}, 5)
    (auto,) = doc["auto_named"]
    assert auto["name"] == wheel.name and auto["distance_px"] < 3
    assert doc["vehicles"][0]["fit"]["pose_from"] == "clicks"


def test_dismissing_a_prediction_hides_it_on_that_frame_only(served, frames, tmp_path):
    client, _ = served
    _first_frame(client)
    doc = _ok(client, {"op": "dismiss_prediction", "track": TRACK}, 2)
    assert doc["predictions"] == [] and doc["dismissed"] == [TRACK]
    assert doc["tracks"] == [{"track": TRACK, "vehicle": None, "pose_from": "dismissed"}]
    assert _view(client, 3)["predictions"][0]["track"] == TRACK
    # Not in the annotation file: in the extras file beside it, read back by the next session.
    assert load_images(tmp_path / "annotations.json")[2].vehicles == ()
    extras = json.loads((tmp_path / "annotations.json.annotate.json").read_text())
    assert extras["dismissed"] == {"000002": [TRACK]}
    assert _session(frames, tmp_path / "annotations.json").image_view(2)["dismissed"] == [TRACK]
    doc = _ok(client, {"op": "undo"}, 2)
    assert [p["track"] for p in doc["predictions"]] == [TRACK] and doc["dismissed"] == []
    _ok(client, {"op": "dismiss_prediction", "track": TRACK}, 2)
    doc = _ok(client, {"op": "restore_prediction", "track": TRACK}, 2)
    assert [p["track"] for p in doc["predictions"]] == [TRACK]


def test_tracks_of_a_file_are_kept_and_new_vehicles_take_new_tracks(served, frames, tmp_path):
    client, _ = served
    _first_frame(client)
    _ok(client, {"op": "confirm_prediction", "track": TRACK}, 1)
    resumed = _session(frames, tmp_path / "annotations.json", sequence=None)  # the file's frames keep theirs
    view = resumed.image_view(1)
    assert (view["sequence"], view["frame"], view["vehicles"][0]["track"]) == (SEQUENCE, 1, TRACK)
    doc = resumed.edit(1, {"revision": 0, "op": "add_vehicle"})
    assert doc["track"] == "0003-2"
    assert [(v.id, v.track) for v in load_images(tmp_path / "annotations.json")[1].vehicles] == [
        ("1", TRACK), ("2", "0003-2")]
    # Frame 2 now predicts both tracks, each from its own frames.
    assert [p["track"] for p in resumed.image_view(2)["predictions"]] == [TRACK, "0003-2"]


@pytest.mark.parametrize(("image", "change", "message"), [
    (1, {"op": "confirm_prediction", "track": "0004-1"}, "track: no track '0004-1' in sequence 0003 (its tracks: "
                                                          "0003-1)"),
    (1, {"op": "confirm_prediction"}, "track: expected the name of a track of sequence 0003, got None"),
    (0, {"op": "confirm_prediction", "track": TRACK}, "track: 0003-1 is on this frame already (vehicle 1)"),
    (0, {"op": "dismiss_prediction", "track": TRACK}, "track: 0003-1 is on this frame already"),
    (1, {"op": "restore_prediction", "track": TRACK}, "track: '0003-1' is not dismissed on image 000001"),
    (1, {"op": "add_vehicle", "track": "0003-9"}, "track: no track '0003-9' in sequence 0003"),
    (1, {"op": "add_vehicle", "track": TRACK, "prototype": "Truck"}, "prototype: track '0003-1' is a Car (one "
                                                                       "prototype per track)"),
    (0, {"op": "set_vehicle", "vehicle": "1", "prototype": "Truck"}, None),  # its only frame: allowed
])
def test_bad_track_changes_get_400_with_a_message(served, image, change, message):
    client, _ = served
    _ok(client, {"op": "add_vehicle"}, 0)
    status, doc = client.edit(change, image=image)
    if message is None:
        assert status == 200, doc
    else:
        assert status == 400 and message in doc["error"], doc


def test_a_tracks_prototype_changes_only_where_it_has_no_other_frame(served):
    client, _ = served
    _first_frame(client)
    _ok(client, {"op": "confirm_prediction", "track": TRACK}, 1)
    status, doc = client.edit({"op": "set_vehicle", "vehicle": "1", "prototype": "Truck"}, image=1)
    assert status == 400 and "a Car on 1 other frame(s) too (one prototype per track)" in doc["error"]


def test_a_vehicle_can_be_moved_to_a_carried_track(served):
    client, _ = served
    _first_frame(client)
    doc = _ok(client, {"op": "add_vehicle"}, 1)  # `n` by mistake: a new track
    assert doc["track"] == "0003-2"
    doc = _ok(client, {"op": "set_vehicle", "vehicle": doc["vehicle"], "track": TRACK}, 1)
    assert doc["vehicles"][0]["track"] == TRACK and doc["vehicles"][0]["fit"]["pose_from"] == "interpolated"


# -- the command line ------------------------------------------------------------------------------------------------


def test_annotate_sequence_numbers_the_frames_and_says_how(monkeypatch, frames, tmp_path):
    def no_port(*args):
        raise OSError("no port in this test")

    monkeypatch.setattr("toosicubix.web.server.serve", no_port)  # stops the command once the session is built
    paths, cameras = frames
    result = CliRunner().invoke(main, ["annotate", *map(str, paths), "--cameras", str(cameras), "-o",
                                       str(tmp_path / "a.json"), "--sequence", "0003"])
    assert result.exit_code == 2 and "no port in this test" in result.output
    assert "sequence 0003: 11 new frame(s), numbered by the last run of digits in each file name (e.g. " \
           "000010.png -> frame 10)" in result.stderr
    renamed = [tmp_path / f"frame{name}.png" for name in ("", "_b", "_c")]
    for path, source in zip(renamed, paths, strict=False):
        path.write_bytes(source.read_bytes())
    result = CliRunner().invoke(main, ["annotate", *map(str, renamed), "--cameras", str(cameras), "-o",
                                       str(tmp_path / "b.json"), "--sequence", "0004"])
    assert "sequence 0004: 3 new frame(s), numbered by their position in the given order" in result.stderr


def test_annotate_refuses_a_bad_sequence_name_and_a_frame_the_file_has(frames, tmp_path):
    paths, cameras = frames
    run = CliRunner().invoke
    result = run(main, ["annotate", *map(str, paths), "--cameras", str(cameras), "-o", str(tmp_path / "a.json"),
                        "--sequence", "../x"])
    assert result.exit_code == 2 and "sequence: expected a name of letters, digits" in result.output
    out = tmp_path / "b.json"
    _session((paths[:1], cameras), out).save({})  # frame 0 of 0003 is image 000000
    renamed = tmp_path / "other_0.png"
    renamed.write_bytes(paths[1].read_bytes())
    (tmp_path / "c.json").write_text(json.dumps({"K": json.loads(cameras.read_text())["K"]}))
    result = run(main, ["annotate", str(renamed), "--cameras", str(tmp_path / "c.json"), "-o", str(out),
                        "--sequence", "0003"])
    assert result.exit_code == 2
    assert "--sequence 0003: other_0.png would be frame 0, which is image '000000''s in" in result.output

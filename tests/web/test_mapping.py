"""The annotate page with a keypoint mapping (``toosicubix annotate --mapping``): the page offers the mapping's
keypoints, a click named one takes its typical position for the vehicle's prototype (and again when the
prototype changes), unnamed clicks are named among them, and the parts to click next are them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.web.conftest import make_session
from tests.web.synthetic import CAMERA, DIMENSIONS, R_CAM_VEHICLE, T_CAM_VEHICLE
from toosicubix.annotations.mapping import MappingFile
from toosicubix.annotations.priors_file import load_priors
from toosicubix.web.request_fields import ApiError
from toosicubix.web.session import Session, load_cameras

#: Keypoints on the synthetic car's front and left side (it shows its front-left corner to the camera), and two
#: on faces turned away. Fractions of (dx, dy, dz).
AT = {"lamp-front-left": (0.47, 0.36, 0.6), "lamp-front-right": (0.47, -0.36, 0.6),
      "plate-front": (0.5, 0.0, 0.35), "glass-front-left": (0.2, 0.38, 0.9), "glass-front-right": (0.2, -0.38, 0.9),
      "mirror-left": (0.2, 0.5, 0.65), "handle-front-left": (0.0, 0.5, 0.55), "handle-rear-left": (-0.25, 0.5, 0.55),
      "sill-left": (-0.1, 0.5, 0.15), "lamp-rear-left": (-0.47, 0.4, 0.6), "wheel-arch-left": (0.3, 0.5, 0.35),
      "lamp-rear-right": (-0.47, -0.36, 0.6), "mirror-right": (0.2, -0.5, 0.65)}
SPREAD = (0.02, 0.02, 0.02)
#: An SUV's lamps sit higher (its own positions in the mapping).
SUV_AT = {"lamp-front-left": (0.48, 0.37, 0.66)}


def _mapping() -> MappingFile:
    parts = [{"kind": "keypoint", "keypoint": name, "position": {"at": list(at), "spread": list(SPREAD)},
              "by_prototype": {"SUV": {"at": list(SUV_AT[name]), "spread": [0.03, 0.03, 0.03]}} if name in SUV_AT
              else {}} for name, at in AT.items()]
    return MappingFile.model_validate({"toosicubix_mapping": 1, "name": "test-13", "parts": parts})


def _uv(name: str) -> list[list[float]]:
    """Where the keypoint is on the synthetic car, exactly."""
    point_cam = R_CAM_VEHICLE @ (np.array(AT[name]) * DIMENSIONS) + T_CAM_VEHICLE
    return CAMERA.project(point_cam[None]).tolist()


def _session(scene, out: Path) -> Session:
    image, cameras = scene
    return Session([image], out, load_cameras(cameras, [image.stem]), load_priors(), mapping=_mapping())


def _edit(session: Session, **change) -> dict:
    return session.edit(0, {"revision": session.revision, **change})


def _file_parts(out: Path) -> list[dict]:
    return json.loads(out.read_text())["images"][0]["vehicles"][0]["parts"]


NAMED = ["lamp-front-left", "lamp-front-right", "plate-front", "glass-front-left", "mirror-left",
         "handle-rear-left", "lamp-rear-left"]


@pytest.fixture
def clicked(scene, tmp_path) -> tuple[Session, Path, str]:
    """A session with one car whose seven NAMED keypoints are clicked exactly."""
    out = tmp_path / "annotations.json"
    session = _session(scene, out)
    vehicle = _edit(session, op="add_vehicle", prototype="Car")["vehicle"]
    for name in NAMED:
        _edit(session, op="add_click", vehicle=vehicle, kind="keypoint", name=name, uv=_uv(name))
    return session, out, vehicle


def test_the_page_offers_the_mappings_keypoints(scene, tmp_path):
    summary = _session(scene, tmp_path / "a.json").summary()
    assert summary["mapping"] == "test-13" and summary["keypoints"] == list(AT)
    plain = make_session(scene, tmp_path / "b.json").summary()
    assert plain["mapping"] is None and plain["keypoints"] == []


def test_a_named_keypoint_takes_its_position_and_fits_as_fit_does(clicked):
    session, out, _ = clicked
    parts = _file_parts(out)
    assert [(p["kind"], p["name"]) for p in parts] == [("keypoint", n) for n in NAMED]
    assert all(p["at"] == list(AT[p["name"]]) and p["spread"] == list(SPREAD) for p in parts)
    # The page's fit is fit's fit of the file's vehicle (the same function on the same parts).
    from toosicubix.annotations.convert import load_images
    from toosicubix.pipeline.vehicle import fit_one
    from toosicubix.solver.fit import SolverOptions

    (image,) = load_images(out)
    expected = fit_one(image.vehicles[0], image.camera, load_priors()["Car"], SolverOptions())
    view = session.image_view(0)["vehicles"][0]
    assert view["fit"]["status"] == "ok"
    np.testing.assert_array_equal(view["fit"]["R_cam_vehicle"], expected.R_cam_vehicle)


def test_the_next_clicks_are_the_mappings_keypoints_not_clicked_yet(clicked):
    session, _, _ = clicked
    targets = session.image_view(0)["vehicles"][0]["targets"]
    assert targets and {t["kind"] for t in targets} == {"keypoint"}
    names = {t["name"] for t in targets}
    assert not names & set(NAMED)
    assert not names & {"lamp-rear-right", "mirror-right"}  # on faces turned away: never a target


def test_an_unnamed_click_is_named_among_the_mappings_keypoints(clicked):
    session, out, vehicle = clicked
    change = _edit(session, op="add_click", vehicle=vehicle, uv=_uv("sill-left"))
    (auto,) = change["auto_named"]
    assert (auto["kind"], auto["name"]) == ("keypoint", "sill-left")
    assert auto["runner_up_kind"] == "keypoint" and auto["runner_up"] in AT
    assert auto["distance_px"] < auto["runner_up_distance_px"]
    last = _file_parts(out)[-1]
    assert (last["name"], last["at"], last["spread"]) == ("sill-left", list(AT["sill-left"]), list(SPREAD))
    # The runner-up, as the page's x key takes it: renamed with its kind, its own position.
    _edit(session, op="rename", vehicle=vehicle, part=len(NAMED), kind=auto["runner_up_kind"], name=auto["runner_up"])
    last = _file_parts(out)[-1]
    assert (last["name"], last["at"]) == (auto["runner_up"], list(AT[auto["runner_up"]]))


def test_a_prototype_change_moves_the_keypoints_to_that_prototypes_positions(clicked):
    session, out, vehicle = clicked
    _edit(session, op="set_vehicle", vehicle=vehicle, prototype="SUV")
    parts = {p["name"]: p for p in _file_parts(out)}
    assert parts["lamp-front-left"]["at"] == list(SUV_AT["lamp-front-left"])
    assert parts["lamp-front-left"]["spread"] == [0.03, 0.03, 0.03]
    assert parts["lamp-front-right"]["at"] == list(AT["lamp-front-right"])  # no SUV position of its own
    _edit(session, op="set_vehicle", vehicle=vehicle, prototype="Car")
    assert _file_parts(out)[0]["at"] == list(AT["lamp-front-left"])


def test_keypoints_the_mapping_does_not_have_are_refused(clicked, scene, tmp_path):
    session, out, vehicle = clicked
    before = out.read_text()
    with pytest.raises(ApiError, match="'door-handle' is not a keypoint of the mapping test-13"):
        _edit(session, op="add_click", vehicle=vehicle, kind="keypoint", name="door-handle", uv=[[10.0, 20.0]])
    with pytest.raises(ApiError, match="has a keypoint 'lamp-front-left' already"):
        _edit(session, op="add_click", vehicle=vehicle, kind="keypoint", name="lamp-front-left", uv=[[10.0, 20.0]])
    with pytest.raises(ApiError, match="has a keypoint 'plate-front' already"):
        _edit(session, op="rename", vehicle=vehicle, part=0, kind="keypoint", name="plate-front")
    assert out.read_text() == before
    plain = make_session(scene, tmp_path / "b.json")
    plain_vehicle = plain.edit(0, {"revision": 0, "op": "add_vehicle"})["vehicle"]
    with pytest.raises(ApiError, match="start the page with --mapping"):
        plain.edit(0, {"revision": plain.revision, "op": "add_click", "vehicle": plain_vehicle, "kind": "keypoint",
                       "name": "lamp-front-left", "uv": _uv("lamp-front-left")})


@pytest.mark.parametrize("name", [["lamp-front-left"], {"a": 1}, 5, None, True, ""])
def test_a_keypoint_name_of_the_wrong_type_is_a_clear_refusal(clicked, name):
    session, out, vehicle = clicked
    before = out.read_text()
    with pytest.raises(ApiError, match="name"):
        _edit(session, op="add_click", vehicle=vehicle, kind="keypoint", name=name, uv=[[10.0, 20.0]])
    with pytest.raises(ApiError, match="name"):
        _edit(session, op="rename", vehicle=vehicle, part=0, kind="keypoint", name=name)
    assert out.read_text() == before


def test_random_requests_get_only_clear_refusals(scene, tmp_path):
    """600 seeded requests, half of them sensible changes and half fields of any type: every one is applied or
    refused with an ApiError (HTTP 400/404/409 and its message), never another exception (HTTP 500)."""
    import random

    rng = random.Random(0)
    session = _session(scene, tmp_path / "a.json")
    junk = [None, True, 0, -1, 1.5, float("nan"), "", "x", "keypoint", "point", "SUV", [], [1], [[1, 2]],
            [[1.0, 2.0], [3.0, 4.0]], {"a": 1}, "1", 10**30, "lamp-front-left", "wheel-front-left", "plate"]
    ops = ["add_vehicle", "set_vehicle", "delete_vehicle", "add_click", "move_click", "rename", "delete_click", "undo"]
    applied = 0
    for _ in range(600):
        ids = [v.id for v in session.images[0].vehicles]
        name = rng.choice(list(AT))
        if rng.random() < 0.5:
            op = rng.choice(["add_vehicle", "add_click", "add_click", "rename", "set_vehicle", "move_click"])
            r = {"op": op, "vehicle": rng.choice(ids) if ids else "1", "kind": "keypoint", "name": name,
                 "uv": _uv(name)[0] if op == "move_click" else _uv(name), "click": 0, "part": rng.randrange(12),
                 "prototype": rng.choice(["Car", "SUV", "Boat"])}
        else:
            r = {key: rng.choice(junk + ids) for key in ("vehicle", "kind", "name", "uv", "part", "click",
                                                         "prototype", "box2d", "done", "known") if rng.random() < 0.6}
            r["op"] = rng.choice([*ops, None, 3])
        try:
            _edit(session, **r)
            applied += 1
        except ApiError:
            pass
    assert applied > 100  # the sensible half grows a state to work on
    from toosicubix.annotations.convert import load_images

    assert sum(len(v.parts) for v in load_images(tmp_path / "a.json")[0].vehicles) > 0  # fit reads the file


def test_swapping_sides_renames_a_keypoint_to_the_one_at_its_mirror_place(scene, tmp_path):
    """s on a mapping's keypoints: each becomes the keypoint whose typical place is its own mirrored across the
    vehicle (lamp-front-left <-> lamp-front-right, mirror-left -> mirror-right), with that keypoint's position; one
    on the centre line (plate-front) and one with no keypoint at its mirror place (sill-left) stay, the latter
    said."""
    out = tmp_path / "annotations.json"
    session = _session(scene, out)
    _edit(session, op="add_vehicle")
    for name in ("lamp-front-left", "plate-front", "mirror-left", "sill-left"):
        _edit(session, op="add_click", vehicle="1", kind="keypoint", name=name, uv=_uv(name))
    doc = _edit(session, op="swap_sides", vehicle="1")
    assert doc["swapped"] == 2 and doc["unpaired"] == ["sill-left"]
    assert [(p["kind"], p["name"]) for p in doc["vehicles"][0]["parts"]] == [
        ("keypoint", "lamp-front-right"), ("keypoint", "plate-front"), ("keypoint", "mirror-right"),
        ("keypoint", "sill-left")]
    saved = _file_parts(out)
    assert saved[0]["at"] == list(AT["lamp-front-right"]) and saved[2]["at"] == list(AT["mirror-right"])

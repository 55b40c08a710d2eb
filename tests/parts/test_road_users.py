"""Road users beyond vehicles (issue 35): every class's own vocabulary recovers a known box from noise-free clicks, a
traffic cone's yaw is reported undetermined, and the bundled mappings are the vocabulary's."""

from __future__ import annotations

import json

import numpy as np
import pytest

from toosicubix.annotations.mapping import load_mapping
from toosicubix.annotations.priors_file import load_priors
from toosicubix.camera import Camera
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle
from toosicubix.model import Part, Vehicle
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.road_users import (
    COCO_PERSON_KEYPOINTS,
    class_keypoints,
    class_notes,
    keypoint_class,
    keypoint_parts,
    mapping_document,
)
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.solver.fit import SolverOptions
from toosicubix.vocabulary import CLASSES, HEADINGS, class_of, family_of, heading_of

K = np.array([[721.5, 0.0, 609.6], [0.0, 721.5, 172.9], [0.0, 0.0, 1.0]])
CAMERA = Camera(K=K, image_size=(1242, 375))
KEYPOINT_CLASSES = [name for name, c in CLASSES.items() if c.vocabulary == "keypoints"]


def _truth_rotation(cls: str, t_cam_vehicle: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A pose each class's vocabulary describes: any yaw for a class with a front; for a traffic cone its X axis along
    the line of sight away from the camera (its near base point toward it); for a barrier its +X end on the image's
    right. Camera frame x right, y down, z forward."""
    if CLASSES[cls].heading == "directed":
        return R_cam_vehicle_from_ypr(0.7)
    along = float(np.arctan2(-t_cam_vehicle[2], t_cam_vehicle[0]))  # KITTI yaw of the line of sight
    if CLASSES[cls].heading == "none":
        return R_cam_vehicle_from_ypr(along)
    R = R_cam_vehicle_from_ypr(along + np.pi / 2)
    u_plus, u_minus = (CAMERA.project((R @ (np.array([s * 0.5, 0.0, 0.0]) * d) + t_cam_vehicle)[None])[0, 0]
                       for s in (1.0, -1.0))
    return R if u_plus > u_minus else R_cam_vehicle_from_ypr(along - np.pi / 2)


def _clicks(cls: str, R: np.ndarray, t: np.ndarray, d: np.ndarray) -> tuple[Part, ...]:
    """Noise-free clicks: every keypoint of the class exactly at its ``at`` fraction of the box, projected."""
    out = []
    for k in CLASSES[cls].keypoints.values():
        X_cam = R @ (np.array(k.at) * d) + t
        out.append(Part("keypoint", k.name, CAMERA.project(X_cam[None]), "$", at=np.array(k.at),
                        spread=np.array(k.spread)))
    return tuple(out)


@pytest.mark.parametrize("cls", KEYPOINT_CLASSES)
def test_each_class_vocabulary_recovers_a_known_box_from_noise_free_clicks(cls):
    """The box of the prior's mean size 12 m away, clicked exactly: zero pixel and prior cost there, and the fit finds
    it (1e-6 tier: a noiseless solve)."""
    prototype = CLASSES[cls].prototypes[0]
    prior = load_priors()[prototype]
    t = np.array([1.5, 1.6, 12.0])
    R = _truth_rotation(cls, t, prior.mean)
    result = fit_one(Vehicle("1", prototype, None, _clicks(cls, R, t, prior.mean), "$"), CAMERA, prior,
                     SolverOptions())
    assert result.ok, result.error
    assert np.rad2deg(geodesic_angle(result.R_cam_vehicle, R)) < 1e-6
    np.testing.assert_allclose(result.t_cam_vehicle, t, atol=1e-6)
    np.testing.assert_allclose(result.dimensions, prior.mean, atol=1e-6)
    assert result.rms_px < 1e-6


def test_every_class_is_well_formed():
    for name, c in CLASSES.items():
        assert c.heading in HEADINGS and c.family in ("person", "two-wheeler", "vehicle", "cone", "barrier")
        assert c.vocabulary in ("keypoints", "cuboid")
        assert class_of(name) is c and all(class_of(p) is c for p in c.prototypes)
        assert (c.vocabulary == "keypoints") == bool(c.keypoints)
        for k in c.keypoints.values():  # fractions of the box: x, y within the box's half, z from 0 to 1
            assert abs(k.at[0]) <= 0.5 and abs(k.at[1]) <= 0.5 and 0.0 <= k.at[2] <= 1.0, (name, k)
            assert min(k.spread) > 0 and k.description
        assert all(a in c.keypoints and b in c.keypoints for a, b in c.edges)
    assert tuple(CLASSES["Pedestrian"].keypoints) == COCO_PERSON_KEYPOINTS
    priors = load_priors()
    assert all(p in priors for c in CLASSES.values() for p in c.prototypes)


def test_families_and_headings():
    assert family_of("Pedestrian") == family_of("Person_sitting") == "person"
    assert family_of(None, "Cyclist") == family_of("bicycle") == family_of("Motorbike") == "two-wheeler"
    assert family_of("Car") == family_of("Urban Bus (Front)") == family_of("Van") == "vehicle"
    assert heading_of("Traffic cone") == "none" and heading_of("Barrier") == "axial" and heading_of("Car") == "directed"
    assert keypoint_class("Bus") is None and class_keypoints("Car") == {}
    assert set(class_keypoints("Cyclist")) == set(CLASSES["Cyclist"].keypoints)


def test_a_class_keypoint_has_no_face_to_hide_behind():
    """A pedestrian's right shoulder sits beyond 0.3 of the width (a car keypoint there counts as on the right face)
    but may be clicked seen from the left (labelled hidden): a body is no box."""
    part = keypoint_parts("Pedestrian", {"right_shoulder": (10.0, 20.0, False)})[0][0]
    model = build_parts_model([Part("keypoint", "right_shoulder", np.array([[10.0, 20.0]]), "$",
                                    at=np.array(part["at"]), spread=np.array(part["spread"]), visible=False)])
    assert model.click_faces == (None,)
    car_like = build_parts_model([Part("keypoint", "mirror", np.array([[10.0, 20.0]]), "$",
                                       at=np.array(part["at"]), spread=np.array(part["spread"]))])
    assert car_like.click_faces == (("right",),)


def test_keypoint_parts_keep_hidden_clicks_and_name_the_unknown():
    parts, unknown = keypoint_parts("Pedestrian", [("nose", (1.0, 2.0, True)), ("left_ankle", (3.0, 4.0, False)),
                                                   ("tail", (5.0, 6.0, True))])
    assert [p["name"] for p in parts] == ["nose", "left_ankle"] and unknown == ["tail"]
    assert "visible" not in parts[0] and parts[1]["visible"] is False
    assert parts[1]["at"] == list(CLASSES["Pedestrian"].keypoints["left_ankle"].at)
    with pytest.raises(ValueError, match="no keypoint vocabulary"):
        keypoint_parts("Car", {})


def test_bundled_road_user_mappings_are_the_vocabulary():
    person, _ = load_mapping("coco-person")
    assert person.keypoints == list(COCO_PERSON_KEYPOINTS) and person.prototype == "Pedestrian"
    assert person.prototypes["person"] == "Pedestrian"
    assert {p.keypoint: p.position.at for p in person.parts} == {
        k: v.at for k, v in CLASSES["Pedestrian"].keypoints.items()}
    two, _ = load_mapping("two-wheeler")
    assert two.prototypes["motorcyclist"] == "Motorcyclist" and two.prototypes["bicycle"] == "Bicycle"
    saddle = next(p for p in two.parts if p.keypoint == "saddle")
    assert saddle.position_for("Bicycle").at == CLASSES["Bicycle"].keypoints["saddle"].at
    assert saddle.position_for("Motorcyclist").at == CLASSES["Motorcyclist"].keypoints["saddle"].at
    head = next(p for p in two.parts if p.keypoint == "head")
    assert set(head.by_prototype) == {"Cyclist", "Motorcyclist"}  # a machine alone has no rider
    assert json.loads(json.dumps(mapping_document("two-wheeler"))) == mapping_document("two-wheeler")


def test_class_notes_say_what_a_fit_cannot_measure():
    assert class_notes("Car", ["nose"]) == ()
    assert class_notes("Pedestrian", ["nose", "left_ankle"]) == ()
    (ankles,) = class_notes("Pedestrian", ["nose", "left_knee"], 1.76)
    assert ankles.startswith("no ankle clicked") and "height prior (1.76 m)" in ankles
    assert class_notes("Traffic cone", ["tip"])[0].startswith("yaw undetermined")
    assert class_notes("Barrier", ["left_end_top"])[0].startswith("yaw known modulo 180 degrees")


def test_a_traffic_cone_s_yaw_is_reported_undetermined(tmp_path):
    """fit writes a cone with heading 'none' and a warning in results.json, and -10 (KITTI's angle not given) as its
    label's rotation_y and alpha; a pedestrian in the same image keeps its yaw and writes no heading key."""
    priors = load_priors()
    vehicles = []
    for cls, t in (("Traffic cone", np.array([-1.0, 1.6, 9.0])), ("Pedestrian", np.array([2.0, 1.6, 11.0]))):
        prototype = CLASSES[cls].prototypes[0]
        d = priors[prototype].mean
        parts = _clicks(cls, _truth_rotation(cls, t, d), t, d)
        vehicles.append({"id": cls[0], "prototype": prototype, "parts": [
            {"kind": "keypoint", "name": p.name, "xy": p.uv[0].tolist(), "at": p.at.tolist(),
             "spread": p.spread.tolist()} for p in parts]})
    doc = {"toosicubix": 1, "images": [{"id": "000001", "size": [1242, 375], "camera": {"K": K.tolist()},
                                        "vehicles": vehicles}]}
    path = tmp_path / "ann.json"
    path.write_text(json.dumps(doc))
    fit_file(path, tmp_path / "out")
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    cone, person = results["images"][0]["vehicles"]
    assert cone["status"] == "ok" and cone["heading"] == "none"
    assert any(w.startswith("yaw undetermined") for w in cone["warnings"])
    assert "heading" not in person and not any("yaw" in w for w in person["warnings"])
    cone_line, person_line = (tmp_path / "out" / "label_2" / "000001.txt").read_text().splitlines()
    fields = cone_line.split()
    assert fields[0] == "Misc" and float(fields[3]) == -10.0 and float(fields[14]) == -10.0  # alpha, rotation_y
    assert person_line.split()[0] == "Pedestrian" and abs(float(person_line.split()[14]) - 0.7) < 1e-4


def test_a_pedestrian_is_offered_its_own_keypoints_to_click_next():
    """Without the left arm, the suggestions are COCO keypoints of a person, never a car's wheels or lamps."""
    prior = load_priors()["Pedestrian"]
    t = np.array([1.5, 1.6, 12.0])
    parts = tuple(p for p in _clicks("Pedestrian", R_cam_vehicle_from_ypr(0.7), t, prior.mean)
                  if p.name not in ("left_elbow", "left_wrist"))
    result = fit_one(Vehicle("1", "Pedestrian", None, parts, "$"), CAMERA, prior, SolverOptions(), next_clicks=3)
    names = [s["name"] for s in result.next_clicks]
    assert names and set(names) <= {"left_elbow", "left_wrist"}


def test_a_road_user_s_sentences_name_no_car_part():
    """What sets a pedestrian's yaw, size and scale is said as for a car, but the advice never sends the person to a
    wheel centre, a lamp, a mirror or a licence plate (its next clicks say which keypoint to click)."""
    prior = load_priors()["Pedestrian"]
    t = np.array([1.5, 1.6, 12.0])
    parts = tuple(p for p in _clicks("Pedestrian", R_cam_vehicle_from_ypr(0.7), t, prior.mean)
                  if p.name in ("nose", "left_shoulder", "right_shoulder", "left_hip", "left_ankle"))
    result = fit_one(Vehicle("1", "Pedestrian", None, parts, "$"), CAMERA, prior, SolverOptions())
    sentences = result.observability.sentences
    assert any(s.startswith("yaw ") and "set by the size prior" in s for s in sentences), sentences
    assert any(s.startswith("scale set by the size prior") and s.endswith("or known dimensions pins it better")
               for s in sentences), sentences
    for word in ("wheel", "lamp", "mirror", "glass", "plate", "tyre", "door"):
        assert not any(word in s for s in sentences), (word, sentences)

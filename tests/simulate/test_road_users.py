"""The simulated annotator on road users (issue 35): posed bodies inside their boxes, COCO visibility from
self-occlusion, and keypoint annotations as the coco-person and two-wheeler mappings write them."""

from __future__ import annotations

import numpy as np
import pytest

from toosicubix.annotations.priors_file import load_priors
from toosicubix.camera import Camera
from toosicubix.formats.kitti import object_from_pose
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle
from toosicubix.model import Vehicle
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.simulate.annotator import AnnotatorOptions, GroundTruthVehicle, simulate_vehicle
from toosicubix.simulate.bodies import hidden, labelled, pose_person, pose_two_wheeler
from toosicubix.solver.fit import SolverOptions
from toosicubix.vocabulary import CLASSES

P2 = np.array([[720.0, 0.0, 620.0, 43.2], [0.0, 720.0, 180.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
CAMERA = Camera.from_P(P2, image_size=(1242, 375))
PERSON_BOX = np.array([0.8, 0.66, 1.75])
CYCLIST_BOX = np.array([1.76, 0.6, 1.73])


def _gt(kind: str, dims: np.ndarray, ry_deg: float = 30.0, location=(1.0, 1.6, 11.0), occluded: int = 0):
    obj = object_from_pose(kind, R_cam_vehicle_from_ypr(np.deg2rad(ry_deg)), np.array(location), dims, CAMERA,
                           np.array([100, 100, 200, 160.0]), occluded=occluded, score=None)
    return GroundTruthVehicle("000001", "4", obj, CAMERA)


@pytest.mark.parametrize("seed", range(20))
def test_a_posed_person_stands_in_its_box(seed):
    """Feet on the floor, head near the top (mid-stride the hips sink, so above 0.8 of the box), every keypoint within
    a stride or an arm's reach of the box (a stride may exceed a label's length, so 0.25 m of slack along X and Y)."""
    body = pose_person(PERSON_BOX, np.random.default_rng(seed))
    points = np.array(list(body.points.values()))
    assert set(body.points) == set(CLASSES["Pedestrian"].keypoints)
    assert np.all(np.abs(points[:, :2]) <= PERSON_BOX[:2] / 2 + 0.25)
    assert min(body.points["left_ankle"][2], body.points["right_ankle"][2]) == pytest.approx(0.039 * 1.75)
    assert 0.8 * 1.75 < body.points["nose"][2] < 1.75
    assert body.points["left_shoulder"][1] > body.points["right_shoulder"][1]  # the person's own left is +Y
    assert body.points["nose"][0] > body.points["left_ear"][0] - 0.05  # the face looks forward, give or take a turn


def test_a_posed_two_wheeler_has_its_wheels_on_the_centre_line():
    body = pose_two_wheeler(CYCLIST_BOX, np.random.default_rng(3))
    front, rear = body.points["front_wheel_contact"], body.points["rear_wheel_contact"]
    assert 0.98 <= front[0] - rear[0] <= 1.10 + 1e-9  # a bicycle's wheelbase
    assert abs(front[2]) < 1e-9 and abs(rear[1]) < 0.05  # on the ground, within a 2-degree lean of the centre line
    assert body.points["head"][2] == pytest.approx(1.73 - 0.115, abs=0.02)
    assert "head" not in pose_two_wheeler(CYCLIST_BOX, np.random.default_rng(3), rider=False).points


def test_self_occlusion_hides_the_far_side_and_the_face_from_behind():
    body = pose_person(PERSON_BOX, np.random.default_rng(1))
    from_left = np.array([0.0, 12.0, 1.6])  # box frame: the camera on the person's left
    assert hidden(body, "right_shoulder", from_left) == "far side" and hidden(body, "left_shoulder", from_left) is None
    from_behind = np.array([-12.0, 0.0, 1.6])
    assert hidden(body, "nose", from_behind) == "face from behind"
    assert hidden(body, "left_ear", from_behind) is None
    seen = labelled(body, np.array([12.0, 0.0, 1.6]), np.random.default_rng(0))  # from the front: all seen
    assert seen == {name: True for name in body.points}
    bike = pose_two_wheeler(CYCLIST_BOX, np.random.default_rng(2))
    from_front = np.array([15.0, 0.5, 1.6])
    assert hidden(bike, "rear_wheel_contact", from_front) == "behind the near wheel"
    assert hidden(bike, "front_wheel_contact", from_front) is None and hidden(bike, "saddle", from_front)


def test_simulated_pedestrian_keypoints_carry_the_vocabulary_and_flags():
    sv = simulate_vehicle(_gt("Pedestrian", PERSON_BOX, ry_deg=0.0), AnnotatorOptions(noise_px=2.0, seed=1))
    assert sv.parts and all(p.kind == "keypoint" for p in sv.parts)
    vocabulary = CLASSES["Pedestrian"].keypoints
    assert all(tuple(p.at) == vocabulary[p.name].at and tuple(p.spread) == vocabulary[p.name].spread for p in sv.parts)
    assert any(not p.visible for p in sv.parts)  # walking across the view: its far side is labelled hidden
    again = simulate_vehicle(_gt("Pedestrian", PERSON_BOX, ry_deg=0.0), AnnotatorOptions(noise_px=2.0, seed=1))
    assert all(np.array_equal(a.uv, b.uv) for a, b in zip(sv.parts, again.parts, strict=True))  # seeded per object


@pytest.mark.parametrize("kind, dims", [("Pedestrian", PERSON_BOX), ("Cyclist", CYCLIST_BOX)])
def test_exact_placement_puts_every_keypoint_at_its_fraction_and_the_fit_recovers_the_box(kind, dims):
    """Exact placement, no noise, the box of the prior's mean size: the solver alone (1e-6 tier)."""
    prior = load_priors()[kind]
    gt = _gt(kind, prior.mean)
    sv = simulate_vehicle(gt, AnnotatorOptions(noise_px=0.0, exact_placement=True))
    assert len(sv.parts) == len(CLASSES[kind].keypoints) and all(p.visible for p in sv.parts)
    result = fit_one(Vehicle("4", kind, None, tuple(sv.parts), "$"), CAMERA, prior, SolverOptions())
    assert result.ok
    assert np.rad2deg(geodesic_angle(result.R_cam_vehicle, sv.R_cam_vehicle)) < 1e-6
    np.testing.assert_allclose(result.t_cam_vehicle, sv.t_cam_vehicle, atol=1e-6)


def test_an_occluded_person_loses_keypoints():
    full = simulate_vehicle(_gt("Pedestrian", PERSON_BOX), AnnotatorOptions(seed=2))
    occluded = simulate_vehicle(_gt("Pedestrian", PERSON_BOX, occluded=2), AnnotatorOptions(seed=2))
    assert len(occluded.parts) < len(full.parts)
    assert all(note.endswith("lost to occlusion") for note in occluded.notes)

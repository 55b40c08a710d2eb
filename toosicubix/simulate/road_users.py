"""The simulated annotator on road users with a keypoint vocabulary of their own (KITTI's Pedestrian and Cyclist):
COCO-style keypoints clicked on a posed body (:mod:`toosicubix.simulate.bodies`) inside each real ground-truth box.

For each object:

1. a body is posed in its box (a person for a Pedestrian, a bicycle and its rider for a Cyclist, a motorcycle and
   rider for a Motorcyclist, the machine alone for a Bicycle or Motorcycle), from the object's own random stream;
2. the person labels the vocabulary's keypoints with COCO's visibility flags (:func:`toosicubix.simulate.bodies
   .labelled`: a hidden keypoint is labelled as not visible, v = 1, or left out); objects KITTI calls partly
   occluded lose each labelled keypoint with probability 0.3, largely occluded with 0.6 (as the vehicles'
   parts); keypoints outside the image (2 px margin) are left out;
3. each click gets Gaussian noise of ``noise_px`` pixels per coordinate, twice that for a hidden one (its place is
   guessed);
4. the keypoint annotations carry the class vocabulary's ``at`` and ``spread``, as an import through the bundled
   ``coco-person`` or ``two-wheeler`` mapping writes them.

``exact_placement`` puts every keypoint exactly at the vocabulary's fraction of the true box and labels all of them
as seen (a test of the solver, not of the model). ``max_clicks`` does not apply: a COCO annotator labels every
keypoint.
"""

from __future__ import annotations

import numpy as np

from toosicubix.formats.datasets import DEFAULT_IMAGE_SIZE
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.model import Part
from toosicubix.parts.road_users import keypoint_class
from toosicubix.simulate.annotator import (
    EDGE_MARGIN_PX,
    OCCLUSION_DROP,
    AnnotatorOptions,
    GroundTruthVehicle,
    SimulatedVehicle,
    vehicle_rng,
)
from toosicubix.simulate.bodies import PosedBody, labelled, pose_person, pose_two_wheeler

#: How much noisier a hidden keypoint's click is than a visible one's.
HIDDEN_NOISE_FACTOR = 2.0


def pose_body(class_name: str, dimensions: np.ndarray, rng: np.random.Generator) -> PosedBody:
    """The body of an object of ``class_name`` in a box of ``dimensions`` (3,).

    Raises
    ------
    ValueError
        A class with no body model (a traffic cone, a barrier).
    """
    if class_name == "Pedestrian":
        return pose_person(dimensions, rng)
    if class_name in ("Cyclist", "Motorcyclist", "Bicycle", "Motorcycle"):
        return pose_two_wheeler(dimensions, rng, motor=class_name.startswith("Motor"),
                                rider=class_name.endswith("ist"))
    raise ValueError(f"no body model for class {class_name!r}")


def simulate_road_user(gt: GroundTruthVehicle, options: AnnotatorOptions) -> SimulatedVehicle:
    """The keypoints the simulated person labels on one ground-truth road user (see the module's description).

    Raises
    ------
    ValueError
        Its type is no class with a keypoint vocabulary of its own.
    """
    cls = keypoint_class(gt.label.type)
    if cls is None:
        raise ValueError(f"{gt.label.type!r} has no keypoint vocabulary of its own")
    rng = vehicle_rng(options.seed, gt.image_id, gt.vehicle_id)
    obj, camera = gt.label, gt.camera
    d = np.asarray(obj.dimensions, dtype=float)
    R = R_cam_vehicle_from_ypr(obj.rotation_y)
    t = obj.t_cam_vehicle(camera.t_cam_rect)
    camera_box = R.T @ (-t)
    size = np.array(camera.image_size or DEFAULT_IMAGE_SIZE, dtype=float)
    drop = OCCLUSION_DROP.get(obj.occluded, 0.6)
    if options.exact_placement:
        points = {k.name: np.array(k.at) * d for k in cls.keypoints.values()}
        seen = {name: True for name in points}
    else:
        body = pose_body(cls.name, d, rng)
        points, seen = body.points, labelled(body, camera_box, rng)
    parts: list[Part] = []
    notes: list[str] = []
    for name, k in cls.keypoints.items():
        if name not in seen:
            continue
        X_cam = R @ points[name] + t
        if X_cam[2] <= 0.1:
            continue
        uv = camera.project(X_cam[None])
        if not np.all((uv >= EDGE_MARGIN_PX) & (uv <= size - 1 - EDGE_MARGIN_PX)):
            continue
        if drop > 0 and rng.uniform() < drop:
            notes.append(f"keypoint {name}: lost to occlusion")
            continue
        sigma = options.noise_px * (1.0 if seen[name] else HIDDEN_NOISE_FACTOR)
        noisy = uv + rng.normal(0.0, sigma, uv.shape) if sigma > 0 else uv
        parts.append(Part("keypoint", name, noisy, f"simulated[{len(parts)}]", at=np.array(k.at),
                          spread=np.array(k.spread), visible=bool(seen[name])))
    return SimulatedVehicle(gt, parts, [], R, t, d, (0.0, 0.0), d.copy(), notes, [])

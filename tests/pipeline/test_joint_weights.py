"""The joint ground fit keeps each vehicle's click weights (keypoints' soft term, robust factors)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tests.parts.test_real_click_kinds import exact_prior
from tests.pipeline.test_click_noise import _keypoint_vehicle
from tests.scenes import CAMERA
from toosicubix.model import GroundPlane, Image
from toosicubix.pipeline.fitting import fit_image_jointly
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.solver.fit import SolverOptions

#: The scenes' vehicles stand 1.6 m below the camera on a level road; the height is left to the joint fit.
GROUND = GroundPlane(normal=np.array([0.0, -1.0, 0.0]), normal_sigma=np.deg2rad(1.0), camera_height=None,
                     camera_height_sigma=0.1, upright_sigma=np.deg2rad(2.0))


def _image(rng, n: int = 3):
    vehicles, priors = [], {}
    for k in range(n):
        vehicle, d = _keypoint_vehicle(rng, 1.0, 0.005, k)
        vehicle = replace(vehicle, id=f"v{k}", prototype=f"car{k}")
        vehicles.append(vehicle)
        priors[vehicle.prototype] = exact_prior(d)
    image = Image(id="im", file=None, camera=CAMERA, vehicles=tuple(vehicles), json_path="$.images[0]", ground=GROUND)
    options = SolverOptions()
    results = [fit_one(v, CAMERA, priors[v.prototype], options, GROUND) for v in vehicles]
    assert all(r.ok for r in results), [r.error for r in results]
    return image, results, priors, options


def test_joint_fit_keeps_each_vehicles_click_weights():
    image, results, priors, options = _image(np.random.default_rng(2))
    joint, plane = fit_image_jointly(image, results, priors, options)
    assert plane.estimated and all(v.cues.joint_ground for v in joint)
    for own, together in zip(results, joint, strict=True):
        assert own.click_weights is not None
        np.testing.assert_array_equal(together.click_weights, own.click_weights)
        assert together.downweighted == own.downweighted


def test_the_weights_enter_the_joint_fit():
    """One keypoint 40 px off: weighted almost to nothing, it no longer pulls its vehicle, whose other clicks
    then fit better than when it weighs as much as they do."""
    image, results, priors, options = _image(np.random.default_rng(4))
    options = replace(options, robust_loss="none")  # the bad click weighs in full unless this test lowers it
    first = image.vehicles[0]
    bad = replace(first.parts[0], uv=first.parts[0].uv + np.array([40.0, 0.0]))
    image = replace(image, vehicles=(replace(first, parts=(bad, *first.parts[1:])), *image.vehicles[1:]))
    refit = fit_one(image.vehicles[0], CAMERA, priors[first.prototype], options, GROUND)
    rms_others = {}
    for label, factor in (("full", 1.0), ("down", 1e-3)):
        w = refit.click_weights.copy()
        w[0] *= factor
        joint, _ = fit_image_jointly(image, [replace(refit, click_weights=w), *results[1:]], priors, options)
        rms_others[label] = float(np.sqrt(np.mean(np.sum(joint[0].residuals_px[1:] ** 2, axis=1))))
    assert rms_others["down"] < 0.5 * rms_others["full"], rms_others

"""A fit no person could have clicked is flagged wherever a person looks (issue 33, item 2): results.json's
``implausible`` and warnings with the likely cause, a KITTI score of at most 0.2, and fit's summary naming the
vehicles. The commonest cause, left and right named as the image's rather than the vehicle's own, is recognised by
fitting the clicks again with the sides swapped (:func:`toosicubix.parts.mirror.mirrored`)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tests.scenes import CAMERA, random_scene
from toosicubix.annotations.convert import part_json
from toosicubix.annotations.priors_file import load_priors
from toosicubix.cli import main
from toosicubix.model import Vehicle
from toosicubix.parts.mirror import mirrored
from toosicubix.pipeline.vehicle import IMPLAUSIBLE_CONFIDENCE, fit_one
from toosicubix.size_priors import CAR_AXLES
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.plausibility import axle_implausibility
from toosicubix.solver.problem import Problem


def test_mirroring_twice_gives_the_clicks_back():
    parts = tuple(random_scene(np.random.default_rng(0), "oblique-front-left").parts)
    again = mirrored(mirrored(parts))
    assert [(p.kind, p.name) for p in again] == [(p.kind, p.name) for p in parts]
    assert all(np.array_equal(a.uv, b.uv) for a, b in zip(again, parts, strict=True))
    names = [p.name for p in mirrored(parts)]
    assert "wheel-front-right" in names and "wheel-front-left" not in names[:1]


@pytest.mark.parametrize(("view", "seed"), [("front", 0), ("front", 1), ("oblique-front-left", 2), ("side", 7)])
def test_left_and_right_named_as_the_image_s_are_recognised(view, seed):
    """A limit, not tested as a success: a car seen almost broadside (side views of seeds 0-6, yaw within 20 deg of
    it; seed 3 was recognised before the axle prior, rule 29) can take mirrored names plausibly, its end face seen at a
    grazing angle showing the "other" side's parts. Over seeds 0-19 of the five views 78 mirrored cars of 100 are
    recognised, as before the axle prior (side 1, front 19, rear 18, both obliques 20)."""
    scene = random_scene(np.random.default_rng(seed), view)
    prior = load_priors()["Car"]
    right = fit_one(Vehicle("1", "Car", None, tuple(scene.parts), "$"), CAMERA, prior, SolverOptions())
    assert right.ok and right.implausible is None  # its confidence is what its sigmas say (a side view's is low)
    assert not any(w.startswith("left and right look swapped") for w in right.warnings)
    swapped = fit_one(Vehicle("1", "Car", None, mirrored(tuple(scene.parts)), "$"), CAMERA, prior, SolverOptions())
    assert swapped.implausible is not None and swapped.confidence <= IMPLAUSIBLE_CONFIDENCE
    assert any(w.startswith("left and right look swapped") for w in swapped.warnings)
    assert swapped.to_json()["implausible"] == swapped.implausible and "implausible" not in right.to_json()


def test_fit_names_the_implausible_vehicles(tmp_path):
    scene = random_scene(np.random.default_rng(0), "front")
    vehicles = [{"id": "ok", "prototype": "Car", "parts": [part_json(p) for p in scene.parts]},
                {"id": "swapped", "prototype": "Car", "parts": [part_json(p) for p in mirrored(tuple(scene.parts))]}]
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"toosicubix": 1, "images": [
        {"id": "im", "size": list(CAMERA.image_size), "camera": {"K": CAMERA.K.tolist()}, "vehicles": vehicles}]}))
    result = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "IMPLAUSIBLE: 1 fitted vehicle(s)" in result.output
    assert "image im vehicle swapped: left and right look swapped" in result.output
    label = (tmp_path / "out" / "label_2" / "im.txt").read_text().splitlines()
    scores = sorted(float(line.split()[-1]) for line in label)
    assert scores[0] <= IMPLAUSIBLE_CONFIDENCE < 0.3 < scores[1]
    # The render's label says it where the cuboid is drawn.
    from toosicubix.formats.results import read_results
    from toosicubix.render.folder import vehicle_label

    labels = {v.id: vehicle_label(v) for im in read_results(tmp_path / "out" / "results.json") for v in im.vehicles}
    assert labels["swapped"].endswith(" IMPLAUSIBLE: LEFT/RIGHT SWAPPED?")
    assert "IMPLAUSIBLE" not in labels["ok"]


_AXLE_SWAP = {"wheel-front-left": "wheel-rear-left", "wheel-rear-left": "wheel-front-left",
              "wheel-front-right": "wheel-rear-right", "wheel-rear-right": "wheel-front-right"}


@pytest.mark.parametrize("seed", [1, 2])
def test_front_and_rear_wheels_swapped_are_flagged(seed):
    """Rule 29: a car's axles sit where real cars have them, so its front and rear wheels named the other way round
    (a side view, where no face turns away to give it away) come out as an implausible fit saying so; the same clicks
    rightly named do not. Before the axle prior the swapped names fitted as well as the right ones (the axles were
    free unknowns: swapping the names swapped their values)."""
    scene = random_scene(np.random.default_rng(seed), "side")
    prior = load_priors()["Car"]
    right = fit_one(Vehicle("1", "Car", None, tuple(scene.parts), "$"), CAMERA, prior, SolverOptions())
    assert right.ok and right.implausible is None
    parts = tuple(replace(p, name=_AXLE_SWAP.get(p.name, p.name)) for p in scene.parts)
    swapped = fit_one(Vehicle("1", "Car", None, parts, "$"), CAMERA, prior, SolverOptions())
    assert swapped.ok and swapped.confidence <= IMPLAUSIBLE_CONFIDENCE
    assert swapped.implausible == "the front axle comes out behind the rear one: front and rear wheels look swapped"
    assert any("check the wheels' names (front and rear)" in w for w in swapped.warnings)
    # A van's axles are free (no real data here says where they are): the same clicks are not judged by them.
    van = fit_one(Vehicle("1", "Van", None, parts, "$"), CAMERA, load_priors()["Van"], SolverOptions())
    assert van.implausible is None or "axle" not in van.implausible


def test_axle_far_from_where_cars_have_it():
    """An axle more than four of the prior's sigmas from its place (a wheel clicked 300 px off, as a newcomer did)."""
    p = np.array([4.0, 1.7, 1.5, 1.2, -1.1])  # dx, dy, dz, Xwf, Xwr: both axles where cars have them
    names = ("dx", "dy", "dz", "Xwf", "Xwr")
    assert axle_implausibility(names, p, "Car", 3.9) is None
    sigma = CAR_AXLES.spread * 3.9
    p[4] = -CAR_AXLES.rear * 4.0 - 4.05 * sigma
    why = axle_implausibility(names, p, "Car", 3.9)
    assert why is not None and why.startswith("the rear axle comes out 1.8 m behind the middle of a 4.0 m car")
    p[4] = -CAR_AXLES.rear * 4.0 - 3.95 * sigma
    assert axle_implausibility(names, p, "Car", 3.9) is None
    assert axle_implausibility(names[:4], p[:4], "Car", 3.9) is None  # the front axle alone, where cars have it
    assert axle_implausibility(names, np.array([4.0, 1.7, 1.5, -1.0, 1.0]), "Truck", 6.0) is None


def test_axle_prior_rows_state_real_cars_axles():
    """Rule 29's rows in the problem: one per clicked axle of a car, zero at the prior's axles, weighed as the size
    prior; none for a van."""
    scene = random_scene(np.random.default_rng(3), "side")
    priors = load_priors()
    car = Problem.build(scene.model, CAMERA, priors["Car"], 1.0, 10.0)
    van = Problem.build(scene.model, CAMERA, priors["Van"], 1.0, 10.0)
    assert len(car.b) == len(van.b) + 2
    names = scene.model.param_names
    p = np.zeros(len(names))
    p[:3] = [4.0, 1.7, 1.5]
    p[names.index("Xwf")], p[names.index("Xwr")] = CAR_AXLES.front * 4.0, -CAR_AXLES.rear * 4.0
    a, b = car.scale_terms(np.zeros(3), p)
    np.testing.assert_allclose((a - b)[3:5], 0.0, atol=1e-12)
    p[names.index("Xwf")] += CAR_AXLES.spread * float(priors["Car"].mean[0])  # one sigma ahead
    a, b = car.scale_terms(np.zeros(3), p)
    np.testing.assert_allclose((a - b)[3:5], [1.0, 0.0], atol=1e-12)
    assert car.row_cues[3:5] == ("axle prior", "axle prior")


def test_an_implausible_fit_is_never_well_determined():
    """However small its sigmas (they are the wrong answer's), a fit no person could have clicked is not well
    determined, and validate's verdict says why first; the same clicks rightly named are well determined."""
    from toosicubix.pipeline.validation import Thresholds, judge

    scene = random_scene(np.random.default_rng(0), "oblique-front-left")
    prior = load_priors()["Car"]
    right = fit_one(Vehicle("1", "Car", None, tuple(scene.parts), "$"), CAMERA, prior, SolverOptions())
    swapped = fit_one(Vehicle("1", "Car", None, mirrored(tuple(scene.parts)), "$"), CAMERA, prior, SolverOptions())
    assert judge(right, Thresholds()) == ()
    assert swapped.implausible is not None and swapped.sigma.yaw_deg < Thresholds().max_yaw_sigma_deg
    problems = judge(swapped, Thresholds())
    assert problems[0] == f"implausible: {swapped.implausible}"

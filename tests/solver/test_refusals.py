"""Issue 33, item 3: every refusal says in plain words what is missing and what would fix it; the parameter
names, the Jacobian and the thresholds stay in the technical detail (results.json's ``error_detail``)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.parts.test_real_click_kinds import exact_prior, project, scene
from tests.scenes import CAMERA
from toosicubix.geometry import geodesic_angle
from toosicubix.model import Part
from toosicubix.parts.linear import build_parts_model
from toosicubix.solver.degenerate import no_start, seen_only_from, starts_collapsed, too_far
from toosicubix.solver.fit import fit_vehicle

#: What a person reading a refusal should never see: unknowns' names, linear algebra, RMS thresholds.
TECHNICAL = re.compile(r"parts\[\d+\]\.[XYZ]|\bXw[fr]\b|\bZh\b|\bd[xyz]\b|Jacobian|rank|RMS|constraints|degenerate")


def rear_view_parts():
    """Issue 14's configuration, seen only from behind: two rear light pairs, the rear badge and a roof pair;
    every pair brings its own width and height, so nothing ties the clicks to the vehicle's size."""
    d, R, t = scene(np.random.default_rng(0))

    def uv(*points):
        return project(np.array(points, dtype=float), R, t)

    x = -0.5 * d[0]
    parts = [Part("symmetry", "rear", uv([x, 0.7, 0.9], [x, -0.7, 0.9]), "a"),
             Part("symmetry", "rear", uv([x, 0.6, 0.7], [x, -0.6, 0.7]), "b"),
             Part("point", "rear-center", uv([x, 0.0, 0.6]), "c"),
             Part("symmetry", "roof", uv([-1.0, 0.6, d[2]], [-1.0, -0.6, d[2]]), "d")]
    return parts, uv, d, R, t


def test_a_rear_view_says_what_it_lacks_and_a_side_wheel_fixes_it():
    parts, uv, d, R, t = rear_view_parts()
    fit = fit_vehicle(build_parts_model(parts), CAMERA, exact_prior(d))
    assert not fit.ok
    assert fit.reason.startswith("seen only from behind, the clicks do not fix ")
    assert fit.reason.endswith("; add a forward arrow along its side, or a wheel or an edge on a side you can see")
    assert TECHNICAL.search(fit.reason) is None, fit.reason
    assert "Jacobian rank deficient" in fit.detail and "parts[0].Y" in fit.detail  # the experts' account
    # What the message suggests works: both wheels on the left side (noise-free: exact to solver tolerance).
    wheels = [Part("point", "wheel-rear-left", uv([-1.4, 0.5 * d[1], 0.0]), "e"),
              Part("point", "wheel-front-left", uv([1.4, 0.5 * d[1], 0.0]), "f")]
    fixed = fit_vehicle(build_parts_model(parts + wheels), CAMERA, exact_prior(d))
    assert fixed.ok, fixed.reason
    assert geodesic_angle(fixed.R_cam_vehicle, R) < 1e-9
    np.testing.assert_allclose(fixed.t_cam_vehicle, t, atol=1e-9)


def test_a_refusal_never_suggests_a_cue_the_vehicle_has():
    parts, uv, d, _, _ = rear_view_parts()
    x = -0.5 * d[0]
    arrow = Part("direction", "forward", uv([x, 0.5 * d[1], 0.3], [x + d[0], 0.5 * d[1], 0.3]), "e")
    fit = fit_vehicle(build_parts_model([*parts, arrow]), CAMERA, exact_prior(d))
    assert not fit.ok  # the arrow fixes the heading, not the pairs' free widths and heights
    assert "forward arrow along" not in fit.reason
    assert fit.reason.endswith("; add a wheel or an edge on a side you can see")


def test_the_view_is_the_one_face_every_click_can_be_seen_on():
    parts, _, _, _, _ = rear_view_parts()
    model = build_parts_model([Part("point", "wheel-front-left", np.array([[300.0, 250.0]]), "a"),
                               Part("point", "wheel-rear-left", np.array([[500.0, 252.0]]), "b"),
                               Part("point", "corner-top-rear-left", np.array([[520.0, 180.0]]), "c")])
    assert seen_only_from(model) == "left"
    assert seen_only_from(build_parts_model(parts)) == "rear"


@pytest.mark.parametrize(("uv", "plain"), [
    (lambda k: (300.0 + 17.0 * k, 200.0), "lie on one straight line"),
    (lambda k: (500.0 + k % 2, 200.0), "within a few pixels of each other"),
])
def test_clicks_in_a_blob_or_on_a_line_are_refused_in_plain_words(uv, plain):
    names = ["wheel-front-left", "wheel-rear-left", "wheel-rear-right", "corner-top-rear-left", "edge-rear-right"]
    parts = [Part("point", n, np.array([uv(k)]), f"parts[{k}]") for k, n in enumerate(names)]
    fit = fit_vehicle(build_parts_model(parts), CAMERA, exact_prior(np.array([4.2, 1.8, 1.5])))
    assert plain in fit.reason
    assert TECHNICAL.search(fit.reason) is None, fit.reason
    assert fit.detail.startswith("degenerate clicks: all 5 clicks lie")


def test_too_few_clicks_say_how_many_more():
    parts = [Part("point", "wheel-rear-left", np.array([[500.0, 250.0]]), "$")]
    fit = fit_vehicle(build_parts_model(parts), CAMERA, exact_prior(np.array([4.2, 1.8, 1.5])))
    # 1 click gives 2 of the 7 constraints needed: 5 short, 2 per click, so 3 more.
    assert fit.reason.startswith("too few clicks: 1 clicked point cannot place a cuboid; click at least 3 more named "
                                 "parts")
    assert TECHNICAL.search(fit.reason) is None, fit.reason


def test_the_other_refusals_are_plain_and_keep_the_detail():
    model = build_parts_model([Part("point", "wheel-rear-left", np.array([[500.0, 250.0]]), "$")])
    far = too_far("degenerate clicks: the fit is at an absurd depth (3500 m)")
    for refusal in (no_start(model), starts_collapsed("not determined"), far):
        assert TECHNICAL.search(refusal.reason) is None, refusal.reason
        assert refusal.detail.startswith("degenerate clicks")
    assert "left and right are the vehicle's own" in no_start(model).reason


def test_clicks_that_hardly_tie_the_vehicle_to_its_size_are_refused_in_plain_words():
    """Three noisy clicks on a car seen from the side (two wheels and a front edge), fitted with the track solver's
    relaxed single-frame options under a prototype with free axles, hardly tie the vehicle to its size. Whether every
    descent start then collapses onto the camera, and how uncertain the distance from typical part positions comes
    out, turns on the last bits of the arithmetic (a nudge of 1e-7 px turns it either way, as does another machine's
    BLAS), so the test takes forty scenes, each also nudged: those refused must be refused for that reason in plain
    words (this path once raised a TypeError, the local flag shadowing the refusal), and some must be. A car's axle
    prior (rule 29) ties the two wheels to its length: every one of the same clicks is then placed."""
    from dataclasses import replace

    from tests.scenes import random_scene
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.size_priors import SizePrior
    from toosicubix.solver.fit import SolverOptions
    from toosicubix.solver.track import RELAXED

    car = load_priors()["Car"]
    free_axles = SizePrior.from_mean_cov("Quadricycle", car.mean, car.cov)
    options = replace(SolverOptions(), **RELAXED)
    refused = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        scene = random_scene(rng, "side")
        parts = [replace(p, uv=p.uv + rng.normal(0.0, 1.5, p.uv.shape)) for p in scene.parts[:3]]
        for nudge in (0.0, 1e-7):
            model = build_parts_model([replace(p, uv=p.uv + nudge) for p in parts])
            assert fit_vehicle(model, CAMERA, car, options).ok, seed
            fit = fit_vehicle(model, CAMERA, free_axles, options)
            if fit.ok:
                continue
            refused += 1
            assert fit.detail.startswith("degenerate clicks: every start collapsed onto the camera, and from typical "
                                         "part positions the distance is "), (seed, fit.detail)
            assert re.match(r"these clicks hardly tie the vehicle to its size, so its distance is (not determined|"
                            r"uncertain by \d+%): click both wheels", fit.reason), fit.reason
            assert TECHNICAL.search(fit.reason) is None, fit.reason
    assert refused >= 2  # 7 of the 80 on the machine this was written on


def test_a_car_s_axles_held_by_its_prior_are_not_the_clicks_to_fix():
    """Rule 31: both wheels of one side and both edges of it (4 points: 8 equations less the two axles and the two
    edges' heights) give 4 constraints of the 6 needed for a prototype with free axles; a car's axles are held by the
    axle prior, as its dimensions by the size prior, so the same clicks give 6 and are fitted."""
    from tests.scenes import random_scene
    from toosicubix.annotations.priors_file import load_priors

    scene = random_scene(np.random.default_rng(1), "side")
    parts = [p for p in scene.parts if p.name in ("wheel-front-right", "wheel-rear-right", "edge-front-right",
                                                  "edge-rear-right")]
    model = build_parts_model(parts)
    assert model.constraints == 4
    car = fit_vehicle(model, CAMERA, load_priors()["Car"])
    assert car.ok, car.reason
    van = fit_vehicle(model, CAMERA, load_priors()["Van"])  # free axles: 4 constraints, 1 more click needed
    assert van.reason.startswith("too few clicks: 4 clicked points cannot place a cuboid; click at least 1 more")
    assert "(2 per point minus 4 auxiliary unknowns); at least 6" in van.detail
    one_wheel = build_parts_model(parts[:1] + parts[2:])  # 3 points, the front axle held: 6 - 3 + 1 = 4, still short
    refused = fit_vehicle(one_wheel, CAMERA, load_priors()["Car"])
    assert "give 4 (2 per point minus 3 auxiliary unknowns, 1 of them held by the axle prior)" in refused.detail

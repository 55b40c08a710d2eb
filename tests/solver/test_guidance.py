"""What to click next (toosicubix.guidance)."""

import numpy as np
import pytest

from tests.scenes import CAMERA, random_scene
from toosicubix.annotations.priors_file import load_priors
from toosicubix.model import Part
from toosicubix.parts.linear import TypicalKeypoint, build_parts_model
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.guidance import ALREADY_CLICKED_SIGMAS, guide, suggest_clicks

CAR = load_priors()["Car"]
OPTIONS = SolverOptions()


def _fit(parts):
    return fit_vehicle(build_parts_model(parts), CAMERA, CAR, OPTIONS)


@pytest.mark.parametrize(("view", "seed", "k"), [("rear", 1, 4), ("front", 2, 4), ("oblique-front-left", 3, 4),
                                                 ("oblique-rear-right", 4, 5)])
def test_clicking_a_suggestion_where_predicted_gives_the_predicted_uncertainty(view, seed, k):
    """A part clicked exactly where the suggestion says lies on the fitted cuboid, so the fit does not move
    and its uncertainty becomes the one predicted (up to the solver's convergence: 1e-3 relative)."""
    scene = random_scene(np.random.default_rng(seed), view)
    parts = tuple(scene.parts[:k])
    fit = _fit(parts)
    suggestions = suggest_clicks(parts, CAMERA, CAR, fit, OPTIONS)
    assert suggestions
    for s in suggestions[:3]:
        refit = _fit((*parts, Part(s.kind, s.name, s.uv, "$")))
        assert refit.ok
        assert refit.uncertainty.yaw_deg == pytest.approx(s.yaw_sigma_deg, rel=1e-3)
        assert refit.uncertainty.depth_rel == pytest.approx(s.depth_sigma_rel, rel=1e-3)
        assert s.yaw_gain_deg == pytest.approx(fit.uncertainty.yaw_deg - s.yaw_sigma_deg, rel=1e-9)


def test_suggestions_are_ranked_visible_first_then_by_score_and_never_repeat_a_click():
    scene = random_scene(np.random.default_rng(1), "rear")
    parts = tuple(scene.parts[:4])
    suggestions = suggest_clicks(parts, CAMERA, CAR, _fit(parts), OPTIONS)
    clicked = {(p.kind, p.name) for p in parts}
    assert not clicked & {(s.kind, s.name) for s in suggestions}
    usable = [s.visible and s.inside for s in suggestions]
    assert usable == sorted(usable, reverse=True)
    scores = [s.score for s in suggestions if s.visible and s.inside]
    assert scores == sorted(scores, reverse=True)
    for s in suggestions:  # the score is the log of the shrink factor of yaw sigma times depth sigma
        base = _fit(parts).uncertainty
        assert s.score == pytest.approx(np.log(base.yaw_deg / s.yaw_sigma_deg * base.depth_rel / s.depth_sigma_rel))


def test_a_rear_view_is_told_what_pins_its_yaw():
    """Rear face and rear wheels only: the yaw is barely determined and the length not at all. The best suggestion
    is visible, inside the image, and cuts the yaw sigma by more than half; a front wheel, out of sight here, would
    pin the yaw (its axle where a car's is, rule 29: from 58 degrees to 2.4). The length stays the cues': the
    wheelbase says it only through where cars have their axles, no better than the size prior."""
    scene = random_scene(np.random.default_rng(2), "rear")
    parts = tuple(scene.parts[:4])
    fit = _fit(parts)
    assert fit.observability.status["length"] == "cues only"
    suggestions = suggest_clicks(parts, CAMERA, CAR, fit, OPTIONS)
    assert suggestions[0].visible and suggestions[0].inside
    assert suggestions[0].yaw_sigma_deg < 0.5 * fit.uncertainty.yaw_deg
    front_wheel = next(s for s in suggestions if s.name.startswith("wheel-front"))
    refit = _fit((*parts, Part(front_wheel.kind, front_wheel.name, front_wheel.uv, "$")))
    assert refit.uncertainty.yaw_deg < 0.1 * fit.uncertainty.yaw_deg
    assert refit.uncertainty.yaw_deg == pytest.approx(front_wheel.yaw_sigma_deg, rel=1e-3)  # clicked where predicted


def test_corners_are_suggested_only_on_box_shaped_vehicles_or_once_one_was_clicked():
    scene = random_scene(np.random.default_rng(3), "oblique-front-left")
    parts = tuple(p for p in scene.parts[:5] if not p.name.startswith("corner-"))
    fit = _fit(parts)
    names = [s.name for s in suggest_clicks(parts, CAMERA, CAR, fit, OPTIONS)]
    assert not any(n.startswith("corner-") for n in names)
    boxy = [s.name for s in suggest_clicks(parts, CAMERA, CAR, fit, OPTIONS, box_shaped=True)]
    assert any(n.startswith("corner-") for n in boxy)


def test_no_suggestions_for_a_failed_fit():
    scene = random_scene(np.random.default_rng(0), "side")
    parts = tuple(scene.parts[:2])
    fit = _fit(parts)
    assert not fit.ok
    assert suggest_clicks(parts, CAMERA, CAR, fit, OPTIONS) == []


def test_suggestions_start_from_the_fits_own_sigma_when_clicks_are_weighted():
    # Keypoints carry their spread as click weights: the guidance's "now" must be the fit's own uncertainty,
    # not that of exactly placed keypoints.
    from dataclasses import replace

    from tests.parts.test_real_click_kinds import exact_prior, keypoint_parts, scene
    from tests.solver.test_robust import TWELVE

    rng = np.random.default_rng(2)
    for _ in range(3):
        d, R, t = scene(rng)
        parts = [replace(p, uv=p.uv + rng.normal(0.0, 1.0, p.uv.shape)) for p in keypoint_parts(d, R, t, TWELVE)][:7]
        options = SolverOptions(click_sigma=1.0)
        fit = fit_vehicle(build_parts_model(parts), CAMERA, exact_prior(d), options)
        assert fit.ok and fit.click_weights is not None and np.all(fit.click_weights < 1)
        suggestions = suggest_clicks(parts, CAMERA, exact_prior(d), fit, options)
        assert suggestions
        for s in suggestions:  # one Jacobian for the fit and the candidates: equal to rounding
            assert s.yaw_sigma_deg + s.yaw_gain_deg == pytest.approx(fit.uncertainty.yaw_deg, rel=1e-9)
            assert s.depth_sigma_rel + s.depth_gain_rel == pytest.approx(fit.uncertainty.depth_rel, rel=1e-9)


def test_a_mappings_keypoints_are_suggested_instead_of_the_vocabulary_at_their_place_and_weight():
    """With ``keypoints`` (a mapping's, for the annotate page), the candidates are those keypoints not clicked
    yet: each placed at ``at`` on the fitted cuboid, seen when a face it sits near is turned to the camera, and
    clicked exactly there it gives the predicted uncertainty (the refit weighs it by its spread as predicted;
    its soft weight is taken at the distance of the refit's best start, not the fitted one: 1e-3 relative)."""
    from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts, project
    from tests.parts.test_real_click_kinds import scene as keypoint_scene

    d, R, t = keypoint_scene(np.random.default_rng(5))
    clicked = keypoint_parts(d, R, t)[:6]
    prior = exact_prior(d)
    fit = fit_vehicle(build_parts_model(tuple(clicked)), CAMERA, prior, OPTIONS)
    assert fit.ok
    more = {"lamp-front-left": (0.46, 0.36, 0.55), "lamp-front-right": (0.46, -0.36, 0.55),
            "mirror-right": (0.18, -0.5, 0.65)}
    keypoints = {name: TypicalKeypoint(np.array(at), np.full(3, 0.02)) for name, at in {**REAR_LEFT, **more}.items()}
    suggestions = suggest_clicks(tuple(clicked), CAMERA, prior, fit, OPTIONS, keypoints=keypoints)
    assert {s.name for s in suggestions} == set(keypoints) - {p.name for p in clicked}
    assert {s.kind for s in suggestions} == {"keypoint"}
    # Seen from behind and the left: the right front lamp and the right mirror sit near faces turned away only;
    # the left front lamp sits near the front and the left face, and the left one is seen.
    assert {s.name for s in suggestions if not s.visible} == {"lamp-front-right", "mirror-right"}
    for s in suggestions:
        at = keypoints[s.name].at
        expected_uv = project((at * fit.dimensions)[None], fit.R_cam_vehicle, fit.t_cam_vehicle)
        np.testing.assert_allclose(s.uv, expected_uv, atol=1e-9)
    for s in [s for s in suggestions if s.visible][:3]:
        at, spread, _, _ = keypoints[s.name]
        refit = fit_vehicle(build_parts_model((*clicked, Part("keypoint", s.name, s.uv, "$", None, at, spread))),
                            CAMERA, prior, OPTIONS)
        assert refit.uncertainty.yaw_deg == pytest.approx(s.yaw_sigma_deg, rel=1e-3)
        assert refit.uncertainty.depth_rel == pytest.approx(s.depth_sigma_rel, rel=1e-3)


def test_a_keypoint_is_seen_on_the_faces_it_was_learned_to_be_seen_from():
    """A rear window's top corner sits on the roof, inside the box's rear end: by its position only the top face
    shows it, which a camera below the roof does not see. Learned to be seen from the rear (``seen_from``), it is
    a visible target on a car seen from behind; learned to be seen from the right, not on a car seen from the
    left."""
    from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts
    from tests.parts.test_real_click_kinds import scene as keypoint_scene
    from toosicubix.solver.plausibility import faces_turned_to_camera

    d, R, t = keypoint_scene(np.random.default_rng(5))
    clicked = keypoint_parts(d, R, t)[:6]
    prior = exact_prior(d)
    fit = fit_vehicle(build_parts_model(tuple(clicked)), CAMERA, prior, OPTIONS)
    facing = faces_turned_to_camera(fit.R_cam_vehicle, fit.t_cam_vehicle, fit.dimensions, grazing_deg=-5.0)
    assert facing["rear"] and facing["left"] and not facing["top"] and not facing["right"]
    at, spread = np.array([-0.29, -0.3, 0.92]), np.full(3, 0.02)
    keypoints = {name: TypicalKeypoint(np.array(a), spread) for name, a in REAR_LEFT.items()}

    def visible(**window: TypicalKeypoint) -> bool:
        suggestions = suggest_clicks(tuple(clicked), CAMERA, prior, fit, OPTIONS, keypoints={**keypoints, **window})
        return next(s.visible for s in suggestions if s.name in window)

    assert TypicalKeypoint(at, spread).faces == ("top",)
    assert not visible(window=TypicalKeypoint(at, spread))
    assert visible(window=TypicalKeypoint(at, spread, ("rear",)))
    assert not visible(window=TypicalKeypoint(at, spread, ("right", "top")))


def test_targets_are_ranked_by_the_gain_to_expect_from_how_often_people_click_them():
    """Two equal keypoints but for how often people click them where they can be seen: the one clicked twice as
    often ranks first, although its own sigmas are the same; each keeps its score (the shrink if clicked)."""
    from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts
    from tests.parts.test_real_click_kinds import scene as keypoint_scene

    d, R, t = keypoint_scene(np.random.default_rng(5))
    clicked = keypoint_parts(d, R, t)[:6]
    prior = exact_prior(d)
    fit = fit_vehicle(build_parts_model(tuple(clicked)), CAMERA, prior, OPTIONS)
    spread = np.full(3, 0.02)
    best = suggest_clicks(tuple(clicked), CAMERA, prior, fit, OPTIONS,
                          keypoints={n: TypicalKeypoint(np.array(a), spread) for n, a in REAR_LEFT.items()})[0]
    at = np.array(REAR_LEFT[best.name])
    rest = {n: TypicalKeypoint(np.array(a), spread) for n, a in REAR_LEFT.items() if n != best.name}
    ranked = suggest_clicks(tuple(clicked), CAMERA, prior, fit, OPTIONS, keypoints={
        **rest, "rarely": TypicalKeypoint(at, spread, (), 0.01), best.name: TypicalKeypoint(at, spread, (), 0.5)})
    by_name = {s.name: s for s in ranked}
    assert by_name["rarely"].score == pytest.approx(by_name[best.name].score, rel=1e-9)
    assert by_name[best.name].expected_score == pytest.approx(0.5 * by_name[best.name].score, rel=1e-12)
    names = [s.name for s in ranked]
    assert names.index(best.name) < names.index("rarely")
    assert by_name[best.name].to_json()["clicked_share"] == 0.5
    assert "clicked_share" not in best.to_json()  # 1: not written


@pytest.mark.parametrize(("view", "seed", "k"), [("rear", 1, 4), ("oblique-front-left", 3, 4)])
def test_clicking_every_visible_suggestion_gives_the_reachable_uncertainty(view, seed, k):
    """Issue 33, item 4: ``reachable`` is what clicking every visible suggestion inside the image gives. Clicked
    exactly where predicted, they all lie on the fitted cuboid, so the refit does not move and its uncertainty is
    the reachable one (up to the solver's convergence: 1e-3 relative, as for one suggestion)."""
    scene = random_scene(np.random.default_rng(seed), view)
    parts = tuple(scene.parts[:k])
    fit = _fit(parts)
    guidance = guide(parts, CAMERA, CAR, fit, OPTIONS)
    seen = [s for s in guidance.suggestions if s.visible and s.inside]
    assert len(seen) >= 3
    refit = _fit((*parts, *(Part(s.kind, s.name, s.uv, "$") for s in seen)))
    assert refit.ok
    assert refit.uncertainty.yaw_deg == pytest.approx(guidance.reachable.yaw_deg, rel=1e-3)
    assert refit.uncertainty.depth_rel == pytest.approx(guidance.reachable.depth_rel, rel=1e-3)
    assert guidance.reachable.yaw_deg <= min(s.yaw_sigma_deg for s in seen)


def test_no_suggestion_where_the_person_clicked_already():
    """A wheel's hub clicked counts as that wheel clicked, and no part is suggested within ALREADY_CLICKED_SIGMAS
    click sigmas of a click (3 px here): no click could tell it from the one already there."""
    scene = random_scene(np.random.default_rng(3), "oblique-front-left")
    parts = tuple(scene.parts[:5])
    fit = _fit(parts)
    before = guide(parts, CAMERA, CAR, fit, OPTIONS).suggestions
    wheel = next(s for s in before if s.name.startswith("wheel-"))
    hub = Part("point", wheel.name.replace("wheel-", "hub-"), wheel.uv - np.array([0.0, 25.0]), "$")
    refit = _fit((*parts, hub))
    assert refit.ok
    assert wheel.name not in {s.name for s in guide((*parts, hub), CAMERA, CAR, refit, OPTIONS).suggestions}
    # A corner (no unknowns of its own: the same fit) clicked 2.5 px from where a suggestion would go hides it.
    target = next(s for s in before if s.kind == "point" and s.name != wheel.name)
    near = Part("point", "corner-top-front-right", target.uv + np.array([[1.5, 2.0]]), "$")
    after = guide((*parts, near), CAMERA, CAR, fit, OPTIONS).suggestions
    assert target.name not in {s.name for s in after}
    clicked = np.concatenate([p.uv for p in (*parts, near)])
    for s in after:
        assert np.min(np.linalg.norm(s.uv[:, None] - clicked[None], axis=2)) >= ALREADY_CLICKED_SIGMAS * 1.5


def test_a_car_clicked_on_one_end_is_told_to_click_toward_the_far_end_first():
    """Issue 36, item 3: every keypoint on the rear (lamps, rear glass, bumper), the car seen from behind and its left:
    the clicks leave its yaw and length to the size prior. The observability says so in one sentence naming the far
    end and the side the camera sees, and the keypoints toward the front along that side come first among the next
    clicks, whatever their linearised gain."""
    from tests.parts.test_real_click_kinds import REAR_LEFT, exact_prior, keypoint_parts
    from tests.parts.test_real_click_kinds import scene as keypoint_scene
    from toosicubix.solver.uncertainty import one_end

    d, R, t = keypoint_scene(np.random.default_rng(5))
    rear = {n: at for n, at in REAR_LEFT.items() if at[0] < -0.15}
    clicked = tuple(keypoint_parts(d, R, t, rear))
    prior = exact_prior(d)
    fit = fit_vehicle(build_parts_model(clicked), CAMERA, prior, OPTIONS)
    assert fit.ok
    assert one_end(build_parts_model(clicked), fit.p, fit.R_cam_vehicle, fit.t_cam_vehicle) == ("rear", "left")
    sentences = fit.observability.sentences
    assert any(s.startswith("every keypoint is on its rear end, so its yaw and length rest on the size prior: click "
                            "one more toward the far end, the front, along its left side") for s in sentences)
    assert not any(s.startswith(("yaw ", "length ")) for s in sentences)  # the one sentence says it for both
    more = {"wheel-front-left": (0.3, 0.49, 0.2), "lamp-front-right": (0.46, -0.36, 0.55),
            "handle-rear": REAR_LEFT["handle-rear"], "bumper-right": (-0.48, -0.35, 0.25)}
    keypoints = {n: TypicalKeypoint(np.array(a), np.full(3, 0.02)) for n, a in {**REAR_LEFT, **more}.items()}
    suggestions = suggest_clicks(clicked, CAMERA, prior, fit, OPTIONS, keypoints=keypoints)
    first = suggestions[0]
    assert first.far_end and first.visible and keypoints[first.name].at[0] > 0.05
    assert first.to_json()["far_end"] is True
    far = [s.name for s in suggestions if s.far_end]
    # past the middle by more than 5 % of the length (the front door handle, at 5 %, is not)
    assert set(far) == {"door-bottom", "mirror", "wheel-front-left", "lamp-front-right"}
    visible_far = [s for s in suggestions if s.far_end and s.visible and s.inside]
    assert suggestions[:len(visible_far)] == visible_far  # every visible one toward the front before the rest
    # Clicks along the length (a front door handle besides the rear): no such sentence, no far end.
    along = (*clicked, *keypoint_parts(d, R, t, {"handle-front": REAR_LEFT["handle-front"]}))
    fit_along = fit_vehicle(build_parts_model(along), CAMERA, prior, OPTIONS)
    assert one_end(build_parts_model(along), fit_along.p) is None
    assert not any(s.startswith("every keypoint") for s in fit_along.observability.sentences)
    assert not any(s.far_end for s in suggest_clicks(along, CAMERA, prior, fit_along, OPTIONS, keypoints=keypoints))

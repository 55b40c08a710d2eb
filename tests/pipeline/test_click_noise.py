"""The click noise estimated from a batch's own residuals (what ``fit`` does unless given ``--click-sigma``)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.parts.test_real_click_kinds import exact_prior, project, scene
from tests.scenes import CAMERA
from tests.solver.test_robust import TWELVE
from toosicubix.formats.results import ImageResult, SolverStats, VehicleResult
from toosicubix.model import Image, Part, Vehicle
from toosicubix.pipeline import click_noise
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.click_noise import (
    MIN_DOF,
    ClickNoise,
    Redundancy,
    clean,
    estimate_from_pilot,
    pilot_images,
    pooled_sigma,
    redundancy,
    sigmas_noise,
)
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.solver.fit import SolverOptions

SAMPLE = "samples/annotations.json"


def test_pooled_sigma_solves_the_moment_equation_with_model_spread():
    rng = np.random.default_rng(0)
    sigma = 1.7
    evidence = []
    for _ in range(300):
        s = rng.uniform(0.5, 4.0, 12)  # the keypoints' spread in pixels
        dof = 24.0 - 9.0
        coords = rng.normal(0.0, 1.0, (12, 2)) * np.sqrt((sigma**2 + s**2) * dof / 24.0)[:, None]
        evidence.append(Redundancy(np.sum(coords**2, axis=1), s**2, dof))
    estimate, dof, vehicles = pooled_sigma(evidence)
    assert vehicles == 300 and dof == pytest.approx(4500.0)
    # 4,500 degrees of freedom; the spread carries about two thirds of each residual's variance, which widens
    # the estimate's error to about 3 % of sigma: 8 % is well past three standard errors.
    assert abs(estimate - sigma) < 0.08 * sigma


def test_pooled_sigma_stops_at_its_bounds_and_needs_redundancy():
    assert pooled_sigma([]) == (None, 0, 0)
    tiny = Redundancy(np.full(10, 1e-8), np.zeros(10), 5.0)
    assert pooled_sigma([tiny])[0] == 0.1
    huge = Redundancy(np.full(10, 1e8), np.zeros(10), 5.0)
    assert pooled_sigma([huge])[0] == 50.0


def _result(weights, dof, status="ok") -> VehicleResult:
    n = 6 if weights is None else len(weights)
    return VehicleResult(id="v", status=status, error=None, prototype="Car", t_cam_vehicle=np.array([0, 1, 20.0]),
                         residuals_px=np.ones((n, 2)), clicks=n, aux_unknowns=0,
                         click_weights=None if weights is None else np.asarray(weights, dtype=float),
                         solver=SolverStats(1, False, 1, 1, 1.0, residual_dof=dof))


def test_only_redundant_vehicles_of_keypoints_and_plates_enter():
    assert redundancy(_result([0.5] * 6, 4.0), 1.5).dof == 4.0
    assert redundancy(_result([0.5] * 6, 0.2), 1.5) is None  # not redundant
    assert redundancy(_result(None, 4.0), 1.5) is None  # parts on the cuboid only
    assert redundancy(_result([0.5] * 5 + [1.0], 4.0), 1.5) is None  # one part on the cuboid
    assert redundancy(_result([0.5] * 6, 4.0, status="failed"), 1.5) is None
    # The model's spread comes back from the weight: w = s0 / sqrt(s0^2 + s^2) with s0 = 1.5, w = 0.5: s^2 = 6.75
    np.testing.assert_allclose(redundancy(_result([0.5] * 6, 4.0), 1.5).model_px2, 6.75)


def test_pilot_takes_every_kth_vehicle_that_can_tell_the_noise():
    keypoint = Part("keypoint", "lamp-rear-left", np.zeros((1, 2)), "", None, np.zeros(3), np.full(3, 0.02))
    wheel = Part("point", "wheel-front-left", np.zeros((1, 2)), "")

    def image(i, n, parts=(keypoint,)):
        return Image(id=f"im{i}", file=None, camera=CAMERA, json_path=f"$.images[{i}]", vehicles=tuple(
            Vehicle(id=f"{i}-{j}", prototype="Car", box2d=None, parts=parts, json_path="") for j in range(n)))

    images = [image(0, 500), image(1, 3), image(2, 0), image(3, 497)]
    chosen = [v.id for im in pilot_images(images, 1000) for v in im.vehicles]
    assert len(chosen) == 334  # every 3rd of 1,000
    assert chosen[:2] == ["0-0", "0-3"] and "1-1" in chosen and "3-0" not in chosen and "3-1" in chosen
    assert [v.id for im in pilot_images(images[1:2], 3) for v in im.vehicles] == ["1-0", "1-1", "1-2"]
    # Parts on the cuboid cannot tell the click noise from where real parts sit: no pilot for them.
    assert not list(pilot_images([image(0, 5, (wheel,)), image(1, 5, (keypoint, wheel))], 10))


def test_pilot_counts_only_vehicles_with_clicks():
    # A track clicked on one frame in five: four of five vehicles carry only a box. The pilot strides over the
    # clicked ones (here 200, every one taken), not over all 1,000, which would leave it a fifth of its sample.
    wheel = Part("point", "wheel-front-left", np.zeros((1, 2)), "")
    vehicles = tuple(Vehicle(id=f"v{j}", prototype="Car", box2d=np.array([0.0, 0.0, 9.0, 9.0]),
                             parts=(wheel,) if j % 5 == 0 else (), json_path="") for j in range(1000))
    images = [Image(id="im", file=None, camera=CAMERA, json_path="$.images[0]", vehicles=vehicles)]
    chosen = [v.id for im in pilot_images(images, 200, keep=None) for v in im.vehicles]
    assert chosen == [f"v{j}" for j in range(0, 1000, 5)]
    chosen = [v.id for im in pilot_images(images, 1000, keep=None) for v in im.vehicles]
    assert chosen == [f"v{j}" for j in range(0, 1000, 15)]  # told of 1,000 clicked: every 3rd clicked one


@pytest.mark.parametrize("seed", range(6))
def test_the_pilot_reads_only_the_images_that_hold_its_vehicles(seed):
    """pilot_positions names the images every k-th clicked vehicle falls in, and pilot_images over those alone (told
    how many clicked vehicles come before each) chooses what it chooses over the whole file."""
    rng = np.random.default_rng(seed)
    keypoint = Part("keypoint", "lamp-rear-left", np.zeros((1, 2)), "", None, np.zeros(3), np.full(3, 0.02))
    wheel = Part("point", "wheel-front-left", np.zeros((1, 2)), "")
    images = []
    for i in range(int(rng.integers(20, 200))):
        vehicles = tuple(Vehicle(id=f"{i}-{j}", prototype="Car", box2d=np.zeros(4), json_path="",
                                 parts=[(), (wheel,), (keypoint,)][int(rng.integers(0, 3))])
                         for j in range(int(rng.integers(0, 9))))
        images.append(Image(id=f"im{i}", file=None, camera=CAMERA, json_path=f"$.images[{i}]", vehicles=vehicles))
    clicked = [sum(bool(v.parts) for v in im.vehicles) for im in images]
    for n_clicked in (sum(clicked), 7 * sum(clicked), 10**6):  # every one, every k-th, every 2,500th
        positions = click_noise.pilot_positions(clicked, n_clicked)
        for keep in (None, click_noise.telling):
            whole = [(im.id, [v.id for v in im.vehicles]) for im in pilot_images(images, n_clicked, keep=keep)]
            some = pilot_images([images[i] for i, _ in positions], n_clicked, keep=keep,
                                clicked_before=[before for _, before in positions])
            assert [(im.id, [v.id for v in im.vehicles]) for im in some] == whole
        # Exactly the images with a pilot vehicle are read (keep=None takes every k-th clicked one).
        assert [images[i].id for i, _ in positions] == [im.id for im in pilot_images(images, n_clicked, keep=None)]
    assert len(click_noise.pilot_positions(clicked, 10**9)) == 1  # a stride past the file: its first clicked one


def _keypoint_vehicle(rng, sigma_px: float, spread: float, k: int,
                      true_spread: float | None = None) -> tuple[Vehicle, np.ndarray]:
    """A car of twelve keypoints learned with ``spread`` (fractions of the dimensions), which really sit
    ``true_spread`` (default: ``spread``) from there, clicked with ``sigma_px`` of noise."""
    d, R, t = scene(rng)
    parts = []
    for n, (name, at) in enumerate(TWELVE.items()):
        offset = rng.normal(0.0, spread if true_spread is None else true_spread, 3)
        X = (np.array(at) + offset) * d  # where this car's keypoint really is
        uv = project(X[None], R, t) + rng.normal(0.0, sigma_px, 2)
        parts.append(Part("keypoint", name, uv, f"$.images[{k}].vehicles[0].parts[{n}]", None, np.array(at),
                          np.full(3, spread)))
    vehicle = Vehicle(id=str(k), prototype="test", box2d=None, parts=tuple(parts),
                      json_path=f"$.images[{k}].vehicles[0]")
    return vehicle, d


@pytest.mark.parametrize("truth", [0.7, 4.0])
def test_the_estimate_recovers_the_click_noise_of_simulated_keypoint_clicks(truth):
    rng = np.random.default_rng(5)
    results = []
    for k in range(80):
        vehicle, d = _keypoint_vehicle(rng, truth, 0.001, k)
        fit = fit_one(vehicle, CAMERA, exact_prior(d), SolverOptions(robust_loss="none"))  # as the pilot: 1.5 px
        results.append(ImageResult(id=str(k), K=CAMERA.K, t_cam_rect=np.zeros(3), image_size=None, vehicles=[fit]))
    noise = estimate_from_pilot(results, 1.5)
    assert noise.source == "estimated" and noise.dof >= MIN_DOF and noise.redundant_vehicles == 80
    # 80 cars of 12 keypoints: about 1,370 effective degrees of freedom, a standard error of 1.9 %; keypoints
    # sit within 0.1 % of the dimensions of their positions, so the click noise dominates: 6 % is three errors.
    assert abs(noise.sigma_px - truth) < 0.06 * truth, noise


def test_fit_says_where_its_click_noise_came_from(tmp_path):
    fit_file(SAMPLE, tmp_path / "estimated", BatchSettings(estimate_click_sigma=True))
    header = json.loads((tmp_path / "estimated" / "results.json").read_text())
    # The sample's clicks are parts on the cuboid: nothing to estimate from, the default stays and says so.
    assert header["click_noise"]["source"] == "default" and header["click_noise"]["redundant_vehicles"] == 0
    assert header["settings"]["click_sigma"] == SolverOptions.click_sigma
    summary = fit_file(SAMPLE, tmp_path / "given", BatchSettings(options=SolverOptions(click_sigma=0.7)))
    header = json.loads((tmp_path / "given" / "results.json").read_text())
    assert "click_noise" not in header and header["settings"]["click_sigma"] == 0.7
    assert summary.pilot.click_noise.source == "given"


def test_an_estimate_says_it_is_on_top_of_the_learned_spread():
    """The estimate is the noise the keypoints' learned spread leaves unexplained: 0.4 px on real clicks is no
    claim that people click to 0.4 px, and the summary says so; at the lower bound it asks why."""
    line = ClickNoise(0.39, "estimated", 0.39, 10632.0, 345, 345).describe()
    assert line.startswith("click noise: 0.39 px on top of each keypoint's learned spread, estimated from the "
                           "residuals of 345 vehicles")
    assert "its lower bound" in ClickNoise(0.1, "estimated", 0.1, 10632.0, 345, 345).describe()
    assert ClickNoise(0.7, "given").describe() == "click noise: 0.7 px (given)"


def test_the_sigmas_noise_recovers_the_click_noise_and_the_scale_on_the_spreads():
    """Rule 34: each residual's expected square is ``2 c (sigma^2 + t^2 s^2)``; the maximum-likelihood pair comes
    back from residuals drawn so."""
    rng = np.random.default_rng(0)
    evidence = []
    for _ in range(1000):
        s = rng.uniform(0.3, 4.0, 12)  # learned spreads, pixels
        dof = 15.0
        coords = rng.normal(0.0, 1.0, (12, 2)) * np.sqrt((0.8**2 + (0.7 * s) ** 2) * dof / 24.0)[:, None]
        evidence.append(Redundancy(np.sum(coords**2, axis=1), s**2, dof))
    sigma, scale = sigmas_noise(evidence)
    # Over 20 seeds of this draw the estimates scatter by 1.3 % (sigma) and 0.5 % (scale) about the truth, with
    # no bias past 0.1 %: 5 % and 2 % are about four standard errors.
    assert abs(sigma - 0.8) < 0.05 * 0.8 and abs(scale - 0.7) < 0.02 * 0.7


@pytest.mark.parametrize(("learned", "true", "low", "high"), [(0.01, 0.005, 0.25, 0.75), (0.005, 0.01, 1.4, 2.8)])
def test_the_pilot_tells_keypoints_that_sit_nearer_or_farther_than_learned(learned, true, low, high):
    """Keypoints half (twice) as far from their learned positions as learned: the sigmas' scale on the spreads is
    near 0.5 (2). Eighty cars at 12-25 m tell the scale from the click noise only roughly (the spreads' pixels vary
    by two with the depth): over three seeds 0.36-0.60 and 1.72-2.11."""
    rng = np.random.default_rng(0)
    results = []
    for k in range(80):
        vehicle, d = _keypoint_vehicle(rng, 1.0, learned, k, true_spread=true)
        fit = fit_one(vehicle, CAMERA, exact_prior(d), SolverOptions(robust_loss="none"))
        results.append(ImageResult(id=str(k), K=CAMERA.K, t_cam_rect=np.zeros(3), image_size=None, vehicles=[fit]))
    noise = estimate_from_pilot(results, 1.5)
    assert noise.source == "estimated" and noise.sigmas_noise is not None
    assert low < noise.sigmas_noise[1] < high, noise
    assert 0 < noise.clean_vehicles <= 80
    assert noise.to_json()["sigmas"] == {"sigma_px": noise.sigmas_noise[0], "spread_scale": noise.sigmas_noise[1],
                                         "vehicles": noise.clean_vehicles}
    assert (f"the sigmas take {noise.sigmas_noise[0]:.2f} px on top of {noise.sigmas_noise[1]:.2f} x each learned "
            f"spread, the likeliest for the {noise.clean_vehicles} of them without a click the robust loss would "
            f"down-weight; --click-sigma sets both") in noise.describe()


def test_the_sigmas_noise_leaves_out_cars_with_a_click_the_robust_loss_would_down_weight():
    """Rule 35: at the batch's click noise 1 px, a click of spread 2 px is down-weighted by the robust loss (factor
    below 0.5) once its squared residual passes 27 (1 + 4) = 135 px^2; its car stays out of the sigmas' estimate, the
    moment estimate keeps it."""
    inlier = Redundancy(np.array([130.0, 1.0]), np.array([4.0, 4.0]), 2.0)
    outlier = Redundancy(np.array([140.0, 1.0]), np.array([4.0, 4.0]), 2.0)
    kept = clean([inlier, outlier], 1.0)
    assert len(kept) == 1 and kept[0] is inlier
    assert sigmas_noise([inlier] * 50) is None  # 100 degrees of freedom: fewer than MIN_DOF


def test_validate_says_what_the_keypoints_sigmas_took():
    """With rule 35's estimate, validate's summary names the noise the keypoints' sigmas are for; without it, the
    fit's click noise on top of each learned spread, as before."""
    from toosicubix.pipeline.pilot import PilotFindings
    from toosicubix.pipeline.validation import Thresholds, ValidationReport, VehicleCheck

    result = VehicleResult(id="v", status="ok", error=None, prototype="Car",
                           click_labels=("keypoint-lamp-rear-left", "wheel-front-left"))
    checks = [VehicleCheck("im", "$.images[0].vehicles[0]", result, (), ())]
    plain = ValidationReport(Path("a.json"), 0.95, 0.09, Thresholds(), checks)
    assert plain._noise_phrase() == ("for clicks off by 0.95 px on parts 9 cm off the cuboid model and on top of "
                                     "each keypoint's learned spread")
    def pilot(soft_noise):
        return PilotFindings(SolverOptions(soft_noise=soft_noise), ClickNoise(0.95, "estimated", 0.95, 500.0, 50, 50))

    estimated = ValidationReport(Path("a.json"), 0.95, 0.09, Thresholds(), checks, pilot((0.686, 0.877)))
    assert estimated._noise_phrase() == ("for clicks off by 0.95 px on parts 9 cm off the cuboid model, keypoints "
                                         "and plates 0.686 px off on top of 0.88 x their learned spread (the batch's "
                                         "residuals)")
    keypoints_only = [VehicleCheck("im", "$.images[0].vehicles[0]", replace(result, click_labels=(
        "keypoint-lamp-rear-left",)), (), ())]
    alone = ValidationReport(Path("a.json"), 0.39, 0.09, Thresholds(), keypoints_only, pilot((0.513, 0.841)))
    assert alone._noise_phrase() == ("for keypoints and plates 0.513 px off on top of 0.84 x their learned spread (the "
                                     "batch's residuals)")

"""How far a batch's parts sit from the cuboid model and its click noise, estimated from its residuals (rule 33: what
``fit`` does for a batch of cuboid parts unless given ``--click-sigma`` or ``--part-sigma``)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tests.scenes import CAMERA, random_scene
from toosicubix.annotations.convert import document_json
from toosicubix.cli import main
from toosicubix.formats.results import ImageResult
from toosicubix.model import Image, Vehicle
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.click_noise import MIN_DOF
from toosicubix.pipeline.part_placement import KAPPA, Evidence, PartPlacement, estimate_placement, evidence
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.size_priors import SizePrior
from toosicubix.solver.fit import SolverOptions

FOCAL = 720.0


def _synthetic(rng: np.random.Generator, sigma_px: float, part_sigma: float, vehicles: int = 400,
               share: float = 0.7) -> list[Evidence]:
    """Squared residuals drawn from the model itself: ten clicks a vehicle 8-60 m away, one of them on the ground;
    each ``|r|^2 = c v chi^2_2`` with ``v = sigma^2 + b (f part_sigma / z)^2``."""
    out = []
    for _ in range(vehicles):
        on_body = np.r_[np.ones(9), 0.0]
        offset = on_body * FOCAL / rng.uniform(8.0, 60.0)
        v = sigma_px**2 + (offset * part_sigma) ** 2
        out.append(Evidence(share * v * rng.chisquare(2, 10), offset, share))
    return out


@pytest.mark.parametrize(("sigma_px", "part_sigma"), [(1.0, 0.06), (2.0, 0.09), (0.5, 0.03)])
def test_the_estimate_recovers_the_click_noise_and_the_parts_offsets(sigma_px, part_sigma):
    rng = np.random.default_rng(7)
    found = estimate_placement(_synthetic(rng, sigma_px, part_sigma))
    assert found is not None and found.vehicles == 400 and found.dof == pytest.approx(0.7 * 2 * 4000)
    # 4,000 squared residuals (5,600 degrees of freedom): maximum likelihood standard errors of a few per cent for
    # both; 8 % and 15 % are about three of them (checked over 50 seeds: the largest misses were 5.3 % and 11 %).
    assert abs(found.sigma_px - sigma_px) < 0.08 * sigma_px, found
    assert abs(found.residual_part_sigma_m - part_sigma) < 0.15 * part_sigma, found
    assert found.part_sigma_m == pytest.approx(KAPPA * found.residual_part_sigma_m)


def test_parts_on_the_model_come_out_near_zero_offset():
    found = estimate_placement(_synthetic(np.random.default_rng(8), 1.0, 0.0))
    assert found is not None
    assert abs(found.sigma_px - 1.0) < 0.08
    assert found.residual_part_sigma_m < 0.01  # 1 px at 720 px focal is 1.4 cm at 10 m: nothing to tell apart


def test_too_few_degrees_of_freedom_give_no_estimate():
    items = _synthetic(np.random.default_rng(9), 1.0, 0.05, vehicles=10)
    assert sum(2 * e.share * len(e.squared) for e in items) < MIN_DOF
    assert estimate_placement(items) is None


def _cuboid_batch(rng: np.random.Generator, n: int, noise_px: float) -> tuple[list[Image], list[ImageResult]]:
    """Vehicles whose parts sit exactly where the cuboid model puts them (tests.scenes), clicked with noise, each
    fitted as the pilot fits it."""
    images, results = [], []
    for k in range(n):
        scene = random_scene(rng, ("oblique-front-left", "side", "rear")[k % 3])
        parts = tuple(replace(p, uv=p.uv + rng.normal(0.0, noise_px, p.uv.shape)) for p in scene.parts)
        vehicle = Vehicle(id="v", prototype="Car", box2d=None, parts=parts, json_path=f"$.images[{k}].vehicles[0]")
        prior = SizePrior.from_mean_cov("Car", scene.dimensions, np.diag([0.3, 0.1, 0.1]) ** 2)
        fit = fit_one(vehicle, CAMERA, prior, SolverOptions(robust_loss="none"))
        images.append(Image(id=str(k), file=None, camera=CAMERA, vehicles=(vehicle,), json_path=f"$.images[{k}]"))
        results.append(ImageResult(id=str(k), K=CAMERA.K, t_cam_rect=np.zeros(3), image_size=None, vehicles=[fit]))
    return images, results


def test_fitted_parts_on_the_model_tell_the_click_noise():
    """Real fits: parts exactly on the model, 1 px of noise; the residuals say so (the fit absorbs its unknowns'
    share, which the degrees of freedom count)."""
    images, results = _cuboid_batch(np.random.default_rng(10), 200, 1.0)
    items = evidence((im.camera for im in images), results)
    assert len(items) >= 190  # a vehicle or two has no redundant clicks
    found = estimate_placement(items)
    assert found is not None and found.dof >= MIN_DOF
    # About 980 degrees of freedom, but these scenes are 8-35 m away, so the noise and an offset trade off: over six
    # seeds the estimates were 0.88-1.12 px and 1.2-2.3 cm. An offset well below the simulated person's realistic
    # placement (5.5 cm on the tuning sequences, rule 33) is what tells parts on the model.
    assert abs(found.sigma_px - 1.0) < 0.2, found
    assert found.residual_part_sigma_m < 0.035, found


def test_vehicles_with_keypoints_are_left_to_the_click_noise_estimate():
    _, results = _cuboid_batch(np.random.default_rng(11), 1, 1.0)
    fit = results[0].vehicles[0]
    assert len(evidence([CAMERA], results)) == 1
    labels = (*fit.click_labels[:-1], "keypoint-lamp")  # one click a keypoint: the vehicle is the other estimate's
    mixed = ImageResult(id="0", K=CAMERA.K, t_cam_rect=np.zeros(3), image_size=None,
                        vehicles=[replace(fit, click_labels=labels)])
    assert evidence([CAMERA], [mixed]) == []


def test_the_summary_and_results_say_what_was_estimated():
    line = PartPlacement(1.12, 0.006, 0.006, 5400.0, 380).describe()
    assert line.startswith("click noise and part placement: 1.12 px, parts 0.6 cm off the cuboid model (estimated "
                           "from the residuals of 380 pilot vehicles' cuboid parts")
    assert "--click-sigma and --part-sigma set them" in line
    assert PartPlacement(1.12, 0.006, 0.006, 5400.0, 380).to_json()["kappa"] == KAPPA
    # Real hub clicks on ApolloCar3D's 3,384 px images: the offsets explain everything, and the line says so.
    assert "the click noise at its lower bound" in PartPlacement(0.1, 0.06, 0.06, 715.0, 68).describe()
    assert "lower bound" not in line


def _annotation_file(tmp_path, n: int = 120):
    images, _ = _cuboid_batch(np.random.default_rng(12), n, 1.0)
    path = tmp_path / "annotations.json"
    path.write_text(json.dumps(document_json(images)))
    return path


def test_fit_estimates_both_for_a_batch_of_cuboid_parts_unless_given(tmp_path):
    path = _annotation_file(tmp_path)
    fit_file(path, tmp_path / "estimated", BatchSettings(estimate_click_sigma=True, estimate_part_sigma=True))
    header = json.loads((tmp_path / "estimated" / "results.json").read_text())
    placement = header["part_placement"]
    assert abs(placement["sigma_px"] - 1.0) < 0.3 and placement["part_sigma_m"] < 0.04  # see the test above
    assert header["settings"]["click_sigma"] == placement["sigma_px"]
    assert header["settings"]["part_sigma"] == placement["part_sigma_m"]
    assert "click_noise" not in header  # the part placement's line says where the click noise came from
    # The command line: estimated by default; --part-sigma (or --click-sigma) given, not.
    runner = CliRunner()
    out = runner.invoke(main, ["fit", str(path), "-o", str(tmp_path / "cli"), "--road-normal", "none"])
    assert out.exit_code == 0, out.output
    assert "click noise and part placement:" in out.output
    assert "part_placement" in json.loads((tmp_path / "cli" / "results.json").read_text())
    out = runner.invoke(main, ["fit", str(path), "-o", str(tmp_path / "given"), "--road-normal", "none",
                               "--part-sigma", "0.09"])
    assert out.exit_code == 0, out.output
    header = json.loads((tmp_path / "given" / "results.json").read_text())
    assert "part_placement" not in header and header["settings"]["part_sigma"] == 0.09
    assert header["click_noise"]["source"] == "default"
    assert "click noise: 1.5 px (default" in out.output  # --part-sigma given: only the click noise was tried


def test_a_batch_too_small_to_estimate_says_what_it_keeps(tmp_path):
    out = CliRunner().invoke(main, ["fit", "samples/annotations.json", "-o", str(tmp_path / "out")])
    assert out.exit_code == 0, out.output
    assert ("click noise and part placement: 1.5 px, parts 9 cm off the cuboid model (defaults: the pilot's cuboid "
            "parts give 19 degrees of freedom, 200 needed to estimate them); --click-sigma and --part-sigma set them"
            in out.output)
    header = json.loads((tmp_path / "out" / "results.json").read_text())
    assert "part_placement" not in header and header["settings"]["part_sigma"] == 0.09

"""Degenerate click sets fail with the reason instead of passing as confident fits (issue 13, item 2)."""

import json

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.camera import Camera
from toosicubix.formats.results import read_results
from toosicubix.pipeline.batch import fit_file
from toosicubix.solver.degenerate import MAX_DEPTH_M, MIN_CLICK_SPREAD_PX, absurd_depth, degenerate_spread

SAMPLE = REPO / "samples" / "annotations.json"
KEYS = ("xy", "left", "right", "tail", "head")


def move_clicks(doc: dict, place) -> None:
    """Put the k-th click of the first vehicle at ``place(k)``."""
    k = 0
    for part in doc["images"][0]["vehicles"][0]["parts"]:
        for key in KEYS:
            if key in part:
                part[key] = list(place(k))
                k += 1


@pytest.mark.parametrize(("place", "reason", "plain"), [
    (lambda k: (300.0 + 17.0 * k, 200.0), "clicks lie on one line", "click parts off that line"),  # issue 13
    (lambda k: (500.0 + k % 2, 200.0), "clicks lie in one cluster", "zoom in"),  # issue 13: was ok at 3.5 km
    (lambda k: (300.0 + 17.0 * k, 200.0 + 0.1 * k), "clicks lie on one line", "click parts off that line"),
])
def test_degenerate_clicks_fail_with_the_reason_and_the_batch_goes_on(tmp_path, place, reason, plain):
    doc = json.loads(SAMPLE.read_text())
    move_clicks(doc, place)
    path = tmp_path / "a.json"
    path.write_text(json.dumps(doc))
    summary = fit_file(path, tmp_path / "out")
    vehicles = [v for im in read_results(tmp_path / "out" / "results.json") for v in im.vehicles]
    first = vehicles[0]
    assert first.status == "failed" and reason in first.error_detail, first.error_detail
    assert plain in first.error, first.error  # the plain words say what to do
    assert first.confidence is None
    assert all(v.ok for v in vehicles[1:])
    assert summary.ok == len(vehicles) - 1


def test_spread_checks_know_a_real_vehicle_from_a_blob(rng):
    uv_vehicle = np.array([[825.8, 272.9], [834.8, 258.1], [728.0, 268.8], [732.3, 223.4], [807.0, 224.9]])
    assert degenerate_spread(uv_vehicle) is None
    blob = 500.0 + rng.uniform(-1.0, 1.0, size=(8, 2))  # RMS spread about 0.6 px
    assert "one cluster" in degenerate_spread(blob).detail
    line = np.column_stack([np.linspace(0, 100, 8), np.linspace(0, 50, 8)])  # exactly collinear
    assert "one line" in degenerate_spread(line).detail
    assert degenerate_spread(line[:2]) is None  # too few clicks is judged elsewhere


def test_absurd_depth():
    camera = Camera(K=np.array([[720.0, 0, 620], [0, 720, 180], [0, 0, 1]]))
    d = np.array([4.0, 1.7, 1.5])
    assert absurd_depth(camera, np.array([1.0, 1.5, 20.0]), d) is None
    assert "absurd depth (3500 m" in absurd_depth(camera, np.array([0.0, 1.5, 3500.0]), d)
    # 720 px * 4 m / depth < MIN_CLICK_SPREAD_PX beyond 720 m: the vehicle would be a dot.
    far = 720.0 * 4.0 / MIN_CLICK_SPREAD_PX + 1.0
    assert far < MAX_DEPTH_M and "spans 4 px" not in absurd_depth(camera, np.array([0.0, 0.0, far]), d)
    assert absurd_depth(camera, np.array([0.0, 0.0, np.nan]), d) is not None


def _roof_pair_problem():
    """A rear view with its rear light pair, and the Jacobian of its fit (the tests below make the pair's own two
    unknowns, how wide it is and how high it sits, trade off exactly; rule 30's case in benchmarks/decisions.md was a
    roof pair seen from straight behind)."""
    from tests.scenes import CAMERA, random_scene
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.solver.fit import SolverOptions, fit_vehicle
    from toosicubix.solver.problem import Problem
    from toosicubix.solver.refine import residuals_and_jacobian

    scene = random_scene(np.random.default_rng(4), "rear")
    options = SolverOptions()
    fit = fit_vehicle(scene.model, CAMERA, load_priors()["Car"], options)
    problem = Problem.build(scene.model, CAMERA, load_priors()["Car"], options.lambda_3d, options.lambda_px)
    _, J = residuals_and_jacobian(problem, fit.R_cam_vehicle, fit.t_cam_vehicle, fit.p)
    return scene.model, problem, J


def test_a_direction_of_one_part_s_own_unknowns_leaves_the_cuboid_fitted():
    """Rule 30: when the direction the clicks leave undetermined moves only a part's own unknowns, the cuboid does
    not move along it: the refusal says so (``cuboid`` False), in plain words, and fit_vehicle fits the vehicle with
    it as a warning; a direction that turns the vehicle is refused as before."""
    from toosicubix.solver.degenerate import degeneracy

    model, problem, J = _roof_pair_problem()
    names = ["rotation"] * 3 + ["position"] * 3 + list(model.param_names)
    k = next(i for i, label in enumerate(model.click_labels) if label.startswith("symmetry-rear"))
    own = [names.index(f"parts[{model.click_part[k]}].{axis}") for axis in ("Y", "Z")]
    loose = J.copy()
    loose[:, own[1]] = loose[:, own[0]] * 2.0  # the pair's Y and Z trade off exactly: rank deficient
    refusal = degeneracy(problem, loose, 1e-8)
    assert refusal is not None and not refusal.cuboid
    assert refusal.reason == ("the clicks do not fix how wide the rear pair is and how high the rear pair sits; the "
                              "cuboid does not depend on it, so it is fitted without it")
    turned = J.copy()
    turned[:, own[0]] = turned[:, 0] * 3.0  # the pair's width trades off with a turn of the vehicle
    refusal = degeneracy(problem, turned, 1e-8)
    assert refusal is not None and refusal.cuboid and "rotation" in refusal.detail
    assert degeneracy(problem, J, 1e-8) is None


def test_a_fit_whose_only_loose_direction_is_a_part_s_own_is_kept_with_a_warning(monkeypatch):
    from tests.scenes import CAMERA, random_scene
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.solver import fit as fit_module
    from toosicubix.solver.degenerate import Refusal

    scene = random_scene(np.random.default_rng(4), "rear")
    said = "the clicks do not fix where the roof pair sits along it; the cuboid does not depend on it, so it is fitted"
    monkeypatch.setattr(fit_module, "degeneracy", lambda *a: Refusal(said, "degenerate clicks: ...", cuboid=False))
    fit = fit_module.fit_vehicle(scene.model, CAMERA, load_priors()["Car"], fit_module.SolverOptions())
    assert fit.ok and said in fit.warnings
    monkeypatch.setattr(fit_module, "degeneracy", lambda *a: Refusal("refused", "degenerate clicks: ..."))
    fit = fit_module.fit_vehicle(scene.model, CAMERA, load_priors()["Car"], fit_module.SolverOptions())
    assert not fit.ok and fit.reason == "refused"

"""A vehicle whose fit goes wrong anywhere is failed with a reason; the batch goes on (issue 13)."""

import json
import re
from dataclasses import replace

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.formats.results import ImageResult, read_results
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.pipeline import vehicle as one
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.solver.fit import FitResult

SAMPLE = REPO / "samples" / "annotations.json"


def fake_fit(t_cam_vehicle, dimensions=(4.0, 1.7, 1.5), first_only=True):
    """A stand-in for fit_vehicle that returns ``t_cam_vehicle`` for the sample's first vehicle."""
    real = one.fit_vehicle
    calls = []

    def fit(parts, camera, prior, options, ground):
        calls.append(1)
        result = real(parts, camera, prior, options, ground)
        if first_only and len(calls) > 1:
            return result
        p = np.array(result.p, dtype=float)
        p[:3] = dimensions
        t = np.asarray(t_cam_vehicle, dtype=float)
        return FitResult("ok", None, result.constraints, result.n_clicks, result.n_aux,
                         R_cam_vehicle=R_cam_vehicle_from_ypr(0.3), t_cam_vehicle=t, p=p,
                         cost=result.cost, cost_prior=result.cost_prior, residuals_px=result.residuals_px)
    return fit


def without_boxes(tmp_path):
    doc = json.loads(SAMPLE.read_text())
    for im in doc["images"]:
        for v in im["vehicles"]:
            v.pop("box2d", None)  # the projected box is what crashed
    path = tmp_path / "a.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(("t", "dimensions", "reason"), [
    ((0.0, 1.0, -1e9), (4.0, 1.7, 1.5), "lies wholly behind the camera"),  # issue 13: aborted the batch
    ((0.0, 1.0, -2.0), (4.0, 1.7, 1.5), "lies wholly behind the camera"),
    ((0.0, 1.0, np.nan), (4.0, 1.7, 1.5), "non-finite"),
    ((0.0, 1.0, 10.0), (np.inf, 1.7, 1.5), "non-finite"),
])
def test_an_unusable_fit_is_failed_and_the_batch_goes_on(tmp_path, monkeypatch, t, dimensions, reason):
    monkeypatch.setattr(one, "fit_vehicle", fake_fit(t, dimensions))
    out = tmp_path / "out"
    summary = fit_file(without_boxes(tmp_path), out)
    vehicles = [v for im in read_results(out / "results.json") for v in im.vehicles]
    assert vehicles[0].status == "failed" and reason in vehicles[0].error, vehicles[0].error
    assert not vehicles[0].error.startswith("internal error")
    assert all(v.ok for v in vehicles[1:]) and summary.ok == len(vehicles) - 1
    for label in (out / "label_2").glob("*.txt"):
        text = label.read_text().lower()
        assert "nan" not in text and "inf" not in text


def test_a_cuboid_half_behind_the_camera_keeps_its_box():
    # The bottom centre 1 m in front, the 4 m body reaching behind: still a usable fit with a clipped box.
    from toosicubix.camera import Camera
    from toosicubix.model import Vehicle

    camera = Camera(K=np.array([[720.0, 0, 620], [0, 720, 180], [0, 0, 1]]), image_size=(1242, 375))
    vehicle = Vehicle(id="1", prototype="Car", box2d=None, parts=(), json_path="$")
    box, truncated = one._box2d(vehicle, camera, R_cam_vehicle_from_ypr(np.pi / 2), np.array([0.0, 1.5, 1.0]),
                                  np.array([4.0, 1.7, 1.5]))
    assert np.all(np.isfinite(box)) and 0.0 <= truncated <= 1.0
    with pytest.raises(one.UnusableFit, match="wholly behind"):
        one._box2d(vehicle, camera, np.eye(3), np.array([0.0, 1.5, -10.0]), np.array([4.0, 1.7, 1.5]))


def test_a_failed_result_keeps_its_reason_and_loses_non_finite_details():
    from toosicubix.formats.results import SolverStats, VehicleResult, dumps, results_to_json

    failed = VehicleResult(id="1", status="failed", error="degenerate clicks: ...", prototype="Car", kitti_type="Car",
                           solver=SolverStats(starts=4, starts_from_lines=True, descent_iterations=0,
                                              refine_iterations=0, initial_cost=float("nan")))
    checked = one.checked_result(failed)
    assert checked.error == failed.error and checked.kitti_type == "Car" and checked.solver is None
    with pytest.raises(ValueError, match=r"NaN or infinity \(not JSON\) at \$\.images\[0\]\.vehicles\[0\]\.solver"):
        dumps(results_to_json([ImageResult("a", np.eye(3), np.zeros(3), None, [failed])]))


@pytest.fixture(scope="module")
def sample_results(tmp_path_factory):
    """The sample's fitted vehicles, with their next clicks."""
    out = tmp_path_factory.mktemp("guard") / "out"
    fit_file(SAMPLE, out, BatchSettings(next_clicks=2))
    return [v for im in read_results(out / "results.json") for v in im.vehicles]


def _alternative(**changes):
    from toosicubix.solver.fit import Alternative

    fields = dict(cost=1.0, rotation_deg=180.0, turned_around=True, implausible=None, close=True,
                  R_cam_vehicle=np.eye(3), t_cam_vehicle=np.array([0.0, 1.5, 20.0]), dimensions=np.ones(3))
    return Alternative(**{**fields, **changes})


@pytest.mark.parametrize(("change", "path"), [
    (lambda v: {"alternatives": (_alternative(), _alternative(t_cam_vehicle=np.array([0.0, np.nan, 20.0])))},
     "$.alternatives[1].t_cam_vehicle[1]"),
    (lambda v: {"alternatives": (_alternative(cost=float("inf")),)}, "$.alternatives[0].cost"),
    (lambda v: {"sigma": replace(v.sigma, dimensions=(0.1, float("nan"), 0.1))}, "$.sigma.dimensions[1]"),
    (lambda v: {"observability": replace(v.observability, ratios={"yaw": np.float64(np.nan)})},
     "$.observability.variance_ratios.yaw"),
    (lambda v: {"parameters": {**v.parameters, "wheelbase": float("nan")}}, "$.parameters.wheelbase"),
    (lambda v: {"residuals_px": np.array([[0.1, 0.2], [np.inf, 0.0]])}, "$.residuals_px[1][0]"),
    (lambda v: {"click_weights": np.array([1.0, np.nan])}, "$.click_weights[1]"),
    (lambda v: {"next_clicks": [*v.next_clicks[:1], {**v.next_clicks[1], "gain": [1.0, {"x": float("nan")}]}]},
     "$.next_clicks[1].gain[1].x"),
    (lambda v: {"extra": {"mine": {"deep": [np.float32("nan")]}}}, "$.mine.deep[0]"),
    (lambda v: {"solver": replace(v.solver, initial_cost=float("-inf"))}, "$.solver.initial_cost"),
])
def test_a_nan_or_infinity_anywhere_in_a_fit_fails_it_with_its_path(sample_results, change, path):
    result = next(v for v in sample_results if v.ok)
    assert one.checked_result(result) is result
    with pytest.raises(one.UnusableFit, match=f"non-finite value at {re.escape(path)}$"):
        one.checked_result(replace(result, **change(result)))


def test_the_quick_finiteness_check_agrees_with_the_json_form(sample_results):
    from toosicubix.formats.results import all_finite, non_finite_path

    assert all(all_finite(v) and non_finite_path(v.to_json()) is None for v in sample_results)
    assert not all_finite(np.array([1.0, np.nan], dtype=object))  # cannot tell: the JSON form decides
    assert not all_finite(object())
    nan_unwritten = replace(next(v for v in sample_results if v.ok), status="failed", cost=float("nan"))
    assert not all_finite(nan_unwritten) and one.checked_result(nan_unwritten) is nan_unwritten

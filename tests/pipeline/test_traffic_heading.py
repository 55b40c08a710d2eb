"""``fit --heading-prior estimate``: the batch's traffic heading estimated by the pilot, carried by the images on the
estimated road, written to results.json, and what it does to a car clicked on its rear only (issue 36)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tests.parts.test_real_click_kinds import project
from tests.pipeline.test_road_normal import NORMAL, R_DOWN
from tests.scenes import CAMERA
from tests.solver.test_robust import TWELVE
from toosicubix.annotations.convert import document_json
from toosicubix.cli import main
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.model import Image, Part, Vehicle
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.solver import heading

REAR = {k: v for k, v in TWELVE.items() if v[0] < -0.4}
#: The traffic: heading along the camera's axis (away from it), within 3 degrees.
SPREAD_DEG = 3.0


def _traffic(n_whole: int, n_rear: int, rng) -> tuple[list[Image], list[float]]:
    """Cars ahead and to the right of a camera looking 9 deg down, heading away along its axis within
    :data:`SPREAD_DEG`: ``n_whole`` clicked on twelve keypoints of the rear and the left side, then ``n_rear`` on the
    rear only; 1 px noise. Returns the images and each car's true heading (degrees, on the road)."""
    images, truth = [], []
    d = np.array([4.4, 1.8, 1.5])
    for i in range(n_whole + n_rear):
        names = TWELVE if i < n_whole else REAR
        yaw = -90.0 + rng.normal(0.0, SPREAD_DEG)  # KITTI yaw -90: along the camera's axis, away from it
        R = R_DOWN @ R_cam_vehicle_from_ypr(np.deg2rad(yaw), 0.0, 0.0)
        t = R_DOWN @ np.array([rng.uniform(3.0, 6.0), 1.6, rng.uniform(20.0, 40.0)])
        parts = []
        for k, (name, at) in enumerate(names.items()):
            uv = project((np.array(at) * d)[None], R, t) + rng.normal(0.0, 1.0, 2)
            parts.append(Part("keypoint", name, uv, f"$.images[{i}].vehicles[0].parts[{k}]", None, np.array(at),
                              np.full(3, 0.01)))
        vehicle = Vehicle(id=f"v{i}", prototype="Car", box2d=None, parts=tuple(parts),
                          json_path=f"$.images[{i}].vehicles[0]")
        images.append(Image(id=f"im{i:03d}", file=None, camera=CAMERA, json_path=f"$.images[{i}]",
                            vehicles=(vehicle,)))
        truth.append(float(np.degrees(heading.headings(R, NORMAL))))
    return images, truth


@pytest.fixture(scope="module")
def batch(tmp_path_factory) -> tuple[Path, list[float]]:
    images, truth = _traffic(40, 12, np.random.default_rng(11))
    path = tmp_path_factory.mktemp("traffic") / "traffic.json"
    path.write_text(json.dumps(document_json(images)))
    return path, truth


def _headings(out: Path) -> np.ndarray:
    results = json.loads((out / "results.json").read_text())
    return np.array([math.degrees(float(heading.headings(np.array(v["R_cam_vehicle"]), NORMAL)))
                     for im in results["images"] for v in im["vehicles"]])


def test_the_pilot_estimates_the_traffic_and_a_rear_view_turns_toward_it(batch, tmp_path):
    path, truth = batch
    plain = BatchSettings(estimate_click_sigma=True, estimate_road_normal=True)
    fit_file(path, tmp_path / "plain", plain)
    summary = fit_file(path, tmp_path / "heading", BatchSettings(estimate_click_sigma=True, estimate_road_normal=True,
                                                                 estimate_heading=True))
    results = json.loads((tmp_path / "heading" / "results.json").read_text())
    (found,) = results["heading_prior"]
    (told,) = summary.pilot.headings.values()
    assert told.prior is not None and found["direction_deg"] == pytest.approx(math.degrees(told.prior.direction))
    # The 40 whole cars tell it (their yaw sigmas are a degree or two); some rear-only ones may too. Their mean
    # heading, 0 within 3 / sqrt(40) = 0.5 deg, and the fits' own errors of a degree or so: within 1.5 deg.
    assert found["vehicles"] >= 40 and found["reason"] is None
    assert abs(found["direction_deg"]) < 1.5
    assert 1.0 < found["sigma_deg"] < 6.0 and found["noise_px"] == results["click_noise"]["sigma_px"]
    assert all(im["ground"]["estimated"] for im in results["images"])
    assert "heading_prior" not in json.loads((tmp_path / "plain" / "results.json").read_text())
    assert any(line.startswith("heading prior of camera") for line in summary.pilot.describe())

    error = {name: np.abs(_headings(tmp_path / name) - truth) for name in ("plain", "heading")}
    rear = slice(40, None)
    # The rear-only cars: their clicks leave the heading to a few degrees, the traffic's 3 degrees hold it.
    assert np.mean(error["heading"][rear]) < 0.75 * np.mean(error["plain"][rear])
    # The whole cars' clicks fix their headings: the prior moves them by a fraction of a degree at most.
    moved = np.abs(_headings(tmp_path / "heading") - _headings(tmp_path / "plain"))[:40]
    assert np.max(moved) < 1.0


def test_one_process_or_two_write_the_same_bytes(batch, tmp_path):
    path, _ = batch
    settings = dict(estimate_click_sigma=True, estimate_road_normal=True, estimate_heading=True)
    fit_file(path, tmp_path / "one", BatchSettings(jobs=1, **settings))
    fit_file(path, tmp_path / "two", BatchSettings(jobs=2, **settings))
    assert (tmp_path / "one" / "results.json").read_bytes() == (tmp_path / "two" / "results.json").read_bytes()


@pytest.mark.parametrize(("whole", "rear", "reason"), [
    (20, 14, "of its vehicles within 3 deg of yaw, 30 needed"),  # a road, but too few determined headings
    (0, 35, "its road normal was not estimated"),  # rear views alone: their up axes scatter, no road either
])
def test_a_camera_without_the_evidence_gets_no_prior_and_says_why(tmp_path, whole, rear, reason):
    images, _ = _traffic(whole, rear, np.random.default_rng(5))
    path = tmp_path / "few.json"
    path.write_text(json.dumps(document_json(images)))
    summary = fit_file(path, tmp_path / "out", BatchSettings(estimate_click_sigma=True, estimate_road_normal=True,
                                                             estimate_heading=True))
    (told,) = summary.pilot.headings.values()
    assert told.prior is None and reason in told.reason
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert results["heading_prior"][0]["reason"] == told.reason
    assert f"heading prior of camera fx 720 px: none, {told.reason}" in summary.pilot.describe()


def test_the_option_needs_the_estimated_road(batch, tmp_path):
    path, _ = batch
    result = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "o"), "--heading-prior", "estimate",
                                       "--road-normal", "0,-1,0"])
    assert result.exit_code == 2 and "--heading-prior estimate needs the road normal" in result.output
    ok = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "o"), "--heading-prior", "estimate"])
    assert ok.exit_code == 0, ok.output
    assert "heading prior of camera" in ok.output

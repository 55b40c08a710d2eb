"""``fit --next-clicks N --mapping M`` and ``validate --mapping M``: the parts to click next are the mapping's
keypoints, in every path of the batch (one process or several, the pilot's own fits, the joint ground)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tests.pipeline.test_road_normal import _pitched_batch
from tests.solver.test_robust import TWELVE
from toosicubix.annotations.convert import document_json
from toosicubix.annotations.mapping import MappingFile
from toosicubix.cli import main
from toosicubix.model import GroundOverride
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.validation import validate_file
from toosicubix.solver.fit import SolverOptions

#: Keypoints the twelve clicked ones leave: the front and right side (turned away from these rear-left views)
#: and two more on the left side.
MORE = {"lamp-front-left": (0.46, 0.36, 0.55), "lamp-front-right": (0.46, -0.36, 0.55),
        "mirror-right": (0.18, -0.5, 0.65), "sill-front": (0.25, 0.49, 0.15), "glass-side-left": (-0.05, 0.45, 0.8)}


def _mapping() -> MappingFile:
    parts = [{"kind": "keypoint", "keypoint": name, "position": {"at": list(at), "spread": [0.01, 0.01, 0.01]}}
             for name, at in {**TWELVE, **MORE}.items()]
    return MappingFile.model_validate({"toosicubix_mapping": 1, "name": "twelve-and-more", "parts": parts})


@pytest.fixture
def keypoint_file(tmp_path: Path) -> Path:
    """Three images of one car each, its twelve keypoints clicked but the last four (left for suggestions)."""
    images = _pitched_batch(3, np.random.default_rng(11))
    doc = document_json(images)
    for im in doc["images"]:
        im["vehicles"][0]["parts"] = im["vehicles"][0]["parts"][:8]
    path = tmp_path / "keypoints.json"
    path.write_text(json.dumps(doc))
    return path


def _suggested(out: Path) -> list[list[tuple[str, str]]]:
    results = json.loads((out / "results.json").read_text())
    return [[(s["kind"], s["name"]) for s in v["next_clicks"]] for im in results["images"] for v in im["vehicles"]]


def test_fit_suggests_the_mappings_keypoints_not_clicked_yet(keypoint_file, tmp_path):
    mapping = _mapping()
    fit_file(keypoint_file, tmp_path / "one", BatchSettings(next_clicks=20, keypoints=mapping))
    suggested = _suggested(tmp_path / "one")
    clicked = set(list(TWELVE)[:8])
    for names in suggested:
        assert names and all(kind == "keypoint" for kind, _ in names)
        assert {n for _, n in names} == set(TWELVE) - clicked | set(MORE)  # every one not clicked, once
    # Several processes: the same bytes. The pilot's own fits, reused (a file too small for a road normal: the
    # pilot fitted every vehicle as the batch does): the same suggestions.
    fit_file(keypoint_file, tmp_path / "two", BatchSettings(next_clicks=20, keypoints=mapping, jobs=2))
    assert (tmp_path / "two" / "results.json").read_bytes() == (tmp_path / "one" / "results.json").read_bytes()
    summary = fit_file(keypoint_file, tmp_path / "pilot",
                       BatchSettings(next_clicks=20, keypoints=mapping, estimate_road_normal=True))
    assert summary.pilot.results is None  # the pilot fits without the robust loss, keypoint vehicles get it
    a, b = (json.loads((d / "results.json").read_text())["images"] for d in (tmp_path / "pilot", tmp_path / "one"))
    assert a == b  # every vehicle as fitted without a pilot, suggestions included
    plain = SolverOptions(robust_loss="none")
    fit_file(keypoint_file, tmp_path / "plain-one", BatchSettings(next_clicks=20, keypoints=mapping, options=plain))
    summary = fit_file(keypoint_file, tmp_path / "plain-pilot",
                       BatchSettings(next_clicks=20, keypoints=mapping, estimate_road_normal=True, options=plain))
    assert summary.pilot.results is not None  # without the robust loss the pilot fits as the batch: reused
    assert _suggested(tmp_path / "plain-pilot") == _suggested(tmp_path / "plain-one")
    a, b = (json.loads((d / "results.json").read_text())["images"]
            for d in (tmp_path / "plain-pilot", tmp_path / "plain-one"))
    assert a == b
    # Refined together with the ground plane, the vehicles keep keypoint suggestions.
    ground = GroundOverride(normal=(0.0, -float(np.cos(np.deg2rad(9.0))), -float(np.sin(np.deg2rad(9.0)))))
    fit_file(keypoint_file, tmp_path / "joint",
             BatchSettings(next_clicks=20, keypoints=mapping, ground=ground, joint_ground=True))
    assert all(names and all(k == "keypoint" for k, _ in names) for names in _suggested(tmp_path / "joint"))
    # Without a mapping: the vocabulary's parts, as before.
    fit_file(keypoint_file, tmp_path / "plain", BatchSettings(next_clicks=20))
    assert all(all(k != "keypoint" for k, _ in names) for names in _suggested(tmp_path / "plain"))


def test_validate_names_keypoints_to_click_next(keypoint_file, tmp_path):
    report = validate_file(keypoint_file, BatchSettings(next_clicks=3, keypoints=_mapping()))
    for check in report.vehicles:
        names = [s["name"] for s in check.result.next_clicks]
        assert len(names) == 3 and set(names) <= set(TWELVE) | set(MORE)
    mapping_file = tmp_path / "mapping.json"
    mapping_file.write_text(_mapping().model_dump_json())
    result = CliRunner().invoke(main, ["validate", str(keypoint_file), "--mapping", str(mapping_file), "--all", "-q"])
    assert result.exit_code in (0, 1), result.output
    assert "click next:" in result.output
    listed = [line.split(". ", 1)[1].split(" near ")[0] for line in result.output.splitlines()
              if line.startswith("    ") and " near (" in line]
    assert listed and set(listed) <= set(TWELVE) | set(MORE)
    # Keypoints carry their learned spread, not the cuboid parts' part sigma: the summary says so.
    assert "px on top of each keypoint's learned spread)" in result.output and "cuboid model" not in result.output
    # With learned clicked shares, each suggestion says how often people click it (the ranking weighs it).
    shared = _mapping().model_dump(mode="json", exclude_none=True)
    for part in shared["parts"]:
        part["position"]["clicked_share"] = 0.5
    mapping_file.write_text(json.dumps(shared))
    result = CliRunner().invoke(main, ["validate", str(keypoint_file), "--mapping", str(mapping_file), "--all", "-q"])
    assert "click next (ranked by each one's shrink of the sigmas times how often people click it):" in result.output
    listed = [line for line in result.output.splitlines() if line.startswith("    ") and " near (" in line]
    assert listed and all(line.endswith("; people click it on 50 % of the cars that show it") for line in listed)
    bad = CliRunner().invoke(main, ["validate", str(keypoint_file), "--mapping", "apollocar3d-66-paper"])
    assert bad.exit_code == 2 and "has no keypoint parts" in bad.output


def test_validate_tells_a_car_clicked_on_its_rear_to_click_toward_the_front(tmp_path):
    """Issue 36, item 3: cars clicked on their rear only (seen from behind and the left) are told, in validate's report
    and by their first next click (the page's first target), to click one keypoint toward the front along the left."""
    images = _pitched_batch(3, np.random.default_rng(11))
    doc = document_json(images)
    for im in doc["images"]:
        vehicle = im["vehicles"][0]
        vehicle["parts"] = [p for p in vehicle["parts"] if p["at"][0] < -0.15]  # lamps, rear glass, bumper, sill
        assert len(vehicle["parts"]) == 9
    path = tmp_path / "rear.json"
    path.write_text(json.dumps(doc))
    mapping = _mapping().model_dump(mode="json", exclude_none=True)
    mapping["parts"].append({"kind": "keypoint", "keypoint": "wheel-front-left",
                             "position": {"at": [0.3, 0.49, 0.2], "spread": [0.01, 0.01, 0.01]}})
    mapping_file = tmp_path / "mapping.json"
    mapping_file.write_text(json.dumps(mapping))
    report = validate_file(path, BatchSettings(next_clicks=3, keypoints=MappingFile.model_validate(mapping)))
    for check in report.vehicles:
        first = check.result.next_clicks[0]
        assert first["far_end"] and first["visible"] and first["inside_image"]
        assert first["name"] in {"wheel-front-left", "sill-front", "mirror", "door-bottom", "lamp-front-left"}
    result = CliRunner().invoke(main, ["validate", str(path), "--mapping", str(mapping_file), "--all", "-q"])
    assert result.exit_code in (0, 1), result.output
    told = ("  every keypoint is on its rear end, so its yaw and length rest on the size prior: click one more toward "
            "the far end, the front, along its left side (its left front wheel centre, or a corner of a front door)")
    assert result.output.count(told) == 3
    firsts = [line for line in result.output.splitlines() if line.startswith("    1. ")]
    assert len(firsts) == 3 and all(line.endswith("[toward the far end: fixes yaw and length]") for line in firsts)


def test_the_batchs_keypoint_noise_leaves_the_ranking_and_rescales_the_sigmas(keypoint_file):
    """Rule 35: the sigmas take the batch's estimate of the keypoints' noise, the guidance ranks as the fit weighs the
    clicks (the estimate changed ApolloCar3D's guided order and left its E_R a little worse). The suggestions come
    in the same order, with their sigmas scaled as the fit's own."""
    from toosicubix.annotations.priors_file import load_priors
    from toosicubix.annotations.stream import index_annotations
    from toosicubix.pipeline.fitting import stream_images
    from toosicubix.pipeline.vehicle import fit_one

    image = next(stream_images(index_annotations(keypoint_file), None))
    vehicle = image.vehicles[0]
    priors = load_priors()
    candidates = _mapping().keypoint_candidates(vehicle.prototype)
    plain = fit_one(vehicle, image.camera, priors[vehicle.prototype], SolverOptions(), next_clicks=8,
                    keypoints=candidates)
    noisy = fit_one(vehicle, image.camera, priors[vehicle.prototype], SolverOptions(soft_noise=(0.5, 0.7)),
                    next_clicks=8, keypoints=candidates)
    np.testing.assert_array_equal(noisy.R_cam_vehicle, plain.R_cam_vehicle)  # the same fit
    assert noisy.sigma.yaw_deg < plain.sigma.yaw_deg  # less noise on its rows
    assert len(plain.next_clicks) == 8
    assert [s["name"] for s in noisy.next_clicks] == [s["name"] for s in plain.next_clicks]
    ratio = noisy.sigma.yaw_deg / plain.sigma.yaw_deg
    for a, b in zip(noisy.next_clicks, plain.next_clicks, strict=True):
        assert a["yaw_sigma_deg"] == pytest.approx(ratio * b["yaw_sigma_deg"], rel=1e-9)  # rounding only

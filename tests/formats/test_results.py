"""The typed vehicle result of results.json (:class:`toosicubix.formats.results.VehicleResult`) round-trips."""

import json
import math

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.annotations.convert import load_images, with_ground
from toosicubix.errors import FormatError
from toosicubix.formats.results import (
    Alternative,
    Cues,
    SolverStats,
    VehicleResult,
    dumps,
    read_results,
    results_to_json,
)
from toosicubix.model import KITTI_GROUND
from toosicubix.pipeline.fitting import fit_images
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.uncertainty import Uncertainty

SAMPLE = REPO / "samples" / "annotations.json"


@pytest.fixture(scope="module", params=[False, True], ids=["own", "joint"])
def fitted(request):
    """The sample fitted with next clicks and the misfit test, on its own (alternatives) or with its ground plane
    (joint blocks)."""
    images = load_images(SAMPLE)
    if request.param:
        images = with_ground(images, KITTI_GROUND)
    return fit_images(images, BatchSettings(options=SolverOptions(misfit_level=0.99), joint_ground=request.param,
                                            next_clicks=2))


def test_every_vehicle_round_trips_through_json(fitted):
    vehicles = [v for im in fitted for v in im.vehicles]
    joint = any(v.cues is not None and v.cues.joint_ground for v in vehicles)
    assert len(vehicles) == 6 and all(v.ok for v in vehicles)  # every vehicle of the sample fits
    assert sum(v.residual_test is not None for v in vehicles) >= 4  # tested where its clicks are redundant
    for v in vehicles:
        text = json.dumps(v.to_json(), allow_nan=False)
        again = VehicleResult.from_json(json.loads(text))
        assert again.to_json() == json.loads(text)
        if v.ok:
            # The typed fields survive: arrays exactly (JSON keeps float64 to the last bit).
            np.testing.assert_array_equal(again.R_cam_vehicle, v.R_cam_vehicle)
            np.testing.assert_array_equal(again.residuals_px, v.residuals_px)
            assert again.sigma == v.sigma and again.cues == v.cues and again.solver == v.solver
            assert again.residual_test == v.residual_test
            assert not joint or (again.cues.joint_ground is True and again.solver.joint_iterations is not None)
            assert len(again.next_clicks) == 2
            for a, b in zip(again.alternatives, v.alternatives, strict=True):
                assert a.to_json() == b.to_json()


def test_results_file_round_trips(fitted, tmp_path):
    doc = results_to_json(fitted, {"generator": "test"})
    path = tmp_path / "results.json"
    path.write_text(dumps(doc))
    read = read_results(path)
    assert dumps(results_to_json(read, {"generator": "test"})) == path.read_text()


@pytest.mark.parametrize("key, value", [("id", "../../etc/passwd"), ("id", "/tmp/x"), ("id", "a/b"),
                                        ("id", ".hidden"), ("sequence", "../seq"), ("sequence", 3)])
def test_an_image_id_or_sequence_that_is_no_file_name_is_refused(fitted, tmp_path, key, value):
    """Image ids and sequence names name the files render writes (<id>.png, <sequence>.mp4): one that climbs out of
    the folder, or that the annotation file would refuse, is refused with its JSON path, as the annotation file's
    own rule states it."""
    doc = results_to_json(fitted, {"generator": "test"})
    doc["images"][1][key] = value
    path = tmp_path / "results.json"
    path.write_text(dumps(doc))
    with pytest.raises(FormatError, match=rf"\$\.images\[1\]\.{key}: expected an? .* \(it names a file\)"):
        read_results(path)


def test_keys_of_a_fitted_vehicle_keep_results_json_order(fitted):
    v = next(v for im in fitted for v in im.vehicles if v.ok)
    keys = list(v.to_json())
    assert keys[:9] == ["id", "status", "error", "prototype", "R_cam_vehicle", "t_cam_vehicle", "dimensions",
                        "box2d", "kitti_type"]
    assert keys.index("cues") < keys.index("sigma") < keys.index("solver") < keys.index("next_clicks")


def test_a_failed_vehicle_writes_only_what_it_has():
    v = VehicleResult(id="1", status="failed", error="too few constraints", prototype="Car", kitti_type="Car")
    assert v.to_json() == {"id": "1", "status": "failed", "error": "too few constraints", "prototype": "Car",
                           "R_cam_vehicle": None, "t_cam_vehicle": None, "dimensions": None, "box2d": None,
                           "kitti_type": "Car"}
    assert VehicleResult.from_json(v.to_json()) == v


def test_unknown_keys_are_kept_and_written_last():
    v = VehicleResult(id="1", status="failed", error=None, prototype="Car", kitti_type="Car",
                      cues=Cues(True, False, False, ("known dx",)), solver=SolverStats(3, True, 1, 0, None))
    doc = {**v.to_json(), "from_a_later_version": {"x": 1}}
    again = VehicleResult.from_json(doc)
    assert again.extra == {"from_a_later_version": {"x": 1}}
    assert list(again.to_json())[-1] == "from_a_later_version"
    assert again.cues.known_sizes == ("known dx",) and again.solver.starts == 3


def test_sigma_keeps_null_for_infinite():
    inf = math.inf
    s = Uncertainty(inf, 1.0, 2.0, 0.5, 0.02, (0.1, inf, 0.05), (0.2, 0.5), inf)
    written = json.loads(json.dumps(s.to_json(), allow_nan=False))
    assert written["yaw_deg"] is None and written["dimensions"] == [0.1, None, 0.05]
    assert Uncertainty.from_json(written) == s


def test_a_fitted_vehicle_with_alternatives_round_trips():
    a = Alternative(3.5, 178.0, True, "tilted 60 degrees from upright", True, np.eye(3), np.array([1.0, 2.0, 20.0]),
                    np.array([4.0, 1.7, 1.5]))
    v = VehicleResult(id="2", status="ok", error=None, prototype="Van", R_cam_vehicle=np.eye(3),
                      t_cam_vehicle=np.array([1.0, 1.6, 20.0]), dimensions=np.array([4.5, 1.8, 1.9]),
                      box2d=np.array([1.0, 2.0, 30.0, 40.0]), kitti_type="Van", constraints=9, clicks=8,
                      aux_unknowns=7, cues=Cues(True, True, True, ()), residuals_px=np.zeros((2, 2)),
                      click_labels=("wheel-front-left", "wheel-rear-left"), cost=1.25, ambiguous=False,
                      alternatives=(a,), warnings=("no plausible answer",))
    again = VehicleResult.from_json(json.loads(json.dumps(v.to_json())))
    assert again.alternatives[0].to_json() == a.to_json()
    assert again.alternatives[0].implausible == "tilted 60 degrees from upright"
    assert again.to_json() == v.to_json()
    assert again.click_labels == v.click_labels and again.warnings == v.warnings


def test_a_malformed_vehicle_names_its_json_path(tmp_path):
    doc = {"id": "1", "status": "ok", "error": None, "prototype": "Car", "R_cam_vehicle": np.eye(3).tolist(),
           "t_cam_vehicle": [0, 0, 10], "dimensions": [4, 2, 1.5], "box2d": None, "sigma": {"yaw_deg": 1.0}}
    with pytest.raises(FormatError, match=r"\$\.images\[0\]\.vehicles\[3\]"):
        VehicleResult.from_json(doc, tmp_path / "results.json", "$.images[0].vehicles[3]")


def test_click_weights_and_downweighted_are_written_only_when_set_and_round_trip():
    plain = VehicleResult(id="1", status="failed", error="x", prototype="Car")
    assert "click_weights" not in plain.to_json() and "downweighted" not in plain.to_json()
    weighted = VehicleResult(id="1", status="ok", error=None, prototype="Car", R_cam_vehicle=np.eye(3),
                             t_cam_vehicle=np.array([0.0, 1.0, 10.0]), dimensions=np.array([4.0, 1.8, 1.5]),
                             click_labels=("a", "b"), click_weights=np.array([1.0, 0.25]), downweighted=("b",))
    doc = json.loads(json.dumps(weighted.to_json()))
    assert doc["click_weights"] == [1.0, 0.25] and doc["downweighted"] == ["b"]
    back = VehicleResult.from_json(doc)
    np.testing.assert_array_equal(back.click_weights, [1.0, 0.25])
    assert back.downweighted == ("b",) and back.extra == {}

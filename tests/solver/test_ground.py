"""Scale and ground cues: known sizes, camera height, the upright prior, the joint image fit.

Tolerances: noise-free clicks with a cue of tiny sigma (1 mm, 0.01 degrees) and a broad size prior: the
cue fixes the scale to within the prior's remaining pull, which the broad prior (5 m per axis) keeps
below 1e-4 of the scale.
"""

import copy
import json

import numpy as np
import pytest
from click.testing import CliRunner

from tests.annotations.test_schemas import DESIGN_EXAMPLE
from tests.conftest import REPO
from tests.scenes import CAMERA
from toosicubix.annotations.priors_file import load_priors
from toosicubix.annotations.schema import parse_annotations
from toosicubix.cli import main
from toosicubix.errors import InputFileError
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle, ypr_from_R_cam_vehicle
from toosicubix.model import GroundPlane, Part
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.synthesis import PartSpec, render_parts, true_parameters
from toosicubix.size_priors import SizePrior
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.joint import JointVehicle, fit_jointly
from toosicubix.solver.problem import Problem
from toosicubix.solver.refine import residuals_and_jacobian

CAR = load_priors()["Car"]
D = np.array([4.3, 1.78, 1.46])
WHEELS = (1.35, -1.25)
LEVEL = np.array([0.0, -1.0, 0.0])
EXACT_CLICKS = SolverOptions(lambda_px=1e-4)


def broad_prior(mean=(5.0, 2.2, 1.9)) -> SizePrior:
    """A prior far off the truth and very broad: it leaves the scale to the cues."""
    return SizePrior.from_mean_cov("broad", np.array(mean), np.diag([25.0, 25.0, 25.0]))


def upright_vehicle(ry_deg: float, t: tuple[float, float, float], specs: list[PartSpec]):
    R = R_cam_vehicle_from_ypr(np.deg2rad(ry_deg))
    parts = render_parts(specs, R, np.array(t), D, CAMERA, WHEELS)
    return R, np.array(t), parts


OBLIQUE_REAR = [
    PartSpec("point", "wheel-rear-right"), PartSpec("point", "wheel-front-right"), PartSpec("point", "wheel-rear-left"),
    PartSpec("symmetry", "rear", {"Y": 0.65, "Z": 0.85}), PartSpec("point", "edge-rear-right", {"Z": 0.9}),
    PartSpec("point", "edge-front-right", {"Z": 0.8}), PartSpec("symmetry", "roof", {"X": -0.3, "Y": 0.6}),
]


def test_scale_from_a_known_plate_width_with_exact_clicks():
    plate = PartSpec("length", "plate-rear", {"Y": 0.26, "Z": 0.5}, known=(0.52, 0.001))
    _, t, parts = upright_vehicle(-60.0, (2.5, 1.6, 18.0), [*OBLIQUE_REAR, plate])
    model = build_parts_model(parts)
    assert [m.label for m in model.measurements] == ["length plate-rear"]
    fit = fit_vehicle(model, CAMERA, broad_prior(), EXACT_CLICKS)
    assert fit.ok, fit.reason
    np.testing.assert_allclose(fit.t_cam_vehicle, t, rtol=1e-4)
    np.testing.assert_allclose(fit.dimensions, D, rtol=1e-4)
    assert fit.scale_from == "length plate-rear" and fit.scale_shares["length plate-rear"] > 0.99


@pytest.mark.parametrize(("feature", "aux", "metres"), [
    ("wheelbase-right", {}, WHEELS[0] - WHEELS[1]),
    ("tyre-rear-right", {"Zt": 0.64}, 0.64),
])
def test_scale_from_a_wheelbase_or_a_tyre_diameter(feature, aux, metres):
    spec = PartSpec("length", feature, aux, known=(metres, 0.001))
    _, t, parts = upright_vehicle(-60.0, (2.5, 1.6, 18.0), [*OBLIQUE_REAR, spec])
    fit = fit_vehicle(build_parts_model(parts), CAMERA, broad_prior(), EXACT_CLICKS)
    assert fit.ok, fit.reason
    np.testing.assert_allclose(fit.t_cam_vehicle, t, rtol=1e-4)
    assert fit.scale_from == f"length {feature}"


def test_scale_from_known_dimensions():
    _, _, parts = upright_vehicle(-60.0, (2.5, 1.6, 18.0), OBLIQUE_REAR)
    model = build_parts_model(parts, {"dz": (D[2], 0.001)})
    fit = fit_vehicle(model, CAMERA, broad_prior(), EXACT_CLICKS)
    assert fit.ok
    np.testing.assert_allclose(fit.dimensions, D, rtol=1e-4)
    assert fit.scale_from == "known dz"


def test_a_known_length_fills_an_unseen_dimension():
    rear = [PartSpec("point", "wheel-rear-left"), PartSpec("point", "wheel-rear-right"),
            PartSpec("symmetry", "rear", {"Y": 0.65, "Z": 0.85}), PartSpec("point", "rear-center", {"Z": 0.5}),
            PartSpec("point", "top-center", {"X": -0.2}),
            PartSpec("direction", "backward", {"X": 0.5, "Y": -1.4, "Z": 0.0})]
    _, _, parts = upright_vehicle(-88.0, (0.8, 1.6, 14.0), rear)
    fit = fit_vehicle(build_parts_model(parts, {"dx": (D[0], 0.001)}), CAMERA, CAR, EXACT_CLICKS)
    assert fit.ok
    assert fit.dimensions[0] == pytest.approx(D[0], abs=2e-3)  # a rear view never shows the length


def test_scale_from_the_camera_height_alone():
    # The vehicle's bottom lies on the road 1.65 m under the camera (camera y points down).
    _, t, parts = upright_vehicle(-60.0, (2.5, 1.65, 18.0), OBLIQUE_REAR)
    ground = GroundPlane(normal=LEVEL, normal_sigma=np.deg2rad(0.01), camera_height=1.65,
                         camera_height_sigma=0.001, upright_sigma=np.deg2rad(2.0))
    fit = fit_vehicle(build_parts_model(parts), CAMERA, broad_prior(), EXACT_CLICKS, ground)
    assert fit.ok
    np.testing.assert_allclose(fit.t_cam_vehicle, t, rtol=1e-4)
    np.testing.assert_allclose(fit.dimensions, D, rtol=1e-4)
    assert fit.scale_from == "ground contact"
    without = fit_vehicle(build_parts_model(parts), CAMERA, broad_prior(), EXACT_CLICKS)
    assert abs(np.linalg.norm(without.t_cam_vehicle) / np.linalg.norm(t) - 1.0) > 0.05  # the broad prior's guess


def test_a_tilted_road_is_used_as_given():
    pitch = np.deg2rad(4.0)
    normal = np.array([0.0, -np.cos(pitch), np.sin(pitch)])  # the camera looks 4 degrees up at the road
    R_level = R_cam_vehicle_from_ypr(np.deg2rad(-60.0))
    from toosicubix.geometry import rotation_between

    R = rotation_between(LEVEL, normal) @ R_level
    t = np.array([2.5, 0.0, 18.0])
    t[1] = (-1.65 - normal[0] * t[0] - normal[2] * t[2]) / normal[1]  # bottom centre on the road
    parts = render_parts(OBLIQUE_REAR, R, t, D, CAMERA, WHEELS)
    ground = GroundPlane(normal=normal, normal_sigma=np.deg2rad(0.01), camera_height=1.65,
                         camera_height_sigma=0.001, upright_sigma=np.deg2rad(0.5))
    fit = fit_vehicle(build_parts_model(parts), CAMERA, broad_prior(), EXACT_CLICKS, ground)
    assert fit.ok
    np.testing.assert_allclose(fit.t_cam_vehicle, t, rtol=1e-4)
    assert np.rad2deg(geodesic_angle(fit.R_cam_vehicle, R)) < 0.01


def test_the_upright_prior_bends_a_noisy_fit_back_to_zero_pitch():
    """2 px click noise on an upright vehicle: alone, the fit leans by a degree or more; with the road
    normal known and vehicles upright within 0.5 degrees, it leans by far less."""
    rng = np.random.default_rng(3)
    tilts_free, tilts_upright = [], []
    ground = GroundPlane(normal=LEVEL, normal_sigma=np.deg2rad(0.1), camera_height=None, camera_height_sigma=0.1,
                         upright_sigma=np.deg2rad(0.5))
    for _ in range(12):
        _, _, parts = upright_vehicle(rng.uniform(-80, -40), (rng.uniform(-3, 3), 1.6, rng.uniform(10, 30)),
                                      OBLIQUE_REAR)
        noisy = [Part(p.kind, p.name, p.uv + rng.normal(0, 2.0, p.uv.shape), p.json_path) for p in parts]
        model = build_parts_model(noisy)
        for g, tilts in ((None, tilts_free), (ground, tilts_upright)):
            fit = fit_vehicle(model, CAMERA, CAR, SolverOptions(), g)
            _, pitch, roll = ypr_from_R_cam_vehicle(fit.R_cam_vehicle)
            tilts.append(np.rad2deg(np.hypot(pitch, roll)))
    assert np.median(tilts_free) > 1.0
    assert np.median(tilts_upright) < 0.5 * np.median(tilts_free) and np.max(tilts_upright) < 1.0


def _numeric_jacobian(problem, R, t, p, pivot, profile):
    from toosicubix.geometry import so3_exp

    _, J = residuals_and_jacobian(problem, R, t, p, pivot=pivot, profile_scale=profile)
    h = 1e-6
    numeric = np.zeros_like(J)
    for k in range(J.shape[1]):
        step = np.zeros(J.shape[1])
        step[k] = h

        def moved(sign, step=step):
            R2 = R @ so3_exp(sign * step[:3])
            t2 = t + sign * step[3:6] + (R - R2) @ pivot
            return residuals_and_jacobian(problem, R2, t2, p + sign * step[6:], False, profile_scale=profile)[0]

        numeric[:, k] = (moved(1) - moved(-1)) / (2 * h)
    return J, numeric


@pytest.mark.parametrize("profile", [False, True])
def test_cue_rows_have_the_right_jacobian(rng, profile):
    plate = PartSpec("length", "plate-rear", {"Y": 0.26, "Z": 0.5}, known=(0.52, 0.01))
    R, t, parts = upright_vehicle(-60.0, (2.5, 1.6, 18.0), [*OBLIQUE_REAR, plate])
    model = build_parts_model(parts, {"dz": (1.5, 0.05)})
    ground = GroundPlane(normal=np.array([0.02, -0.999, 0.03]) / np.linalg.norm([0.02, -0.999, 0.03]),
                         normal_sigma=0.02, camera_height=1.7, camera_height_sigma=0.1, upright_sigma=0.03)
    problem = Problem.build(model, CAMERA, CAR, 0.5, 3.0, ground, 18.0)
    _, p_true = true_parameters([*OBLIQUE_REAR, plate], D, WHEELS)
    R = R @ R_cam_vehicle_from_ypr(0.05, 0.02, -0.03) @ R_cam_vehicle_from_ypr(0.0).T  # off the truth
    pivot = model.A.mean(axis=0) @ p_true
    J, numeric = _numeric_jacobian(problem, R, t * 1.03, p_true * 0.98, pivot, profile)
    # Central differences err by O(h^2) ~ 1e-9 relative to entries up to ~1e3 px per unit.
    np.testing.assert_allclose(J, numeric, rtol=1e-6, atol=1e-5)


def test_joint_fit_recovers_an_unknown_camera_height():
    """Five vehicles on one road, the camera 1.55 m above it, clicks exact, size priors centred on each
    vehicle's size: the joint fit finds the height (and each vehicle) exactly."""
    rng = np.random.default_rng(1)
    h = 1.55
    ground_unknown = GroundPlane(normal=LEVEL, normal_sigma=np.deg2rad(1.0), camera_height=None,
                                 camera_height_sigma=0.1, upright_sigma=np.deg2rad(2.0))
    vehicles, truths = [], []  # truths: true bottom centres
    for k in range(5):
        d = D * rng.uniform(0.9, 1.1, 3)
        R = R_cam_vehicle_from_ypr(np.deg2rad(rng.uniform(-120, -30)))
        t = np.array([rng.uniform(-6, 6), h, rng.uniform(10, 35)])
        parts = render_parts(OBLIQUE_REAR, R, t, d, CAMERA, (0.3 * d[0], -0.3 * d[0]))
        prior = SizePrior.from_mean_cov(f"car{k}", d, CAR.cov)
        model = build_parts_model(parts)
        own = fit_vehicle(model, CAMERA, prior, EXACT_CLICKS, ground_unknown)
        assert own.ok
        problem = Problem.build(model, CAMERA, prior, 0.1, 1e-4)
        vehicles.append(JointVehicle(problem, own.R_cam_vehicle, own.t_cam_vehicle * 1.05, own.p * 1.05))
        truths.append(t)
    result = fit_jointly(vehicles, ground_unknown)
    assert result.camera_height == pytest.approx(h, abs=1e-3)
    for t, t_fit in zip(truths, result.t, strict=True):
        np.testing.assert_allclose(t_fit, t, atol=2e-3)


@pytest.mark.parametrize(("mutate", "path", "fragment"), [
    (lambda d: d["images"][0].update(ground={"camera_height": -1.2}),
     "$.images[0].ground.camera_height", "greater than 0"),
    (lambda d: d["images"][0].update(ground={"normal": [0, 0, 0]}),
     "$.images[0].ground.normal", "non-zero road normal"),
    (lambda d: d["images"][0].update(ground={"normal": [0, -1, 0], "camera_pitch_deg": 2}),
     "$.images[0].ground", "not both"),
    (lambda d: d["images"][0].update(ground={"camera_height_sigma": 0}),
     "$.images[0].ground.camera_height_sigma", "greater than 0"),
    (lambda d: d["images"][0]["vehicles"][0].update(known_dimensions={"dx": {"metres": -4, "sigma": 0.1}}),
     "$.images[0].vehicles[0].known_dimensions.dx.metres", "greater than 0"),
    (lambda d: d["images"][0]["vehicles"][0].update(known_dimensions={"length": {"metres": 4, "sigma": 0.1}}),
     "$.images[0].vehicles[0].known_dimensions.length", "bad key"),
    (lambda d: d["images"][0]["vehicles"][0]["parts"].append(
        {"kind": "length", "feature": "plate", "a": [1, 2], "b": [3, 4], "metres": 0.5, "sigma": 0.01}),
     "$.images[0].vehicles[0].parts[3].feature", "'plate-rear'"),
])
def test_bad_cue_values_are_rejected_with_the_json_path(mutate, path, fragment):
    doc = copy.deepcopy(DESIGN_EXAMPLE)
    mutate(doc)
    with pytest.raises(InputFileError) as info:
        parse_annotations(doc, "cues.json")
    assert any(p == path and fragment in m for p, m in info.value.problems), info.value.problems


def test_cli_records_the_cues_and_says_where_the_scale_came_from(tmp_path):
    doc = json.loads((REPO / "samples" / "annotations.json").read_text())
    doc["images"][0]["vehicles"][0]["known_dimensions"] = {"dz": {"metres": 1.46, "sigma": 0.01}}
    path = tmp_path / "ann.json"
    path.write_text(json.dumps(doc))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["fit", str(path), "-o", str(out), "--kitti-ground", "--camera-height", "1.6"])
    assert result.exit_code == 0, result.output
    assert "scale set by:" in result.output
    results = json.loads((out / "results.json").read_text())
    first = results["images"][0]["vehicles"][0]
    assert first["cues"] == {"size_prior": True, "upright": True, "ground_contact": True, "known_sizes": ["known dz"]}
    assert first["scale_from"] in first["scale_shares"]
    assert abs(sum(first["scale_shares"].values()) - 1.0) < 1e-9
    assert results["images"][0]["ground"]["camera_height"] == 1.6
    assert results["settings"]["ground"]["camera_height"] == 1.6


def test_cli_joint_ground_estimates_the_height(tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["fit", str(REPO / "samples" / "annotations.json"), "-o", str(out), "-q",
                                       "--road-normal", "0,-1,0", "--joint-ground"])
    assert result.exit_code == 0, result.output
    images = json.loads((out / "results.json").read_text())["images"]
    assert all(im["ground"]["estimated"] for im in images)
    assert all(v["cues"]["joint_ground"] for im in images for v in im["vehicles"] if v["status"] == "ok")


def test_cli_rejects_bad_ground_options(tmp_path):
    runner = CliRunner()
    sample = str(REPO / "samples" / "annotations.json")
    result = runner.invoke(main, ["fit", sample, "-o", str(tmp_path / "a"), "--road-normal", "0,-1"])
    assert result.exit_code == 2 and "expected three numbers" in result.output
    result = runner.invoke(main, ["fit", sample, "-o", str(tmp_path / "b"), "--road-normal", "0,0,0"])
    assert result.exit_code == 2 and "non-zero road normal" in result.output
    result = runner.invoke(main, ["fit", sample, "-o", str(tmp_path / "c"), "--camera-height", "-1"])
    assert result.exit_code == 2

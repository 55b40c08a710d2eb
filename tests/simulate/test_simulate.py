import json

import numpy as np
import pytest
from click.testing import CliRunner

from toosicubix.annotations.priors_file import load_priors
from toosicubix.annotations.schema import parse_annotations
from toosicubix.camera import Camera
from toosicubix.cli import main
from toosicubix.formats.kitti import format_label_line, object_from_pose, read_label_file
from toosicubix.geometry import R_cam_vehicle_from_ypr, geodesic_angle
from toosicubix.parts.linear import build_parts_model
from toosicubix.simulate.annotator import (
    AnnotatorOptions,
    GroundTruthVehicle,
    SelectionOptions,
    annotation_document,
    select_kitti_object,
    select_kitti_tracking,
    simulate_vehicle,
    tracking_image_id,
)
from toosicubix.solver.fit import SolverOptions, fit_vehicle
from toosicubix.solver.observability import determines_8dof
from toosicubix.solver.plausibility import unseen_clicks
from toosicubix.solver.problem import Problem

P2 = np.array([[720.0, 0.0, 620.0, 43.2], [0.0, 720.0, 180.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
CAMERA = Camera.from_P(P2, image_size=(1242, 375))


def gt_vehicle(ry_deg: float, location_cam: tuple[float, float, float], kind: str = "Car",
               dims=(4.2, 1.75, 1.5), occluded: int = 0, vehicle_id: str = "0") -> GroundTruthVehicle:
    R = R_cam_vehicle_from_ypr(np.deg2rad(ry_deg))
    obj = object_from_pose(kind, R, np.array(location_cam), np.array(dims), CAMERA, np.array([100, 100, 200, 160.0]),
                           occluded=occluded, score=None)
    return GroundTruthVehicle("000001", vehicle_id, obj, CAMERA)


VIEWS = [(-90.0, (0.5, 1.65, 15.0)), (90.0, (-1.0, 1.65, 20.0)), (0.0, (1.0, 1.65, 12.0)),
         (-45.0, (3.0, 1.65, 18.0)), (135.0, (-4.0, 1.65, 25.0)), (-150.0, (-2.0, 1.65, 9.0))]


@pytest.mark.parametrize(("ry", "loc"), VIEWS)
def test_clicks_only_on_faces_the_camera_sees(ry, loc):
    for exact in (True, False):
        sv = simulate_vehicle(gt_vehicle(ry, loc), AnnotatorOptions(noise_px=0.0, exact_placement=exact))
        labels = tuple(label for part in sv.parts for label in part.click_labels)
        assert labels, "a vehicle in plain view gets clicks"
        assert unseen_clicks(labels, sv.R_cam_vehicle, sv.t_cam_vehicle, sv.dimensions) == []
        assert sv.n_clicks <= 12


@pytest.mark.parametrize(("ry", "loc"), VIEWS)
def test_exact_placement_without_noise_reproduces_the_model(ry, loc):
    sv = simulate_vehicle(gt_vehicle(ry, loc), AnnotatorOptions(noise_px=0.0, exact_placement=True))
    model = build_parts_model(sv.parts)
    points_cam = model.points_vehicle(sv.p_true) @ sv.R_cam_vehicle.T + sv.t_cam_vehicle
    np.testing.assert_allclose(CAMERA.project(points_cam), model.uv, atol=1e-9)


def test_realistic_placement_moves_parts_off_the_model():
    gt = gt_vehicle(-45.0, (3.0, 1.65, 18.0))
    exact = simulate_vehicle(gt, AnnotatorOptions(noise_px=0.0, exact_placement=True))
    real = simulate_vehicle(gt, AnnotatorOptions(noise_px=0.0, exact_placement=False))
    model = build_parts_model(real.parts)
    projected = CAMERA.project(model.points_vehicle(real.p_true) @ real.R_cam_vehicle.T + real.t_cam_vehicle)
    offsets = np.linalg.norm(projected - model.uv, axis=1)
    # Tyres 0-5 cm inside, lights 3-20 cm behind the faces: a few pixels at 18 m (40 px per metre).
    assert offsets.max() > 0.5
    assert [p.name for p in exact.parts] == [p.name for p in real.parts]


def test_wheel_axles_and_tyres_sit_as_on_real_cars():
    sv = simulate_vehicle(gt_vehicle(-45.0, (3.0, 1.65, 18.0)), AnnotatorOptions(noise_px=0.0))
    front, rear = sv.wheel_x
    length = sv.dimensions[0]
    assert 0.26 * length <= front <= 0.33 * length  # front overhang 17-24 % of the length
    assert -0.32 * length <= rear <= -0.24 * length


def test_tyres_sit_inside_the_body_as_measured_on_real_cars():
    """Each wheel click, noise-free, back-projected onto the road (vehicle Z = 0): its outer tyre face is
    uniformly 0 to TYRE_INSET_MAX inside the cuboid's side, one inset per vehicle."""
    from toosicubix.simulate.annotator import TYRE_INSET_MAX

    insets = []
    for k in range(200):
        sv = simulate_vehicle(gt_vehicle(-45.0, (3.0, 1.65, 12.0), vehicle_id=str(k)), AnnotatorOptions(noise_px=0.0))
        R, t = sv.R_cam_vehicle, sv.t_cam_vehicle
        origin = R.T @ -t  # the camera centre, vehicle frame
        per_vehicle = set()
        for part in sv.parts:
            if part.name.startswith("wheel-"):
                ray = R.T @ np.linalg.solve(CAMERA.K, np.append(part.uv[0], 1.0))
                point = origin - origin[2] / ray[2] * ray
                per_vehicle.add(round(sv.dimensions[1] / 2 - abs(point[1]), 9))
        assert len(per_vehicle) == 1
        insets.append(per_vehicle.pop())
    insets = np.array(insets)
    assert insets.min() >= 0.0 and insets.max() <= TYRE_INSET_MAX
    # Uniform: of 200 draws, some in the first and last tenth of the range (each missed with p = 0.9^200).
    assert insets.min() < 0.005 and insets.max() > 0.045


@pytest.mark.parametrize(("ry", "loc"), VIEWS)
def test_parts_left_out_by_the_click_budget_are_kept_as_spares(ry, loc):
    """With a budget of 4 clicks the person clicks the first parts and keeps the rest as spares: together
    they are what the person clicks with a budget of 30; spares are visible and inside the image, and the
    clicks do not depend on them."""
    gt = gt_vehicle(ry, loc)
    small = simulate_vehicle(gt, AnnotatorOptions(noise_px=1.0, exact_placement=True, max_clicks=4))
    large = simulate_vehicle(gt, AnnotatorOptions(noise_px=1.0, exact_placement=True, max_clicks=30))
    assert small.n_clicks <= 4 and not large.spare
    names = [(p.kind, p.name) for p in small.parts + small.spare]
    assert sorted(names) == sorted((p.kind, p.name) for p in large.parts)
    labels = tuple(label for part in small.spare for label in part.click_labels)
    assert unseen_clicks(labels, small.R_cam_vehicle, small.t_cam_vehicle, small.dimensions) == []
    for part in small.spare:
        assert np.all((part.uv > 0) & (part.uv < np.array([1242, 375])))
    np.testing.assert_array_equal(small.parts[0].uv, large.parts[0].uv)


def test_noise_has_the_requested_spread():
    gt = gt_vehicle(-45.0, (3.0, 1.65, 18.0))
    clean = simulate_vehicle(gt, AnnotatorOptions(noise_px=0.0, exact_placement=True))
    deltas = []
    for seed in range(200):
        noisy = simulate_vehicle(gt, AnnotatorOptions(noise_px=2.0, exact_placement=True, seed=seed))
        clean_seeded = simulate_vehicle(gt, AnnotatorOptions(noise_px=0.0, exact_placement=True, seed=seed))
        if [p.name for p in noisy.parts] == [p.name for p in clean_seeded.parts]:
            deltas.append(np.concatenate([a.uv - b.uv for a, b in zip(noisy.parts, clean_seeded.parts, strict=True)]))
    d = np.concatenate(deltas).ravel()
    assert len(d) > 2000 and clean.n_clicks > 0
    # Sample standard deviation of n > 2000 Gaussian values: within 4 standard errors (2/sqrt(2n)) of 2.
    assert abs(d.std() - 2.0) < 4 * 2.0 / np.sqrt(2 * len(d))
    assert abs(d.mean()) < 4 * 2.0 / np.sqrt(len(d))


def test_clicks_do_not_depend_on_the_other_vehicles():
    a = gt_vehicle(-45.0, (3.0, 1.65, 18.0), vehicle_id="7")
    alone = simulate_vehicle(a, AnnotatorOptions(seed=3))
    again = simulate_vehicle(a, AnnotatorOptions(seed=3))
    for p, q in zip(alone.parts, again.parts, strict=True):
        np.testing.assert_array_equal(p.uv, q.uv)
    other_seed = simulate_vehicle(a, AnnotatorOptions(seed=4))
    assert not np.allclose(np.concatenate([p.uv for p in alone.parts]),
                           np.concatenate([p.uv for p in other_seed.parts])[: alone.n_clicks])


def test_straight_views_get_a_ground_arrow():
    rear = simulate_vehicle(gt_vehicle(-90.0, (0.0, 1.65, 15.0)), AnnotatorOptions(noise_px=0.0))
    assert any(p.kind == "direction" and p.name in ("forward", "backward") for p in rear.parts)
    side = simulate_vehicle(gt_vehicle(0.0, (0.0, 1.65, 12.0)), AnnotatorOptions(noise_px=0.0))
    assert any(p.kind == "direction" and p.name in ("leftward", "rightward") for p in side.parts)
    oblique = simulate_vehicle(gt_vehicle(-45.0, (3.0, 1.65, 18.0)), AnnotatorOptions(noise_px=0.0))
    assert not any(p.kind == "direction" for p in oblique.parts)


def test_occlusion_loses_parts():
    kept = []
    for seed in range(40):
        visible = simulate_vehicle(gt_vehicle(-45.0, (3.0, 1.65, 18.0)), AnnotatorOptions(seed=seed))
        occluded = simulate_vehicle(gt_vehicle(-45.0, (3.0, 1.65, 18.0), occluded=1), AnnotatorOptions(seed=seed))
        kept.append(len(occluded.parts) / len(visible.parts))
        assert any("lost to occlusion" in n for n in occluded.notes) or len(occluded.parts) == len(visible.parts)
    # Each annotation survives with probability 0.7 (fewer are then pushed out by the click cap).
    assert 0.55 < np.mean(kept) < 0.9


def test_boxy_vehicles_get_top_corners_cars_do_not():
    truck = simulate_vehicle(gt_vehicle(-60.0, (2.0, 1.65, 25.0), kind="Truck", dims=(9.0, 2.5, 3.4)),
                             AnnotatorOptions(noise_px=0.0, max_clicks=30))
    assert any(p.name.startswith("corner-top-") for p in truck.parts)
    car = simulate_vehicle(gt_vehicle(-60.0, (2.0, 1.65, 25.0)), AnnotatorOptions(noise_px=0.0, max_clicks=30))
    assert not any(p.name.startswith("corner-") for p in car.parts)


@pytest.mark.parametrize(("ry", "loc"), VIEWS)
def test_exact_noise_free_simulation_is_fitted_exactly_when_determined(ry, loc):
    sv = simulate_vehicle(gt_vehicle(ry, loc), AnnotatorOptions(noise_px=0.0, exact_placement=True, max_clicks=30))
    model = build_parts_model(sv.parts)
    prior = load_priors()["Car"]
    problem = Problem.build(model, CAMERA, prior, 1.0, 1e-9)
    fit = fit_vehicle(model, CAMERA, prior, SolverOptions(lambda_px=1e-9))
    assert fit.ok, fit.reason
    angle = np.rad2deg(geodesic_angle(fit.R_cam_vehicle, sv.R_cam_vehicle))
    if determines_8dof(problem, sv.R_cam_vehicle, sv.t_cam_vehicle, sv.p_true):
        assert angle < 0.01


def write_kitti_folder(root, vehicles):
    (root / "label_2").mkdir(parents=True)
    (root / "calib").mkdir()
    numbers = " ".join(f"{v:.6e}" for v in P2.ravel())
    lines = [format_label_line(g.label) for g in vehicles]
    (root / "label_2" / "000001.txt").write_text("".join(f"{ln}\n" for ln in lines))
    (root / "calib" / "000001.txt").write_text("".join(f"P{i}: {numbers}\n" for i in range(4))
                                                + "R0_rect: 1 0 0 0 1 0 0 0 1\n")


def test_selection_filters(tmp_path):
    vehicles = [gt_vehicle(-45.0, (3.0, 1.65, 18.0)), gt_vehicle(-45.0, (3.0, 1.65, 2.0)),  # too close
                gt_vehicle(-45.0, (3.0, 1.65, 18.0), occluded=2), gt_vehicle(-45.0, (3.0, 1.65, 18.0), kind="Tram")]
    write_kitti_folder(tmp_path / "kitti", vehicles)
    chosen = select_kitti_object(tmp_path / "kitti")
    assert [g.vehicle_id for g in chosen] == ["0"]
    assert chosen[0].camera.image_size == (1242, 375)
    more = select_kitti_object(tmp_path / "kitti", SelectionOptions(max_occlusion=2, classes=("Car", "Tram")))
    assert [g.vehicle_id for g in more] == ["0", "2", "3"]


def test_annotation_document_is_a_valid_v1_file():
    svs = [simulate_vehicle(gt_vehicle(ry, loc, vehicle_id=str(i)), AnnotatorOptions())
           for i, (ry, loc) in enumerate(VIEWS)]
    doc = parse_annotations(annotation_document(svs))
    assert len(doc.images) == 1 and len(doc.images[0].vehicles) == len(VIEWS)
    np.testing.assert_allclose(np.array(doc.images[0].camera.P), P2, atol=1e-12)


def test_cli_writes_annotations_and_ground_truth_that_fit_and_eval_read(tmp_path):
    vehicles = [gt_vehicle(ry, loc, vehicle_id=str(i)) for i, (ry, loc) in enumerate(VIEWS)]
    write_kitti_folder(tmp_path / "kitti", vehicles)
    runner = CliRunner()
    ann = tmp_path / "sim.json"
    result = runner.invoke(main, ["simulate", "--kitti", str(tmp_path / "kitti"), "-o", str(ann), "--noise", "0",
                                  "--exact-placement"])
    assert result.exit_code == 0, result.output
    assert "simulated 6 vehicles in 1 images" in result.output
    assert len(read_label_file(tmp_path / "sim_gt" / "label_2" / "000001.txt")) == 6
    assert json.loads(ann.read_text())["toosicubix"] == 1
    out = tmp_path / "out"
    assert runner.invoke(main, ["fit", str(ann), "-o", str(out), "-q", "--lambda-p", "1e-9"]).exit_code == 0
    result = runner.invoke(main, ["eval", str(out), "--kitti", str(tmp_path / "sim_gt"), "--json",
                                  str(tmp_path / "eval.json")])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "eval.json").read_text())["summary"]
    assert summary["n_matched"] == 6
    assert summary["e_r_median_deg"] < 0.01


def test_cli_needs_exactly_one_ground_truth(tmp_path):
    result = CliRunner().invoke(main, ["simulate", "-o", str(tmp_path / "a.json")])
    assert result.exit_code == 2 and "exactly one of --kitti" in result.output
    result = CliRunner().invoke(main, ["simulate", "--kitti", str(tmp_path), "-o", str(tmp_path / "a.json")])
    assert result.exit_code == 2 and "expected a KITTI object folder" in result.output


def test_cli_sequence_ranges():
    from toosicubix.cli.options import parse_sequences as _parse_sequences

    assert _parse_sequences("0010-0012,0015") == ("0010", "0011", "0012", "0015")
    assert _parse_sequences(None) is None


@pytest.mark.kitti_data
def test_real_tracking_selection(shared_data):
    selection = SelectionOptions(sequences=("0010",))
    vehicles = select_kitti_tracking(shared_data / "kitti_tracking", selection)
    assert vehicles and all(g.image_id.startswith("0010_") for g in vehicles)
    tracks: dict[str, int] = {}
    for g in vehicles:
        tracks[g.vehicle_id] = tracks.get(g.vehicle_id, 0) + 1
        assert g.label.truncated == 0 and g.label.occluded <= 1 and g.label.type in ("Car", "Van", "Truck")
        assert 3.0 <= g.label.location_rect[2] + g.camera.t_cam_rect[2] <= 60.0
    assert max(tracks.values()) <= 3
    assert tracking_image_id("0010", 7) == "0010_000007"


def test_cli_can_give_every_image_kittis_ground(tmp_path):
    vehicles = [gt_vehicle(ry, loc, vehicle_id=str(i)) for i, (ry, loc) in enumerate(VIEWS)]
    write_kitti_folder(tmp_path / "kitti", vehicles)
    ann = tmp_path / "sim.json"
    result = CliRunner().invoke(main, ["simulate", "--kitti", str(tmp_path / "kitti"), "-o", str(ann),
                                       "--ground", "kitti"])
    assert result.exit_code == 0, result.output
    image = json.loads(ann.read_text())["images"][0]
    assert image["ground"]["camera_height"] == 1.65 and image["ground"]["normal"] == [0.0, -1.0, 0.0]
    assert parse_annotations(json.loads(ann.read_text())).images[0].ground is not None


def test_cli_never_writes_into_a_dataset_or_over_its_annotation_file(tmp_path):
    vehicles = [gt_vehicle(ry, loc, vehicle_id=str(i)) for i, (ry, loc) in enumerate(VIEWS)]
    write_kitti_folder(tmp_path / "kitti", vehicles)
    kitti_files = {p: p.read_bytes() for p in (tmp_path / "kitti").rglob("*") if p.is_file()}
    runner = CliRunner()

    def simulate(*args: str):
        return runner.invoke(main, ["simulate", "--kitti", str(tmp_path / "kitti"), *args])

    # issue 13: --gt-out into an existing KITTI folder overwrote its label and calib files
    result = simulate("-o", str(tmp_path / "sim.json"), "--gt-out", str(tmp_path / "kitti"))
    assert result.exit_code == 2 and "did not write" in result.output
    assert {p: p.read_bytes() for p in (tmp_path / "kitti").rglob("*") if p.is_file()} == kitti_files
    assert not (tmp_path / "sim.json").exists()
    # --gt-out equal to or containing -o
    for gt in (tmp_path / "same.json", tmp_path):
        result = simulate("-o", str(tmp_path / "same.json"), "--gt-out", str(gt))
        assert result.exit_code == 2 and "contains the annotation file" in result.output
    # Its own earlier ground truth is replaced, stale label files of that run removed.
    assert simulate("-o", str(tmp_path / "sim.json")).exit_code == 0
    (tmp_path / "sim_gt" / "label_2" / "999999.txt").write_text("")
    assert simulate("-o", str(tmp_path / "sim.json")).exit_code == 0
    assert sorted(p.name for p in (tmp_path / "sim_gt" / "label_2").iterdir()) == ["000001.txt"]

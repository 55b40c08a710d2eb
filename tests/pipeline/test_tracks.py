"""A file with tracks through ``fit`` (:mod:`toosicubix.pipeline.tracks`): every frame gets a pose, one size per
track, ``track`` and ``pose_from`` in results.json, KITTI tracking labels that read back as the object labels, and
``eval --kitti-tracking`` pairs the frames with ground truth by their sequence and frame."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tests.scenes import CAMERA, _specs
from toosicubix.annotations.convert import part_json
from toosicubix.cli import main
from toosicubix.evaluation import EvalOptions, evaluate_folder, summarize
from toosicubix.formats.kitti import read_label_file, read_tracking_file
from toosicubix.geometry import R_cam_vehicle_from_ypr, cuboid_corners_cam
from toosicubix.parts.mirror import mirrored
from toosicubix.parts.synthesis import render_parts
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.vehicle import IMPLAUSIBLE_CONFIDENCE

D = np.array([4.3, 1.8, 1.5])
FRAMES, EVERY = 21, 10


def _truth(f: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([-3.0, 1.6, 15.0]) + np.array([0.05, 0.0, 0.3]) * f
    return R_cam_vehicle_from_ypr(3 * np.pi / 4 + 0.02 * f), t


@pytest.fixture
def tracked_file(tmp_path):
    """Sequence 0003: one car clicked on frames 0, 10 and 20, boxed on two frames in three, nothing on the rest; and
    an untracked car clicked on every frame, which is fitted alone as ever."""
    rng = np.random.default_rng(0)
    specs = _specs("oblique-front-left", D, rng)
    other = _specs("oblique-rear-right", D, rng)
    wheel_x = (0.32 * D[0], -0.3 * D[0])
    images = []
    for f in range(FRAMES):
        R, t = _truth(f)
        parts = render_parts(specs, R, t, D, CAMERA, wheel_x) if f % EVERY == 0 else []
        uv = CAMERA.project(cuboid_corners_cam(R, t, D))
        tracked = {"id": "1", "prototype": "Car", "track": "0003-car", "parts": [part_json(p) for p in parts]}
        if f % 3:
            tracked["box2d"] = [float(uv[:, 0].min()), float(uv[:, 1].min()), float(uv[:, 0].max()),
                                float(uv[:, 1].max())]
        R2, t2 = R_cam_vehicle_from_ypr(-np.pi / 4), np.array([4.0, 1.6, 25.0])
        alone = {"id": "2", "prototype": "Car",
                 "parts": [part_json(p) for p in render_parts(other, R2, t2, D, CAMERA, wheel_x)]}
        images.append({"id": f"frame-{f}", "sequence": "0003", "frame": f, "size": list(CAMERA.image_size),
                       "camera": {"K": CAMERA.K.tolist()}, "vehicles": [tracked, alone]})
    path = tmp_path / "tracked.json"
    path.write_text(json.dumps({"toosicubix": 1, "images": images}))
    return path


def test_every_frame_of_a_track_gets_a_pose_and_its_track_one_size(tracked_file, tmp_path):
    summary = fit_file(tracked_file, tmp_path / "out")
    assert summary.ok == summary.vehicles == 2 * FRAMES
    assert summary.tracks == 1 and summary.pose_from == {"clicks": 3, "box": 12, "interpolated": 6}
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    tracked = [im["vehicles"][0] for im in doc["images"]]
    assert {v["track"] for v in tracked} == {"0003-car"}
    assert [v["pose_from"] for v in tracked[:4]] == ["clicks", "box", "box", "interpolated"]
    assert len({tuple(v["dimensions"]) for v in tracked}) == 1  # one size for the track
    assert all("track" not in im["vehicles"][1] and "pose_from" not in im["vehicles"][1] for im in doc["images"])
    assert doc["track_ids"] == {"0003": {"0003-car": 0}}
    assert doc["images"][5]["sequence"] == "0003" and doc["images"][5]["frame"] == 5
    # The interpolated and box-only frames are where the vehicle is: within the prior's scale error of the truth.
    for f, v in enumerate(tracked):
        _, t = _truth(f)
        assert np.linalg.norm(np.array(v["t_cam_vehicle"]) - t) < 0.1 * np.linalg.norm(t), f


def test_kitti_tracking_labels_read_back_as_the_object_labels(tracked_file, tmp_path):
    fit_file(tracked_file, tmp_path / "out")
    frames = read_tracking_file(tmp_path / "out" / "label_02" / "0003.txt")
    assert sorted(frames) == list(range(FRAMES))
    for f, objects in frames.items():
        (obj,) = objects  # the tracked car only: the other is not a track
        (label, _) = read_label_file(tmp_path / "out" / "label_2" / f"frame-{f}.txt")
        assert obj.track_id == 0
        for field in ("type", "truncated", "occluded", "alpha", "rotation_y", "score"):
            assert getattr(obj, field) == getattr(label, field), field
        for field in ("box2d", "dimensions", "location_rect"):
            np.testing.assert_array_equal(getattr(obj, field), getattr(label, field))


def test_eval_pairs_frames_with_kitti_tracking_ground_truth_by_sequence_and_frame(tracked_file, tmp_path):
    fit_file(tracked_file, tmp_path / "out")
    gt = tmp_path / "gt"
    (gt / "label_02").mkdir(parents=True)
    (gt / "calib").mkdir()
    P = np.hstack([CAMERA.K, np.zeros((3, 1))])
    (gt / "calib" / "0003.txt").write_text("\n".join(f"P{k}: " + " ".join(f"{v:.6e}" for v in P.ravel())
                                                     for k in range(4)) + "\nR0_rect: 1 0 0 0 1 0 0 0 1\n")
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    lines = []
    for f, im in enumerate(results["images"]):
        v = im["vehicles"][0]
        _, t = _truth(f)
        R, _ = _truth(f)
        ry = float(np.arctan2(-R[2, 0], R[0, 0]))
        box = " ".join(f"{x:.2f}" for x in v["box2d"])
        lines.append(f"{f} 0 Car 0 0 0 {box} {D[2]} {D[1]} {D[0]} {t[0]} {t[1]} {t[2]} {ry}")
    (gt / "label_02" / "0003.txt").write_text("\n".join(lines) + "\n")
    result = evaluate_folder(tmp_path / "out", "kitti-tracking", gt, EvalOptions())
    stats = summarize(result)
    assert stats["n_matched"] == FRAMES and stats["e_r_median_deg"] < 2.0  # paired by (sequence, frame): ids differ


def test_tracks_off_fits_every_frame_alone(tracked_file, tmp_path):
    summary = fit_file(tracked_file, tmp_path / "out", replace(BatchSettings(), tracks=False))
    assert summary.ok == FRAMES + 3 and summary.tracks == 0  # the clicked frames and the car fitted alone
    reasons = {reason for _, vehicle, reason in summary.failed if vehicle == "1"}
    assert len(reasons) == 1 and "too few" in next(iter(reasons))
    assert summary.failed_tracks == []  # fitted alone, its frames are not a track's


def test_a_track_that_cannot_be_placed_is_said_once_with_its_frames(tracked_file, tmp_path):
    # Without the clicked frames' clicks the track cannot be placed: fit says so in one line for its 21 frames, and
    # the untracked car's failures (its clicks dropped on two frames) in one line each.
    doc = json.loads(tracked_file.read_text())
    for im in doc["images"]:
        im["vehicles"][0]["parts"] = []
    for im in doc["images"][:2]:
        im["vehicles"][1]["parts"] = im["vehicles"][1]["parts"][:2]
    path = tmp_path / "unclicked.json"
    path.write_text(json.dumps(doc))
    result = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 1, result.output
    failed = [line for line in result.stderr.splitlines() if line.startswith("  failed: ")]
    assert len(failed) == 3 and "more failed vehicles" not in result.stderr
    assert failed[0].startswith("  failed: track 0003-car (21 frames, images frame-0 to frame-20): the track cannot "
                                "be placed: no frame has clicks")
    assert failed[1].startswith("  failed: image frame-0 vehicle 2: ")
    assert failed[2].startswith("  failed: image frame-1 vehicle 2: ")
    # validate says it in one paragraph too, with the first and last frames' JSON paths.
    checked = CliRunner().invoke(main, ["validate", str(path)])
    paragraphs = checked.stdout.split("\n\n")
    assert sum("0003-car" in block for block in paragraphs) == 1, checked.stdout
    (track,) = [block for block in paragraphs if "0003-car" in block]
    assert track.startswith("track 0003-car (Car): 21 frames failed, image frame-0 vehicle 1 ($.images[0].vehicles[0]) "
                            "to image frame-20 vehicle 1 ($.images[20].vehicles[0]): the track cannot be placed")


def test_fit_says_how_the_tracks_frames_were_determined(tracked_file, tmp_path):
    result = CliRunner().invoke(main, ["fit", str(tracked_file), "-o", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "tracks: 1 fitted as tracks" in result.output and "3 from their clicks, 12 from a box alone, 6 " \
                                                                "interpolated" in result.output
    off = CliRunner().invoke(main, ["fit", str(tracked_file), "-o", str(tmp_path / "off"), "--tracks", "off"])
    assert off.exit_code == 1 and "tracks:" not in off.output


def _fit_clicked_track(tmp_path, clicks, pose) -> tuple[str, list[dict]]:
    """Fit with ``fit`` a track clicked on its frames 0, 10 and 20 (``clicks(R, t)``: the frame's parts; ``pose(f)``:
    its (R, t)); its output and the frames' results.json entries."""
    images = []
    for f in range(0, FRAMES, EVERY):
        vehicle = {"id": "1", "prototype": "Car", "track": "0003-car",
                   "parts": [part_json(p) for p in clicks(*pose(f))]}
        images.append({"id": f"frame-{f}", "sequence": "0003", "frame": f, "size": list(CAMERA.image_size),
                       "camera": {"K": CAMERA.K.tolist()}, "vehicles": [vehicle]})
    path = tmp_path / "track.json"
    path.write_text(json.dumps({"toosicubix": 1, "images": images}))
    result = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    frames = [v for im in json.loads((tmp_path / "out" / "results.json").read_text())["images"] for v in im["vehicles"]]
    assert len(frames) == 3 and all(v["pose_from"] == "clicks" for v in frames)
    return result.output, frames


def test_a_track_clicked_with_left_and_right_swapped_is_flagged_with_its_likely_cause(tmp_path):
    """A person who names left and right as the image's does so on every frame they click: the track's poses in its
    clicked frames are then implausible, flagged as a vehicle fitted alone is (issue 33, item 2), with the cause."""
    specs = _specs("front", D, np.random.default_rng(0))
    output, frames = _fit_clicked_track(
        tmp_path, lambda R, t: mirrored(tuple(render_parts(specs, R, t, D, CAMERA, (0.32 * D[0], -0.3 * D[0])))),
        lambda f: (R_cam_vehicle_from_ypr(np.pi / 2 + 0.2), np.array([1.0, 1.6, 20.0 - 0.3 * f])))  # driving at us
    assert all(v.get("implausible") for v in frames)
    assert all(any(w.startswith("left and right look swapped") for w in v["warnings"]) for v in frames)
    assert all(v["confidence"] <= IMPLAUSIBLE_CONFIDENCE for v in frames)
    assert "IMPLAUSIBLE: 3 fitted vehicle(s)" in output


def test_a_track_clicked_with_front_and_rear_wheels_swapped_is_flagged(tmp_path):
    """Rule 29: a car seen from its side, its front and rear wheels named the other way round on every clicked frame:
    the track's poses in those frames are flagged as a car fitted alone is (the front axle behind the rear one),
    with what to check, and their KITTI score is at most 0.2."""
    swap = {"wheel-front-right": "wheel-rear-right", "wheel-rear-right": "wheel-front-right"}
    specs = [replace(s, name=swap.get(s.name, s.name)) for s in _specs("side", D, np.random.default_rng(1))]
    # Rendered where the names say: the "front" wheels at the rear axle. Crossing, its right side seen.
    _, frames = _fit_clicked_track(
        tmp_path, lambda R, t: render_parts(specs, R, t, D, CAMERA, (-0.3 * D[0], 0.32 * D[0])),
        lambda f: (R_cam_vehicle_from_ypr(0.1), np.array([-2.0 + 0.1 * f, 1.6, 18.0])))
    assert all(v.get("implausible") == "the front axle comes out behind the rear one: front and rear wheels look "
                                       "swapped" for v in frames), [v.get("implausible") for v in frames]
    assert all(any("check the wheels' names (front and rear)" in w for w in v["warnings"]) for v in frames)
    assert all(v["confidence"] <= IMPLAUSIBLE_CONFIDENCE for v in frames)


def test_interleaved_sequences_give_each_frame_its_own_track_s_pose(tracked_file, tmp_path):
    """Two sequences whose images alternate in the file (A0, B0, A1, B1, ...) are fitted as when each comes whole:
    a sequence's results arrive once its last image is read, before the other's images come (before, an assert
    stopped fit, or under python -O frames took the other sequence's poses)."""
    doc = json.loads(tracked_file.read_text())
    a = doc["images"]
    # Sequence 0004: the same frames numbered backwards, so each of its frames has another pose than 0003's.
    b = [{**im, "id": f"b-{im['id']}", "sequence": "0004", "frame": FRAMES - 1 - im["frame"],
          "vehicles": [{**im["vehicles"][0], "track": "0004-car"}, im["vehicles"][1]]} for im in a]
    fitted = {}
    for name, images in (("grouped", a + b), ("interleaved", [im for pair in zip(a, b, strict=True) for im in pair])):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps({**doc, "images": images}))
        summary = fit_file(path, tmp_path / name)
        assert summary.ok == summary.vehicles == 4 * FRAMES
        out = json.loads((tmp_path / name / "results.json").read_text())
        fitted[name] = {im["id"]: [(v.get("track"), v["t_cam_vehicle"]) for v in im["vehicles"]]
                        for im in out["images"]}
    assert fitted["interleaved"] == fitted["grouped"]
    assert fitted["grouped"]["frame-3"][0][0] == "0003-car" and fitted["grouped"]["b-frame-3"][0][0] == "0004-car"
    assert fitted["grouped"]["frame-3"][0][1] != fitted["grouped"]["b-frame-3"][0][1]


def test_a_tracked_frames_next_clicks_never_widen_its_sigmas(tracked_file, tmp_path):
    """A track's frame has the track's sigmas; the next clicks were worked out on its own rows and set against them,
    so a click 'took' yaw 4.1 -> 11.2 deg (a newcomer's validate). Now a click's information on its frame is added
    to the track's: every suggestion is at most the frame's sigma, and on a frame clicked or boxed it is lower."""
    fit_file(tracked_file, tmp_path / "out", BatchSettings(next_clicks=3))
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    tracked = [im["vehicles"][0] for im in doc["images"]]
    assert all(v["next_clicks"] for v in tracked)
    for v in tracked:
        for s in v["next_clicks"]:
            assert s["yaw_sigma_deg"] <= v["sigma"]["yaw_deg"] * (1 + 1e-12)
            assert s["depth_sigma_rel"] <= v["sigma"]["depth_rel"] * (1 + 1e-12)
        assert min(s["yaw_sigma_deg"] for s in v["next_clicks"]) < v["sigma"]["yaw_deg"]


def test_validate_says_a_box_only_frame_is_placed_by_its_track(tracked_file):
    """validate described a box-only frame as 'constraints 0 from 0 clicked points ... 8 fix the cuboid up to scale',
    as if it had been fitted alone; it is placed by its track."""
    out = CliRunner().invoke(main, ["validate", str(tracked_file), "--all"])
    assert out.exit_code == 0, out.output
    assert "its pose from its track (its 2D box here) and the track's other frames" in out.output
    assert "its pose from its track (nothing here: interpolated)" in out.output
    assert "constraints 0 from 0 clicked points" not in out.output

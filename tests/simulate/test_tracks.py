"""simulate --tracks (issue 32): one vehicle per track across the frames of its longest clean run, clicks on the
keyframes only, a 2D box on every frame, every frame's ground truth; the file passes the track rules."""

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from toosicubix.annotations.stream import index_annotations
from toosicubix.camera import Camera
from toosicubix.cli import main
from toosicubix.formats.kitti import format_label_line, object_from_pose, read_label_file
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.simulate.annotator import (
    AnnotatorOptions,
    SelectionOptions,
    TrackOptions,
    keyframe_indices,
    select_kitti_tracking,
    select_kitti_tracks,
    simulate_tracks,
    simulate_vehicle,
    track_body_shape,
)
from toosicubix.simulate.boxes import projection_box2d

P2 = np.array([[720.0, 0.0, 620.0, 43.2], [0.0, 720.0, 180.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
CAMERA = Camera.from_P(P2, image_size=(1242, 375))
SEQUENCE = "0003"


def label(frame: int, track: int, kind: str = "Car", occluded: int = 0) -> str:
    """A tracking label line: a vehicle driving away across the view, 14-25 m ahead, its box the projected cuboid."""
    dims = {"Car": (4.2, 1.75, 1.5), "Van": (5.0, 1.9, 2.1)}[kind]
    R = R_cam_vehicle_from_ypr(np.deg2rad(-60.0 + 3.0 * track))
    t = np.array([-4.0 + 3.0 * track + 0.1 * frame, 1.65, 14.0 + 0.5 * frame + 2.0 * track])
    obj = object_from_pose(kind, R, t, np.array(dims), CAMERA, projection_box2d(R, t, np.array(dims), CAMERA),
                           occluded=occluded, score=None)
    return f"{frame} {track} {format_label_line(obj)}"


def tracking_folder(root):
    """Track 0: a car on frames 0-11. Track 1: a van on frames 0-9, largely occluded on frame 6 (runs 0-5 and 7-9).
    Track 2: a car on frames 0-2 and 4-8 (a gap at 3). Track 3: a car occluded on every frame (no run)."""
    lines = [label(f, 0) for f in range(12)]
    lines += [label(f, 1, "Van", occluded=2 if f == 6 else 0) for f in range(10)]
    lines += [label(f, 2) for f in (0, 1, 2, 4, 5, 6, 7, 8)]
    lines += [label(f, 3, occluded=2) for f in range(5)]
    lines.sort(key=lambda ln: int(ln.split()[0]))
    (root / "label_02").mkdir(parents=True)
    (root / "calib").mkdir()
    (root / "label_02" / f"{SEQUENCE}.txt").write_text("".join(f"{ln}\n" for ln in lines))
    numbers = " ".join(f"{v:.6e}" for v in P2.ravel())
    (root / "calib" / f"{SEQUENCE}.txt").write_text("".join(f"P{i}: {numbers}\n" for i in range(4))
                                                    + "R_rect 1 0 0 0 1 0 0 0 1\n")
    return root


RUNS = {"0": list(range(12)), "1": list(range(6)), "2": [4, 5, 6, 7, 8]}


def frames_by_track(vehicles) -> dict[str, list[int]]:
    out: dict[str, list[int]] = {}
    for g in vehicles:
        out.setdefault(g.vehicle_id, []).append(g.label.frame)
    return out


def test_a_track_keeps_its_longest_run_of_clean_consecutive_frames(tmp_path):
    root = tracking_folder(tmp_path / "kitti")
    vehicles = select_kitti_tracks(root, SelectionOptions(frames_per_track=None))
    assert frames_by_track(vehicles) == RUNS
    assert all(g.sequence == SEQUENCE and g.track == f"{SEQUENCE}-{g.vehicle_id}"
               and g.image_id == f"{SEQUENCE}_{g.frame:06d}" for g in vehicles)
    cut = select_kitti_tracks(root, SelectionOptions(frames_per_track=4))
    assert frames_by_track(cut) == {k: v[:4] for k, v in RUNS.items()}
    # Without tracks the same folder gives at most 3 of each track's eligible frames, spread, gaps or not (unchanged).
    without = select_kitti_tracking(root)
    assert frames_by_track(without) == {"0": [0, 6, 11], "1": [0, 4, 9], "2": [0, 5, 8]}
    assert all(g.sequence is None and g.frame is None and g.track is None for g in without)


@pytest.mark.parametrize(("n", "k", "expected"), [(12, 5, [0, 5, 10, 11]), (12, 1, list(range(12))), (6, 5, [0, 5]),
                                                  (5, 10, [0, 4]), (1, 2, [0]), (0, 3, [])])
def test_keyframes_are_the_first_every_kth_and_the_last(n, k, expected):
    assert keyframe_indices(n, k) == expected


def test_clicks_on_keyframes_boxes_on_every_frame(tmp_path):
    vehicles = select_kitti_tracks(tracking_folder(tmp_path / "kitti"), SelectionOptions(frames_per_track=None))
    options = AnnotatorOptions(seed=4)
    simulated = simulate_tracks(vehicles, options, TrackOptions(keyframes=5))
    keyframes = {"0": {0, 5, 10, 11}, "1": {0, 5}, "2": {4, 8}}
    for sv in simulated:
        gt = sv.source
        if gt.frame in keyframes[gt.vehicle_id]:
            assert sv.n_clicks >= 6
            # A keyframe's clicks are the very clicks of the frame simulated alone.
            alone = simulate_vehicle(replace(gt, sequence=None, frame=None, track=None), options)
            assert [p.name for p in sv.parts] == [p.name for p in alone.parts]
            np.testing.assert_array_equal(np.concatenate([p.uv for p in sv.parts]),
                                          np.concatenate([p.uv for p in alone.parts]))
        else:
            assert sv.parts == [] and sv.n_clicks == 0
        assert sv.box2d is not None and sv.box2d[2] > sv.box2d[0] and sv.box2d[3] > sv.box2d[1]
    # One solid per track, the person's error per frame: the same call draws the same boxes.
    again = simulate_tracks(vehicles, options, TrackOptions(keyframes=5))
    assert all(np.array_equal(a.box2d, b.box2d) for a, b in zip(simulated, again, strict=True))
    assert track_body_shape(4, "0003-0", "Car") == track_body_shape(4, "0003-0", "Car")


def test_the_box_kinds(tmp_path):
    vehicles = select_kitti_tracks(tracking_folder(tmp_path / "kitti"), SelectionOptions(frames_per_track=2))
    projection = simulate_tracks(vehicles, AnnotatorOptions(), TrackOptions(boxes="projection"))
    for sv in projection:
        np.testing.assert_array_equal(sv.box2d, np.round(sv.source.label.box2d, 2))
    assert all(sv.box2d is None for sv in simulate_tracks(vehicles, AnnotatorOptions(), TrackOptions(boxes="none")))
    person = simulate_tracks(vehicles, AnnotatorOptions(), TrackOptions(boxes="person"))
    # The person's box hugs the silhouette: inside KITTI's on average (the error is a pixel or two).
    inward = np.array([(sv.box2d - sv.source.label.box2d) * [1, 1, -1, -1] for sv in person])
    assert inward.mean() > 0.0
    with pytest.raises(ValueError, match="option boxes: expected one of person, projection, none"):
        TrackOptions(boxes="amodal")
    with pytest.raises(ValueError, match="option keyframes"):
        TrackOptions(keyframes=0)


def test_cli_tracks_write_a_file_that_passes_the_track_rules_and_every_frames_ground_truth(tmp_path):
    root = tracking_folder(tmp_path / "kitti")
    ann = tmp_path / "tracks.json"
    result = CliRunner().invoke(main, ["simulate", "--kitti-tracking", str(root), "-o", str(ann), "--tracks",
                                       "--keyframes", "5"])
    assert result.exit_code == 0, result.output
    assert "simulated 23 vehicles of 3 tracks, 8 with clicks (keyframes every 5), 23 with a person box in " \
           "12 images" in result.output
    index = index_annotations(ann)  # the track rules: frames once per sequence, one prototype per track, ...
    assert index.tracked == 23
    doc = json.loads(ann.read_text())
    keyframes = {"0": {0, 5, 10, 11}, "1": {0, 5}, "2": {4, 8}}
    seen: dict[str, list[int]] = {}
    for image in doc["images"]:
        assert image["sequence"] == SEQUENCE and image["id"] == f"{SEQUENCE}_{image['frame']:06d}"
        for v in image["vehicles"]:
            assert v["track"] == f"{SEQUENCE}-{v['id']}" and len(v["box2d"]) == 4
            assert bool(v["parts"]) == (image["frame"] in keyframes[v["id"]])
            seen.setdefault(v["id"], []).append(image["frame"])
        labels = read_label_file(tmp_path / "tracks_gt" / "label_2" / f"{image['id']}.txt")
        assert len(labels) == len(image["vehicles"])
        assert (tmp_path / "tracks_gt" / "calib" / f"{image['id']}.txt").is_file()
    assert seen == RUNS
    assert len(list((tmp_path / "tracks_gt" / "label_2").glob("*.txt"))) == len(doc["images"]) == 12


def test_cli_tracks_options(tmp_path):
    root = tracking_folder(tmp_path / "kitti")
    runner = CliRunner()

    def simulate(*args: str):
        return runner.invoke(main, ["simulate", "--kitti-tracking", str(root), "-o", str(tmp_path / "s.json"), *args])

    result = simulate("--tracks", "--boxes", "none", "--frames-per-track", "3")
    assert result.exit_code == 0, result.output
    vehicles = [v for im in json.loads((tmp_path / "s.json").read_text())["images"] for v in im["vehicles"]]
    assert len(vehicles) == 9 and all("box2d" not in v and v["parts"] for v in vehicles)
    for args, message in ((("--keyframes", "2"), "--keyframes needs --tracks"),
                          (("--boxes", "person"), "--boxes needs --tracks"),
                          (("--tracks", "--keyframes", "0"), "Invalid value for '--keyframes'")):
        result = simulate(*args)
        assert result.exit_code == 2 and message in result.output, result.output
    result = runner.invoke(main, ["simulate", "--kitti", str(root), "-o", str(tmp_path / "k.json"), "--tracks"])
    assert result.exit_code == 2 and "--tracks needs tracking labels (--kitti-tracking), got --kitti" in result.output

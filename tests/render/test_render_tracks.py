"""`toosicubix render` of a sequence: each frame's bird's-eye view draws its tracks over every frame, a tracked
vehicle keeps its track's colour and its label says how the frame's pose was determined; untracked outputs render
as before (the README's picture, made by the renderer before tracks, is reproduced pixel for pixel)."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from tests.pipeline.test_tracks import FRAMES, tracked_file  # noqa: F401  (the fixture: a tracked car, 21 frames)
from toosicubix.camera import Camera
from toosicubix.cli import main
from toosicubix.formats.results import VehicleResult, read_results
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.pipeline.batch import fit_file
from toosicubix.render.folder import (
    TrackPath,
    Tracks,
    drawn_tracks,
    drawn_vehicles,
    render_image,
    track_colours,
    vehicle_label,
)
from toosicubix.render.overlay import (
    PALETTE_BGR,
    DrawnTrack,
    DrawnVehicle,
    birds_eye_layout,
    birds_eye_side,
    draw_birds_eye,
)

TRACK = "0003-car"


@pytest.fixture
def fitted_tracks(tracked_file, tmp_path):  # noqa: F811
    """The tracked file fitted: frames 0, 10 and 20 from clicks, the others from a box or interpolated."""
    fit_file(tracked_file, tmp_path / "out")
    return tmp_path / "out", tracked_file


def _near(pixel: np.ndarray, colour: tuple[int, int, int], tolerance: int = 40) -> bool:
    return bool(np.max(np.abs(pixel.astype(int) - np.array(colour))) < tolerance)


def test_a_sequence_renders_one_picture_per_frame_with_each_track_drawn_where_its_frames_put_it(fitted_tracks,
                                                                                                tmp_path):
    out, annotations = fitted_tracks
    result = CliRunner().invoke(main, ["render", str(out), "--annotations", str(annotations), "-o",
                                       str(tmp_path / "pictures")])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "pictures").iterdir()) == sorted(f"frame-{f}.png" for f in
                                                                               range(FRAMES))
    results = read_results(out / "results.json")
    tracks = Tracks.of(results)
    path = tracks.paths[("0003", TRACK)]
    assert list(path.frames) == list(range(FRAMES))
    assert path.pose_from[:4] == ("clicks", "box", "box", "interpolated")
    colour = PALETTE_BGR[tracks.colours[("0003", TRACK)]]
    result0 = results[0]
    picture = cv2.imread(str(tmp_path / "pictures" / "frame-0.png"))
    width, height = result0.image_size
    # The panel's pixels of the track's positions in frames 15 (a box) and 20 (clicks), mapped as the overlay maps
    # them: the panel's layout for frame 0's vehicles and tracks, its left edge at the image's right edge.
    vehicles = drawn_vehicles(None, result0, _camera(result0), tracks.colours)
    layout = birds_eye_layout(birds_eye_side(height), vehicles, (), height, drawn_tracks(result0, tracks))
    plain = render_image(result0, None, None)  # the same frame without its track
    for f in (15, 20):
        u, v = np.rint(layout.frame.uv(path.xz[f])[0]).astype(int)
        assert _near(picture[v, width + u], colour), f  # a dot of the track's colour at its position
        assert not _near(plain[v, width + u], colour), f  # where nothing of that colour was before
    # The clicked frames (0, 10, 20) are ringed: the same track with every frame from a box differs only round them.
    unringed = Tracks({key: replace(p, pose_from=("box",) * len(p.frames)) for key, p in tracks.paths.items()},
                      tracks.colours)
    ringed = render_image(result0, None, None, tracks=tracks)[:, width:]
    differ = np.argwhere(np.any(ringed != render_image(result0, None, None, tracks=unringed)[:, width:], axis=2))
    centres = layout.frame.uv(path.xz[[0, 10, 20]])  # (3, 2)
    distance = np.linalg.norm(differ[:, None, ::-1] - centres[None], axis=2)  # (n, 3) pixels to each centre
    assert np.all(distance.min(axis=1) < 10.0)  # rings of 4 px (7 px round this frame's big dot), anti-aliased
    assert np.all(np.bincount(distance.argmin(axis=1), minlength=3) > 10)  # round each of the three


def _camera(result) -> Camera:
    return Camera(K=result.K, image_size=result.image_size)


def test_a_tracked_vehicle_keeps_its_track_colour_in_every_frame_and_others_take_other_colours(fitted_tracks):
    results = read_results(fitted_tracks[0] / "results.json")
    tracks = Tracks.of(results)
    colour = PALETTE_BGR[tracks.colours[("0003", TRACK)]]
    for result in results:
        tracked, alone = drawn_vehicles(None, result, _camera(result), tracks.colours)
        assert tracked.colour == colour and alone.colour not in (None, colour)
        (drawn,) = drawn_tracks(result, tracks)
        assert drawn.name == TRACK and drawn.current == result.frame and drawn.clicked.sum() == 3
    # Without tracks (an untracked output) the overlay colours vehicles by their place, as before.
    assert all(v.colour is None for v in drawn_vehicles(None, results[0], _camera(results[0])))
    # Eleven tracks and an untracked vehicle in one frame: the palette's ten colours are all taken, so the
    # two tracks share one and the untracked vehicle takes the palette's first.
    first = results[0]
    tracked, alone = first.vehicles
    crowded = replace(first, vehicles=[replace(tracked, track=f"car-{k}") for k in range(11)] + [alone])
    crowd = Tracks.of([crowded])
    colours = [v.colour for v in drawn_vehicles(None, crowded, _camera(first), crowd.colours)]
    assert len(set(colours[:11])) == 10 and colours[11] == PALETTE_BGR[0]  # ten colours for eleven tracks


def test_the_label_says_the_track_and_what_determined_the_frame():
    v = VehicleResult(id="3", status="ok", error=None, prototype="Car", R_cam_vehicle=np.eye(3),
                      t_cam_vehicle=np.array([1.0, 1.5, 14.2]), dimensions=np.array([4.1, 1.7, 1.5]), confidence=0.81)
    assert vehicle_label(v) == "3 Car 4.1x1.7x1.5m z14.2m conf 0.81"
    for pose_from, said in (("clicks", "(clicks)"), ("box", "(box)"), ("interpolated", "(interp.)")):
        tracked = replace(v, track="0003-7", pose_from=pose_from)
        assert vehicle_label(tracked) == f"3 Car 4.1x1.7x1.5m z14.2m conf 0.81 track 0003-7 {said}"
    failed_track = replace(v, track="0003-7")  # its track failed: no pose_from
    assert vehicle_label(failed_track).endswith("track 0003-7")


def _path(first: int, last: int) -> TrackPath:
    frames = np.arange(first, last + 1)
    return TrackPath(tuple(str(f) for f in frames), frames, np.zeros((len(frames), 2)), ("box",) * len(frames),
                     first, last)


def test_tracks_seen_together_take_different_colours_and_a_track_s_colour_depends_on_its_name():
    names = [f"car-{k}" for k in range(10)]
    together = {("s", name): _path(0, 9) for name in names}
    colours = track_colours(together)
    assert sorted(colours.values()) == list(range(len(PALETTE_BGR)))  # ten at once: the ten colours
    one_by_one = {("s", name): _path(10 * k, 10 * k + 9) for k, name in enumerate(names)}
    alone = track_colours(one_by_one)  # never seen together: each the colour its name hashes to
    assert alone == {key: track_colours({key: one_by_one[key]})[key] for key in one_by_one}
    assert len(set(alone.values())) > 1
    other_sequence = track_colours({**together, ("t", "car-0"): _path(0, 9)})
    assert other_sequence[("t", "car-0")] == alone[("s", "car-0")]  # other sequences' tracks do not count


def test_the_bird_s_eye_view_draws_a_track_under_the_footprints_and_rings_its_clicked_frames():
    car = DrawnVehicle(id="1", ok=True, R_cam_vehicle=R_cam_vehicle_from_ypr(0.0),
                       t_cam_vehicle=np.array([0.0, 1.5, 20.0]), dimensions=np.array([4.0, 1.7, 1.5]),
                       colour=PALETTE_BGR[3])
    xz = np.array([[-6.0, 8.0], [-4.0, 12.0], [-2.0, 16.0], [0.0, 20.0]])
    track = DrawnTrack("a", PALETTE_BGR[3], xz, np.array([True, False, False, True]), current=3)
    camera = Camera(K=np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]), image_size=(640, 480))
    bare = draw_birds_eye(480, camera, [car], image_width=640)
    panel = draw_birds_eye(480, camera, [car], image_width=640, tracks=[track])
    frame = birds_eye_layout(480, [car], tracks=[track]).frame
    assert frame == birds_eye_layout(480, [car]).frame  # the track lies within the view the car sets
    for k in range(3):
        u, v = frame.uv(xz[k])[0]
        assert _near(panel[round(v), round(u)], track.colour)  # a dot per frame
    # A ring round frame 0's dot, clicked, and none round frame 1's or 2's: the same track unclicked differs only
    # within 4 m + 2 px of frame 0's centre, in an annulus (m = 480 / 380: the panel's sizes grow with its width).
    plain = draw_birds_eye(480, camera, [car], image_width=640, tracks=[replace(track, clicked=np.zeros(4, bool))])
    differ = np.argwhere(np.any(panel != plain, axis=2))[:, ::-1]
    m = 480 / 380
    distance = np.linalg.norm(differ - frame.uv(xz[0])[0], axis=1)
    current = np.linalg.norm(differ - frame.uv(xz[3])[0], axis=1)  # this frame's, clicked too: ringed round its dot
    assert len(differ) > 20 and np.all((np.abs(distance - 4.0 * m) < 2.5) | (current < (7.0 + 3.5) * m + 2.5))
    # The footprint's outline is drawn over the track: where it was without the track, it still is, but under the
    # dot and ring that mark this frame's position, drawn last, at the footprint's centre.
    outline = np.all(bare == np.array(car.colour, np.uint8), axis=2)
    rows, cols = np.indices(outline.shape)
    u, v = frame.uv(xz[3])[0]
    outline &= np.hypot(cols - u, rows - v) > (7.0 + 2.0) * m + 1.0
    assert outline.sum() > 20 and np.all(panel[outline] == bare[outline])


def test_the_untracked_sample_renders_as_before(tmp_path, monkeypatch):
    """docs/sample-overlay.png was made by the renderer before tracks existed (its command is in the README)."""
    monkeypatch.chdir(tmp_path)
    fit_file(REPO / "samples" / "annotations.json", tmp_path / "toosicubix-out")
    result = CliRunner().invoke(main, ["render", "--png-compression", "9", "-q"])
    assert result.exit_code == 0, result.output
    made = cv2.imread(str(tmp_path / "toosicubix-out-render" / "000002.png"))
    before = cv2.imread(str(REPO / "docs" / "sample-overlay.png"))
    assert made.shape == before.shape and np.array_equal(made, before)
    header = json.loads((tmp_path / "toosicubix-out" / "results.json").read_text())
    assert "track_ids" not in header or not header["track_ids"]  # untracked indeed

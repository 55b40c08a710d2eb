"""``render --video``: a sequence's rendered frames as one MPEG-4 video, in frame order at the frame rate, gaps held."""

from __future__ import annotations

import json

import cv2
import numpy as np
from click.testing import CliRunner

from tests.scenes import CAMERA, _specs
from toosicubix.annotations.convert import part_json
from toosicubix.cli import main
from toosicubix.geometry import R_cam_vehicle_from_ypr
from toosicubix.parts.synthesis import render_parts
from toosicubix.render.video import MAX_HOLD_S, write_videos


def _png(path, width: int, height: int, value: int):
    cv2.imwrite(str(path), np.full((height, width, 3), value, np.uint8))
    return path


def _read(path) -> tuple[int, float, tuple[int, int], list[float]]:
    """Frames, frame rate, (width, height) and each frame's mean grey of a video."""
    capture = cv2.VideoCapture(str(path))
    means = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        means.append(float(frame.mean()))
    size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    return len(means), capture.get(cv2.CAP_PROP_FPS), size, means


def test_frames_in_order_gaps_held_and_odd_sides_padded(tmp_path):
    # Frames 4, 0, 1 and 100 of one sequence (given out of order), 33 x 21 px, at 2 frames a second: 0, 1, then
    # frames 2 and 3 missing (frame 1 held twice), 4, then a gap of 95 frames cut to 5 s (10 frames), then 100.
    grey = {0: 20, 1: 60, 4: 120, 100: 200}
    frames = [(n, _png(tmp_path / f"f{n}.png", 33, 21, v)) for n, v in ((4, 120), (0, 20), (1, 60), (100, 200))]
    summary = write_videos({"clip": frames}, tmp_path, 2.0)
    assert summary.written == [tmp_path / "clip.mp4"]
    assert summary.warnings == [f"sequence clip: 1 gap(s) between rendered frames longer than {MAX_HOLD_S:g} s, "
                                "shortened to it in its video"]
    count, fps, size, means = _read(tmp_path / "clip.mp4")
    expected = [grey[0], grey[1], grey[1], grey[1], grey[4], *[grey[4]] * 10, grey[100]]
    assert (count, fps, size) == (len(expected), 2.0, (34, 22))  # odd sides padded to even ones
    # Each frame's mean grey within the codec's loss and the one black pixel row and column of padding.
    np.testing.assert_allclose(means, [v * 33 * 21 / (34 * 22) for v in expected], atol=3.0)
    assert not list(tmp_path.glob(".*.tmp"))  # written whole, then moved in
    first = (tmp_path / "clip.mp4").read_bytes()
    write_videos({"clip": frames}, tmp_path, 2.0)
    assert (tmp_path / "clip.mp4").read_bytes() == first  # as render's PNGs: the same bytes again


def test_a_frame_of_another_size_is_scaled_and_said(tmp_path):
    frames = [(0, _png(tmp_path / "a.png", 40, 20, 50)), (1, _png(tmp_path / "b.png", 80, 40, 50))]
    summary = write_videos({"s": frames}, tmp_path, 10.0)
    assert summary.warnings == ["sequence s: 1 frame(s) drawn at another size than its first, scaled to 40x20 in "
                                "its video"]
    assert _read(tmp_path / "s.mp4")[:3] == (2, 10.0, (40, 20))


def test_render_video_of_a_fitted_sequence(tmp_path):
    # Four frames of a car turning slowly, each clicked: render --video writes <sequence>.mp4 beside the PNGs, and
    # says so; a folder without sequences says that no video was written.
    D = np.array([4.3, 1.8, 1.5])
    specs = _specs("oblique-front-left", D, np.random.default_rng(0))
    images = []
    for f in range(4):
        R, t = R_cam_vehicle_from_ypr(3 * np.pi / 4 + 0.02 * f), np.array([-3.0 + 0.05 * f, 1.6, 15.0 + 0.3 * f])
        parts = render_parts(specs, R, t, D, CAMERA, (0.32 * D[0], -0.3 * D[0]))
        car = {"id": "1", "prototype": "Car", "track": "drive-car", "parts": [part_json(p) for p in parts]}
        images.append({"id": f"frame-{f}", "sequence": "drive", "frame": f, "size": list(CAMERA.image_size),
                       "camera": {"K": CAMERA.K.tolist()}, "vehicles": [car]})
    annotations = tmp_path / "video.json"
    annotations.write_text(json.dumps({"toosicubix": 1, "images": images}))
    runner = CliRunner()
    assert runner.invoke(main, ["fit", str(annotations), "-o", str(tmp_path / "out")]).exit_code == 0
    result = runner.invoke(main, ["render", str(tmp_path / "out"), "--video", "--frame-rate", "5"])
    assert result.exit_code == 0, result.output
    video = tmp_path / "out-render" / "drive.mp4"
    assert f"videos: drive.mp4 in {tmp_path / 'out-render'}" in result.stderr
    count, fps, size, _ = _read(video)
    picture = cv2.imread(str(tmp_path / "out-render" / "frame-0.png"))
    assert (count, fps) == (4, 5.0) and size == (picture.shape[1] + picture.shape[1] % 2,
                                                  picture.shape[0] + picture.shape[0] % 2)
    images[0].pop("sequence"), images[0].pop("frame"), images[0]["vehicles"][0].pop("track")
    alone = tmp_path / "alone.json"
    alone.write_text(json.dumps({"toosicubix": 1, "images": images[:1]}))
    assert runner.invoke(main, ["fit", str(alone), "-o", str(tmp_path / "alone-out")]).exit_code == 0
    result = runner.invoke(main, ["render", str(tmp_path / "alone-out"), "--video"])
    assert result.exit_code == 0 and "--video: no rendered image is a frame of a sequence" in result.stderr


def test_frames_beyond_the_codec_s_side_are_scaled_down(tmp_path, monkeypatch):
    # MPEG-4 Part 2 takes at most 8190 px a side (a 13-bit size); here the bound is lowered to 20 so that the test
    # draws small frames: 50 x 30 frames become a 20 x 12 video, said once.
    import toosicubix.render.video as video

    monkeypatch.setattr(video, "MAX_SIDE", 20)
    frames = [(n, _png(tmp_path / f"{n}.png", 50, 30, 90)) for n in range(3)]
    summary = write_videos({"big": frames}, tmp_path, 10.0)
    assert summary.warnings == ["sequence big: its frames are 50x30 pixels, more than MPEG-4 takes a side (20): its "
                                "video is scaled by 0.4"]
    assert _read(tmp_path / "big.mp4")[:3] == (3, 10.0, (20, 12))

"""render bounds what it draws (issue 34, item 5): canvases beyond MAX_CANVAS_SIDE / MAX_CANVAS_PIXELS are drawn
scaled with a warning (left out when a side would be under a pixel), image files are not decoded before their
header says their size, and a file that cannot be decoded is named and drawn on a blank canvas, the rest rendered."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.render import folder
from toosicubix.render.folder import (
    MAX_CANVAS_PIXELS,
    MAX_CANVAS_SIDE,
    canvas_scale,
    header_size,
    read_image,
    scaled_camera,
)

SAMPLE = REPO / "samples" / "annotations.json"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_declaring(width: int, height: int) -> bytes:
    """A small PNG whose header declares ``width`` x ``height`` (its data is far too short for that)."""
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(b"\x00" * 4096)) + _chunk(b"IEND", b""))


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".webp", ".tiff", ".ppm"])
def test_header_size_reads_what_opencv_writes(ext):
    image = np.zeros((37, 53, 3), np.uint8)
    ok, data = cv2.imencode(ext, image)
    assert ok
    assert header_size(data.tobytes()) == (53, 37)


def test_header_size_of_gif_and_of_what_it_does_not_know():
    assert header_size(b"GIF89a" + struct.pack("<HH", 640, 480) + b"\x00" * 8) == (640, 480)
    assert header_size(b"\x89PNG\r\n\x1a\n" + b"garbage") is None
    assert header_size(b"\x00\x00\x00\x0cjP  \r\n\x87\n") is None  # JPEG 2000: not read here
    assert header_size(b"") is None
    assert header_size(b"\xff\xd8\xff\xe1\xff\xff") is None  # a JPEG cut in its first segment


def test_a_png_declaring_60000_square_is_not_decoded(tmp_path, monkeypatch):
    path = tmp_path / "huge.png"
    path.write_bytes(png_declaring(60_000, 60_000))
    assert path.stat().st_size < 10_000

    def never(*_):
        raise AssertionError("decoded before its size was checked")

    monkeypatch.setattr(folder.cv2, "imdecode", never)
    image, why = read_image(path)
    assert image is None
    assert why == f"its header declares 60000x60000 pixels: beyond the {MAX_CANVAS_SIDE} px a side and " \
                  f"{MAX_CANVAS_PIXELS} pixels render decodes"


def test_canvas_scale_brings_any_size_within_the_bounds():
    assert canvas_scale((1242, 375)) == 1.0
    for size in ((40_000, 40_000), (10**6, 10**6), (16_385, 10), (8_000, 8_000), (10**6, 100)):
        scale = canvas_scale(size)
        w, h = folder.scaled_size(size, scale)
        assert 1 <= w <= MAX_CANVAS_SIDE and 1 <= h <= MAX_CANVAS_SIDE and w * h <= MAX_CANVAS_PIXELS
    assert canvas_scale((1, 10**6)) is None and canvas_scale((10**6, 1)) is None


def test_a_scaled_camera_projects_to_scaled_pixels():
    from toosicubix.camera import Camera

    camera = Camera(np.array([[700.0, 0.0, 600.0], [0.0, 710.0, 180.0], [0.0, 0.0, 1.0]]),
                    np.array([-0.2, 0.05, 0.001, 0.0, 0.0]), image_size=(1242, 375))
    points = np.array([[1.0, 0.5, 10.0], [-3.0, 1.0, 20.0]])
    np.testing.assert_allclose(scaled_camera(camera, 0.25).project(points), 0.25 * camera.project(points),
                               rtol=1e-12)


@pytest.fixture(scope="module")
def sized(tmp_path_factory) -> Path:
    """The sample's three images fitted; sizes and files set per test in a copy of the annotation file."""
    root = tmp_path_factory.mktemp("bounds")
    annotations = root / "annotations.json"
    annotations.write_text(SAMPLE.read_text())
    result = CliRunner().invoke(main, ["fit", str(annotations), "-o", str(root / "out"), "-q"])
    assert result.exit_code == 0, result.output
    return root


def test_absurd_sizes_and_broken_images_are_named_the_rest_rendered(sized, tmp_path, monkeypatch):
    monkeypatch.setattr(folder, "MAX_CANVAS_PIXELS", 2_000_000)  # the same rules on smaller pictures: a fast test
    monkeypatch.setattr(folder, "MAX_CANVAS_SIDE", 2048)
    doc = json.loads(SAMPLE.read_text())
    doc["images"][0]["size"] = [40_000, 40_000]  # drawn scaled
    doc["images"][1]["size"] = [1, 1_000_000]  # cannot be drawn: left out
    doc["images"][2]["file"] = "broken.png"  # named, drawn on a blank canvas
    (tmp_path / "broken.png").write_bytes(png_declaring(60_000, 60_000))
    annotations = tmp_path / "annotations.json"
    annotations.write_text(json.dumps(doc))
    out = tmp_path / "pictures"
    result = CliRunner().invoke(main, ["render", str(sized / "out"), "--annotations", str(annotations), "-o",
                                       str(out)])
    assert result.exit_code == 0, result.output
    assert ("warning: image 000001: 40000x40000 pixels, beyond the 2048 px a side or 2000000 pixels render draws: "
            "drawn scaled by 0.0354 to 1414x1414") in result.stderr
    assert "warning: image 000002: 1x1000000 pixels cannot be drawn" in result.stderr
    assert f"warning: image 000003: {tmp_path / 'broken.png'}: its header declares 60000x60000 pixels: beyond the " \
           "2048 px a side" in result.stderr
    assert "rendered 2 images, 2 on a blank canvas, 1 left out (too large to draw even scaled)" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["000001.png", "000003.png"]
    picture = cv2.imread(str(out / "000001.png"))
    assert picture.shape[0] == 1414 and picture.shape[1] > 1414  # the overlay and its bird's-eye view beside it
    assert picture[:, :1414].std() > 0  # the cuboid is drawn


@settings(max_examples=200, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_file_is_read_within_the_bounds_or_named(tmp_path, data):
    """An image file cut, changed or with any declared size: an image within the bounds, or None and why; never an
    exception, and nothing beyond the bounds decoded."""
    kind = data.draw(st.sampled_from(["declared", "mutated", "random"]))
    if kind == "declared":
        blob = png_declaring(data.draw(st.integers(0, 2**32 - 1)), data.draw(st.integers(0, 2**32 - 1)))
    elif kind == "mutated":
        _, encoded = cv2.imencode(data.draw(st.sampled_from([".png", ".jpg", ".bmp", ".tiff", ".webp"])),
                                   np.full((24, 32, 3), 90, np.uint8))
        blob = bytearray(encoded.tobytes())
        for _ in range(data.draw(st.integers(1, 4))):
            blob[data.draw(st.integers(0, len(blob) - 1))] = data.draw(st.integers(0, 255))
        blob = bytes(blob[: data.draw(st.integers(0, len(blob)))])
    else:
        blob = data.draw(st.binary(max_size=64))
    path = tmp_path / "x.img"
    path.write_bytes(blob)
    image, why = read_image(path)
    if image is None:
        assert isinstance(why, str) and why
    else:
        h, w = image.shape[:2]
        assert image.shape[2] == 3 and w <= MAX_CANVAS_SIDE and h <= MAX_CANVAS_SIDE and w * h <= MAX_CANVAS_PIXELS

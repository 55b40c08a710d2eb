"""The size of a served image, from its file's header (never decoded): every format the page shows, and the files
that used to crash ``annotate`` at start (a PNG declaring 60000 x 60000 pixels)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image as PilImage

from toosicubix.cli import main
from toosicubix.errors import InputFileError
from toosicubix.web.images import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, image_size


def png_header(width: int, height: int) -> bytes:
    """A PNG declaring ``width`` x ``height`` (8-bit RGB) with one empty IDAT: its header is all that is read."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


@pytest.mark.parametrize(("name", "write"), [
    ("a.png", lambda p, im: cv2.imwrite(str(p), im)),
    ("a.jpg", lambda p, im: cv2.imwrite(str(p), im)),
    ("a.bmp", lambda p, im: cv2.imwrite(str(p), im)),
    ("lossy.webp", lambda p, im: cv2.imwrite(str(p), im, [cv2.IMWRITE_WEBP_QUALITY, 80])),
    ("lossless.webp", lambda p, im: cv2.imwrite(str(p), im, [cv2.IMWRITE_WEBP_QUALITY, 101])),
    ("extended.webp", lambda p, im: PilImage.fromarray(im).convert("RGBA").save(p, "WEBP", exif=b"Exif\0\0MM")),
    ("progressive-exif.jpg", lambda p, im: PilImage.fromarray(im).save(p, "JPEG", progressive=True,
                                                                       exif=b"Exif\0\0" + bytes(70000 // 2))),
    ("top-down.bmp", lambda p, im: p.write_bytes(_top_down_bmp(im))),
])
def test_the_header_gives_the_size_opencv_decodes(tmp_path: Path, name, write):
    image = np.random.default_rng(0).integers(0, 255, (37, 53, 3), dtype=np.uint8)
    path = tmp_path / name
    write(path, image)
    assert image_size(path) == (53, 37)
    decoded = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert decoded.shape[:2] == (37, 53)


def _top_down_bmp(image: np.ndarray) -> bytes:
    """A 24-bit BMP stored top-down (negative height), rows padded to 4 bytes."""
    height, width = image.shape[:2]
    row = width * 3 + (-width * 3) % 4
    pixels = b"".join(image[y].tobytes() + bytes(row - width * 3) for y in range(height))
    info = struct.pack("<IiiHHIIiiII", 40, width, -height, 1, 24, 0, len(pixels), 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 14 + len(info) + len(pixels), 0, 0, 14 + len(info)) + info + pixels


def test_a_png_declaring_60000_squared_is_refused_naming_its_size(tmp_path: Path):
    """Issue 34: a small PNG declaring 60000 x 60000 pixels (14 GB decoded) crashed annotate at start; its header
    says its size, which is refused."""
    path = tmp_path / "huge.png"
    path.write_bytes(png_header(60000, 60000))
    with pytest.raises(InputFileError, match=r"huge.png: \$: its header declares 60000 x 60000 pixels: the page shows "
                                             f"images of at most {MAX_IMAGE_SIDE} px a side"):
        image_size(path)
    path.write_bytes(png_header(MAX_IMAGE_SIDE, MAX_IMAGE_PIXELS // MAX_IMAGE_SIDE))
    assert image_size(path) == (MAX_IMAGE_SIDE, MAX_IMAGE_PIXELS // MAX_IMAGE_SIDE)
    path.write_bytes(png_header(10000, 10000))
    with pytest.raises(InputFileError, match="10000 x 10000 pixels"):
        image_size(path)


@pytest.mark.parametrize(("data", "message"), [
    (b"", "not an image the page shows"),
    (b"GIF89a" + bytes(20), "not an image the page shows"),
    (b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR\0\0", "cannot read the image's header"),
    (b"\xff\xd8\xff\xe0\0\x10JFIF", "cannot read the image's header: a JPEG cut short"),
    (b"\xff\xd8\xff\xda\0\x10", "a JPEG without a frame header"),
    (b"\xff\xd8" + b"\xff\xfe\0\x02" * 2000, "without a frame header in its first 1000 segments"),
    (png_header(0, 10), "declares 0 x 10 pixels"),
    # Found by the test below: a WebP cut short inside its first chunk's header (an IndexError; for VP8X a size of
    # 1 x 1 read from nothing).
    (b"RIFF\0\0\0\0WEBPVP8L", "a WebP header cut short"),
    (b"RIFF\0\0\0\0WEBPVP8X" + bytes(10), "a WebP header cut short"),
])
def test_files_that_are_no_image_are_refused_naming_why(tmp_path: Path, data: bytes, message: str):
    path = tmp_path / "x.png"
    path.write_bytes(data)
    with pytest.raises(InputFileError, match=message):
        image_size(path)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(magic=st.sampled_from([b"\x89PNG\r\n\x1a\n", b"\xff\xd8", b"BM", b"RIFF\0\0\0\0WEBP", b""]),
       rest=st.binary(max_size=80))
def test_any_bytes_give_a_size_or_an_input_error(tmp_path: Path, magic: bytes, rest: bytes):
    path = tmp_path / "x.png"
    path.write_bytes(magic + rest)
    try:
        width, height = image_size(path)
    except InputFileError as exc:
        assert str(exc).startswith(str(path))
    else:
        assert 0 < width <= MAX_IMAGE_SIDE and 0 < height <= MAX_IMAGE_SIDE


def test_annotate_refuses_the_huge_png_at_start_naming_it(scene, tmp_path: Path):
    _, cameras = scene
    path = tmp_path / "huge.png"
    path.write_bytes(png_header(60000, 60000))
    result = CliRunner().invoke(main, ["annotate", str(path), "--cameras", str(cameras),
                                       "-o", str(tmp_path / "a.json")])
    assert result.exit_code == 2, result.output
    assert f"{path}: $: its header declares 60000 x 60000 pixels" in result.output

"""The size of an image the page serves, read from its file's header, never by decoding it.

The browser decodes the whole image it shows (4 bytes a pixel), and the server only needs its size: a PNG of a
few hundred KB may declare 60000 x 60000 pixels (14 GB decoded), so the size is read from the header of the
formats a browser shows and ``annotate`` takes (PNG, JPEG, BMP, WebP) and an image beyond
:data:`MAX_IMAGE_SIDE` or :data:`MAX_IMAGE_PIXELS` is refused, naming the file and its declared size.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import BinaryIO

from toosicubix.errors import InputFileError

#: The largest side the page shows, pixels: the largest image side browsers decode (Firefox: 32,767).
MAX_IMAGE_SIDE = 32_767
#: The most pixels the page shows: 200 MB decoded in the browser (a 50-megapixel camera's frame).
MAX_IMAGE_PIXELS = 50_000_000

#: The formats :func:`image_size` reads, by what their files start with.
FORMATS = ("PNG", "JPEG", "BMP", "WebP")


def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` in pixels of the image file at ``path``, from its header.

    Raises
    ------
    InputFileError
        The file cannot be read, is none of :data:`FORMATS`, its header is cut short or declares a size of 0, or
        the size is beyond :data:`MAX_IMAGE_SIDE` or :data:`MAX_IMAGE_PIXELS`.
    """
    try:
        with open(path, "rb") as handle:
            size = _header_size(handle)
    except OSError as exc:
        raise InputFileError(path, [("$", f"cannot read the image: {exc.strerror or exc}")]) from None
    except (struct.error, ValueError) as exc:
        raise InputFileError(path, [("$", f"cannot read the image's header: {exc}")]) from None
    if size is None:
        raise InputFileError(path, [("$", f"not an image the page shows (its first bytes are those of none of "
                                          f"{', '.join(FORMATS)})")])
    width, height = size
    if width <= 0 or height <= 0:
        raise InputFileError(path, [("$", f"its header declares {width} x {height} pixels: no image to click on")])
    if width > MAX_IMAGE_SIDE or height > MAX_IMAGE_SIDE or width * height > MAX_IMAGE_PIXELS:
        raise InputFileError(path, [("$", f"its header declares {width} x {height} pixels: the page shows images of "
                                          f"at most {MAX_IMAGE_SIDE} px a side and {MAX_IMAGE_PIXELS:,} pixels (the "
                                          "browser decodes all of it); scale it down, or leave it out")])
    return width, height


def _header_size(handle: BinaryIO) -> tuple[int, int] | None:
    """The size a PNG, JPEG, BMP or WebP file declares; None for other files. ``struct.error`` or ``ValueError``
    when its header is cut short or broken."""
    head = handle.read(32)
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        if head[12:16] != b"IHDR":
            raise ValueError("a PNG whose first chunk is not IHDR")
        return struct.unpack(">II", head[16:24])
    if head.startswith(b"\xff\xd8"):
        handle.seek(2)
        return _jpeg_size(handle)
    if head.startswith(b"BM"):
        (header_bytes,) = struct.unpack("<I", head[14:18])
        if header_bytes == 12:  # OS/2's BITMAPCOREHEADER: 16-bit sides
            return struct.unpack("<HH", head[18:22])
        width, height = struct.unpack("<ii", head[18:26])
        return width, abs(height)  # a negative height: rows stored top-down
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        if len(head) < 30:
            raise ValueError(f"a WebP header cut short ({len(head)} bytes; its size is in the first 30)")
        chunk = head[12:16]
        if chunk == b"VP8X":  # extended: the canvas size, 24 bits each, minus one
            return int.from_bytes(head[24:27], "little") + 1, int.from_bytes(head[27:30], "little") + 1
        if chunk == b"VP8L":  # lossless: 14 bits each, minus one, after the signature byte
            if head[20] != 0x2F:
                raise ValueError("a lossless WebP without its signature")
            (bits,) = struct.unpack("<I", head[21:25])
            return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
        if chunk == b"VP8 ":  # lossy: the key frame's start code, then 14 bits each
            if head[23:26] != b"\x9d\x01\x2a":
                raise ValueError("a lossy WebP without its start code")
            width, height = struct.unpack("<HH", head[26:30])
            return width & 0x3FFF, height & 0x3FFF
        raise ValueError(f"a WebP whose first chunk is {chunk!r}")
    return None


#: The most JPEG segments followed to its frame header (ICC profiles and EXIF come in segments of up to 64 KB).
_JPEG_SEGMENTS = 1000
#: JPEG markers of a frame header (SOF0 to SOF15 but DHT, JPG and DAC), which holds the image's size.
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(handle: BinaryIO) -> tuple[int, int]:
    """The size in a JPEG's frame header, following the segments from after SOI: each segment's length is skipped,
    never read, and at most :data:`_JPEG_SEGMENTS` are followed."""
    for _ in range(_JPEG_SEGMENTS):
        byte = handle.read(1)
        if byte != b"\xff":
            raise ValueError("a JPEG segment that does not start with a marker" if byte else "a JPEG cut short")
        marker = handle.read(1)
        while marker == b"\xff":  # fill bytes before the marker
            marker = handle.read(1)
        if not marker:
            raise ValueError("a JPEG cut short")
        code = marker[0]
        if code == 0x01 or 0xD0 <= code <= 0xD7:  # markers without a segment
            continue
        if code in (0xD9, 0xDA):
            raise ValueError("a JPEG without a frame header before its image data")
        (length,) = struct.unpack(">H", handle.read(2))
        if code in _SOF:
            _, height, width = struct.unpack(">BHH", handle.read(5))
            return width, height
        if length < 2:
            raise ValueError("a JPEG segment shorter than its length field")
        handle.seek(length - 2, 1)
    raise ValueError(f"a JPEG without a frame header in its first {_JPEG_SEGMENTS} segments")

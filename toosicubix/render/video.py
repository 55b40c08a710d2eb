"""A sequence's rendered frames as one video (``toosicubix render --video``): ``OUT/<sequence>.mp4``.

The frames are the PNGs :func:`toosicubix.render.folder.render_folder` wrote, in frame order, at the frame rate (a
sequence's frame numbers are its timing: a frame missing between two rendered ones, one without any vehicle that
the annotation file leaves out, shows the previous frame for as long, up to :data:`MAX_HOLD_S`). A frame drawn at
another size than the sequence's first (a canvas scaled down, a photo of another size) is scaled to it. MPEG-4
Part 2 (``mp4v``), which OpenCV's own FFmpeg writes on every platform its wheels cover. The file is written whole
elsewhere, then moved in atomically: a reader sees the old video or the new one.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from toosicubix.formats.atomic import atomic_write

#: The longest stretch of missing frames shown as the frame before it, seconds; a longer gap is cut short.
MAX_HOLD_S = 5.0
FOURCC = "mp4v"
#: The longest side MPEG-4 Part 2 takes (13 bits, even): a larger frame is scaled down to it.
MAX_SIDE = 8190


@dataclass
class VideoSummary:
    """What :func:`write_videos` wrote: the videos, and one warning line each for what it could not do as asked."""

    written: list[Path] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def write_videos(frames: dict[str, list[tuple[int, Path]]], out_dir: Path, frame_rate: float) -> VideoSummary:
    """``out_dir/<sequence>.mp4`` for each sequence of ``frames`` (sequence -> its rendered frames, ``(frame
    number, PNG)``, in any order) at ``frame_rate`` frames per second (> 0)."""
    summary = VideoSummary()
    for sequence in sorted(frames):
        shown = sorted(frames[sequence])
        target = out_dir / f"{sequence}.mp4"
        with tempfile.TemporaryDirectory(prefix="toosicubix-video-") as tmp:
            staged = Path(tmp) / "video.mp4"
            problem = _encode(shown, staged, frame_rate, sequence, summary.warnings)
            if problem is not None:
                summary.warnings.append(f"sequence {sequence}: {problem}; no video written")
                continue
            with open(staged, "rb") as source:
                atomic_write(target, lambda handle, source=source: shutil.copyfileobj(source, handle), binary=True,
                             clean=False)
        summary.written.append(target)
    return summary


def _encode(shown: list[tuple[int, Path]], staged: Path, frame_rate: float, sequence: str,
            warnings: list[str]) -> str | None:
    """Write the frames to ``staged``; what went wrong, or None."""
    first = cv2.imread(str(shown[0][1]), cv2.IMREAD_COLOR)
    if first is None:
        return f"{shown[0][1]} cannot be read"
    height, width = first.shape[:2]
    if max(height, width) > MAX_SIDE:  # beyond the codec: the video is drawn smaller
        shrink = MAX_SIDE / max(height, width)
        warnings.append(f"sequence {sequence}: its frames are {width}x{height} pixels, more than MPEG-4 takes a "
                        f"side ({MAX_SIDE}): its video is scaled by {shrink:.3g}")
        height, width = max(1, int(height * shrink)), max(1, int(width * shrink))
    # The codec's 4:2:0 chroma needs even sides: an odd one is padded by a black pixel rather than cropped.
    pad_bottom, pad_right = height % 2, width % 2
    writer = cv2.VideoWriter(str(staged), cv2.VideoWriter_fourcc(*FOURCC), frame_rate,
                             (width + pad_right, height + pad_bottom))
    if not writer.isOpened():
        return f"OpenCV could not open a {FOURCC} writer for {width}x{height} frames here (built without FFmpeg?)"
    longest = max(1, round(MAX_HOLD_S * frame_rate))
    scaled, cut = 0, 0
    try:
        previous: tuple[int, np.ndarray] | None = None
        for number, path in shown:
            picture = first if previous is None else cv2.imread(str(path), cv2.IMREAD_COLOR)
            if picture is None:
                return f"{path} cannot be read"
            if picture.shape[:2] != (height, width):
                scaled += picture.shape[:2] != first.shape[:2]  # another size than the first (not the codec's bound)
                picture = cv2.resize(picture, (width, height), interpolation=cv2.INTER_AREA)
            if pad_bottom or pad_right:
                picture = cv2.copyMakeBorder(picture, 0, pad_bottom, 0, pad_right, cv2.BORDER_CONSTANT, value=0)
            if previous is not None:
                missing = number - previous[0] - 1
                for _ in range(min(missing, longest)):
                    writer.write(previous[1])
                cut += missing > longest
            writer.write(picture)
            previous = (number, picture)
    finally:
        writer.release()
    if scaled:
        warnings.append(f"sequence {sequence}: {scaled} frame(s) drawn at another size than its first, scaled to "
                        f"{width}x{height} in its video")
    if cut:
        warnings.append(f"sequence {sequence}: {cut} gap(s) between rendered frames longer than {MAX_HOLD_S:g} s, "
                        "shortened to it in its video")
    return None

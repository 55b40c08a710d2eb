"""Sequences on the annotate page: frame numbers from file names, new track names, and which of a track's frames the
page fits together when it shows one frame.

The page fits a tracked vehicle as ``fit`` fits its track (:func:`toosicubix.pipeline.tracks.results_of_track`), but
over the frames near the one shown only (:func:`frames_to_fit`), so that a refit after a click takes a fraction of a
second however long the sequence: the track's frames within :data:`TRACK_WINDOW` of it, and, on a side where none of
those has clicks, the nearest clicked frame beyond (a track needs a clicked frame to be placed; confirmed
predictions chain without clicks). ``fit`` fits the whole track, so its answer may differ a little far from the
clicks.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

from toosicubix.annotations.schema import MAX_FRAME

#: Frames on each side of the shown one whose vehicles of a track are fitted with it (41 frames of a track take
#: about 0.3 s to fit; a track is carried, as a prediction, to the frames within this many of one of its own).
TRACK_WINDOW = 30

_DIGITS = re.compile(r"\d+")
#: Runs of ASCII digits: what a track's name is ordered by (a name of other digits, e.g. '²', which ``int``
#: refuses though ``str.isdigit`` passes it, or of hundreds of digits, sorts as text).
_ASCII_DIGITS = re.compile(r"([0-9]{1,18})")


def frame_numbers(names: list[str]) -> tuple[list[int], bool]:
    """The frame numbers of a sequence's files given in frame order: the last run of digits in each file name (its
    stem: ``000123.png`` -> 123) when every name has one and no two give the same number (within the schema's
    :data:`~toosicubix.annotations.schema.MAX_FRAME`), else each file's position in ``names`` (0, 1, ...). The
    second value says which: True for the file names' digits."""
    runs = [_DIGITS.findall(Path(name).stem) for name in names]
    if runs and all(runs):
        numbers = [int(run[-1]) for run in runs]
        if len(set(numbers)) == len(numbers) and max(numbers) <= MAX_FRAME:
            return numbers, True
    return list(range(len(names))), False


def new_track_name(sequence: str, used: Iterable[str]) -> str:
    """``"<sequence>-<k>"`` with the smallest k >= 1 that no track of the file has (a track name is the file's,
    across its sequences)."""
    taken = set(used)
    k = 1
    while f"{sequence}-{k}" in taken:
        k += 1
    return f"{sequence}-{k}"


def track_sort_key(track: str) -> tuple:
    """Tracks in natural order: '0003-2' before '0003-10'."""
    return tuple((0, int(piece)) if _ASCII_DIGITS.match(piece) else (1, piece)
                 for piece in _ASCII_DIGITS.split(track) if piece)


def frames_to_fit(target: int, frames: dict[int, bool], window: int = TRACK_WINDOW) -> list[int]:
    """Which of a track's frames to fit with frame ``target``: ``frames`` maps each of its frames but the target's
    to whether its vehicle has clicks. Those within ``window`` of the target, and on each side where none of those
    has clicks, the nearest clicked frame beyond; in frame order."""
    near = {f for f in frames if f != target and abs(f - target) <= window}
    for side in (-1, 1):
        if any(frames[f] and (f - target) * side > 0 for f in near):
            continue
        beyond = [f for f, clicked in frames.items() if clicked and (f - target) * side > window]
        if beyond:
            near.add(min(beyond, key=lambda f: abs(f - target)))
    return sorted(near)

"""Cameras files: which intrinsics belong to which image, by a glob on the image's file name.

::

    {"cameras": [{"match": "*Camera_5*", "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "distortion": [k1, ...]},
                 {"match": "*", "K": [...]}]}

The first entry whose ``match`` fits the file name (``fnmatch``, case-sensitive, ``*`` crosses ``/``) wins.
``distortion`` is optional (OpenCV order, 4, 5, 8, 12 or 14 numbers).
"""

from __future__ import annotations

from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from toosicubix.annotations.schema import CameraModel
from toosicubix.errors import FormatError
from toosicubix.jsonfile import json_field, read_json


@dataclass(frozen=True)
class CameraRule:
    """One entry of a cameras file.

    Attributes
    ----------
    match : glob on the image file name
    camera : the annotation file v1 ``camera`` object, ``{"K": 3x3[, "distortion": [...]]}``
    """

    match: str
    camera: dict[str, Any]


@dataclass(frozen=True)
class CameraTable:
    """The entries of a cameras file, in order."""

    rules: tuple[CameraRule, ...]
    source: str

    def camera_for(self, file_name: str) -> dict[str, Any] | None:
        """The ``camera`` object of the first entry whose glob fits ``file_name``, or None."""
        for rule in self.rules:
            if fnmatchcase(file_name, rule.match):
                return rule.camera
        return None


def load_cameras(path: str | Path) -> CameraTable:
    """Read a cameras file.

    Raises
    ------
    FormatError
        Not JSON, no ``cameras`` list, an entry without ``match`` or with a bad ``K`` or ``distortion``:
        naming the file and the JSON path.
    """
    path = Path(path)
    doc = read_json(path)
    rules = []
    for i, entry in enumerate(json_field(doc, "cameras", list, path, "$")):
        where = f"$.cameras[{i}]"
        match = json_field(entry, "match", str, path, where)
        unknown = sorted(set(entry) - {"match", "K", "distortion"})
        if unknown:
            raise FormatError(path, f"{where}: unknown field {unknown[0]!r} (expected match, K, distortion)")
        camera = {key: entry[key] for key in ("K", "distortion") if key in entry}
        if "K" not in camera:
            raise FormatError(path, f"{where}.K: missing")
        try:
            CameraModel.model_validate(camera)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = "".join(f"[{item}]" if isinstance(item, int) else f".{item}" for item in err["loc"])
            raise FormatError(path, f"{where}{loc}: {err['msg'].removeprefix('Value error, ')}") from None
        rules.append(CameraRule(match, camera))
    return CameraTable(tuple(rules), str(path))

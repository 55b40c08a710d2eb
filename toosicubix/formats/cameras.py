"""Cameras for the importers (``--cameras``): which intrinsics belong to which image.

Four forms are read, told apart by their content (a folder by being one):

- **our JSON cameras file**, a glob on the image's file name per entry::

      {"cameras": [{"match": "*Camera_5*", "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "distortion": [k1, ...]},
                   {"match": "*", "K": [fx, 0, cx, 0, fy, cy, 0, 0, 1]}]}

  The first entry whose ``match`` fits the file name (``fnmatch``, case-sensitive, ``*`` crosses ``/``) wins.
  ``K`` is 3x3, or 9 numbers row by row; ``distortion`` is optional (OpenCV order, 4, 5, 8, 12 or 14 numbers).
- **a KITTI calibration file** (``P2: p00 ... p23``, 12 numbers; ``P_rect_02`` of a raw-data
  ``calib_cam_to_cam.txt`` too): its ``P2`` for every image, as the annotation file's ``{"P": 3x4}``, so that
  the KITTI label files ``fit`` writes are in the rectified camera 0 frame, as KITTI's ground truth is.
- **a folder of KITTI calibration files**: each image's ``P2`` from ``<folder>/<image file stem>.txt``
  (KITTI's ``calib/000123.txt`` for ``image_2/000123.png``); an image without one has no camera.
- **an OpenCV or ROS camera YAML**, one camera for every image: ROS ``camera_info`` (``camera_matrix: {rows: 3,
  cols: 3, data: [...]}``, ``distortion_coefficients``, ``distortion_model``, as ``camera_calibration`` writes
  it) or OpenCV ``FileStorage`` (``%YAML:1.0``, ``camera_matrix: !!opencv-matrix {rows, cols, dt, data}``,
  ``distortion_coefficients``). These two fixed layouts are read here (:func:`read_camera_yaml`), not by a YAML
  library: PyYAML is no dependency and rejects OpenCV's ``%YAML:1.0`` directive, and OpenCV's ``FileStorage``
  reads both but reports a bad file as a C++ assertion without a line. ROS's ``equidistant`` (fisheye) model
  is refused: its 4 coefficients are not OpenCV's standard ``k1, k2, p1, p2``.

Every refusal names the file, the place (JSON path or line) and what was expected there; a file in none of
the forms is refused naming all four (:data:`ACCEPTED`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from pydantic import ValidationError

from toosicubix import fields
from toosicubix.annotations.schema import CameraModel
from toosicubix.errors import FormatError
from toosicubix.fields import shown
from toosicubix.formats.kitti import read_text
from toosicubix.jsonfile import json_field, read_json

#: The forms ``--cameras`` takes, for refusals.
ACCEPTED = ('a cameras JSON file {"cameras": [{"match": GLOB, "K": 3x3 or 9 numbers, "distortion": [...]}]}, '
            "a KITTI calib file (a line 'P2:' with 12 numbers), a folder of KITTI calib files (<image stem>.txt), "
            "or an OpenCV or ROS camera YAML (camera_matrix with rows, cols and data)")
#: The distortion coefficient counts OpenCV's standard model takes (the annotation file's ``distortion``).
DISTORTION_COUNTS = (4, 5, 8, 12, 14)
#: The largest distortion coefficient magnitude the annotation file takes.
MAX_DISTORTION = 1e6
#: ROS ``distortion_model`` values whose coefficients are OpenCV's standard model (``plumb_bob``: 5,
#: ``rational_polynomial``: 8).
ROS_MODELS = ("plumb_bob", "rational_polynomial")
_K_SHAPE = "a 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] or 9 numbers row by row"
_DISTORTION_SHAPE = ("4, 5, 8, 12 or 14 numbers (OpenCV order k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, "
                     "ty]]]])")


@dataclass(frozen=True)
class CameraRule:
    """One entry of a cameras file.

    Attributes
    ----------
    match : glob on the image file name
    camera : the annotation file v1 ``camera`` object, ``{"K": 3x3[, "distortion": [...]]}`` or ``{"P": 3x4}``
    """

    match: str
    camera: dict[str, Any]


@dataclass(frozen=True)
class CameraTable:
    """Cameras by image file name: the entries of a cameras file in order, or (a folder of KITTI calibration
    files) one camera per image file stem.

    Attributes
    ----------
    rules : globs and their cameras; the first that fits wins
    source : the file or folder, for messages
    by_stem : image file stem -> camera, for a folder of KITTI calibration files (``rules`` is then empty)
    """

    rules: tuple[CameraRule, ...]
    source: str
    by_stem: Mapping[str, dict[str, Any]] | None = field(default=None, compare=False)

    def camera_for(self, file_name: str) -> dict[str, Any] | None:
        """The ``camera`` object of ``file_name``: of the first entry whose glob fits it, or of its stem's
        calibration file; None when there is none."""
        if self.by_stem is not None:
            return self.by_stem.get(_stem(file_name))
        for rule in self.rules:
            if fnmatchcase(file_name, rule.match):
                return rule.camera
        return None

    def why_none(self, file_name: str) -> str:
        """Why :meth:`camera_for` gives ``file_name`` no camera, for messages."""
        if self.by_stem is not None:
            return f"no KITTI calib file {Path(self.source) / (_stem(file_name) + '.txt')}"
        return f"no entry of {self.source} matches it"


def intrinsics(camera: Mapping[str, Any]) -> np.ndarray:
    """The (3, 3) ``K`` of an annotation file ``camera`` object: its ``K``, or ``P[:, :3]`` of a KITTI ``P`` (the
    camera's rays; its offset ``K^-1 P[:, 3]`` from the reference camera, some 6 cm for KITTI, is not in K)."""
    if "K" in camera:
        return np.array(camera["K"], dtype=float).reshape(3, 3)
    return np.array(camera["P"], dtype=float).reshape(3, 4)[:, :3]


def _stem(file_name: str) -> str:
    return PurePosixPath(file_name.replace("\\", "/")).stem


def load_cameras(path: str | Path) -> CameraTable:
    """Read ``--cameras``: a cameras JSON file, a KITTI calibration file or a folder of them, or an OpenCV or ROS
    camera YAML (see the module).

    Raises
    ------
    FormatError
        Missing, unreadable or in none of the forms (naming them all); a bad entry, line or matrix, naming the
        file, the JSON path or line and what was expected there.
    """
    path = Path(path)
    if path.is_dir():
        return _kitti_folder(path)
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096).decode("utf-8-sig", errors="replace")
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror or exc}; expected {ACCEPTED}") from None
    kind = _kind(head)
    if kind == "json":
        return _json_cameras(path)
    if kind == "kitti":
        return CameraTable((CameraRule("*", kitti_P2_camera(path)),), str(path))
    if kind == "yaml":
        return CameraTable((CameraRule("*", read_camera_yaml(path)),), str(path))
    raise FormatError(path, f"not a cameras file: expected {ACCEPTED}")


_KITTI_KEY = re.compile(r"^\s*(P[0-3]|P_rect_0[0-3])\s*:", re.MULTILINE)
_YAML_HINT = re.compile(r"^\s*(%YAML|camera_matrix\s*:)", re.MULTILINE)


def _kind(head: str) -> str | None:
    """'json', 'kitti', 'yaml' or None, from the first characters of a file."""
    text = head.lstrip()
    if text[:1] in ("{", "["):
        return "json"
    if _YAML_HINT.search(head):
        return "yaml"
    if _KITTI_KEY.search(head):
        return "kitti"
    return None


def _checked(camera: dict[str, Any], path: Path, where: str | None, line: int | None = None) -> dict[str, Any]:
    """``camera`` once the annotation file's camera rules pass (invertible K, focal lengths in range, ...).

    Raises
    ------
    FormatError
        The first rule broken, at ``where`` (a JSON path) or ``line``.
    """
    try:
        CameraModel.model_validate(camera)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = "".join(f"[{item}]" if isinstance(item, int) else f".{item}" for item in err["loc"])
        message = err["msg"].removeprefix("Value error, ")
        if where is not None:
            raise FormatError(path, f"{where}{loc}: {message}") from None
        raise FormatError(path, f"{loc.lstrip('.') or 'camera'}: {message}", line) from None
    return camera


def _json_K(K: Any, path: Path, where: str) -> list:
    """``K`` as 3x3 rows: as given when 3x3, else from 9 numbers row by row."""
    if isinstance(K, list) and len(K) == 9 and all(fields.passes(fields.number, v) for v in K):
        return [K[0:3], K[3:6], K[6:9]]
    if isinstance(K, list) and len(K) == 3 and all(
            isinstance(r, list) and len(r) == 3 and all(fields.passes(fields.number, v) for v in r) for r in K):
        return K
    raise FormatError(path, f"{where}.K: expected {_K_SHAPE}, got {shown(K, 80)}")


def _json_distortion(d: Any, path: Path, where: str) -> list:
    if not (isinstance(d, list) and all(fields.passes(fields.number, v) for v in d) and len(d) in DISTORTION_COUNTS):
        raise FormatError(path, f"{where}.distortion: expected {_DISTORTION_SHAPE}, got {shown(d, 80)}")
    if any(abs(v) > MAX_DISTORTION for v in d):
        raise FormatError(path, f"{where}.distortion: expected coefficients within +-{MAX_DISTORTION:g}, got {d}")
    return d


def _json_cameras(path: Path) -> CameraTable:
    doc = read_json(path)
    if not isinstance(doc, dict) or "cameras" not in doc:
        raise FormatError(path, f'$.cameras: missing: expected {ACCEPTED}')
    rules = []
    for i, entry in enumerate(json_field(doc, "cameras", list, path, "$")):
        where = f"$.cameras[{i}]"
        match = json_field(entry, "match", str, path, where)
        unknown = sorted(set(entry) - {"match", "K", "distortion"})
        if unknown:
            raise FormatError(path, f"{where}: unknown field {unknown[0]!r} (expected match, K, distortion)")
        if "K" not in entry:
            raise FormatError(path, f"{where}.K: missing")
        camera: dict[str, Any] = {"K": _json_K(entry["K"], path, where)}
        if "distortion" in entry:
            camera["distortion"] = _json_distortion(entry["distortion"], path, where)
        rules.append(CameraRule(match, _checked(camera, path, where)))
    return CameraTable(tuple(rules), str(path))


# --- KITTI -------------------------------------------------------------------------------------------------------

def kitti_P2_camera(path: Path) -> dict[str, Any]:
    """The annotation file's camera of a KITTI calibration file: ``{"P": P2 (3x4)}`` (``P_rect_02`` in a raw-data
    ``calib_cam_to_cam.txt``).

    Raises
    ------
    FormatError
        No ``P2:`` line, not 12 finite numbers, or not a camera's ``K [I | t]``: naming the file and line.
    """
    text = read_text(path)
    for number, line in enumerate(text.splitlines(), 1):
        key, sep, rest = line.partition(":")
        if not sep or key.strip() not in ("P2", "P_rect_02"):
            continue
        try:  # decimal notation only (fields.text_number): '4_01.2' and 'nan' are refused
            values = [fields.text_number(v, path, number) for v in rest.split()]
        except fields.FieldError:
            values = []
        if len(values) != 12:
            raise FormatError(path, f"{key.strip()}: expected 12 numbers (the 3x4 projection matrix of camera 2, row "
                                    f"by row), got {rest.strip()[:80]!r}", number)
        P = [values[0:4], values[4:8], values[8:12]]
        return _checked({"P": P}, path, None, number)
    raise FormatError(path, "a KITTI calib file needs a line 'P2:' with 12 numbers (camera 2's projection matrix); "
                            "none found")


def _kitti_folder(folder: Path) -> CameraTable:
    files = sorted(p for p in folder.iterdir() if p.suffix == ".txt" and p.is_file())
    if not files:
        calib = folder / "calib"
        hint = f" (did you mean {calib}?)" if calib.is_dir() else ""
        raise FormatError(folder, f"a folder of KITTI calib files needs <image stem>.txt files; found none{hint}. "
                                  f"--cameras takes {ACCEPTED}")
    return CameraTable((), str(folder), {p.stem: kitti_P2_camera(p) for p in files})


# --- OpenCV and ROS camera YAML ------------------------------------------------------------------------------------

@dataclass
class _Node:
    """A value of the small YAML subset read here: a scalar (str), a list of scalars, or a mapping of nodes."""

    value: Any
    line: int


_YAML_LAYOUTS = ("ROS camera_info: camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}; "
                 "OpenCV: camera_matrix: !!opencv-matrix {rows: 3, cols: 3, dt: d, data: [...]}")


def _yaml_error(path: Path, line: int | None, message: str) -> FormatError:
    return FormatError(path, f"{message} (an OpenCV or ROS camera YAML: {_YAML_LAYOUTS})", line)


def _strip_comment(line: str) -> str:
    quote = None
    for i, ch in enumerate(line):
        if ch in "\"'" and quote in (None, ch):
            quote = None if quote else ch
        elif ch == "#" and quote is None and (i == 0 or line[i - 1] in " \t"):
            return line[:i]
    return line


def _flow_items(text: str, path: Path, line: int) -> list[str]:
    inner = text.strip()
    if not (inner.startswith("[") and inner.endswith("]")):
        raise _yaml_error(path, line, f"expected a list [a, b, ...], got {text.strip()[:60]!r}")
    items = [item.strip() for item in inner[1:-1].split(",")]
    if items and items[-1] == "":
        items.pop()
    if any(not item or item.startswith(("[", "{")) for item in items):
        raise _yaml_error(path, line, f"expected a flat list of numbers, got {text.strip()[:60]!r}")
    return items


def _yaml_document(text: str, path: Path) -> dict[str, _Node]:
    """The two-level mapping of an OpenCV or ROS camera YAML: ``key: scalar``, ``key: [flow, list]`` (on one line
    or several), ``key:`` followed by ``- item`` lines, or ``key:`` followed by an indented mapping of the same.
    Comments, ``%`` directives, ``---`` and tags (``!!opencv-matrix``) are skipped."""
    top: dict[str, _Node] = {}
    parent: _Node | None = None  # the top-level key whose indented mapping is being filled
    opened: tuple[_Node, int] | None = None  # a key without a value, and its indent: '- item' lines may follow
    flow: tuple[_Node, int, list[str]] | None = None  # a '[' list that spans lines, its key's indent
    for number, raw in enumerate(text.splitlines(), 1):
        line = _strip_comment(raw).rstrip()
        content = line.strip()
        if flow is not None and content:
            if len(line) - len(line.lstrip()) <= flow[1]:  # continuation lines are indented past the key
                raise _yaml_error(path, flow[0].line, "a list opened with '[' is never closed")
            flow[2].append(content)
            if "]" in content:
                flow[0].value = _flow_items(" ".join(flow[2]), path, flow[0].line)
                flow = None
            continue
        if not content or content.startswith(("%", "---", "...")):
            continue
        margin = line[: len(line) - len(line.lstrip())]
        if "\t" in margin:
            raise _yaml_error(path, number, "expected spaces for indentation, found a tab")
        indent = len(margin)
        if content == "-" or content.startswith("- "):
            item = content[1:].strip()
            if opened is None or indent < opened[1]:
                raise _yaml_error(path, number, f"a list item {content[:40]!r} where no key opened a list")
            if not item or item.startswith(("[", "{", "-")) or ": " in item:
                raise _yaml_error(path, number, f"expected a list of numbers, got {content[:60]!r}")
            node = opened[0]
            if not isinstance(node.value, list):
                node.value = []
            node.value.append(item.strip("\"'"))
            continue
        key, sep, rest = content.partition(":")
        key, rest = key.strip().strip("\"'"), rest.strip()
        if not sep or not key:
            raise _yaml_error(path, number, f"expected 'key: value', got {content[:60]!r}")
        if rest.startswith("!"):  # a tag: !!opencv-matrix
            rest = rest.partition(" ")[2].strip()
        if indent == 0:
            mapping, parent = top, None
        elif parent is not None and isinstance(parent.value, dict):
            mapping = parent.value
        else:
            raise _yaml_error(path, number, f"{key!r} is indented under a key that holds no mapping")
        if key in mapping:
            raise _yaml_error(path, number, f"{key!r} given twice")
        node = mapping[key] = _Node(None, number)
        opened = None
        if rest.startswith("{"):
            raise _yaml_error(path, number, f"{key}: expected its keys one per line, not {{...}}")
        if rest.startswith("[") and "]" in rest:
            node.value = _flow_items(rest, path, number)
        elif rest.startswith("["):
            flow = (node, indent, [rest])
        elif rest:
            node.value = rest.strip("\"'")
        else:
            opened = (node, indent)
            if indent == 0:
                node.value, parent = {}, node
    if flow is not None:
        raise _yaml_error(path, flow[0].line, "a list opened with '[' is never closed")
    return top


def _yaml_numbers(node: _Node, path: Path, name: str) -> list[float]:
    items = node.value if isinstance(node.value, list) else None
    try:  # decimal notation only (fields.text_number): '4_01.2', '.nan' and other scripts' digits are refused
        values = [fields.text_number(v, path, node.line) for v in items] if items is not None else None
    except fields.FieldError:
        values = None
    if values is None:
        raise _yaml_error(path, node.line, f"{name}: expected a list of finite numbers, got {shown(node.value)}")
    return values


def _yaml_matrix(doc: dict[str, _Node], key: str, path: Path) -> tuple[list[float], int, int, int]:
    """A matrix node ``{rows, cols, data}``: its numbers row by row, rows, cols and its line."""
    node = doc[key]
    if not isinstance(node.value, dict):
        raise _yaml_error(path, node.line, f"{key}: expected rows, cols and data one level down")
    members = node.value
    for name in ("rows", "cols", "data"):
        if name not in members:
            raise _yaml_error(path, node.line, f"{key}.{name}: missing")
    try:
        rows, cols = (fields.text_integer(members[name].value if isinstance(members[name].value, str) else None,
                                          path, node.line, low=0, high=1000) for name in ("rows", "cols"))
    except fields.FieldError:
        raise _yaml_error(path, node.line, f"{key}: expected integer rows and cols, got "
                                           f"{shown(members['rows'].value, 20)} and {shown(members['cols'].value, 20)}"
                          ) from None
    data = _yaml_numbers(members["data"], path, f"{key}.data")
    if len(data) != rows * cols:
        raise _yaml_error(path, members["data"].line, f"{key}.data: expected {rows * cols} numbers (rows {rows} x "
                                                     f"cols {cols}), got {len(data)}")
    return data, rows, cols, node.line


def read_camera_yaml(path: str | Path) -> dict[str, Any]:
    """The annotation file's camera of an OpenCV or ROS camera YAML: ``{"K": 3x3[, "distortion": [...]]}``.

    Raises
    ------
    FormatError
        Not the layout (see the module), a matrix of the wrong shape, an unsupported distortion model or a K
        that is no camera's: naming the file, the line and the layout expected.
    """
    path = Path(path)
    doc = _yaml_document(read_text(path), path)
    if "camera_matrix" not in doc:
        raise _yaml_error(path, None, "camera_matrix: missing")
    data, rows, cols, line = _yaml_matrix(doc, "camera_matrix", path)
    if (rows, cols) != (3, 3):
        raise _yaml_error(path, line, f"camera_matrix: expected rows 3 and cols 3, got {rows} and {cols}")
    camera: dict[str, Any] = _checked({"K": [data[0:3], data[3:6], data[6:9]]}, path, None, line)
    model = doc.get("distortion_model")
    if model is not None and model.value not in ROS_MODELS:
        raise _yaml_error(path, model.line, f"distortion_model: expected {' or '.join(ROS_MODELS)} (OpenCV's "
                                            f"standard model), got {model.value!r:.40}")
    if "distortion_coefficients" in doc:
        dist, rows, cols, line = _yaml_matrix(doc, "distortion_coefficients", path)
        if dist and any(dist):
            if min(rows, cols) != 1 or len(dist) not in DISTORTION_COUNTS or max(map(abs, dist)) > MAX_DISTORTION:
                raise _yaml_error(path, line, f"distortion_coefficients: expected one row of {_DISTORTION_SHAPE} "
                                              f"within +-{MAX_DISTORTION:g}, got {rows} x {cols}")
            camera["distortion"] = dist
    return _checked(camera, path, None, line)

"""Label Studio's JSON export -> annotation file v1.

The export is a list of tasks ``{"id", "data": {"image": URL}, "annotations": [{"id", "result": [...],
"was_cancelled"}], ...}`` (exports of old versions say ``completions`` instead of ``annotations``). Results
this importer reads:

- ``rectanglelabels``: one vehicle; its label is the prototype, its box ``box2d``;
- ``keypointlabels``: one keypoint named by its label (:mod:`toosicubix.parts.keypoints`); ``value.x`` and
  ``value.y`` are **percent** of ``original_width`` / ``original_height``;
- ``relation`` (``from_id``, ``to_id``): ties a keypoint to a box, like ``parentID``.

A keypoint belongs to the box named by its ``parentID`` (set when the point is nested under the box), else
to the box a relation ties it to, else to the one box that contains it (grown by 10 % each way); an image
without any box makes one vehicle of all its keypoints. Anything else is a warning naming the task, the
image and the region id.

The image's file name (the annotation file's ``file``; its stem is the image id) is what the person named the
file, not what Label Studio made of it (:func:`original_file_name`):

- an uploaded file, ``/data/upload/<project id>/<8 hex>-<name>`` (the 8 lowercase hex digits are the start of a
  uuid4 Label Studio adds: ``upload_name_generator`` in ``label_studio/data_import/models.py``), also after a
  host or a script name: ``<name>``, percent-decoded;
- a local file, ``/data/local-files/?d=<path>`` (``io_storages/localfiles/models.py``): ``<path>``,
  percent-decoded; a path with a ``..`` component is refused;
- a cloud storage object, ``s3://<bucket>/<key>``, ``gs://<bucket>/<key>``, ``azure-blob://<container>/<key>``
  (``io_storages/{s3,gcs,azure_blob}/models.py``): the key's base name;
- any other http(s) URL: its path, percent-decoded; anything else as it is.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import unquote, urlparse

from toosicubix import fields
from toosicubix.errors import FormatError
from toosicubix.fields import shown
from toosicubix.formats.cameras import CameraTable
from toosicubix.formats.tool_import import DocumentBuilder, ImportSummary, ToolKeypoint, ToolVehicle
from toosicubix.jsonfile import read_json

#: How far a box is grown, as a share of its size each way, when keypoints are grouped by containment.
CONTAINMENT_MARGIN = 0.1


#: How far outside its image a region may reach, in percent of the image (``value.x``, ``y``, ``width``,
#: ``height``): 100 times the image's size; a point beyond is a typo, not a click.
MAX_PERCENT = 1e4


def _percent(value: Any, path: Path, where: str) -> float:
    return fields.number(value, path, where, low=-MAX_PERCENT, high=MAX_PERCENT,
                         what="a percentage of the image's size")


def _region_id(value: Any, path: Path, where: str) -> str:
    """A region's ``id`` (or a ``parentID``, ``from_id``, ``to_id``) as the text that ties regions together."""
    return str(fields.identifier(value, path, where, what="a region id"))


#: An uploaded file as Label Studio names it: ``/data/upload/<project id>/<8 lowercase hex digits>-<name>``
#: (``upload_name_generator``, label_studio/data_import/models.py: ``str(uuid.uuid4())[0:8] + '-' + filename``
#: under ``UPLOAD_DIR`` 'upload', served at ``MEDIA_URL`` '/data/'); anything may come before ``/data``
#: (a host, a script name).
UPLOAD_NAME = re.compile(r"(?:^|/)data/upload/[0-9]+/[0-9a-f]{8}-(?P<name>[^/]+)$")
#: Label Studio's cloud storage URLs, ``<scheme>://<bucket or container>/<object key>`` (``get_data`` of
#: io_storages/s3, gcs and azure_blob).
STORAGE_SCHEMES = ("s3", "gs", "azure-blob")


def original_file_name(value: str, path: Path, where: str) -> str:
    """The file name the person gave an image, from a task's image URL as Label Studio exports it (the rule of
    the module's docstring).

    Parameters
    ----------
    value : the task's ``data`` value, e.g. ``/data/upload/3/9f834e14-000001.png``
    path, where : the export and the JSON path (and task), for the error

    Raises
    ------
    FormatError
        A value Python's URL parser refuses (``http://[abc/x.png``), or a file name with a ``..`` component (a local
        files path, an http path or a plain value: the annotation file's ``file`` is relative to it, and a ``..``
        would reach out of that folder).
    """
    try:
        name = _file_name_of(value, path, where)
    except FormatError:
        raise
    except ValueError as exc:  # urlparse: 'Invalid IPv6 URL', a port out of range, ...
        raise FormatError(path, f"{where}: expected an image URL or file name, got {shown(value)}: {exc}") from None
    if ".." in re.split(r"[/\\]", name):
        raise FormatError(path, f"{where}: the file name {shown(name)} (from {shown(value)}) has a '..' component: "
                                "refused (expected a path inside the folder the images are in)")
    return name


def _file_name_of(value: str, path: Path, where: str) -> str:
    parsed = urlparse(value)
    if parsed.scheme in STORAGE_SCHEMES:  # the object key as Label Studio keeps it, not percent-decoded
        return PurePosixPath(urlparse(value, allow_fragments=False).path).name or value
    local = [item[2:] for item in parsed.query.split("&") if item.startswith("d=")] if parsed.query else []
    if local:  # local files: /data/local-files/?d=folder/image.png
        name = unquote(local[0])
        if ".." in re.split(r"[/\\]", name):
            raise FormatError(path, f"{where}: the local-files path {shown(name)} has a '..' component: refused "
                                    "(expected a path inside Label Studio's LOCAL_FILES_DOCUMENT_ROOT)")
        return name
    if parsed.scheme in ("http", "https"):
        value = unquote(parsed.path)
    upload = UPLOAD_NAME.search(parsed.path if parsed.scheme else value)
    if upload is not None:
        return unquote(upload.group("name"))
    return value


def _file_name(data: dict[str, Any], image_key: str | None, path: Path, where: str, task_id: Any) -> str | None:
    key = image_key or "image"
    value = data.get(key)
    if value is None and image_key is None:
        key, value = next(((k, v) for k, v in data.items() if isinstance(v, str)), (key, None))
    if not isinstance(value, str):
        return None
    return original_file_name(value, path, f"{where}.data.{key} (task {shown(task_id)})")


def _pick_annotation(task: dict[str, Any], where: str, builder: DocumentBuilder, name: str,
                     path: Path) -> tuple[dict[str, Any] | None, str]:
    key = "annotations" if "annotations" in task else "completions"
    entries = task.get(key) or []
    if not isinstance(entries, list):
        raise FormatError(path, f"{where}.{key}: expected a list")
    usable = [(i, a) for i, a in enumerate(entries) if isinstance(a, dict) and not a.get("was_cancelled")]
    if not usable:
        return None, key
    if len(usable) > 1:
        builder.warn(name, f"task {shown(task.get('id'))}", f"{len(usable)} annotations: the last one "
                                                             f"({key}[{usable[-1][0]}]) is used")
    index, annotation = usable[-1]
    return annotation, f"{where}.{key}[{index}]"


def _regions(result: list[Any], path: Path, where: str) -> tuple[list[dict], list[dict], list[dict], tuple | None]:
    boxes, points, relations = [], [], []
    size = None
    for j, region in enumerate(result):
        rw = f"{where}.result[{j}]"
        if not isinstance(region, dict):
            raise FormatError(path, f"{rw}: expected an object")
        kind = region.get("type")
        if kind == "relation":
            relations.append(region)
            continue
        if kind not in ("rectanglelabels", "keypointlabels"):
            continue
        value = region.get("value")
        if not isinstance(value, dict):
            raise FormatError(path, f"{rw}.value: missing")
        width = fields.image_side(region.get("original_width"), path, f"{rw}.original_width")
        height = fields.image_side(region.get("original_height"), path, f"{rw}.original_height")
        if size is None:
            size = (width, height)
        if region.get("image_rotation", 0) not in (0, 0.0, None):
            raise FormatError(path, f"{rw}.image_rotation: rotated images are not supported "
                                    f"(got {shown(region['image_rotation'])})")
        labels = value.get(kind)
        if not isinstance(labels, list) or len(labels) != 1 or not isinstance(labels[0], str):
            raise FormatError(path, f"{rw}.value.{kind}: expected one label, got {shown(labels)}")
        x = _percent(value.get("x"), path, f"{rw}.value.x") / 100.0 * width
        y = _percent(value.get("y"), path, f"{rw}.value.y") / 100.0 * height
        parent = region.get("parentID")
        entry = {"id": _region_id(region.get("id", j), path, f"{rw}.id"), "label": labels[0], "where": rw, "x": x,
                 "y": y, "parent": None if parent is None else _region_id(parent, path, f"{rw}.parentID")}
        if kind == "rectanglelabels":
            w = _percent(value.get("width"), path, f"{rw}.value.width") / 100.0 * width
            h = _percent(value.get("height"), path, f"{rw}.value.height") / 100.0 * height
            entry["box"] = (x, y, x + w, y + h)
            entry["rotated"] = bool(value.get("rotation", 0))
            boxes.append(entry)
        else:
            points.append(entry)
    return boxes, points, relations, size


def _tie(value: Any) -> str | None:
    """A relation's ``from_id`` or ``to_id`` as a region id (:func:`_region_id`), or None when it is none (a
    relation that ties nothing is left unused, as one naming no region of the annotation)."""
    try:
        return _region_id(value, None, None)  # type: ignore[arg-type]
    except fields.FieldError:
        return None


def _inside(box: tuple[float, float, float, float], x: float, y: float) -> bool:
    mx = CONTAINMENT_MARGIN * (box[2] - box[0])
    my = CONTAINMENT_MARGIN * (box[3] - box[1])
    return box[0] - mx <= x <= box[2] + mx and box[1] - my <= y <= box[3] + my


def read_label_studio(path: str | Path, cameras: CameraTable | None, default_prototype: str = "Car",
                      lengths: dict[str, tuple[float, float]] | None = None,
                      image_key: str | None = None) -> tuple[dict[str, Any], ImportSummary]:
    """Read a Label Studio JSON export into an annotation file v1 document.

    Parameters
    ----------
    path : the export (JSON, a list of tasks)
    cameras : intrinsics by image file name; every image needs one
    default_prototype : for vehicles without a box (no prototype label)
    lengths : known sizes of length features, feature -> (metres, sigma)
    image_key : the task ``data`` key of the image (default ``image``, else the first text value)

    Returns
    -------
    (document, summary)

    Raises
    ------
    FormatError
        Not JSON, not a list of tasks, malformed regions, an image without camera: naming the file and JSON path.
    toosicubix.fields.FieldError
        A value the field rules refuse (an image size of inf, nan or 400 digits, a percentage beyond
        :data:`MAX_PERCENT`, a region id that is a list): naming the file and JSON path.
    """
    path = Path(path)
    tasks = read_json(path)
    if isinstance(tasks, dict):  # a single task
        tasks = [tasks]
    if not isinstance(tasks, list):
        raise FormatError(path, "$: expected a list of tasks (Label Studio's JSON export)")
    builder = DocumentBuilder(str(path), cameras, default_prototype, lengths)
    for t, task in enumerate(tasks):
        where = f"$[{t}]"
        if not isinstance(task, dict) or not isinstance(task.get("data"), dict):
            raise FormatError(path, f"{where}.data: missing (not a Label Studio task)")
        name = _file_name(task["data"], image_key, path, where, task.get("id"))
        if name is None:
            raise FormatError(path, f"{where}.data: no image ({image_key or 'image'})")
        annotation, awhere = _pick_annotation(task, where, builder, name, path)
        if annotation is None:
            builder.warn(name, f"task {shown(task.get('id'))}", "no annotation that is not cancelled: image left out")
            continue
        result = annotation.get("result")
        if not isinstance(result, list):
            raise FormatError(path, f"{awhere}.result: expected a list")
        boxes, points, relations, size = _regions(result, path, awhere)
        builder.add_image(name, size, _vehicles(boxes, points, relations, builder, name, task.get("id")))
    return builder.document(), builder.summary


def _vehicles(boxes: list[dict], points: list[dict], relations: list[dict], builder: DocumentBuilder, name: str,
              task_id: Any) -> list[ToolVehicle]:
    vehicles = []
    by_id: dict[str, ToolVehicle] = {}
    for i, box in enumerate(boxes):
        vehicle = ToolVehicle(id=str(i + 1), element=f"task {shown(task_id)}, box {box['id']} ({box['where']})",
                              prototype=box["label"], box2d=None if box["rotated"] else box["box"])
        if box["rotated"]:
            builder.warn(name, vehicle.element, "rotated box: not used as box2d")
        vehicles.append(vehicle)
        by_id[box["id"]] = vehicle
    related: dict[str, str] = {}
    for rel in relations:
        a, b = (_tie(rel.get(key)) for key in ("from_id", "to_id"))
        if a is None or b is None:
            continue
        if a in by_id and b not in by_id:
            related[b] = a
        elif b in by_id and a not in by_id:
            related[a] = b
    loose: list[ToolKeypoint] = []
    for point in points:
        element = f"task {shown(task_id)}, keypoint {point['id']} {shown(point['label'])} ({point['where']})"
        keypoint = ToolKeypoint(point["label"], (point["x"], point["y"]), element)
        parent = point["parent"]
        if parent is not None and parent in by_id:
            by_id[parent].keypoints.append(keypoint)
            continue
        if parent is not None:
            builder.warn(name, element, f"parentID {shown(parent)} is not a vehicle box of this annotation")
        if point["id"] in related:
            by_id[related[point["id"]]].keypoints.append(keypoint)
            continue
        holders = [v for v, box in zip(vehicles, boxes, strict=True) if _inside(box["box"], *keypoint.xy)]
        if len(holders) == 1:
            holders[0].keypoints.append(keypoint)
        elif not boxes:
            loose.append(keypoint)
        else:
            why = "inside no vehicle box" if not holders else f"inside {len(holders)} vehicle boxes"
            builder.warn(name, element, f"cannot be grouped to a vehicle (no parentID, no relation, {why}): "
                                        "left out")
            builder.summary.left_out[keypoint.name] += 1
    if loose:
        vehicles.append(ToolVehicle(id="1", element=f"task {shown(task_id)}, keypoints without a box",
                                    keypoints=loose))
    return vehicles

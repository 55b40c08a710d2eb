"""CVAT for images 1.1 XML -> annotation file v1 (the review export is :mod:`toosicubix.formats.cvat_export`).

Import (as CVAT's ``dump_as_cvat_annotation`` writes it, task, job or project export)::

    <annotations><version>1.1</version><meta><task|project|job>...<labels>...</labels>...</meta>
      <image id="0" name="frames/000001.png" width="1242" height="375" [subset task_id]>
        <skeleton label="vehicle" source="manual" z_order="0">
          <points label="wheel-front-left" source="manual" outside="0" occluded="0" points="401.20,202.00"/>
          <points label="rear-pair1-left" source="manual" outside="1" occluded="0" points="0.00,0.00"/>
          <attribute name="prototype">Car</attribute>
        </skeleton>
        <points label="rear-center" source="manual" occluded="0" points="769.00,243.80" z_order="0" group_id="2"/>
        <box label="Car" source="manual" occluded="0" xtl=".." ytl=".." xbr=".." ybr=".." z_order="0" group_id="2"/>
      </image>

- A ``skeleton`` is one vehicle; its ``points`` children are its keypoints, named by their label
  (:mod:`toosicubix.parts.keypoints`); ``outside="1"`` marks a keypoint not clicked (left out), ``occluded="1"``
  one clicked where it is hidden (kept). The ``prototype`` attribute names the size prior.
- Loose ``points`` shapes are grouped into vehicles by ``group_id``; a ``box`` in the group gives the box
  and the prototype (its ``prototype`` attribute, else its label). In an image without skeletons or groups,
  all loose points are one vehicle.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix.errors import FormatError
from toosicubix.formats.cameras import CameraTable
from toosicubix.formats.templates import PROTOTYPE_ATTRIBUTE
from toosicubix.formats.tool_import import DocumentBuilder, ImportSummary, ToolKeypoint, ToolVehicle


def _parse(path: Path) -> ET.Element:
    try:
        if "<!DOCTYPE" in path.read_text(encoding="utf-8", errors="replace")[:4096].upper():
            raise FormatError(path, "a DOCTYPE is not allowed in CVAT XML (entities are not expanded)")
        return ET.parse(path).getroot()
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror or exc}") from None
    except ET.ParseError as exc:
        raise FormatError(path, f"not valid XML: {exc}", exc.position[0]) from None


def _xy_list(text: str | None, path: Path, where: str) -> list[tuple[float, float]]:
    try:
        pairs = [tuple(float(v) for v in item.split(",")) for item in (text or "").split(";") if item.strip()]
    except ValueError:
        pairs = [()]
    if not pairs or any(len(p) != 2 or not all(np.isfinite(p)) for p in pairs):
        raise FormatError(path, f"{where}: expected points=\"x,y[;x,y...]\", got {text!r:.60}")
    return [(p[0], p[1]) for p in pairs]


def _attributes(element: ET.Element) -> dict[str, str]:
    return {a.get("name", ""): (a.text or "").strip() for a in element.findall("attribute")}


def read_cvat(path: str | Path, cameras: CameraTable | None, default_prototype: str = "Car",
              lengths: dict[str, tuple[float, float]] | None = None) -> tuple[dict[str, Any], ImportSummary]:
    """Read a CVAT for images 1.1 ``annotations.xml`` into an annotation file v1 document.

    Parameters
    ----------
    path : the XML file (from a task, job or project export)
    cameras : intrinsics by image name; every image with vehicles needs one
    default_prototype : for vehicles without a prototype attribute or box
    lengths : known sizes of length features, feature -> (metres, sigma)

    Returns
    -------
    (document, summary)

    Raises
    ------
    FormatError
        Not XML, not CVAT for images 1.1 (e.g. CVAT for video's tracks), malformed shapes, an image without a
        camera: naming the file and the image and element.
    """
    path = Path(path)
    root = _parse(path)
    if root.tag != "annotations":
        raise FormatError(path, f"expected <annotations> (CVAT for images 1.1), found <{root.tag}>")
    version = (root.findtext("version") or "").strip()
    if version and version != "1.1":
        raise FormatError(path, f"<version>: expected 1.1, found {version}")
    if root.find("track") is not None:
        raise FormatError(path, "<track> found: this is CVAT for video; export the task as CVAT for images 1.1")
    builder = DocumentBuilder(str(path), cameras, default_prototype, lengths)
    for image in root.findall("image"):
        name = image.get("name")
        if not name:
            raise FormatError(path, f"<image id={image.get('id')!r}>: missing name")
        where = f"<image id={image.get('id')!r} name={name!r}>"
        try:
            size = (int(image.get("width", "")), int(image.get("height", "")))
        except ValueError:
            raise FormatError(path, f"{where}: expected integer width and height") from None
        vehicles = _image_vehicles(image, path, where, builder, name)
        if not vehicles and image.find("*") is None:
            continue  # an image nobody labelled
        builder.add_image(name, size, vehicles)
    return builder.document(), builder.summary


def _image_vehicles(image: ET.Element, path: Path, where: str, builder: DocumentBuilder,
                    name: str) -> list[ToolVehicle]:
    vehicles: list[ToolVehicle] = []
    for s, skeleton in enumerate(image.findall("skeleton")):
        element = f"skeleton {s + 1} (label {skeleton.get('label')!r})"
        attrs = _attributes(skeleton)
        vehicle = ToolVehicle(id=str(len(vehicles) + 1), element=element, prototype=attrs.get(PROTOTYPE_ATTRIBUTE))
        for point in skeleton.findall("points"):
            label = point.get("label", "")
            pwhere = f"{where} {element}, points {label!r}"
            if point.get("outside", "0") == "1":
                continue
            xy = _xy_list(point.get("points"), path, pwhere)
            if len(xy) != 1:
                builder.warn(name, f"{element}, points {label!r}", f"{len(xy)} points in one element: left out")
                builder.summary.left_out[label] += 1
                continue
            vehicle.keypoints.append(ToolKeypoint(label, xy[0], f"{element}, points {label!r}"))
        vehicles.append(vehicle)
    groups: dict[str, ToolVehicle] = {}
    loose: list[ToolKeypoint] = []
    for index, shape in enumerate(image):
        if shape.tag not in ("points", "box"):
            continue
        label = shape.get("label", "")
        group = shape.get("group_id")
        element = f"{shape.tag} {index + 1} (label {label!r}{f', group_id {group}' if group else ''})"
        if group and group != "0" and group not in groups:
            groups[group] = ToolVehicle(id="", element=f"group_id {group}")
        if shape.tag == "box":
            if not group or group == "0":
                continue  # a box on its own is not ours
            try:
                box = tuple(float(shape.get(k, "")) for k in ("xtl", "ytl", "xbr", "ybr"))
            except ValueError:
                raise FormatError(path, f"{where} {element}: expected numbers xtl, ytl, xbr, ybr") from None
            groups[group].box2d = box  # type: ignore[assignment]
            groups[group].prototype = _attributes(shape).get(PROTOTYPE_ATTRIBUTE) or label
            continue
        xy = _xy_list(shape.get("points"), path, f"{where} {element}")
        if len(xy) != 1:
            builder.warn(name, element, f"{len(xy)} points in one shape: left out")
            builder.summary.left_out[label] += 1
            continue
        keypoint = ToolKeypoint(label, xy[0], element)
        if group and group != "0":
            groups[group].keypoints.append(keypoint)
            prototype = _attributes(shape).get(PROTOTYPE_ATTRIBUTE)
            if prototype and not groups[group].prototype:
                groups[group].prototype = prototype
        else:
            loose.append(keypoint)
    for group in sorted(groups, key=lambda g: int(g) if g.isdigit() else 0):
        groups[group].id = str(len(vehicles) + 1)
        vehicles.append(groups[group])
    if loose and not vehicles:
        vehicles.append(ToolVehicle(id="1", element="points without group_id", keypoints=loose))
    elif loose:
        for keypoint in loose:
            builder.warn(name, keypoint.element, "cannot be grouped to a vehicle (no group_id, and the image has "
                                                 "skeletons or groups): left out")
            builder.summary.left_out[keypoint.name] += 1
    return vehicles

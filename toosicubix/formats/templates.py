"""Label templates for the labelling tools: what a user pastes into CVAT, Label Studio or a COCO file.

Every template lists the flat keypoint vocabulary of :mod:`toosicubix.parts.keypoints`, one keypoint per
click, and the vehicle prototypes (size classes of the priors table) to choose from.

- CVAT: the Raw label JSON (a list of labels) for the label constructor or ``cvat-cli project create
  --labels``: a ``skeleton`` label ``vehicle`` with one ``points`` sublabel per keypoint, an ``svg`` with one
  ``<circle data-type="element node">`` per keypoint and ``<line data-type="edge">`` per edge, and a
  ``prototype`` select attribute; plus the two review labels ``toosicubix export cvat`` writes.
- Label Studio: the labelling config XML: ``RectangleLabels`` (one box per vehicle, labelled with its
  prototype) and ``KeyPointLabels`` (the keypoints; nest each under its box, which sets ``parentID``).
- COCO: ``categories``, one per prototype, each with the keypoint names and a 1-based skeleton.

Road users with a keypoint vocabulary of their own (a Pedestrian's COCO keypoints, a Cyclist's wheels, handlebar,
saddle, head and shoulders: :data:`toosicubix.vocabulary.CLASSES`) get that vocabulary instead of the flat one: in
CVAT a skeleton label per class (``pedestrian``, ``cyclist``, ...) with its keypoints, its edges and a ``prototype``
attribute of its prototypes among those asked for; in Label Studio their keypoint labels beside the vehicles' (each
name once); in COCO their categories' keypoint lists. Vehicles of the cuboid vocabulary (Car, Van, Truck, a Bus)
keep the flat vocabulary.
"""

from __future__ import annotations

import json
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from toosicubix.parts.keypoints import KEYPOINTS, SLOTS, describe, skeleton_edges
from toosicubix.parts.road_users import keypoint_class
from toosicubix.vocabulary import CLASSES

#: The CVAT label of the skeleton and the Label Studio / COCO name of a vehicle.
VEHICLE_LABEL = "vehicle"
#: Labels of the review shapes ``toosicubix export cvat`` writes (the edges of the cuboid, its front face).
CUBOID_LABEL = "toosicubix-cuboid"
FRONT_LABEL = "toosicubix-front"
#: The prototype attribute of a CVAT skeleton.
PROTOTYPE_ATTRIBUTE = "prototype"
#: Label Studio control names the importer looks for by type, not by name; the template uses these.
LS_IMAGE, LS_BOX, LS_KEYPOINT = "image", "vehicle", "keypoint"
DEFAULT_PROTOTYPES = ("Car", "Van", "Truck")

_COLORS = {"point": "#33ddff", "symmetry": "#fa3253", "direction": "#ffcc33", "length": "#34d1b7"}


def _typical_positions() -> dict[str, np.ndarray]:
    """A schematic 3D position (vehicle frame, metres) per keypoint, only to lay out the skeleton drawing."""
    dx, dy, dz = 4.2, 1.8, 1.5
    hx, hy = dx / 2, dy / 2
    side = {"front": 1.0, "rear": -1.0, "left": 1.0, "right": -1.0}
    pos: dict[str, np.ndarray] = {}
    for slot in SLOTS:
        name = slot.name
        if slot.kind == "point":
            words = name.split("-")
            if words[0] == "wheel":
                pos[name] = np.array([side[words[1]] * 1.3, side[words[2]] * hy, 0.0])
            elif words[0] == "edge":
                pos[name] = np.array([side[words[1]] * hx, side[words[2]] * hy, 0.6])
            elif words[0] == "corner":
                pos[name] = np.array([side[words[2]] * hx, side[words[3]] * hy, dz if words[1] == "top" else 0.0])
            elif name == "top-center":
                pos[name] = np.array([0.0, 0.0, dz])
            else:
                pos[name] = np.array([side[words[0]] * hx, 0.0, 0.45])
        elif slot.kind == "symmetry":
            for field, keypoint in slot.fields:
                pair = int(keypoint.split("-pair")[1][0])
                y = side[field] * (0.45 + 0.12 * pair)
                if name == "roof":
                    pos[keypoint] = np.array([0.9 - 0.6 * pair, y, dz])
                else:
                    pos[keypoint] = np.array([side[name] * hx, y, 0.5 + 0.25 * pair])
        elif slot.kind == "direction":
            axis = {"forward": 0, "backward": 0, "leftward": 1, "rightward": 1, "upward": 2, "downward": 2}[name]
            sign = 1.0 if name in ("forward", "leftward", "upward") else -1.0
            base = np.array([0.0, hy + 1.2, 0.0]) + 0.3 * axis * np.array([1.0, 0.0, 0.0])
            base[2] += 0.3 if sign > 0 else 0.0
            step = np.zeros(3)
            step[axis] = 1.0 * sign
            pos[slot.fields[0][1]], pos[slot.fields[1][1]] = base - 0.5 * step, base + 0.5 * step
        else:
            a, b = slot.fields[0][1], slot.fields[1][1]
            words = name.split("-")
            if words[0] == "plate":
                pos[a] = np.array([side[words[1]] * hx, side[words[1]] * 0.26, 0.35])
                pos[b] = np.array([side[words[1]] * hx, -side[words[1]] * 0.26, 0.35])
            elif words[0] == "wheelbase":
                pos[a] = np.array([1.3, side[words[1]] * (hy + 0.25), -0.1])
                pos[b] = np.array([-1.3, side[words[1]] * (hy + 0.25), -0.1])
            else:
                pos[a] = np.array([side[words[1]] * 1.3 + 0.15, side[words[2]] * (hy + 0.1), -0.05])
                pos[b] = np.array([side[words[1]] * 1.3 + 0.15, side[words[2]] * (hy + 0.1), 0.65])
    return pos


def layout_2d(size: float = 100.0, margin: float = 6.0) -> dict[str, tuple[float, float]]:
    """Drawing positions of the keypoints in a ``size`` x ``size`` box: the schematic positions seen obliquely
    from the front left and above."""
    pos = _typical_positions()
    names = list(KEYPOINTS)
    points_vehicle = np.array([pos[n] for n in names])  # (K, 3)
    # Oblique view: image u from X and Y, image v (down) from Z with a little of X and Y for depth.
    uv = np.column_stack([0.85 * points_vehicle[:, 0] - 0.55 * points_vehicle[:, 1],
                          -points_vehicle[:, 2] + 0.2 * points_vehicle[:, 0] + 0.35 * points_vehicle[:, 1]])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    scale = (size - 2 * margin) / float(max(hi - lo))
    uv = margin + (uv - lo) * scale
    return {n: (round(float(u), 2), round(float(v), 2)) for n, (u, v) in zip(names, uv, strict=True)}


def cvat_skeleton_svg() -> str:
    """The ``svg`` of the skeleton label: edges first, then one node per keypoint (ids 1-based in vocabulary order)."""
    xy = layout_2d()
    node = {name: i + 1 for i, name in enumerate(KEYPOINTS)}
    parts = []
    for a, b in skeleton_edges():
        (x1, y1), (x2, y2) = xy[a], xy[b]
        parts.append(f'<line x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}" stroke="black" data-type="edge" '
                     f'data-node-from="{node[a]}" stroke-width="0.5" data-node-to="{node[b]}"></line>')
    for name in KEYPOINTS:
        x, y = xy[name]
        parts.append(f'<circle r="0.75" stroke="black" fill="#b3b3b3" cx="{x}" cy="{y}" stroke-width="0.1" '
                     f'data-type="element node" data-element-id="{node[name]}" data-node-id="{node[name]}" '
                     f'data-label-name="{name}"></circle>')
    return "".join(parts)


def _by_vocabulary(prototypes: tuple[str, ...]) -> tuple[tuple[str, ...], dict[str, tuple[str, ...]]]:
    """The prototypes of the flat (cuboid) vocabulary, and those of each class with a keypoint vocabulary of its own
    (class name -> its prototypes among ``prototypes``), each in the order given."""
    flat, own = [], {}
    for p in prototypes:
        cls = keypoint_class(p)
        if cls is None:
            flat.append(p)
        else:
            own.setdefault(cls.name, []).append(p)
    return tuple(flat), {name: tuple(ps) for name, ps in own.items()}


def class_layout_2d(class_name: str, size: float = 100.0, margin: float = 6.0) -> dict[str, tuple[float, float]]:
    """Drawing positions of a class's keypoints in a ``size`` x ``size`` box: their typical places on its prior's
    mean box, seen obliquely from the front left (the X axis to the right, a little of Y for depth, Z up)."""
    cls = CLASSES[class_name]
    d = np.array([1.0, 1.0, 1.0]) if not cls.prototypes else _mean_box(cls.prototypes[0])
    names = list(cls.keypoints)
    points_vehicle = np.array([np.array(cls.keypoints[n].at) * d for n in names])  # (K, 3) metres
    uv = np.column_stack([points_vehicle[:, 0] - 0.45 * points_vehicle[:, 1],
                          -points_vehicle[:, 2] + 0.15 * points_vehicle[:, 1]])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    scale = (size - 2 * margin) / float(max(hi - lo))
    uv = margin + (uv - lo) * scale
    return {n: (round(float(u), 2), round(float(v), 2)) for n, (u, v) in zip(names, uv, strict=True)}


def _mean_box(prototype: str) -> np.ndarray:
    from toosicubix.annotations.priors_file import load_priors

    priors = load_priors()
    return np.asarray(priors[prototype].mean, dtype=float) if prototype in priors else np.ones(3)


def _class_svg(class_name: str) -> str:
    """The ``svg`` of a class's skeleton label (node ids 1-based in the class vocabulary's order)."""
    cls = CLASSES[class_name]
    xy = class_layout_2d(class_name)
    node = {name: i + 1 for i, name in enumerate(cls.keypoints)}
    parts = []
    for a, b in cls.edges:
        (x1, y1), (x2, y2) = xy[a], xy[b]
        parts.append(f'<line x1="{x1}" y1="{y1}" x2="{x2}" y2="{y2}" stroke="black" data-type="edge" '
                     f'data-node-from="{node[a]}" stroke-width="0.5" data-node-to="{node[b]}"></line>')
    for name in cls.keypoints:
        x, y = xy[name]
        parts.append(f'<circle r="0.75" stroke="black" fill="#b3b3b3" cx="{x}" cy="{y}" stroke-width="0.1" '
                     f'data-type="element node" data-element-id="{node[name]}" data-node-id="{node[name]}" '
                     f'data-label-name="{name}"></circle>')
    return "".join(parts)


def _class_skeleton(class_name: str, prototypes: tuple[str, ...]) -> dict[str, Any]:
    cls = CLASSES[class_name]
    return {
        "name": class_name.lower(),
        "type": "skeleton",
        "color": cls.palette[0],
        "attributes": [{"name": PROTOTYPE_ATTRIBUTE, "mutable": False, "input_type": "select",
                        "default_value": prototypes[0], "values": list(prototypes)}],
        "sublabels": [{"name": name, "type": "points", "color": cls.palette[i % len(cls.palette)], "attributes": []}
                      for i, name in enumerate(cls.keypoints)],
        "svg": _class_svg(class_name),
    }


def cvat_labels(prototypes: tuple[str, ...] = DEFAULT_PROTOTYPES, review_labels: bool = True) -> list[dict[str, Any]]:
    """CVAT's Raw label JSON: the vehicle skeleton (for the prototypes of the cuboid vocabulary), a skeleton per class
    of road users with a keypoint vocabulary of its own, and, with ``review_labels``, the labels of the review
    export."""
    kind_of = {keypoint: slot.kind for slot in SLOTS for keypoint in slot.keypoints}
    flat, own = _by_vocabulary(prototypes)
    labels = []
    if flat:
        labels.append({
            "name": VEHICLE_LABEL,
            "type": "skeleton",
            "color": "#ff6037",
            "attributes": [{"name": PROTOTYPE_ATTRIBUTE, "mutable": False, "input_type": "select",
                            "default_value": flat[0], "values": list(flat)}],
            "sublabels": [{"name": name, "type": "points", "color": _COLORS[kind_of[name]], "attributes": []}
                          for name in KEYPOINTS],
            "svg": cvat_skeleton_svg(),
        })
    labels += [_class_skeleton(name, ps) for name, ps in own.items()]
    if review_labels:
        status = {"name": "status", "mutable": False, "input_type": "select", "default_value": "ok",
                  "values": ["ok", "failed"]}
        vehicle = {"name": "vehicle_id", "mutable": False, "input_type": "text", "default_value": "", "values": [""]}
        labels += [{"name": CUBOID_LABEL, "type": "polyline", "color": "#aaf0d1", "attributes": [vehicle, status]},
                   {"name": FRONT_LABEL, "type": "polygon", "color": "#fa3253", "attributes": [vehicle]}]
    return labels


def label_studio_config(prototypes: tuple[str, ...] = DEFAULT_PROTOTYPES) -> str:
    """Label Studio's labelling config XML: a box per vehicle labelled with its prototype, and the keypoints."""
    kind_of = {keypoint: slot.kind for slot in SLOTS for keypoint in slot.keypoints}
    flat, own = _by_vocabulary(prototypes)
    keypoint_labels = [f'    <Label value="{name}" background="{_COLORS[kind_of[name]]}" '
                       f'hint={quoteattr(describe(name))}/>' for name in (KEYPOINTS if flat else ())]
    named = set(KEYPOINTS) if flat else set()
    for class_name in own:
        cls = CLASSES[class_name]
        for name, k in cls.keypoints.items():
            if name not in named:
                named.add(name)
                keypoint_labels.append(f'    <Label value="{name}" background="{cls.palette[0]}" '
                                       f'hint={quoteattr(f"{class_name}: {k.description}")}/>')
    lines = [
        "<View>",
        '  <Header value="ToosiCubix: draw a box per vehicle (its prototype), then click its parts; nest each '
        'keypoint under its box in the Regions panel"/>',
        f'  <Image name="{LS_IMAGE}" value="$image" zoom="true" zoomControl="true"/>',
        f'  <RectangleLabels name="{LS_BOX}" toName="{LS_IMAGE}" strokeWidth="2">',
        *[f"    <Label value={quoteattr(p)}/>" for p in prototypes],
        "  </RectangleLabels>",
        f'  <KeyPointLabels name="{LS_KEYPOINT}" toName="{LS_IMAGE}" strokeWidth="2">',
        *keypoint_labels,
        "  </KeyPointLabels>",
        "</View>",
    ]
    return "\n".join(lines) + "\n"


def coco_categories(prototypes: tuple[str, ...] = DEFAULT_PROTOTYPES) -> dict[str, Any]:
    """COCO ``categories``: one per prototype, each with every keypoint name and the skeleton (1-based indices)."""
    index = {name: i + 1 for i, name in enumerate(KEYPOINTS)}
    skeleton = [[index[a], index[b]] for a, b in skeleton_edges()]
    categories = []
    for i, p in enumerate(prototypes):
        cls = keypoint_class(p)
        if cls is None:
            categories.append({"id": i + 1, "name": p, "supercategory": VEHICLE_LABEL, "keypoints": list(KEYPOINTS),
                               "skeleton": skeleton})
            continue
        own = {name: j + 1 for j, name in enumerate(cls.keypoints)}
        categories.append({"id": i + 1, "name": p, "supercategory": cls.family, "keypoints": list(cls.keypoints),
                           "skeleton": [[own[a], own[b]] for a, b in cls.edges]})
    return {"categories": categories}


def template_text(tool: str, prototypes: tuple[str, ...] = DEFAULT_PROTOTYPES) -> str:
    """The template of ``tool`` ('cvat', 'label-studio' or 'coco') as the text to paste or save."""
    if tool == "cvat":
        return json.dumps(cvat_labels(prototypes), indent=2) + "\n"
    if tool == "label-studio":
        return label_studio_config(prototypes)
    if tool == "coco":
        return json.dumps(coco_categories(prototypes), indent=2) + "\n"
    raise ValueError(f"unknown tool {tool!r}: expected cvat, label-studio or coco")

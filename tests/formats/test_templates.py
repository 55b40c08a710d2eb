"""Templates: CVAT's Raw label JSON, Label Studio's config XML, COCO categories, all over the flat vocabulary."""

import json
import xml.etree.ElementTree as ET

from toosicubix.formats.templates import (
    CUBOID_LABEL,
    FRONT_LABEL,
    coco_categories,
    cvat_labels,
    label_studio_config,
    template_text,
)
from toosicubix.parts.keypoints import KEYPOINTS, skeleton_edges

PROTOTYPES = ("Car", "Van")


def test_cvat_skeleton_has_one_node_per_keypoint():
    labels = cvat_labels(PROTOTYPES)
    skeleton = labels[0]
    assert skeleton["type"] == "skeleton" and skeleton["name"] == "vehicle"
    assert [s["name"] for s in skeleton["sublabels"]] == list(KEYPOINTS)
    assert all(s["type"] == "points" for s in skeleton["sublabels"])
    assert skeleton["attributes"] == [{"name": "prototype", "mutable": False, "input_type": "select",
                                       "default_value": "Car", "values": ["Car", "Van"]}]
    # cvat-core wraps the field in <svg>...</svg> itself; a wrapper of our own would hide every node from it.
    assert "<svg" not in skeleton["svg"]
    svg = ET.fromstring(f"<svg>{skeleton['svg']}</svg>")
    nodes = [e for e in svg if e.get("data-type") == "element node"]
    assert [n.get("data-label-name") for n in nodes] == list(KEYPOINTS)
    assert [int(n.get("data-node-id")) for n in nodes] == list(range(1, len(KEYPOINTS) + 1))
    edges = [(int(e.get("data-node-from")), int(e.get("data-node-to"))) for e in svg if e.get("data-type") == "edge"]
    assert len(edges) == len(skeleton_edges())
    assert all(1 <= a <= len(KEYPOINTS) and 1 <= b <= len(KEYPOINTS) for a, b in edges)
    # Nodes lie inside CVAT's 100 x 100 drawing area.
    assert all(0 <= float(n.get("cx")) <= 100 and 0 <= float(n.get("cy")) <= 100 for n in nodes)
    assert [(label["name"], label["type"]) for label in labels[1:]] == [(CUBOID_LABEL, "polyline"),
                                                                        (FRONT_LABEL, "polygon")]
    assert len(cvat_labels(PROTOTYPES, review_labels=False)) == 1


def test_label_studio_config_has_boxes_and_keypoints_on_one_image():
    root = ET.fromstring(label_studio_config(PROTOTYPES))
    assert root.tag == "View"
    image = root.find("Image")
    assert image.get("value") == "$image"
    boxes, keypoints = root.find("RectangleLabels"), root.find("KeyPointLabels")
    assert boxes.get("toName") == keypoints.get("toName") == image.get("name")
    assert [label.get("value") for label in boxes] == list(PROTOTYPES)
    assert [label.get("value") for label in keypoints] == list(KEYPOINTS)


def test_coco_categories_carry_keypoints_and_a_one_based_skeleton():
    categories = coco_categories(PROTOTYPES)["categories"]
    assert [c["name"] for c in categories] == list(PROTOTYPES) and [c["id"] for c in categories] == [1, 2]
    for category in categories:
        assert category["keypoints"] == list(KEYPOINTS)
        assert min(min(edge) for edge in category["skeleton"]) >= 1
        assert max(max(edge) for edge in category["skeleton"]) <= len(KEYPOINTS)
    first = categories[0]["skeleton"][0]
    assert (KEYPOINTS[first[0] - 1], KEYPOINTS[first[1] - 1]) == skeleton_edges()[0]


def test_template_text_is_what_the_tool_reads():
    assert json.loads(template_text("cvat", PROTOTYPES))[0]["type"] == "skeleton"
    assert ET.fromstring(template_text("label-studio", PROTOTYPES)).tag == "View"
    assert "categories" in json.loads(template_text("coco", PROTOTYPES))

"""Templates and tool imports speak each road-user class's own vocabulary (issue 35): a CVAT skeleton per class, its
keypoints in Label Studio and COCO, and the importers turn those names into keypoint annotations at the class's
places."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

from toosicubix.formats.cameras import load_cameras
from toosicubix.formats.cvat import read_cvat
from toosicubix.formats.templates import coco_categories, cvat_labels, label_studio_config
from toosicubix.parts.keypoints import KEYPOINTS, parts_from_keypoints
from toosicubix.vocabulary import CLASSES


def test_cvat_gives_a_skeleton_per_class_beside_the_vehicles():
    labels = cvat_labels(("Car", "Pedestrian", "Cyclist", "Motorcyclist"), review_labels=False)
    assert [label["name"] for label in labels] == ["vehicle", "pedestrian", "cyclist", "motorcyclist"]
    vehicle, person, cyclist, _ = labels
    assert vehicle["attributes"][0]["values"] == ["Car"]
    assert [s["name"] for s in person["sublabels"]] == list(CLASSES["Pedestrian"].keypoints)
    assert person["attributes"][0]["values"] == ["Pedestrian"] and person["color"] == CLASSES["Pedestrian"].palette[0]
    svg = ET.fromstring(f"<svg>{cyclist['svg']}</svg>")
    nodes = [e for e in svg if e.get("data-type") == "element node"]
    assert [n.get("data-label-name") for n in nodes] == list(CLASSES["Cyclist"].keypoints)
    assert all(0 <= float(n.get("cx")) <= 100 and 0 <= float(n.get("cy")) <= 100 for n in nodes)
    edges = [e for e in svg if e.get("data-type") == "edge"]
    assert len(edges) == len(CLASSES["Cyclist"].edges)
    assert [label["name"] for label in cvat_labels(("Pedestrian",), review_labels=False)] == ["pedestrian"]


def test_label_studio_lists_each_keypoint_name_once():
    root = ET.fromstring(label_studio_config(("Car", "Pedestrian", "Cyclist")))
    names = [label.get("value") for label in root.find("KeyPointLabels")]
    assert len(names) == len(set(names))
    assert names[:len(KEYPOINTS)] == list(KEYPOINTS)
    assert set(CLASSES["Pedestrian"].keypoints) | set(CLASSES["Cyclist"].keypoints) == set(names[len(KEYPOINTS):])
    alone = [label.get("value") for label in ET.fromstring(label_studio_config(("Pedestrian",))).find("KeyPointLabels")]
    assert alone == list(CLASSES["Pedestrian"].keypoints)


def test_coco_categories_of_road_users_carry_their_own_keypoints():
    car, person = coco_categories(("Car", "Pedestrian"))["categories"]
    assert car["keypoints"] == list(KEYPOINTS)
    assert person["keypoints"][:3] == ["nose", "left_eye", "right_eye"] and len(person["keypoints"]) == 17
    assert person["supercategory"] == "person"
    assert all(1 <= a <= 17 and 1 <= b <= 17 for a, b in person["skeleton"])


def test_a_class_s_names_become_keypoints_at_its_places():
    conversion = parts_from_keypoints([("left_handlebar_end", (10.0, 20.0)), ("front_wheel_contact", (30.0, 40.0)),
                                       ("wheel-front-left", (50.0, 60.0))], prototype="Bicycle")
    by_name = {p.get("name", p.get("part")): p for p in conversion.parts}
    assert by_name["left_handlebar_end"]["at"] == list(CLASSES["Bicycle"].keypoints["left_handlebar_end"].at)
    assert by_name["wheel-front-left"] == {"kind": "point", "part": "wheel-front-left", "xy": [50.0, 60.0]}
    assert conversion.problems == []
    # A Car knows no handlebar: the name is a problem, not a keypoint.
    assert parts_from_keypoints({"left_handlebar_end": (1.0, 2.0)}, prototype="Car").problems == [
        ("left_handlebar_end", "not a toosicubix keypoint name")]


def test_a_cvat_pedestrian_skeleton_imports_as_keypoints(tmp_path):
    cameras = tmp_path / "cameras.json"
    cameras.write_text(json.dumps({"cameras": [{"match": "*", "K": [[800, 0, 500], [0, 800, 250], [0, 0, 1]]}]}))
    names = CLASSES["Pedestrian"].keypoints
    points = "".join(f'<points label="{name}" source="manual" outside="0" occluded="0" '
                     f'points="{400 + i},{200 + 5 * i}"></points>' for i, name in enumerate(names))
    xml = tmp_path / "a.xml"
    xml.write_text('<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n  <version>1.1</version>\n'
                   '<image id="0" name="frames/a.png" width="1000" height="500">'
                   f'<skeleton label="pedestrian" source="manual" z_order="0">{points}'
                   '<attribute name="prototype">Pedestrian</attribute></skeleton></image>\n</annotations>\n')
    document, _ = read_cvat(xml, load_cameras(cameras))
    (vehicle,) = document["images"][0]["vehicles"]
    assert vehicle["prototype"] == "Pedestrian"
    assert [p["name"] for p in vehicle["parts"]] == list(CLASSES["Pedestrian"].keypoints)
    assert all(p["kind"] == "keypoint" for p in vehicle["parts"])

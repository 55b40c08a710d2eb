"""Exports written the way CVAT and Label Studio write them, from an annotation file v1: test fixtures.

CVAT for images 1.1 follows ``dump_as_cvat_annotation`` (cvat/apps/dataset_manager/formats/cvat.py): image
attributes id, name[, subset, task_id], width, height; a ``skeleton`` with label, source, z_order[, group_id];
its ``points`` children with label, source, outside, occluded, points (two decimals); ``attribute`` children
after the elements. Label Studio's JSON export: tasks with ``data``, ``annotations`` (or ``completions``), results
with ``original_width``, ``original_height``, ``image_rotation``, ``value`` in percent, ``id``, ``from_name``,
``to_name``, ``type``, ``origin`` and, for nested regions, ``parentID``.
"""

from __future__ import annotations

import functools
import json
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from tests.conftest import REPO
from toosicubix.formats.templates import cvat_labels, label_studio_config
from toosicubix.parts.keypoints import keypoints_from_parts

SAMPLE = REPO / "samples" / "annotations.json"


def sample_doc() -> dict[str, Any]:
    return json.loads(SAMPLE.read_text())


def file_name(image: dict[str, Any]) -> str:
    return image.get("file") or f"frames/{image['id']}.png"


def cameras_doc(doc: dict[str, Any]) -> dict[str, Any]:
    """A cameras file with one entry per image (K = P[:, :3] for KITTI P cameras)."""
    entries = []
    for image in doc["images"]:
        camera = image["camera"]
        K = camera.get("K") or [row[:3] for row in camera["P"]]
        entry = {"match": f"*{image['id']}.png", "K": K}
        if camera.get("distortion"):
            entry["distortion"] = camera["distortion"]
        entries.append(entry)
    return {"cameras": entries}


def _meta(kind: str, labels: list[str]) -> str:
    sub = "".join(
        f"\n        <label>\n          <name>{name}</name>\n          <color>#33ddff</color>"
        "\n          <type>points</type>\n          <attributes>\n          </attributes>"
        "\n          <parent>vehicle</parent>\n        </label>"
        for name in labels)
    return (f"\n  <meta>\n    <{kind}>\n      <id>7</id>\n      <name>toosicubix</name>\n      <labels>"
            "\n        <label>\n          <name>vehicle</name>\n          <color>#ff6037</color>"
            "\n          <type>skeleton</type>\n          <attributes>\n            <attribute>"
            "\n              <name>prototype</name>\n              <mutable>False</mutable>"
            "\n              <input_type>select</input_type>\n              <default_value>Car</default_value>"
            "\n              <values>Car\nVan\nTruck</values>\n            </attribute>\n          </attributes>"
            "\n          <svg>&lt;circle r=\"0.75\"&gt;&lt;/circle&gt;</svg>\n          <parent></parent>"
            f"\n        </label>{sub}\n      </labels>\n    </{kind}>"
            "\n    <dumped>2026-11-22 10:00:00.000000+00:00</dumped>\n  </meta>")


def cvat_xml(doc: dict[str, Any], project: bool = False, outside_absent: bool = True) -> str:
    """CVAT for images 1.1 of a task made from ``toosicubix template cvat``: one skeleton per vehicle with every
    sublabel of the template, those not clicked ``outside="1"``."""
    skeleton = cvat_labels()[0]
    sublabels = [s["name"] for s in skeleton["sublabels"]]
    out = ['<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n  <version>1.1</version>',
           _meta("project" if project else "task", sublabels)]
    for index, image in enumerate(doc["images"]):
        w, h = image["size"]
        extra = ' subset="default" task_id="3"' if project else ""
        out.append(f'\n  <image id="{index}" name={quoteattr(file_name(image))}{extra} width="{w}" height="{h}">')
        for vehicle in image["vehicles"]:
            clicked = dict(keypoints_from_parts(vehicle["parts"]))
            out.append(f'\n    <skeleton label="{skeleton["name"]}" source="manual" z_order="0">')
            for name in sublabels:
                if name in clicked:
                    x, y = clicked[name]
                    out.append(f'\n      <points label="{name}" source="manual" outside="0" occluded="0" '
                               f'points="{x:.2f},{y:.2f}">\n      </points>')
                elif outside_absent:
                    out.append(f'\n      <points label="{name}" source="manual" outside="1" occluded="0" '
                               f'points="10.00,10.00">\n      </points>')
            attribute = skeleton["attributes"][0]["name"]
            out.append(f'\n      <attribute name="{attribute}">{vehicle["prototype"]}</attribute>\n    </skeleton>')
        out.append("\n  </image>")
    out.append("\n</annotations>\n")
    return "".join(out)


def _control_names() -> dict[str, str]:
    """The names of the controls of ``toosicubix template label-studio``: tag -> name."""
    root = ET.fromstring(label_studio_config())
    return {child.tag: child.get("name") for child in root if child.get("name")}


def _region(image: dict[str, Any], rid: str, kind: str, value: dict[str, Any], parent: str | None) -> dict[str, Any]:
    w, h = image["size"]
    names = _control_names()
    region = {"original_width": w, "original_height": h, "image_rotation": 0, "value": value, "id": rid,
              "from_name": names["RectangleLabels" if kind == "rectanglelabels" else "KeyPointLabels"],
              "to_name": names["Image"], "type": kind, "origin": "manual"}
    if parent is not None:
        region["parentID"] = parent
    return region


def label_studio_results(image: dict[str, Any], parent_ids: bool = True) -> list[dict[str, Any]]:
    """The ``result`` list of one image: a box per vehicle, then its keypoints (nested when ``parent_ids``)."""
    w, h = image["size"]
    result = []
    for j, vehicle in enumerate(image["vehicles"]):
        box_id = f"box{j}x"
        x1, y1, x2, y2 = vehicle["box2d"]
        result.append(_region(image, box_id, "rectanglelabels",
                              {"x": x1 / w * 100, "y": y1 / h * 100, "width": (x2 - x1) / w * 100,
                               "height": (y2 - y1) / h * 100, "rotation": 0,
                               "rectanglelabels": [vehicle["prototype"]]}, None))
        for k, (name, (x, y)) in enumerate(keypoints_from_parts(vehicle["parts"])):
            result.append(_region(image, f"kp{j}_{k}", "keypointlabels",
                                  {"x": x / w * 100, "y": y / h * 100, "width": 0.4, "keypointlabels": [name]},
                                  box_id if parent_ids else None))
    return result


def label_studio_export(doc: dict[str, Any], parent_ids: bool = True, completions: bool = False) -> list[dict]:
    """Label Studio's JSON export of the document's images (``completions`` as old versions wrote)."""
    tasks = []
    for t, image in enumerate(doc["images"]):
        annotation = {"id": 100 + t, "completed_by": 1, "result": label_studio_results(image, parent_ids),
                      "was_cancelled": False, "ground_truth": False, "created_at": "2026-11-22T10:00:00.000000Z",
                      "updated_at": "2026-11-22T10:00:00.000000Z", "lead_time": 12.5, "prediction": {},
                      "result_count": 0, "task": t + 1, "project": 1}
        task = {"id": t + 1, "data": {"image": f"/data/upload/1/{file_name(image).split('/')[-1]}"},
                "meta": {}, "created_at": "2026-11-22T09:00:00.000000Z", "updated_at": "2026-11-22T10:00:00.000000Z",
                "inner_id": t + 1, "total_annotations": 1, "cancelled_annotations": 0, "total_predictions": 0,
                "comment_count": 0, "unresolved_comment_count": 0, "last_comment_updated_at": None, "project": 1,
                "updated_by": 1, "comment_authors": [], "file_upload": None, "drafts": [], "predictions": []}
        task["completions" if completions else "annotations"] = [annotation]
        tasks.append(task)
    return tasks


def write_json(path: Path, doc: Any) -> Path:
    path.write_text(json.dumps(doc, indent=1))
    return path


def fit_results(annotations: Path) -> dict[str, Any]:
    """``results.json`` of fitting an annotation file with the default settings."""
    from toosicubix.pipeline.batch import fit_file

    with tempfile.TemporaryDirectory() as out:
        fit_file(annotations, Path(out) / "fit")
        return json.loads((Path(out) / "fit" / "results.json").read_text())


@functools.lru_cache(maxsize=1)
def sample_fit() -> str:
    """The sample's ``results.json`` as text (cached: one fit per test session)."""
    return json.dumps(fit_results(SAMPLE))


def max_pose_difference(a: dict[str, Any], b: dict[str, Any]) -> float:
    """Largest difference of R_cam_vehicle, t_cam_vehicle (m) and dimensions (m) between two results files whose
    images and vehicles come in the same order; every vehicle must be fitted in both."""
    worst = 0.0
    assert [im["id"] for im in a["images"]] == [im["id"] for im in b["images"]]
    for image_a, image_b in zip(a["images"], b["images"], strict=True):
        for va, vb in zip(image_a["vehicles"], image_b["vehicles"], strict=True):
            assert va["status"] == vb["status"] == "ok"
            for key in ("R_cam_vehicle", "t_cam_vehicle", "dimensions"):
                worst = max(worst, float(np.abs(np.array(va[key]) - np.array(vb[key])).max()))
    return worst


def same_clicks(doc_a: dict[str, Any], doc_b: dict[str, Any]) -> bool:
    """Whether two annotation documents hold the same vehicles (in order) with the same named clicks."""
    for image_a, image_b in zip(doc_a["images"], doc_b["images"], strict=True):
        if len(image_a["vehicles"]) != len(image_b["vehicles"]):
            return False
        for va, vb in zip(image_a["vehicles"], image_b["vehicles"], strict=True):
            ka, kb = dict(keypoints_from_parts(va["parts"])), dict(keypoints_from_parts(vb["parts"]))
            if ka.keys() != kb.keys() or va["prototype"] != vb["prototype"]:
                return False
            if any(abs(ka[k][i] - kb[k][i]) > 1e-9 for k in ka for i in (0, 1)):
                return False
    return len(doc_a["images"]) == len(doc_b["images"])

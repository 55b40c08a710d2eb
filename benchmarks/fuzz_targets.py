"""The surfaces ``benchmarks/fuzz.py`` attacks beyond ``fit``, ``validate`` and ``eval`` (issue 34, item 6): each a
:class:`Target` that makes its base inputs once per worker and, per case, one mutated input and the commands to run
on it.

- ``coco``: ``import coco`` on an ApolloCar3D-like keypoint file or a video (TAO-like) file, or its cameras file;
- ``cvat``: ``import cvat`` on CVAT for images and for video XML: text and attribute mutations, entity expansion,
  external and parameter entities, DOCTYPEs after long comments, other encodings (UTF-16, Latin-1), zips (bombs,
  several or no annotations.xml, cut archives);
- ``label-studio``: ``import label-studio`` on an export: JSON mutations, URLs Python cannot parse or that climb,
  sizes of inf, nan or 400 digits;
- ``learn-parts``: ``learn-parts`` on mutated keypoint, car model and cameras files (JSON, KITTI calib, YAML) and
  mapping files (``--mapping FILE``, for ``learn-parts`` and ``import coco``);
- ``eval-apollocar3d``: ``eval --apollocar3d`` of a fit against mutated ground truth;
- ``export``: ``export openlabel`` and ``export cvat`` on a fit folder whose results.json (or annotation file) is
  mutated;
- ``render``: ``render`` with absurd image sizes, broken or lying image files and mutated results;
- ``page``: the annotate page's JSON API, mutated requests to a live server (:mod:`fuzz_page`).

A new surface (the page's JSON API) is a new :class:`Target` in :data:`TARGETS`; one whose case is not a command
line overrides :meth:`Target.run_case`. ``python benchmarks/fuzz_targets.py TARGET INDEX [--seed S] -o DIR`` writes
one case's inputs and prints its commands, to reproduce a finding.
"""

from __future__ import annotations

import argparse
import copy
import io
import json
import random
import shutil
import struct
import sys
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))
from fuzz import nodes, set_at  # noqa: E402  (the generic mutations are fuzz.py's)

SAMPLE = REPO / "samples" / "annotations.json"
CVAT_VIDEO = REPO / "tests" / "formats" / "fixtures" / "cvat-video-1.1.xml"
#: Values a hostile file puts where an id, a number or a name belongs (and ``"__HUGE__"``: a 5,000-digit integer
#: written into the text, which Python's JSON writer cannot write).
HOSTILE: tuple[Any, ...] = (
    10**400, -(10**400), 2**63, 10**18, "__HUGE__", "9" * 5000, "\u00b2", "\u0663\u0665", "035", "4_01.2", " 1",
    [1], {"a": 1}, [], {}, float("nan"), float("inf"), float("-inf"), 1e308, -1e308, 1e-300, 5e-324, 0, -1, 1e6 + 1,
    True, None, "", "\x00", "\ud800", "a" * 10_000, "../../etc/passwd", "http://[::1/x.png", 1.5,
)
#: Image sizes the annotation file allows that no canvas should be made of as they are.
ABSURD_SIZES = ([40_000, 40_000], [1, 1_000_000], [1_000_000, 1], [1_000_000, 1_000_000], [16_385, 16_385],
                [7_000, 7_000], [100_000, 3], [1, 1])


@dataclass
class Command:
    """One command of a case: its label, its arguments and what it writes (a file, or a folder of files: checked
    for NaN or infinity, and for not existing at all after exit 2)."""

    label: str
    args: list[str]
    writes: Path | None = None


class Target:
    """A surface the fuzz attacks: :meth:`prepare` makes the base inputs once in a worker's folder, :meth:`case`
    writes case ``index``'s mutated inputs into ``folder`` and returns a name for the mutation and the commands.
    :meth:`run_case` runs them (:func:`fuzz.run_isolated`: each in a forked process, its peak memory measured); a
    target whose case is not a command line (the page's JSON API) overrides it."""

    name = ""

    def prepare(self, work: Path) -> None:
        self.work = work

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        raise NotImplementedError

    def rng(self, index: int, seed: int) -> random.Random:
        return random.Random(f"{seed}/{self.name}/{index}")

    def run_case(self, index: int, seed: int, folder: Path, timeout: float, run) -> list[dict[str, Any]]:
        kind, commands = self.case(index, seed, folder)
        return [run(command, timeout, folder) | {"kind": kind} for command in commands]


# --- generic mutations ------------------------------------------------------------------------------------------

def hostile_value(rng: random.Random) -> Any:
    return copy.deepcopy(rng.choice(HOSTILE))


def mutate_json(doc: Any, rng: random.Random, keys: tuple[str, ...] = ()) -> tuple[Any, str]:
    """One mutation of a JSON document: a hostile value at a random node (or at a node whose key is one of ``keys``,
    half the time), a structural change, a number made extreme, or (the caller's) a text mutation."""
    from fuzz import mutate_numbers, mutate_structure

    family = rng.choice(["hostile", "hostile", "keyed", "structure", "numbers"])
    if family == "keyed" and keys:
        found = [p for p, _ in nodes(doc) if p and p[-1] in keys]
        if found:
            return set_at(doc, rng.choice(found), hostile_value(rng)), "json:keyed"
        family = "hostile"
    if family == "hostile":
        path, _ = rng.choice(nodes(doc))
        return set_at(doc, path, hostile_value(rng)), "json:hostile"
    if family == "structure":
        return mutate_structure(doc, rng)[0], "json:structure"
    return mutate_numbers(doc, rng)[0], "json:numbers"


def json_bytes(doc: Any, rng: random.Random) -> bytes:
    """The document as JSON text, NaN and infinities as Python writes them, ``"__HUGE__"`` as 5,000 digits."""
    try:
        text = json.dumps(doc, indent=rng.choice([None, 1]))
    except (ValueError, RecursionError):  # an integer too long to write, or nested too deep
        return b"[" * 5000
    return text.replace('"__HUGE__"', "9" * 5000).encode("utf-8", "surrogatepass")


def mutated_json_file(doc: Any, rng: random.Random, path: Path, keys: tuple[str, ...] = ()) -> str:
    """Write one mutation of ``doc`` to ``path`` (a JSON mutation, or a text one of its bytes); the mutation's name."""
    from fuzz import mutate_text

    if rng.random() < 0.2:
        data, kind = mutate_text(json.dumps(doc).encode(), rng)
        path.write_bytes(data)
        return kind
    doc, kind = mutate_json(copy.deepcopy(doc), rng, keys)
    path.write_bytes(json_bytes(doc, rng))
    return kind


# --- base inputs -------------------------------------------------------------------------------------------------

K_APOLLO = [[2304.5, 0.0, 1686.2], [0.0, 2305.9, 1355.0], [0.0, 0.0, 1.0]]
CAR_MODELS = {"0": {"name": "hatch", "type": "2x", "length": 3.96, "width_body": 1.68, "width_with_mirrors": 1.93,
                    "height": 1.43},
              "35": {"name": "saloon", "type": "3x", "length": 4.85, "width_body": 1.82, "width_with_mirrors": 2.05,
                     "height": 1.46},
              "60": {"name": "suv", "type": "SUV", "length": 4.6, "width_body": 1.9, "width_with_mirrors": 2.1,
                     "height": 1.7}}


def apollo_dataset(folder: Path, images: int = 3, seed: int = 0) -> dict[str, Path]:
    """A small ApolloCar3D-like dataset: a keypoint file (cars at poses, 14-30 of the 66 keypoints labelled where
    the bundled mapping puts them, projected), car models, and the cameras as JSON, KITTI calib and OpenCV YAML."""
    from toosicubix.annotations.mapping import load_mapping
    from toosicubix.formats.apollocar3d import PROTOTYPE_OF_TYPE, pose_to_vehicle

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    mapping = load_mapping("apollocar3d-66")[0]
    K = np.array(K_APOLLO)
    coco: dict[str, Any] = {"images": [], "categories": [{"id": 0, "name": "car", "keypoints": [""] * 66}],
                            "annotations": []}
    for i in range(images):
        coco["images"].append({"id": 1000 + i, "file_name": f"17120{i}_Camera_5.jpg", "width": 3384, "height": 2710})
        for c in range(2):
            model = ["0", "35", "60"][(i + c) % 3]
            d = np.array([CAR_MODELS[model][k] for k in ("length", "width_body", "height")])
            pose = np.array([np.pi, rng.uniform(-0.05, 0.05), rng.uniform(-np.pi, np.pi), -4.0 + 8.0 * c,
                             rng.uniform(1.2, 1.6), rng.uniform(12.0, 30.0)])
            R, t = pose_to_vehicle(pose, d)
            typical = mapping.keypoint_candidates(PROTOTYPE_OF_TYPE[CAR_MODELS[model]["type"]])
            keypoints = [0.0] * 198
            for j in rng.choice(66, size=int(rng.integers(14, 31)), replace=False):
                at = typical.get(mapping.keypoints[j])
                if at is None:
                    continue
                x = K @ (R @ (d * np.asarray(at.at)) + t)
                keypoints[3 * j: 3 * j + 3] = [round(float(x[0] / x[2]), 1), round(float(x[1] / x[2]), 1), 2]
            u = np.array(keypoints).reshape(-1, 3)
            u = u[u[:, 2] > 0]
            box = [float(u[:, 0].min() - 10), float(u[:, 1].min() - 10), float(np.ptp(u[:, 0]) + 20),
                   float(np.ptp(u[:, 1]) + 20)]
            coco["annotations"].append({"id": 10 * i + c, "image_id": 1000 + i, "category_id": int(model),
                                        "bbox": box, "keypoints": keypoints, "pose": pose.round(6).tolist(),
                                        "num_keypoints": len(u)})
    files = {"keypoints": folder / "apollo.json", "car_models": folder / "car_models.json",
             "cameras": folder / "cameras.json", "calib": folder / "calib.txt", "yaml": folder / "camera.yaml"}
    files["keypoints"].write_text(json.dumps(coco))
    files["car_models"].write_text(json.dumps(CAR_MODELS))
    files["cameras"].write_text(json.dumps({"cameras": [{"match": "*Camera_5*", "K": K_APOLLO}]}))
    P2 = " ".join(f"{v:.6f}" for v in np.hstack([K, np.zeros((3, 1))]).ravel())
    files["calib"].write_text(f"P0: {P2}\nP1: {P2}\nP2: {P2}\nP3: {P2}\nR0_rect: 1 0 0 0 1 0 0 0 1\n")
    files["yaml"].write_text("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: ["
                             + ", ".join(str(v) for v in K.ravel()) + "]\ndistortion_coefficients: !!opencv-matrix\n"
                             "  rows: 1\n  cols: 5\n  dt: d\n  data: [0, 0, 0, 0, 0]\n")
    return files


def video_coco(folder: Path) -> tuple[Path, Path]:
    """A TAO-like video COCO file from the sample's clicks (the ``toosicubix`` mapping's keypoint names), and a
    cameras file for it."""
    from toosicubix.parts.keypoints import KEYPOINTS, keypoints_from_parts

    sample = json.loads(SAMPLE.read_text())
    names = list(KEYPOINTS)
    coco: dict[str, Any] = {"videos": [{"id": 3, "name": "drive/3"}], "images": [], "annotations": [],
                            "categories": [{"id": 1, "name": "car", "keypoints": names}]}
    for i, image in enumerate(sample["images"]):
        w, h = image["size"]
        coco["images"].append({"id": i + 1, "video_id": 3, "frame_index": i, "file_name": f"drive/{i:04d}.jpg",
                               "width": w, "height": h})
        for j, vehicle in enumerate(image["vehicles"]):
            flat = [0.0] * (3 * len(names))
            for name, xy in keypoints_from_parts([p for p in vehicle["parts"]
                                                  if p["kind"] in ("point", "symmetry", "direction")]):
                k = names.index(name)
                flat[3 * k: 3 * k + 3] = [xy[0], xy[1], 2]
            coco["annotations"].append({"id": 10 * i + j, "image_id": i + 1, "category_id": 1, "track_id": j,
                                        "keypoints": flat, "bbox": [10.0, 20.0, 100.0, 50.0]})
    path, cameras = folder / "video.json", folder / "video_cameras.json"
    path.write_text(json.dumps(coco))
    K = sample["images"][0]["camera"].get("K") or [row[:3] for row in sample["images"][0]["camera"]["P"]]
    cameras.write_text(json.dumps({"cameras": [{"match": "*", "K": K}]}))
    return path, cameras


def cvat_images_xml(sample: dict[str, Any]) -> str:
    """CVAT for images 1.1 of the sample's clicks: a skeleton per vehicle, its box as a grouped box."""
    from xml.sax.saxutils import quoteattr

    from toosicubix.parts.keypoints import keypoints_from_parts

    out = ['<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n  <version>1.1</version>\n  <meta><task><id>7</id>'
           '<name>sample</name></task></meta>']
    for i, image in enumerate(sample["images"]):
        w, h = image["size"]
        out.append(f'  <image id="{i}" name="frames/{image["id"]}.png" width="{w}" height="{h}">')
        for j, vehicle in enumerate(image["vehicles"]):
            out.append(f'    <skeleton label="vehicle" source="manual" z_order="0" group_id="{j + 1}">')
            for name, xy in keypoints_from_parts([p for p in vehicle["parts"]
                                                  if p["kind"] in ("point", "symmetry", "direction")]):
                out.append(f'      <points label={quoteattr(name)} source="manual" outside="0" occluded="0" '
                           f'points="{xy[0]:.2f},{xy[1]:.2f}"></points>')
            out.append(f'      <attribute name="prototype">{vehicle["prototype"]}</attribute>\n    </skeleton>')
            if vehicle.get("box2d"):
                x1, y1, x2, y2 = vehicle["box2d"]
                out.append(f'    <box label="Car" source="manual" occluded="0" xtl="{x1:.2f}" ytl="{y1:.2f}" '
                           f'xbr="{x2:.2f}" ybr="{y2:.2f}" z_order="0" group_id="{j + 1}"></box>')
        out.append("  </image>")
    out.append("</annotations>\n")
    return "\n".join(out)


def label_studio_export(sample: dict[str, Any]) -> list[dict[str, Any]]:
    """Label Studio's export of the sample's clicks: a box per vehicle, its keypoints nested in it (percent)."""
    from toosicubix.parts.keypoints import keypoints_from_parts

    tasks = []
    for i, image in enumerate(sample["images"]):
        w, h = image["size"]
        result = []
        for j, vehicle in enumerate(image["vehicles"]):
            clicked = keypoints_from_parts([p for p in vehicle["parts"] if p["kind"] in ("point", "symmetry",
                                                                                         "direction")])
            xs = [xy[0] for _, xy in clicked]
            ys = [xy[1] for _, xy in clicked]
            box = vehicle.get("box2d") or [min(xs) - 5, min(ys) - 5, max(xs) + 5, max(ys) + 5]
            box_id = f"b{i}_{j}"
            result.append({"id": box_id, "type": "rectanglelabels", "from_name": "vehicle", "to_name": "image",
                           "original_width": w, "original_height": h, "image_rotation": 0,
                           "value": {"x": 100 * box[0] / w, "y": 100 * box[1] / h, "width": 100 * (box[2] - box[0]) / w,
                                     "height": 100 * (box[3] - box[1]) / h, "rotation": 0,
                                     "rectanglelabels": [vehicle["prototype"]]}})
            for k, (name, xy) in enumerate(clicked):
                result.append({"id": f"k{i}_{j}_{k}", "type": "keypointlabels", "from_name": "keypoint",
                               "to_name": "image", "original_width": w, "original_height": h, "image_rotation": 0,
                               "parentID": box_id, "value": {"x": 100 * xy[0] / w, "y": 100 * xy[1] / h,
                                                             "width": 0.5, "keypointlabels": [name]}})
        tasks.append({"id": i + 1, "data": {"image": f"/data/upload/1/5f3a2b1c-{image['id']}.png"},
                      "annotations": [{"id": 100 + i, "result": result, "was_cancelled": False}]})
    return tasks


def sample_cameras(sample: dict[str, Any], folder: Path) -> Path:
    """A cameras file for the sample's images under any name (K = P[:, :3])."""
    camera = sample["images"][0]["camera"]
    K = camera.get("K") or [row[:3] for row in camera["P"]]
    path = folder / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*", "K": K}]}))
    return path


def fit_in_process(annotations: Path, out: Path) -> None:
    from toosicubix.pipeline.batch import fit_file

    fit_file(annotations, out)


# --- cameras files ----------------------------------------------------------------------------------------------

def mutated_cameras(files: dict[str, Path], rng: random.Random, folder: Path) -> tuple[Path, str]:
    """A cameras file in one of the forms ``--cameras`` takes, mutated (or a folder of KITTI calib files)."""
    from fuzz import mutate_text

    form = rng.choice(["json", "calib", "yaml", "folder"])
    if form == "json":
        path = folder / "cameras.json"
        return path, "cameras-" + mutated_json_file(json.loads(files["cameras"].read_text()), rng, path, ("K",))
    if form == "folder":
        calib = folder / "calib"
        calib.mkdir(exist_ok=True)
        keypoints = json.loads(files["keypoints"].read_text())
        for image in keypoints["images"][: rng.randint(0, len(keypoints["images"]))]:
            (calib / f"{Path(image['file_name']).stem}.txt").write_bytes(files["calib"].read_bytes())
        return calib, "cameras-folder"
    source = files["calib" if form == "calib" else "yaml"]
    data = source.read_bytes()
    if rng.random() < 0.5:
        tokens = data.split(b" ")
        k = rng.randrange(len(tokens))
        value = hostile_value(rng)
        tokens[k] = (str(value)[:6000] if not isinstance(value, int) or value.bit_length() < 1000 else "9" * 5000
                     ).encode("utf-8", "surrogatepass") + (b"\n" if tokens[k].endswith(b"\n") else b"")
        data, kind = b" ".join(tokens), "token"
    else:
        data, kind = mutate_text(data, rng)
    path = folder / source.name
    path.write_bytes(data)
    return path, f"cameras-{form}-{kind}"


# --- the targets ------------------------------------------------------------------------------------------------

class CocoTarget(Target):
    name = "coco"

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        self.apollo = apollo_dataset(work / "apollo")
        self.video, self.video_cameras = video_coco(work)

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        rng = self.rng(index, seed)
        out = folder / "ann.json"
        if rng.random() < 0.5:
            source, mapping, cameras = self.apollo["keypoints"], "apollocar3d-66", self.apollo["cameras"]
        else:
            source, mapping, cameras = self.video, "toosicubix", self.video_cameras
        doc = json.loads(source.read_text())
        path = folder / "coco.json"
        if rng.random() < 0.15 and source == self.apollo["keypoints"]:
            cameras, kind = mutated_cameras(self.apollo, rng, folder)
            path.write_text(json.dumps(doc))
        elif rng.random() < 0.02:  # a large file: its memory is what is measured
            annotations = doc["annotations"]
            doc["images"] = [{**im, "id": im["id"] * 1000 + r, "file_name": f"r{r}_{im['file_name']}"}
                             for r in range(300) for im in doc["images"]]
            doc["annotations"] = [{**a, "id": n, "image_id": a["image_id"] * 1000 + r}
                                  for n, (r, a) in enumerate((r, a) for r in range(300) for a in annotations)]
            path.write_text(json.dumps(doc))
            kind = "large"
        else:
            kind = mutated_json_file(doc, rng, path, ("id", "image_id", "category_id", "bbox", "keypoints", "width",
                                                      "height", "K", "track_id", "video_id", "frame_index"))
        return kind, [Command("import coco", ["import", "coco", str(path), "--mapping", mapping, "--cameras",
                                              str(cameras), "-o", str(out), "-q"], out)]


#: XML documents an attacker writes around (or instead of) the CVAT export (``{body}``: the export without its
#: XML declaration).
XML_ATTACKS = {
    "laughs": ('<!DOCTYPE annotations [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
               '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;"><!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">'
               '<!ENTITY e "&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;"><!ENTITY f "&e;&e;&e;&e;&e;&e;&e;&e;&e;&e;">]>\n'),
    "external": '<!DOCTYPE annotations [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n',
    "remote": '<!DOCTYPE annotations SYSTEM "http://127.0.0.1:9/cvat.dtd">\n',
    "parameter": '<!DOCTYPE annotations [<!ENTITY % p SYSTEM "http://127.0.0.1:9/p.dtd"> %p;]>\n',
    "comment": "<!--" + "x" * 5000 + "-->\n" + '<!DOCTYPE annotations [<!ENTITY c "cccccccccc">]>\n',
}


class CvatTarget(Target):
    name = "cvat"

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        sample = json.loads(SAMPLE.read_text())
        self.images_xml = cvat_images_xml(sample)
        self.video_xml = CVAT_VIDEO.read_text()
        self.cameras = sample_cameras(sample, work)

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        from fuzz import mutate_text

        rng = self.rng(index, seed)
        text = self.images_xml if rng.random() < 0.6 else self.video_xml
        body = text.split("?>", 1)[1] if text.startswith("<?xml") else text
        family = rng.choice(["text", "attribute", "attribute", "attack", "encoding", "zip"])
        kind = family
        data: bytes
        if family == "text":
            data, kind = mutate_text(text.encode(), rng)
        elif family == "attribute":
            import re

            values = list(re.finditer(r'="([^"]*)"', text))
            found = rng.choice(values)
            value = hostile_value(rng)
            new = ("9" * 5000 if value == "__HUGE__" else str(value)[:6000]).replace("&", "&amp;").replace(
                "<", "&lt;").replace('"', "&quot;")
            data = (text[:found.start(1)] + new + text[found.end(1):]).encode("utf-8", "surrogatepass")
        elif family == "attack":
            name = rng.choice(sorted(XML_ATTACKS))
            use = {"laughs": "&f;", "external": "&x;", "comment": "&c;"}.get(name, "")
            data = ('<?xml version="1.0" encoding="utf-8"?>\n' + XML_ATTACKS[name]
                    + body.replace("<version>1.1</version>", f"<version>1.1</version><x>{use}</x>", 1)).encode()
            kind = f"attack:{name}"
        elif family == "encoding":
            encoding = rng.choice(["utf-16", "utf-16-le", "utf-16-be", "latin-1", "utf-32"])
            head = f'<?xml version="1.0" encoding="{encoding.replace("-le", "").replace("-be", "")}"?>'
            attack = XML_ATTACKS["laughs"] if rng.random() < 0.5 else ""
            xml = head + "\n" + attack + body.replace("<version>1.1</version>",
                                                      f"<version>1.1</version><x>{'&f;' if attack else ''}</x>", 1)
            data = xml.encode(encoding, "replace")
            kind = f"encoding:{encoding}{':laughs' if attack else ''}"
        else:
            data, kind = self._zip(text, rng, folder)
        path = folder / ("export.zip" if family == "zip" else "annotations.xml")
        path.write_bytes(data)
        out = folder / "ann.json"
        return kind, [Command("import cvat", ["import", "cvat", str(path), "--cameras", str(self.cameras), "-o",
                                              str(out), "-q"], out)]

    def _bomb(self) -> bytes:
        """A zip whose annotations.xml is 600 MB of spaces deflated to under a megabyte (made once: seconds)."""
        if getattr(self, "_bomb_zip", None) is None:
            buffer = io.BytesIO()
            with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
                info = zipfile.ZipInfo("annotations.xml")
                info.compress_type = zipfile.ZIP_DEFLATED
                with archive.open(info, "w", force_zip64=True) as handle:
                    handle.write(b"<annotations>")
                    block = b" " * (1 << 20)
                    for _ in range(600):
                        handle.write(block)
                    handle.write(b"</annotations>")
            self._bomb_zip = buffer.getvalue()
        return self._bomb_zip

    def _zip(self, text: str, rng: random.Random, folder: Path) -> tuple[bytes, str]:
        how = rng.choice(["plain", "bomb", "two", "none", "cut", "traversal", "stored-huge"])
        if how == "bomb":
            return self._bomb(), "zip:bomb"
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
            if how in ("plain", "cut", "two", "traversal"):
                archive.writestr("../annotations.xml" if how == "traversal" else "annotations.xml", text)
            if how == "two":
                archive.writestr("old/annotations.xml", text)
            if how == "stored-huge":
                archive.writestr("annotations.xml", "<annotations>" + " " * 1000 + "</annotations>")
            archive.writestr("images/frame_000000.PNG", b"\x89PNG\r\n\x1a\n" + bytes(32))
        data = buffer.getvalue()
        if how == "cut":
            data = data[: rng.randrange(len(data))]
        if how == "stored-huge":  # the central directory understates the member's size
            data = data.replace(struct.pack("<I", 1026 + 13), struct.pack("<I", 10), 2)
        return data, f"zip:{how}"


class LabelStudioTarget(Target):
    name = "label-studio"

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        sample = json.loads(SAMPLE.read_text())
        self.export = label_studio_export(sample)
        self.cameras = sample_cameras(sample, work)

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        rng = self.rng(index, seed)
        doc = copy.deepcopy(self.export)
        path = folder / "export.json"
        if rng.random() < 0.25:
            url = rng.choice(["http://[abc/x.png", "http://[::1/x.png", "/data/local-files/?d=..%2F..%2F000001.png",
                              "http://host/img/..%2F..%2Fetc%2Fx.png", "../../x.png", "s3://b/../../x.png",
                              "/data/local-files/?d=%2Fetc%2Fpasswd", "http://h:99999/x.png", "%zz%00", "\x00",
                              "/data/upload/1/5f3a2b1c-" + "a" * 5000 + ".png", "azure-blob://c/k/x.png"])
            rng.choice(doc)["data"]["image"] = url
            path.write_text(json.dumps(doc))
            kind = "url"
        else:
            kind = mutated_json_file(doc, rng, path, ("original_width", "original_height", "x", "y", "width",
                                                      "height", "id", "parentID", "from_id", "to_id", "image"))
        out = folder / "ann.json"
        return kind, [Command("import label-studio", ["import", "label-studio", str(path), "--cameras",
                                                      str(self.cameras), "-o", str(out), "-q"], out)]


class LearnPartsTarget(Target):
    name = "learn-parts"

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        self.apollo = apollo_dataset(work / "apollo", images=2)
        from toosicubix.annotations.mapping import load_mapping

        self.mapping = load_mapping("apollocar3d-66")[0].model_dump(mode="json", exclude_none=True)

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        rng = self.rng(index, seed)
        keypoints, models, cameras = self.apollo["keypoints"], self.apollo["car_models"], self.apollo["cameras"]
        which = rng.choice(["keypoints", "car_models", "car_models", "cameras", "mapping", "mapping-coco"])
        mapping = "apollocar3d-66"
        if which == "keypoints":
            keypoints = folder / "apollo.json"
            kind = mutated_json_file(json.loads(self.apollo["keypoints"].read_text()), rng, keypoints,
                                     ("image_id", "category_id", "pose", "id", "keypoints", "bbox"))
        elif which == "car_models":
            models = folder / "car_models.json"
            kind = self._car_models(rng, models)
        elif which == "cameras":
            cameras, kind = mutated_cameras(self.apollo, rng, folder)
        else:
            mapping_path = folder / "mapping.json"
            kind = mutated_json_file(self.mapping, rng, mapping_path, ("keypoints", "at", "spread", "metres", "sigma",
                                                                       "prototypes", "seen_from"))
            mapping = str(mapping_path)
        out = folder / "learned.json"
        if which == "mapping-coco":
            return f"mapping:{kind}", [Command("import coco --mapping", [
                "import", "coco", str(keypoints), "--mapping", mapping, "--cameras", str(cameras), "-o",
                str(folder / "ann.json"), "-q"], folder / "ann.json")]
        return f"{which}:{kind}", [Command("learn-parts", [
            "learn-parts", str(keypoints), "--car-models", str(models), "--cameras", str(cameras), "--mapping", mapping,
            "--min-samples", "3", "-o", str(out)], out)]

    def _car_models(self, rng: random.Random, path: Path) -> str:
        """Car models with colliding, hostile or odd keys half the time, else a JSON mutation."""
        if rng.random() < 0.5:
            return mutated_json_file(CAR_MODELS, rng, path, ("length", "width_body", "height", "name", "type"))
        key = rng.choice(["035", "\u0663\u0665", "35", "\u00b2", "9" * 5000, "-1", " 35", "3_5", "1e3", "", "+0",
                          "\uff13\uff15", "0" * 30 + "35"])
        text = json.dumps(CAR_MODELS)[:-1] + f', "{key}": ' + json.dumps(CAR_MODELS["35"]) + "}"
        path.write_text(text)
        return f"key:{key[:8]!r}"


class EvalApolloTarget(Target):
    name = "eval-apollocar3d"

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        from toosicubix.annotations.mapping import load_mapping
        from toosicubix.formats.cameras import load_cameras
        from toosicubix.formats.coco import CocoImport

        self.apollo = apollo_dataset(work / "apollo", images=2)
        imported = CocoImport(self.apollo["keypoints"], load_mapping("apollocar3d-66")[0],
                              load_cameras(self.apollo["cameras"]))
        annotations = work / "apollo_ann.json"
        imported.write(annotations)
        self.fit = work / "apollo_fit"
        fit_in_process(annotations, self.fit)

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        rng = self.rng(index, seed)
        keypoints, models, cameras = self.apollo["keypoints"], self.apollo["car_models"], self.apollo["cameras"]
        which = rng.choice(["keypoints", "keypoints", "car_models", "cameras"])
        if which == "keypoints":
            keypoints = folder / "apollo.json"
            kind = mutated_json_file(json.loads(self.apollo["keypoints"].read_text()), rng, keypoints,
                                     ("image_id", "category_id", "pose", "id", "keypoints", "bbox", "file_name"))
        elif which == "car_models":
            models = folder / "car_models.json"
            kind = LearnPartsTarget._car_models(self, rng, models)  # type: ignore[arg-type]
        else:
            cameras, kind = mutated_cameras(self.apollo, rng, folder)
        report = folder / "eval"
        return f"{which}:{kind}", [Command("eval --apollocar3d", [
            "eval", str(self.fit), "--apollocar3d", str(keypoints), "--car-models", str(models), "--cameras",
            str(cameras), "-q", "--json", str(report / "eval.json"), "--csv", str(report / "eval.csv")], report)]


ROTATIONS = {"reflection": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]], "zero": [[0, 0, 0]] * 3,
             "scaled": [[2, 0, 0], [0, 2, 0], [0, 0, 2]], "huge": [[1e154, 0, 0], [0, 1, 0], [0, 0, 1]],
             "nearly": [[1, 1e-5, 0], [0, 1, 0], [0, 0, 1]]}


class SampleFitTarget(Target):
    """A target whose base input is the bundled sample's fit: :attr:`annotations` (the sample, copied), :attr:`fit`
    (its output folder) and :attr:`results` (its results.json)."""

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        self.annotations = work / "sample.json"
        shutil.copy(SAMPLE, self.annotations)
        self.fit = work / "sample_fit"
        fit_in_process(self.annotations, self.fit)
        self.results = json.loads((self.fit / "results.json").read_text())


class ExportTarget(SampleFitTarget):
    name = "export"

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        rng = self.rng(index, seed)
        out = folder / "fit"
        shutil.copytree(self.fit, out)
        doc = copy.deepcopy(self.results)
        vehicles = [v for im in doc["images"] for v in im["vehicles"]]
        roll = rng.random()
        if roll < 0.3:
            v = rng.choice(vehicles)
            key = rng.choice(["R_cam_vehicle", "t_cam_vehicle", "dimensions", "sigma", "confidence", "rms_px",
                              "prototype", "warnings", "residuals_px", "status", "box2d"])
            if key == "R_cam_vehicle" and rng.random() < 0.6:
                name = rng.choice(sorted(ROTATIONS))
                v[key], kind = ROTATIONS[name], f"rotation:{name}"
            elif key == "t_cam_vehicle" and rng.random() < 0.6:
                v[key], kind = [rng.choice([1e308, 1e6, 9e5, -1e5, 0.0, 1e-300]), 0.0, rng.choice([1e308, 20.0, 0.01])
                                ], "translation"
            elif key == "sigma" and isinstance(v.get("sigma"), dict):
                v["sigma"][rng.choice(sorted(v["sigma"]))] = hostile_value(rng)
                kind = "sigma"
            else:
                v[key], kind = hostile_value(rng), f"value:{key}"
            (out / "results.json").write_bytes(json_bytes(doc, rng))
        elif roll < 0.9:
            kind = "results-" + mutated_json_file(doc, rng, out / "results.json",
                                                  ("K", "image_size", "t_cam_rect", "R_cam_vehicle", "sigma"))
        else:
            annotations = folder / "annotations.json"
            kind = "annotations-" + mutated_json_file(json.loads(self.annotations.read_text()), rng, annotations)
            doc["annotations"], doc["annotations_sha256"] = str(annotations), None
            (out / "results.json").write_text(json.dumps(doc))
        return kind, [Command("export openlabel", ["export", "openlabel", str(out), "-o", str(folder / "l.json"),
                                                   "-q"], folder / "l.json"),
                      Command("export cvat", ["export", "cvat", str(out), "-o", str(folder / "r.xml"), "-q"],
                              folder / "r.xml")]


def png_declaring(width: int, height: int) -> bytes:
    """A tiny PNG whose header declares ``width`` x ``height``."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00" * 4096)) + chunk(b"IEND", b""))


class RenderTarget(SampleFitTarget):
    name = "render"

    def prepare(self, work: Path) -> None:
        super().prepare(work)
        import cv2

        self.sample = json.loads(SAMPLE.read_text())
        w, h = self.sample["images"][0]["size"]
        self.photo = cv2.imencode(".png", np.full((h, w, 3), 90, np.uint8))[1].tobytes()
        self.jpeg = cv2.imencode(".jpg", np.full((h, w, 3), 90, np.uint8))[1].tobytes()

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        from fuzz import mutate_text

        rng = self.rng(index, seed)
        doc = copy.deepcopy(self.sample)
        image = rng.choice(doc["images"])
        kinds = []
        if rng.random() < 0.5:
            image["size"] = list(rng.choice(ABSURD_SIZES))
            kinds.append(f"size:{image['size'][0]}x{image['size'][1]}")
        if rng.random() < 0.5:
            name = rng.choice(["huge.png", "cut.png", "random.png", "lying.jpg", "photo.png", "bad.jpg", "empty.png"])
            data = {"huge.png": png_declaring(rng.choice([60_000, 20_000, 2**31 - 1, 0]), rng.choice([60_000, 5, 0])),
                    "cut.png": self.photo[: rng.randrange(len(self.photo))],
                    "random.png": bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))),
                    "lying.jpg": self.photo, "photo.png": self.photo,
                    "bad.jpg": mutate_text(self.jpeg, rng)[0], "empty.png": b""}[name]
            (folder / name).write_bytes(data)
            image["file"] = name
            kinds.append(f"file:{name}")
        results = copy.deepcopy(self.results)
        if rng.random() < 0.3:
            results, kind = mutate_json(results, rng, ("K", "image_size", "t_cam_vehicle", "dimensions", "sigma"))
            kinds.append(f"results-{kind}")
        if not kinds or rng.random() < 0.2:
            doc, kind = mutate_json(doc, rng, ("size", "K", "P", "distortion", "xy", "box2d"))
            kinds.append(f"annotations-{kind}")
        annotations = folder / "annotations.json"
        annotations.write_bytes(json_bytes(doc, rng))
        out = folder / "fit"
        shutil.copytree(self.fit, out)
        if isinstance(results, dict):
            results["annotations"] = str(annotations)
        (out / "results.json").write_bytes(json_bytes(results, rng))
        pictures = folder / "pictures"
        return "+".join(kinds), [Command("render", ["render", str(out), "--annotations", str(annotations), "-o",
                                                    str(pictures), "-q"], pictures)]


#: A synthetic KITTI tracking sequence for :class:`TracksTarget`: (track id, type, h, w, l, first frame, last frame,
#: the bottom centre (x, y, z) in metres and rotation_y at the first frame, and their change a frame).
SYNTHETIC_TRACKS = ((0, "Car", 1.5, 1.7, 4.2, 0, 15, (-3.0, 1.65, 12.0, -1.45), (0.0, 0.0, 0.6, 0.004)),
                    (1, "Van", 2.1, 1.9, 5.0, 0, 15, (-9.0, 1.65, 26.0, 0.05), (1.1, 0.0, 0.0, 0.0)),
                    (2, "Car", 1.45, 1.75, 4.4, 3, 14, (4.5, 1.7, 15.0, 1.9), (0.0, 0.0, 0.0, 0.0)))
P_TRACKING = np.array([[720.0, 0.0, 621.0, 0.0], [0.0, 720.0, 187.5, 0.0], [0.0, 0.0, 1.0, 0.0]])


def synthetic_tracking(root: Path, sequence: str = "0007") -> Path:
    """A KITTI tracking root (``label_02/<sequence>.txt``, ``calib/<sequence>.txt``) of :data:`SYNTHETIC_TRACKS`:
    made here, so that the fuzz needs no dataset."""
    lines = []
    for track, kind, h, w, length, first, last, start, step in SYNTHETIC_TRACKS:
        for frame in range(first, last + 1):
            x, y, z, ry = (a + b * (frame - first) for a, b in zip(start, step, strict=True))
            c, s = np.cos(ry), np.sin(ry)
            # KITTI's box: bottom centre (x, y, z), y down, rotation_y about y; its 8 corners in camera 2
            corners = np.array([[x + c * dx * length / 2 + s * dz * w / 2, y - dy * h,
                                 z - s * dx * length / 2 + c * dz * w / 2]
                                for dx in (-1, 1) for dz in (-1, 1) for dy in (0, 1)])
            uvw = np.c_[corners, np.ones(8)] @ P_TRACKING.T
            u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
            box = (max(u.min(), 0.0), max(v.min(), 0.0), min(u.max(), 1241.0), min(v.max(), 374.0))
            alpha = ry - np.arctan2(x, z)
            lines.append(f"{frame} {track} {kind} 0 0 {alpha:.6f} " + " ".join(f"{b:.2f}" for b in box)
                         + f" {h:.6f} {w:.6f} {length:.6f} {x:.6f} {y:.6f} {z:.6f} {ry:.6f}")
    (root / "label_02").mkdir(parents=True, exist_ok=True)
    (root / "calib").mkdir(exist_ok=True)
    lines.sort(key=lambda line: (int(line.split()[0]), int(line.split()[1])))
    (root / "label_02" / f"{sequence}.txt").write_text("\n".join(lines) + "\n")
    P = " ".join(f"{v:.6e}" for v in P_TRACKING.ravel())
    (root / "calib" / f"{sequence}.txt").write_text(
        "".join(f"P{k}: {P}\n" for k in range(4)) + "R_rect: 1 0 0 0 1 0 0 0 1\n"
        "Tr_velo_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\nTr_imu_velo: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    return root


class TracksTarget(Target):
    """Sequences (issue 32) and what reads their fits: a file of frames with tracks (simulated on
    :func:`synthetic_tracking`, clicks on every fifth frame, boxes on every frame; its frames named as ``import
    cvat`` names a video task's, so that ``export cvat`` writes CVAT tracks) mutated, then ``fit`` and
    ``validate``; or its fit's results.json mutated where a sequence lives (``track``, ``pose_from``, ``sequence``,
    ``frame``, ``track_ids``), then ``export openlabel``, ``export cvat`` and ``render --video``."""

    name = "tracks"

    def prepare(self, work: Path) -> None:
        from click.testing import CliRunner

        from toosicubix.cli import main

        super().prepare(work)
        root = synthetic_tracking(work / "kitti_tracking")
        self.annotations = work / "tracks.json"
        result = CliRunner().invoke(main, ["simulate", "--kitti-tracking", str(root), "--tracks", "--keyframes", "5",
                                           "-o", str(self.annotations)], catch_exceptions=False)
        if result.exit_code != 0:
            raise RuntimeError(f"simulate --tracks failed: {result.output}")
        self.doc = json.loads(self.annotations.read_text())
        for image in self.doc["images"]:  # named as import cvat names a CVAT video task's frames: export cvat's tracks
            image["file"] = f"images/frame_{image['frame']:06d}.PNG"
        self.annotations.write_text(json.dumps(self.doc))
        self.fit = work / "tracks_fit"
        fit_in_process(self.annotations, self.fit)
        self.results = json.loads((self.fit / "results.json").read_text())

    def case(self, index: int, seed: int, folder: Path) -> tuple[str, list[Command]]:
        rng = self.rng(index, seed)
        if rng.random() < 0.5:
            annotations = folder / "annotations.json"
            if rng.random() < 0.5:
                doc, kind = self._sequence_mutation(copy.deepcopy(self.doc), rng)
                annotations.write_bytes(json_bytes(doc, rng))
            else:
                kind = mutated_json_file(self.doc, rng, annotations, ("sequence", "frame", "track", "box2d", "xy"))
            out = folder / "fit"
            return kind, [Command("fit", ["fit", str(annotations), "-o", str(out), "-q", "--jobs", "1"], out),
                          Command("validate", ["validate", str(annotations), "-q"]),
                          Command("render --video", ["render", str(out), "--video", "-o", str(folder / "pictures"),
                                                     "-q"], folder / "pictures")]
        out = folder / "fit"
        shutil.copytree(self.fit, out)
        kind = "results-" + mutated_json_file(self.results, rng, out / "results.json",
                                              ("track", "pose_from", "sequence", "frame", "track_ids", "id"))
        return kind, [Command("export openlabel", ["export", "openlabel", str(out), "-o", str(folder / "l.json"),
                                                   "-q"], folder / "l.json"),
                      Command("export cvat", ["export", "cvat", str(out), "-o", str(folder / "r.xml"), "-q"],
                              folder / "r.xml"),
                      Command("render --video", ["render", str(out), "--video", "-o", str(folder / "pictures"), "-q"],
                              folder / "pictures")]

    @staticmethod
    def _sequence_mutation(doc: dict[str, Any], rng: random.Random) -> tuple[dict[str, Any], str]:
        """A change a sequence's file may plausibly carry: frames far apart or out of order, a track moved, clicks
        taken off a track, boxes outside the image or turned inside out."""
        images = doc["images"]
        vehicles = [v for im in images for v in im["vehicles"]]
        kind = rng.choice(["frame-far", "frame-negative", "frame-shuffle", "frame-same", "track-moved",
                           "track-unclicked", "box-outside", "box-inverted", "sequence-split", "track-prototype"])
        if kind == "frame-far":
            rng.choice(images)["frame"] = rng.choice([10**6, 2**31 - 1, 2**53, 10**12])
        elif kind == "frame-negative":
            rng.choice(images)["frame"] = rng.choice([-1, -(2**31)])
        elif kind == "frame-shuffle":
            frames = [im["frame"] for im in images]
            rng.shuffle(frames)
            for im, frame in zip(images, frames, strict=True):
                im["frame"] = frame
            rng.shuffle(images)
        elif kind == "frame-same":
            a, b = rng.sample(images, 2)
            a["frame"] = b["frame"]
        elif kind == "track-moved":
            rng.choice(vehicles)["track"] = rng.choice([v["track"] for v in vehicles])
        elif kind == "track-unclicked":
            track = rng.choice(vehicles)["track"]
            for v in vehicles:
                if v["track"] == track:
                    v["parts"] = []
        elif kind in ("box-outside", "box-inverted"):
            for v in rng.sample(vehicles, max(1, len(vehicles) // 3)):
                x1, y1, x2, y2 = v.get("box2d") or [10.0, 10.0, 50.0, 40.0]
                v["box2d"] = ([x1 + 5000, y1 - 3000, x2 + 9000, y2 + 1e6] if kind == "box-outside"
                              else [x2, y2, x1, y1])
        elif kind == "sequence-split":
            for im in rng.sample(images, len(images) // 2):
                im["sequence"] = "0008"
        else:
            v = rng.choice(vehicles)
            v["prototype"] = "Van" if v.get("prototype") == "Car" else "Car"
        return doc, f"sequence:{kind}"


#: Every target by name, in the order a run takes them.
TARGETS: dict[str, type[Target]] = {t.name: t for t in (CocoTarget, CvatTarget, LabelStudioTarget, LearnPartsTarget,
                                                         EvalApolloTarget, ExportTarget, RenderTarget,
                                                         TracksTarget)}

# The page's JSON API: requests to a live server per worker, in a module of its own, which imports this one and adds
# its target to TARGETS (whichever of the two is imported first).
import fuzz_page  # noqa: E402, F401


def main(argv: list[str] | None = None) -> int:
    """Write one case's inputs into a folder and print its commands (to reproduce a finding)."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("target", choices=sorted(TARGETS))
    parser.add_argument("index", type=int)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-o", "--out", type=Path, required=True, help="folder for the base inputs and the case")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).parent))
    target = TARGETS[args.target]()
    (args.out / "base").mkdir(parents=True, exist_ok=True)
    target.prepare(args.out / "base")
    case = args.out / f"case{args.index}"
    case.mkdir(exist_ok=True)
    kind, commands = target.case(args.index, args.seed, case)
    print(f"{args.target} case {args.index} ({kind}):")
    for command in commands:
        print("  toosicubix " + " ".join(command.args))
    return 0


__all__ = ["TARGETS", "Command", "Target", "main"]

if __name__ == "__main__":
    sys.exit(main())

"""How many actions a person needs per vehicle with ``toosicubix annotate``: simulated annotators replayed through
the page's HTTP JSON API.

KITTI has no human part clicks, so the clicks are the simulated annotator's (:mod:`toosicubix.simulate.annotator`:
real ground-truth cuboids of the KITTI tracking *test* sequences 0010-0020, or with ``--split tuning`` the tuning
sequences 0000-0009, realistic part placement, 1 px noise, every visible part available). Each vehicle is annotated
in three modes, each stopping as soon as the fit is **right** (benchmarks/decisions.md, rule 24): after an annotation
is complete (clicked, its name the true one), the page's fit has its yaw within 5 degrees and its depth within 10 %
of KITTI's ground truth, whatever the page's own sigmas say. Counted: clicks and naming actions (choosing a name by
hotkey or palette, or renaming a click the page named wrong or left unnamed):

- ``named``: the annotator's parts in its order of preference, every one named first (one naming action each);
- ``auto``: the same order; a point part is clicked unnamed, and the page's name is kept when right (no action) and
  renamed when wrong or missing (one action); pairs and arrows are named first;
- ``guided``: as ``auto``, but once the fit exists the next part is the best of the page's targets the
  annotator can see (falling back to its own order when none of the five is visible to it).

Auto-naming accuracy is how often the name the page gave an unnamed click is the true one. The script uses the
page's API only, so it runs on older code too (rule 24 item 5: a page that names no click before a fit exists leaves
those clicks to the person).

``--apollocar3d`` measures it on ApolloCar3D's real keypoints instead (no replay through the page): every car of
``apollocar3d_val_dev.json`` with at least 10 labelled keypoints, imported with the bundled ``apollocar3d-66``
mapping, its parts in a seeded order (one generator, seed 0, shuffling each car in file order); the first k
named and fitted as the page fits them (``fit_one`` with the click noise and road normals the page estimates from
a file of the scored images, :func:`loaded_as_the_page`; ``--page-defaults``: 1.5 px and no road); then every other
click of the car is named by the page's rule (:func:`toosicubix.web.naming.naming_candidates` and
:func:`~toosicubix.web.naming.nearest_parts`) among every part of the mapping not in the first k, each
keypoint at its learned ``at`` fractions of the fitted cuboid (the mapping's positions are learned on these
same 100 images: in-sample for the positions; ``--out-of-sample`` learns them on the even images, as
``benchmarks/apollocar3d.py`` does, and scores the odd images' cars).

    python benchmarks/annotate.py --vehicles 60 -o benchmarks/results/annotate.json
    python benchmarks/annotate.py --vehicles 60 --kitti-ground -o benchmarks/results/annotate-kitti-ground.json
    python benchmarks/annotate.py --vehicles 60 --split tuning -o /tmp/annotate-tuning.json   # choosing settings
    python benchmarks/annotate.py --apollocar3d -o benchmarks/results/annotate-apollocar3d.json
    python benchmarks/annotate.py --apollocar3d --out-of-sample -o benchmarks/results/annotate-apollocar3d-odd.json
    python benchmarks/annotate.py --apollocar3d --guidance -o benchmarks/results/annotate-apollocar3d-guidance.json

``--apollocar3d --guidance`` measures the page's targets with a mapping (``annotate --mapping``) on the same real
keypoints, out of sample (positions learned on the even images, the odd images' cars with at least 10 labelled
keypoints scored). Each car starts from the first 4 of its labelled keypoints in a seeded order (seed 0), then
gains one labelled keypoint at a time in two orders: ``seeded`` (the rest of that order) and ``guided`` (the
first of the page's drawn targets, the five best visible ones inside the image, that the person labelled on this
car, else the next of the seeded order: a labelled keypoint stands for one the person could see). Each fit is
the page's (``fit_one`` with the page's estimates, as above, and the mapping's keypoints as candidates). Reported per
order and number of clicks: the share of cars validate calls well determined, and mean / median E_R (degrees)
and E_t (``|t - t_gt| / |t_gt|``, bottom-face centres) against the ground-truth poses.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from apollocar3d import learned_on, sorted_images
from common import SPLITS, default_data_dir, machine

from toosicubix.annotations.convert import load_images
from toosicubix.annotations.mapping import load_mapping
from toosicubix.annotations.priors_file import load_priors
from toosicubix.formats.cameras import load_cameras
from toosicubix.formats.coco import coco_to_annotations
from toosicubix.model import KITTI_GROUND
from toosicubix.pipeline.vehicle import fit_one
from toosicubix.simulate.annotator import (
    AnnotatorOptions,
    SelectionOptions,
    select_kitti_tracking,
    simulate_vehicle,
)
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.uncertainty import infinite_as_none
from toosicubix.web.client import Client
from toosicubix.web.naming import NAMING_GRAZING_DEG, naming_candidates, nearest_parts
from toosicubix.web.server import serve_in_thread
from toosicubix.web.session import Session

STRATEGIES = ("named", "auto", "guided")


def _state(client: Client, image: int, vehicle: str) -> dict:
    view = client.request("GET", f"/api/images/{image}")[1]
    return next(v for v in view["vehicles"] if v["id"] == vehicle)


#: Seconds per ``add_click`` request (the refit, auto-naming, suggestions and the atomic save included).
LATENCIES: list[float] = []


def _timed_edit(client: Client, change: dict, image: int) -> tuple[int, dict]:
    t0 = time.perf_counter()
    out = client.edit(change, image=image)
    LATENCIES.append(time.perf_counter() - t0)
    return out


#: Rule 24's criterion: the fit is right when its yaw is within this many degrees of the ground truth's ...
RIGHT_YAW_DEG = 5.0
#: ... and its depth within this share of the ground truth's.
RIGHT_DEPTH_REL = 0.10


def fit_errors(fit: dict, truth: tuple[float, float]) -> tuple[float, float] | None:
    """How far the page's fit (a vehicle's ``fit`` in ``GET /api/images/<i>``) is from the ground truth ``truth``
    = (KITTI ry, radians; bottom-centre depth, metres, in the frame of the image's K): the yaw error in degrees
    (wrapped, absolute) and the relative depth error; None when it is not fitted."""
    if fit.get("status") != "ok":
        return None
    ry_gt, z_gt = truth
    yaw = abs((fit["yaw_pitch_roll_deg"][0] - np.rad2deg(ry_gt) + 180.0) % 360.0 - 180.0)
    return float(yaw), float(abs(fit["t_cam_vehicle"][2] - z_gt) / z_gt)


def is_right(fit: dict, truth: tuple[float, float]) -> bool:
    """Rule 24's criterion: the fit's yaw within :data:`RIGHT_YAW_DEG` and its depth within :data:`RIGHT_DEPTH_REL`
    of the ground truth's."""
    errors = fit_errors(fit, truth)
    return errors is not None and errors[0] <= RIGHT_YAW_DEG and errors[1] <= RIGHT_DEPTH_REL


def replay(client: Client, image: int, parts: list, prototype: str, strategy: str,
           truth: tuple[float, float]) -> dict:
    """Annotate one vehicle with ``strategy`` until its fit is right (:func:`is_right`) or the person has no part
    left; the counts and auto-naming outcomes."""
    status, doc = client.edit({"op": "add_vehicle", "prototype": prototype}, image=image)
    assert status == 200, doc
    vehicle = doc["vehicle"]
    left = list(parts)
    clicks = naming = auto_right = auto_wrong = asked = asked_offered = 0
    confusions: list[tuple[str, str]] = []  # (true part, auto-given name)
    outcomes: list[tuple[int, bool, float | None]] = []  # (points clicked before, auto-given name right, its p)
    v = _state(client, image, vehicle)
    while left and not is_right(v["fit"], truth):
        fitted = v["fit"]["status"] == "ok"
        part = left[0]
        if strategy == "guided" and fitted:
            available = {(p.kind, p.name): p for p in left}
            part = next((available[(t["kind"], t["name"])] for t in v["targets"]
                         if (t["kind"], t["name"]) in available), left[0])
        left.remove(part)
        uv = part.uv.tolist()
        if strategy != "named" and part.kind == "point":
            if any(p["kind"] == part.kind and p["name"] == part.name for p in v["parts"]):
                continue  # clicked already (named so by the page before): the person leaves it
            status, doc = _timed_edit(client, {"op": "add_click", "vehicle": vehicle, "uv": uv}, image)
            assert status == 200, doc
            clicks += len(uv)
            auto = [a for a in doc["auto_named"] if a["vehicle"] == vehicle]
            mine = next(x for x in doc["vehicles"] if x["id"] == vehicle)["parts"]
            index = len(mine) - 1
            given = next((a for a in auto if a["part"] == index), None)
            if given is not None:
                outcomes.append((clicks - len(uv), given["name"] == part.name, given.get("probability")))
            if given is None:  # the page asked (or cannot name it yet): the person names it
                asked += 1
                offered = mine[index].get("choices") or []
                asked_offered += any(c["name"] == part.name for c in offered)
                naming += 1
                _rename(client, image, vehicle, index, part)
            elif given["name"] == part.name:
                auto_right += 1
            else:
                auto_wrong += 1
                confusions.append((part.name, given["name"]))
                naming += 1
                _rename(client, image, vehicle, index, part)
        else:
            change = {"op": "add_click", "vehicle": vehicle, "kind": part.kind, "name": part.name, "uv": uv}
            status, doc = _timed_edit(client, change, image)
            if status != 200:  # e.g. a part the annotator clicked twice: skip it
                continue
            clicks += len(uv)
            naming += 1
        v = _state(client, image, vehicle)
    right = is_right(v["fit"], truth)
    errors = fit_errors(v["fit"], truth)
    client.edit({"op": "delete_vehicle", "vehicle": vehicle}, image=image)
    return {"right": right, "clicks": clicks, "naming": naming, "actions": clicks + naming,
            "auto_right": auto_right, "auto_wrong": auto_wrong, "asked": asked, "asked_offered": asked_offered,
            "confusions": confusions, "outcomes": outcomes,
            "yaw_error_deg": None if errors is None else round(errors[0], 2),
            "depth_error_rel": None if errors is None else round(errors[1], 4),
            "well_determined": bool(v["fit"].get("well_determined")),
            "failed": None if v["fit"]["status"] == "ok" else v["fit"].get("error")}


def _rename(client: Client, image: int, vehicle: str, index: int, part) -> None:
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": index, "kind": part.kind,
                               "name": part.name}, image=image)
    assert status == 200, doc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=default_data_dir())
    parser.add_argument("--vehicles", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kitti-ground", action="store_true",
                        help="give the images KITTI's ground block (as annotate --kitti-ground)")
    parser.add_argument("--naming-confidence", type=float, default=None,
                        help="the page names a click when its best name is at least this probable, else asks "
                             "[default: the page's]")
    parser.add_argument("--naming-camera-height-sigma", default=None, metavar="METRES|none",
                        help="the camera height's sigma the page assumes before a fit (none: no height) "
                             "[default: the page's]")
    parser.add_argument("--naming-after-fit", choices=("prior", "fit"), default=None,
                        help="how the page names a click once a fit exists [default: the page's]")
    parser.add_argument("--naming-grid", action="store_true",
                        help="rule 24a: the auto mode under every naming setting of GRID (run with --split tuning)")
    parser.add_argument("--split", choices=sorted(SPLITS), default="test",
                        help="KITTI tracking sequences to draw from: test (0010-0020, the figures) or tuning "
                             "(0000-0009, for choosing the page's settings; rule 24)")
    parser.add_argument("--apollocar3d", action="store_true",
                        help="auto-naming on ApolloCar3D's real keypoints after the first k named clicks")
    parser.add_argument("--out-of-sample", action="store_true",
                        help="with --apollocar3d: positions learned on the even images, the odd images scored")
    parser.add_argument("--design", action="store_true",
                        help="with --apollocar3d: the learning half only (positions learned on images 0, 4, 8, ..., "
                             "the cars of images 2, 6, 10, ... scored), for choosing a setting "
                             "(benchmarks/decisions.md, rule 12)")
    parser.add_argument("--naming-grazing-deg", type=float, default=NAMING_GRAZING_DEG,
                        help="with --apollocar3d: name among keypoints on faces turned away by up to this (degrees; "
                             "negative: turned toward the camera by at least that) [default: the page's]")
    parser.add_argument("--guidance", action="store_true",
                        help="with --apollocar3d: the page's targets against a seeded order (out of sample)")
    parser.add_argument("--page-defaults", action="store_true",
                        help="with --apollocar3d: fit with the page's defaults (1.5 px, no road normal) instead of "
                             "the click noise and road normals it estimates from the file (as before they were)")
    parser.add_argument("--position-faces", action="store_true",
                        help="with --apollocar3d: a keypoint is seen on the faces its position sits near, not on "
                             "those it was learned to be seen from (as before rule 13)")
    parser.add_argument("--nearest", action="store_true",
                        help="with --apollocar3d (naming): the nearest keypoint, not the most probable (as before "
                             "rule 15)")
    parser.add_argument("-o", "--out", type=Path, default=None)
    args = parser.parse_args()
    if args.apollocar3d:
        estimates = not args.page_defaults
        report = (apollocar3d_guidance(args.data / "apollocar3d", args.seed, estimates, args.design,
                                       args.position_faces) if args.guidance else
                  apollocar3d_naming(args.data / "apollocar3d", args.seed, out_of_sample=args.out_of_sample,
                                     design=args.design, grazing_deg=args.naming_grazing_deg, estimates=estimates,
                                     position_faces=args.position_faces, nearest=args.nearest))
        if args.out:
            args.out.write_text((_compact_steps(report) if args.guidance else json.dumps(report, indent=1)) + "\n")
        print(json.dumps({k: v for k, v in report.items() if k != "cars"}, indent=1))
        return

    naming = _naming_settings(args)
    if args.naming_grid:
        report = naming_grid(args)
        if args.out:
            args.out.write_text(json.dumps(report, indent=1) + "\n")
        print(json.dumps(report, indent=1))
        return
    report = kitti_run(args.data, args.split, args.vehicles, args.seed, args.kitti_ground, naming)
    if args.out:
        args.out.write_text(_compact(report) + "\n")
    print(json.dumps({k: report[k] for k in ("vehicles", "seconds", "naming", "summary")}, indent=1))


def _naming_settings(args):
    """The naming settings the flags give, or None (the page's own)."""
    given = {"confidence": args.naming_confidence, "after_fit": args.naming_after_fit}
    if args.naming_camera_height_sigma is not None:
        given["camera_height_sigma_m"] = (None if args.naming_camera_height_sigma == "none"
                                          else float(args.naming_camera_height_sigma))
    given = {k: v for k, v in given.items() if v is not None}
    if not given:
        return None
    from toosicubix.web.placement import NAMING_SETTINGS

    return replace(NAMING_SETTINGS, **given)


#: Rule 24a's grid of the page's naming settings, run on the tuning sequences.
GRID = {"after_fit": ("prior", "fit"), "camera_height_sigma_m": (None, 0.25, 0.5, 1.0),
        "confidence": (0.0, 0.5, 0.7, 0.9)}


def naming_grid(args) -> dict:
    """Rule 24a: every setting of :data:`GRID` on ``args.split`` (the tuning sequences), the *auto* mode's figures of
    each, and the choice the rule makes."""
    import itertools

    from toosicubix.web.placement import NAMING_SETTINGS

    rows = []
    for after_fit, sigma, confidence in itertools.product(*GRID.values()):
        settings = replace(NAMING_SETTINGS, after_fit=after_fit, camera_height_sigma_m=sigma, confidence=confidence)
        report = kitti_run(args.data, args.split, args.vehicles, args.seed, args.kitti_ground, settings,
                           strategies=("auto",))
        auto = report["summary"]["auto"]
        rows.append({"settings": settings.to_json(), **{k: auto[k] for k in (
            "right", "right_share", "median_actions", "mean_actions", "auto_named", "auto_naming_accuracy",
            "asked")}})
        print(json.dumps(rows[-1]), file=sys.stderr)
    return {"benchmark": "annotate --naming-grid", "split": args.split, "vehicles": args.vehicles,
            "seed": args.seed, "machine": machine(), "grid": {k: list(v) for k, v in GRID.items()}, "rows": rows}


def kitti_run(data: Path, split: str, vehicles: int, seed: int, kitti_ground: bool, naming=None,
              strategies: tuple[str, ...] = STRATEGIES) -> dict:
    """The simulated annotators on ``vehicles`` vehicles of the KITTI tracking ``split`` (see the module), the
    page naming with ``naming`` (None: its own settings); the report."""
    LATENCIES.clear()
    chosen = select_kitti_tracking(data / "kitti_tracking",
                                   SelectionOptions(sequences=SPLITS[split], frames_per_track=1))
    rng = np.random.default_rng(seed)
    chosen = [chosen[i] for i in sorted(rng.choice(len(chosen), min(vehicles, len(chosen)), replace=False))]
    options = AnnotatorOptions(noise_px=1.0, max_clicks=40, seed=seed)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        cameras, images = {}, []
        for gt in chosen:
            if gt.image_id in cameras:
                continue
            w, h = gt.camera.image_size or (1242, 375)
            path = folder / f"{gt.image_id}.png"
            cv2.imwrite(str(path), np.zeros((h, w), np.uint8))
            cameras[gt.image_id] = gt.camera
            images.append(path)
        ground = KITTI_GROUND if kitti_ground else None
        given = {} if naming is None else {"naming": naming}  # older code takes no naming settings (rule 24 item 5)
        session = Session(images, folder / "annotations.json", cameras, load_priors(), ground=ground, **given)
        server = serve_in_thread(session)
        client = Client(*server.server_address[:2])
        index = {p.stem: i for i, p in enumerate(images)}
        rows = []
        try:
            for gt in chosen:
                sim = simulate_vehicle(gt, options)
                row = {"image": gt.image_id, "vehicle": gt.vehicle_id, "type": gt.label.type,
                       "available_parts": len(sim.parts)}
                truth = (float(gt.label.rotation_y), float(sim.t_cam_vehicle[2]))
                for strategy in strategies:
                    row[strategy] = replay(client, index[gt.image_id], sim.parts, gt.label.type, strategy, truth)
                rows.append(row)
        finally:
            server.shutdown()
            server.server_close()
    seconds = time.perf_counter() - t0
    summary = summarise(rows, strategies)
    summary["add_click_seconds"] = {"n": len(LATENCIES), "median": round(float(np.median(LATENCIES)), 3),
                                    "p90": round(float(np.percentile(LATENCIES, 90)), 3)}
    report = {"benchmark": "annotate", "vehicles": len(rows), "seconds": round(seconds, 1), "machine": machine(),
              "selection": (f"KITTI tracking {split} sequences {SPLITS[split][0]}-{SPLITS[split][-1]}, "
                            "one frame per track, seeded sample"),
              "annotator": {"noise_px": 1.0, "placement": "realistic"}, "kitti_ground": kitti_ground,
              "stop": (f"the fit is right: yaw within {RIGHT_YAW_DEG:g} deg and depth within "
                       f"{100 * RIGHT_DEPTH_REL:g} % of the ground truth's (rule 24)"),
              "naming": naming.to_json() if naming is not None else naming_settings(),
              "summary": summary, "rows": rows}
    return report


APOLLO_KS = (4, 6, 8)
APOLLO_MIN_KEYPOINTS = 10


def loaded_as_the_page(document: dict, scored_images: set[str] | None, priors, estimates: bool = True
                       ) -> tuple[list, SolverOptions, str]:
    """The scored images of an imported annotation ``document`` (all when ``scored_images`` is None), and the solver
    settings to fit them with, as the annotate page opened on a file of those images fits them: with the click
    noise and each camera's road normal that `fit` estimates from that file (the images put on their camera's
    estimated road). ``estimates`` False: the Session's defaults (1.5 px, no road), as this benchmark fitted
    before the page estimated. Also says which, for the report."""
    from toosicubix.pipeline.pilot import file_estimates, on_estimated_roads

    doc = dict(document, images=[im for im in document["images"]
                                 if scored_images is None or im["id"] in scored_images])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "annotations.json"
        path.write_text(json.dumps(doc))
        images = load_images(path)
        if not estimates:
            return images, SolverOptions(), "the page's defaults: click noise 1.5 px, no road normal"
        findings = file_estimates(path, priors, SolverOptions())
    normals = [n for n in (findings.road_normals or {}).values() if n.normal is not None]
    said = (f"the page's estimates from the scored images' file: click noise {findings.options.click_sigma:.3g} px "
            f"({findings.click_noise.source}), road normals of {len(normals)} camera(s)")
    return list(on_estimated_roads(images, findings.road_normals)), findings.options, said


def apollocar3d_naming(folder: Path, seed: int = 0, ks: tuple[int, ...] = APOLLO_KS,
                       out_of_sample: bool = False, design: bool = False,
                       grazing_deg: float = NAMING_GRAZING_DEG, estimates: bool = True,
                       position_faces: bool = False, nearest: bool = False) -> dict:
    """Auto-naming on ApolloCar3D's real keypoints (see the module's docstring): per k, how often the nearest
    candidate is the true part, and how often the true part is among the nearest two. ``out_of_sample``: the
    keypoint positions learned on the even images only (:func:`apollocar3d.learned_on`), the odd images'
    cars scored; ``design``: the same within the even images (learned on images 0, 4, 8, ..., images 2, 6, 10, ...
    scored). ``grazing_deg``: :func:`~toosicubix.web.naming.naming_candidates`'s. ``estimates``: as
    :func:`loaded_as_the_page`. ``position_faces``: as :func:`_faces`. ``nearest``: name by the nearest keypoint,
    not the most probable (as before rule 15, benchmarks/decisions.md)."""
    keypoints_path = folder / "apollocar3d_val_dev.json"
    cameras = load_cameras(folder / "cameras.json")
    scored_images = None
    if out_of_sample or design:
        sorted_ = sorted_images(folder)
        if design:
            sorted_ = sorted_[0::2]
        mapping = _faces(learned_on(sorted_[0::2], cameras, "even images"), position_faces)
        scored_images = {im.id for im in sorted_[1::2]}
    else:
        mapping = _faces(load_mapping("apollocar3d-66")[0], position_faces)
    document, _ = coco_to_annotations(keypoints_path, mapping, cameras)
    priors = load_priors()
    images, options, estimated = loaded_as_the_page(document, scored_images, priors, estimates)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    per_k = {k: Counter() for k in ks}
    cars = []
    for image in images:
        for vehicle in image.vehicles:
            clicks = [p for p in vehicle.parts if p.kind in ("point", "keypoint")]
            if len(clicks) < APOLLO_MIN_KEYPOINTS:
                continue
            order = [clicks[i] for i in rng.permutation(len(clicks))]
            keypoints = mapping.keypoint_candidates(vehicle.prototype)
            points = {p.part for p in mapping.parts if p.kind == "point"}
            row = {"image": image.id, "vehicle": vehicle.id, "keypoints": len(clicks)}
            for k in ks:
                named = tuple(order[:k])
                result = fit_one(replace(vehicle, parts=named), image.camera, priors[vehicle.prototype], options,
                                 image.ground, next_clicks=1000 if points else 0)
                counts = per_k[k]
                counts["cars"] += 1
                if not result.ok:
                    counts["not_fitted"] += 1
                    counts["clicks_not_fitted"] += len(order) - k
                    row[str(k)] = None
                    continue
                taken = {(p.kind, p.name) for p in named}
                candidates = naming_candidates(
                    result, image.camera, {n: k for n, k in keypoints.items() if ("keypoint", n) not in taken},
                    {n for n in points if ("point", n) not in taken}, grazing_deg,
                    None if nearest else options.click_sigma)
                right = top2 = 0
                for part in order[k:]:
                    ranked = [(c["kind"], c["name"]) for c in nearest_parts(part.uv[0].tolist(), candidates)]
                    counts["scored"] += 1
                    counts["right"] += ranked[:1] == [(part.kind, part.name)]
                    counts["top2"] += (part.kind, part.name) in ranked[:2]
                    counts["true_not_visible"] += (part.kind, part.name) not in ranked
                    right += ranked[:1] == [(part.kind, part.name)]
                    top2 += (part.kind, part.name) in ranked[:2]
                row[str(k)] = {"scored": len(order) - k, "right": right, "top2": top2}
            cars.append(row)
    summary = {}
    for k, c in per_k.items():
        summary[str(k)] = {
            "cars": c["cars"], "not_fitted": c["not_fitted"], "clicks_scored": c["scored"],
            "clicks_on_cars_not_fitted": c["clicks_not_fitted"],
            "nearest_is_true": round(c["right"] / c["scored"], 3) if c["scored"] else None,
            "true_in_top_2": round(c["top2"] / c["scored"], 3) if c["scored"] else None,
            "true_part_not_visible_on_fit": c["true_not_visible"]}
    return {"benchmark": "annotate --apollocar3d", "data": "ApolloCar3D apollocar3d_val_dev.json (100 images)",
            "mapping": ("apollocar3d-66, positions learned on images 0, 4, 8, ...; images 2, 6, 10, ... scored "
                        "(design, learning half only)" if design else
                        "apollocar3d-66, positions learned on the even images; odd images scored (out of sample)"
                        if out_of_sample else "apollocar3d-66 (bundled; positions learned on these images: in-sample)"),
            "naming_grazing_deg": grazing_deg, "fitted_with": estimated, "keypoint_faces": _faces_said(position_faces),
            "naming": ("the nearest visible keypoint" if nearest else
                       "the most probable visible keypoint (spread, click noise and clicked_share; rule 15)"),
            "min_keypoints": APOLLO_MIN_KEYPOINTS, "seed": seed, "ks": list(ks),
            "order": "one numpy generator (seed) permuting each car's mapped parts, cars in file order",
            "candidates": "every part of the mapping not among the first k, visible on the fit (naming_candidates)",
            "seconds": round(time.perf_counter() - t0, 1), "machine": machine(), "summary": summary, "cars": cars}


def _faces(mapping, position_faces: bool):
    """``mapping`` as it is, or with ``position_faces`` without the faces its keypoints were learned to be seen
    from, so that each is seen on the faces its position sits near (as before rule 13, benchmarks/decisions.md)."""
    if not position_faces:
        return mapping
    document = mapping.model_dump(mode="json", exclude_none=True)
    for part in document["parts"]:
        for position in [part.get("position", {}), *part.get("by_prototype", {}).values()]:
            position.pop("seen_from", None)
    return type(mapping).model_validate(document)


def _faces_said(position_faces: bool) -> str:
    return ("the faces each keypoint's position sits near (--position-faces)" if position_faces else
            "the faces each keypoint was learned to be seen from (seen_from), else those its position sits near")


GUIDANCE_START = 4
GUIDANCE_SCORED_AT = (4, 5, 6, 7, 8, 10, 12)
ORDERS = ("seeded", "guided")


def apollocar3d_guidance(folder: Path, seed: int = 0, estimates: bool = True, design: bool = False,
                         position_faces: bool = False) -> dict:
    """The page's targets with a keypoint mapping against a seeded order, on ApolloCar3D's real keypoints, out
    of sample (see the module's docstring); ``estimates`` as :func:`loaded_as_the_page`; ``design`` as
    :func:`apollocar3d_naming`'s (the learning half only); ``position_faces`` as :func:`_faces`."""
    from toosicubix.formats.apollocar3d import read_apollocar3d, read_car_models
    from toosicubix.geometry import geodesic_angle
    from toosicubix.pipeline.validation import Thresholds, judge
    from toosicubix.web.session import TARGETS

    keypoints_path = folder / "apollocar3d_val_dev.json"
    cameras = load_cameras(folder / "cameras.json")
    images_sorted = sorted_images(folder)
    if design:
        images_sorted = images_sorted[0::2]
    mapping = _faces(learned_on(images_sorted[0::2], cameras, "even images"), position_faces)
    scored_images = {im.id for im in images_sorted[1::2]}
    truth = {(im.id, car.id): car for im in read_apollocar3d(keypoints_path, read_car_models(
        folder / "car_models.json")) for car in im.cars}
    document, _ = coco_to_annotations(keypoints_path, mapping, cameras)
    priors, thresholds = load_priors(), Thresholds()
    images, options, estimated = loaded_as_the_page(document, scored_images, priors, estimates)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    cars = []
    for image in images:
        for vehicle in image.vehicles:
            clicks = [p for p in vehicle.parts if p.kind == "keypoint"]
            if len(clicks) < APOLLO_MIN_KEYPOINTS:
                continue
            order = [clicks[i] for i in rng.permutation(len(clicks))]
            keypoints = mapping.keypoint_candidates(vehicle.prototype)
            gt = truth[(image.id, vehicle.id)]
            row = {"image": image.id, "vehicle": vehicle.id, "keypoints": len(clicks)}
            for how in ORDERS:
                named, rest, steps = list(order[:GUIDANCE_START]), list(order[GUIDANCE_START:]), []
                while True:
                    result = fit_one(replace(vehicle, parts=tuple(named)), image.camera, priors[vehicle.prototype],
                                     options, image.ground, next_clicks=1000, keypoints=keypoints)
                    step = {"clicks": len(named), "ok": result.ok}
                    if result.ok:
                        problems = judge(result, thresholds)
                        step.update({"well_determined": not problems,
                                     "problems": "".join(sorted({p.split()[0][0] for p in problems})),
                                     "yaw_sigma_deg": infinite_as_none(result.sigma.yaw_deg),
                                     "depth_sigma_rel": infinite_as_none(result.sigma.depth_rel),
                                     "e_r_deg": round(float(np.rad2deg(geodesic_angle(result.R_cam_vehicle,
                                                                                     gt.R_cam_vehicle))), 3),
                                     "e_t": round(float(np.linalg.norm(result.t_cam_vehicle - gt.t_cam_vehicle)
                                                        / np.linalg.norm(gt.t_cam_vehicle)), 4)})
                    steps.append(step)
                    if not rest:
                        break
                    nxt = rest[0]
                    if how == "guided" and result.ok:
                        targets = [t["name"] for t in result.next_clicks if t["visible"] and t["inside_image"]]
                        labelled = {p.name: p for p in rest}
                        nxt = next((labelled[n] for n in targets[:TARGETS] if n in labelled), None)
                        step["target_taken"] = nxt is not None
                        nxt = nxt or rest[0]
                    rest.remove(nxt)
                    named.append(nxt)
                row[how] = steps
            cars.append(row)
    summary = {}
    for how in ORDERS:
        per_n = {}
        for n in GUIDANCE_SCORED_AT:
            steps = [s for c in cars for s in c[how] if s["clicks"] == n]
            fitted = [s for s in steps if s["ok"]]
            per_n[str(n)] = {
                "cars": len(steps), "fitted": len(fitted),
                "well_determined": round(sum(s["well_determined"] for s in fitted) / len(steps), 3) if steps else None,
                "e_r_deg_mean": _mean([s["e_r_deg"] for s in fitted]),
                "e_r_deg_median": round(float(np.median([s["e_r_deg"] for s in fitted])), 2) if fitted else None,
                "e_t_mean": round(float(np.mean([s["e_t"] for s in fitted])), 4) if fitted else None,
                "e_t_median": round(float(np.median([s["e_t"] for s in fitted])), 4) if fitted else None}
        reached = [next((s["clicks"] for s in c[how] if s.get("well_determined")), None) for c in cars]
        summary[how] = {"by_clicks": per_n, "reached_well_determined": sum(r is not None for r in reached)}
    taken = [s["target_taken"] for c in cars for s in c["guided"] if "target_taken" in s]
    summary["guided"]["steps_that_took_a_target"] = f"{sum(taken)} of {len(taken)}"
    both = [c for c in cars if all(any(s.get("well_determined") for s in c[how]) for how in ORDERS)]
    for how in ORDERS:
        summary[how]["mean_clicks_to_well_determined_on_common"] = _mean(
            [next(s["clicks"] for s in c[how] if s.get("well_determined")) for c in both])
    summary["reached_by_both"] = len(both)
    return {"benchmark": "annotate --apollocar3d --guidance", "data": "ApolloCar3D apollocar3d_val_dev.json",
            "mapping": ("apollocar3d-66, positions learned on images 0, 4, 8, ...; images 2, 6, 10, ... scored "
                        "(design, learning half only)" if design else
                        "apollocar3d-66, positions learned on the even images; odd images scored (out of sample)"),
            "fitted_with": estimated, "keypoint_faces": _faces_said(position_faces),
            "min_keypoints": APOLLO_MIN_KEYPOINTS, "seed": seed, "start": GUIDANCE_START, "targets": TARGETS,
            "orders": {"seeded": "one numpy generator (seed) permuting each car's keypoints, cars in file order",
                       "guided": "after the start, the first of the page's targets the car has labelled, else "
                                 "the next of the seeded order"},
            "seconds": round(time.perf_counter() - t0, 1), "machine": machine(), "summary": summary, "cars": cars}


#: The fields of a step of ``--guidance``'s cars, as the JSON lists them.
STEP_FIELDS = ("clicks", "ok", "well_determined", "e_r_deg", "e_t", "target_taken", "problems", "yaw_sigma_deg",
               "depth_sigma_rel")


def _compact_steps(report: dict) -> str:
    """``--guidance``'s report as JSON, one line per car, each step a list of :data:`STEP_FIELDS` (None: not
    known, e.g. a failed fit's errors, or a seeded step's target)."""
    cars = [{**{k: v for k, v in c.items() if k not in ORDERS},
             **{how: [[step.get(f) for f in STEP_FIELDS] for step in c[how]] for how in ORDERS}}
            for c in report["cars"]]
    head = json.dumps({**{k: v for k, v in report.items() if k != "cars"}, "step_fields": list(STEP_FIELDS)},
                      indent=1)
    rows = ",\n  ".join(json.dumps(c, separators=(",", ":")) for c in cars)
    return head[:-2] + ',\n "cars": [\n  ' + rows + "\n ]\n}"


def _compact(report: dict) -> str:
    """The report as JSON, one line per vehicle row."""
    head = json.dumps({k: v for k, v in report.items() if k != "rows"}, indent=1)
    rows = ",\n  ".join(json.dumps(r, separators=(",", ":")) for r in report["rows"])
    return head[:-2] + ',\n "rows": [\n  ' + rows + "\n ]\n}"


def naming_settings() -> dict | None:
    """The page's naming settings, for the report (None on code older than them)."""
    try:
        from toosicubix.web.placement import NAMING_SETTINGS
    except ImportError:  # code older than them (rule 24 item 5)
        return None
    return NAMING_SETTINGS.to_json()


def summarise(rows: list[dict], strategies: tuple[str, ...] = STRATEGIES) -> dict:
    out = {}
    for strategy in strategies:
        reached = [r[strategy] for r in rows if r[strategy]["right"]]
        right = sum(r[strategy]["auto_right"] for r in rows)
        wrong = sum(r[strategy]["auto_wrong"] for r in rows)
        out[strategy] = {
            "right": len(reached), "right_share": round(len(reached) / len(rows), 3) if rows else None,
            "median_actions": float(np.median([r["actions"] for r in reached])) if reached else None,
            "mean_actions": _mean([r["actions"] for r in reached]),
            "mean_clicks": _mean([r["clicks"] for r in reached]),
            "mean_naming_actions": _mean([r["naming"] for r in reached]),
            "auto_named": right + wrong,
            "auto_naming_accuracy": round(right / (right + wrong), 3) if right + wrong else None,
            "asked": sum(r[strategy]["asked"] for r in rows),
            "asked_true_name_offered": sum(r[strategy]["asked_offered"] for r in rows),
            "well_determined_when_stopped": sum(r[strategy]["well_determined"] for r in rows),
        }
    never = [r["named"] for r in rows if "named" in r and not r["named"]["right"]]
    out["named_not_right_because"] = dict(Counter(
        "not fitted" if r["failed"] else "yaw and depth" if r["yaw_error_deg"] > RIGHT_YAW_DEG and
        r["depth_error_rel"] > RIGHT_DEPTH_REL else "yaw" if r["yaw_error_deg"] > RIGHT_YAW_DEG else "depth"
        for r in never).most_common())
    confusions = Counter(f"{a} -> {b}" for r in rows for s in ("auto", "guided") if s in r
                         for a, b in r[s]["confusions"])
    out["auto_naming_confusions"] = dict(confusions.most_common(8))
    by_k: dict[str, list[bool]] = {}
    for r in rows:
        for k, right, _ in r["auto"]["outcomes"]:
            by_k.setdefault("0-1" if k < 2 else "2-3" if k < 4 else "4-5" if k < 6 else "6-7" if k < 8 else "8+",
                            []).append(right)
    out["auto_naming_accuracy_by_points_before"] = {
        k: {"n": len(v), "accuracy": round(sum(v) / len(v), 3)} for k, v in sorted(by_k.items(), key=lambda kv:
                                                                                   int(kv[0].rstrip("+").split("-")[0]))}
    by_p: dict[str, list[bool]] = {}
    for r in rows:
        for _, right, p in r["auto"]["outcomes"]:
            if p is not None:
                by_p.setdefault(f"{min(int(p * 10), 9) / 10:.1f}", []).append(right)
    out["auto_naming_accuracy_by_probability"] = {
        k: {"n": len(v), "accuracy": round(sum(v) / len(v), 3)} for k, v in sorted(by_p.items())}
    both = [r for r in rows if all(r[s]["right"] for s in strategies)]
    out["right_in_all"] = len(both)
    for strategy in strategies:
        out[f"{strategy}_median_actions_on_common"] = (float(np.median([r[strategy]["actions"] for r in both]))
                                                       if both else None)
    return out


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 2) if values else None


if __name__ == "__main__":
    main()

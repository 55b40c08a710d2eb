"""The annotation file to the numpy model and back (:mod:`toosicubix.annotations.convert`)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix import vocabulary
from toosicubix.annotations.convert import (
    document_json,
    images_from_schema,
    load_images,
    part_json,
    vehicle_json,
)
from toosicubix.annotations.schema import parse_annotations
from toosicubix.model import Image, Part, Vehicle


def _every_part(rng: np.random.Generator) -> list[dict]:
    """One annotation of every kind and name the vocabulary knows, with random pixels (and known sizes)."""
    out = []
    extra = {"row3": lambda: rng.uniform(-0.5, 0.5, 3).tolist(),
             "positive_row3": lambda: rng.uniform(0.01, 0.2, 3).tolist(), "bool_default_true": lambda: False}
    for kind in vocabulary.KINDS.values():
        for name in kind.names or (["top_left_c_rear_glass"] if kind.open_names else []):
            part = {"kind": kind.kind, kind.name_field: name}
            part.update({key: rng.uniform(0.0, 1000.0, 2).tolist() for key in kind.clicks})
            part.update({key: float(rng.uniform(0.01, 3.0)) for key in kind.known})
            part.update({key: extra[type_name]() for key, type_name in kind.fields_extra})
            out.append(part)
    return out


def _document(rng: np.random.Generator) -> dict:
    return {"toosicubix": 1, "images": [
        {"id": "kitti", "file": "image_2/kitti.png", "size": [1242, 375],
         "camera": {"P": [[721.5, 0.0, 609.6, 44.9], [0.0, 721.5, 172.9, 0.2], [0.0, 0.0, 1.0, 0.003]]},
         "ground": {"camera_height": 1.65, "camera_height_sigma": 0.1, "normal": [0.0, -1.0, 0.0]},
         "vehicles": [{"id": "1", "prototype": "Car", "box2d": [10.0, 20.0, 110.5, 90.25], "parts": _every_part(rng),
                       "known_dimensions": {"dx": {"metres": 4.2, "sigma": 0.05}}},
                      {"id": "2", "prototype": "Van", "parts": _every_part(rng)[:3]}]},
        {"id": "wide", "camera": {"K": [[900.0, 0.0, 640.0], [0.0, 910.0, 360.0], [0.0, 0.0, 1.0]],
                                  "distortion": [-0.1, 0.01, 0.0, 0.0, 0.0]},
         "vehicles": []},
    ]}


def _assert_same_images(a: list[Image], b: list[Image]) -> None:
    assert len(a) == len(b)
    for im, jm in zip(a, b, strict=True):
        assert (im.id, im.file, im.json_path, im.ground_block) == (jm.id, jm.file, jm.json_path, jm.ground_block)
        assert im.camera.image_size == jm.camera.image_size
        # K is stored exactly; P = K [I | t] is rebuilt from K and t = K^-1 P[:, 3]: equal up to rounding (1e-12).
        np.testing.assert_array_equal(im.camera.K, jm.camera.K)
        np.testing.assert_allclose(im.camera.t_cam_rect, jm.camera.t_cam_rect, rtol=0, atol=1e-12)
        assert (im.camera.distortion is None) == (jm.camera.distortion is None)
        if im.camera.distortion is not None:
            np.testing.assert_array_equal(im.camera.distortion, jm.camera.distortion)
        assert (im.ground is None) == (jm.ground is None)
        if im.ground is not None:
            np.testing.assert_array_equal(im.ground.normal, jm.ground.normal)
        assert len(im.vehicles) == len(jm.vehicles)
        for v, w in zip(im.vehicles, jm.vehicles, strict=True):
            assert (v.id, v.prototype, v.json_path, v.known_dimensions) == (w.id, w.prototype, w.json_path,
                                                                            w.known_dimensions)
            assert (v.box2d is None) == (w.box2d is None)
            if v.box2d is not None:
                np.testing.assert_array_equal(v.box2d, w.box2d)
            assert len(v.parts) == len(w.parts)
            for p, q in zip(v.parts, w.parts, strict=True):
                assert (p.kind, p.name, p.json_path, p.known) == (q.kind, q.name, q.json_path, q.known)
                np.testing.assert_array_equal(p.uv, q.uv)  # full precision: exact


def test_file_model_file_model_round_trip_for_every_part_kind():
    rng = np.random.default_rng(0)
    doc = _document(rng)
    images = images_from_schema(parse_annotations(doc))
    written = document_json(images)
    again = images_from_schema(parse_annotations(json.loads(json.dumps(written))))
    _assert_same_images(images, again)
    # The second trip writes the same vehicles (a P camera is rebuilt from K and t, equal up to rounding).
    assert [im["vehicles"] for im in document_json(again)["images"]] == [im["vehicles"] for im in written["images"]]
    kinds = {p.kind for p in again[0].vehicles[0].parts}
    assert kinds == set(vocabulary.KINDS) and "length" in kinds


def test_written_parts_are_the_file_s_parts():
    doc = _document(np.random.default_rng(0))
    images = images_from_schema(parse_annotations(doc))
    vehicle = doc["images"][0]["vehicles"][0]
    assert vehicle_json(images[0].vehicles[0]) == vehicle
    assert [part_json(p) for p in images[0].vehicles[1].parts] == doc["images"][0]["vehicles"][1]["parts"]


def test_part_json_rounds_only_when_asked():
    part = Part("length", "plate-rear", np.array([[1.26, 2.0], [3.0, 4.04]]), "$", (0.52, 0.01))
    assert part_json(part, decimals=1) == {"kind": "length", "feature": "plate-rear", "a": [1.3, 2.0],
                                           "b": [3.0, 4.0], "metres": 0.52, "sigma": 0.01}
    assert part_json(part)["a"] == [1.26, 2.0]
    with pytest.raises(ValueError, match="known size"):
        part_json(Part("length", "plate-rear", part.uv, "$.x"))


def test_vehicle_json_of_a_simulated_vehicle_leaves_out_what_it_lacks():
    v = Vehicle("7", "Car", None, (Part("point", "top-center", np.array([[5.0, 6.0]]), "$"),), "")
    assert vehicle_json(v) == {"id": "7", "prototype": "Car",
                               "parts": [{"kind": "point", "part": "top-center", "xy": [5.0, 6.0]}]}


def test_sample_file_round_trips():
    images = load_images(REPO / "samples" / "annotations.json")
    again = images_from_schema(parse_annotations(json.loads(json.dumps(document_json(images)))))
    _assert_same_images(images, again)


def test_importing_the_solver_does_not_load_pydantic():
    code = "import sys, toosicubix.solver, toosicubix.solver.guidance; print('pydantic' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, check=True)
    assert out.stdout.strip() == "False", out.stderr


def test_parts_pickle_to_the_same_arrays():
    """Part.__reduce__ sends float arrays as lists (a batch's workers get every part); they come back the same."""
    import pickle

    from toosicubix.model import Part

    parts = [
        Part("keypoint", "wheel", np.array([[2298.5, 2034.25]]), "$.p", at=np.array([0.387, 0.4265, 0.5408]),
             spread=np.array([0.0077, 0.0571, 1e-300]), visible=False),
        Part("length", "plate-rear", np.array([[1.0, 2.0], [3.0, 4.0]]), "$.q", known=(0.52, 0.01)),
        Part("keypoint", "empty", np.empty((0, 2)), "$", at=np.array([1, 2, 3])),  # int64: numpy pickles it
        Part("point", "fortran", np.asfortranarray(np.arange(6.0).reshape(3, 2)), "$"),  # not C order: numpy's
        Part("point", "float32", np.array([[0.1, 0.2]], dtype=np.float32), "$"),
    ]
    for part in parts:
        back = pickle.loads(pickle.dumps(part))
        for name in ("uv", "at", "spread"):
            a, b = getattr(part, name), getattr(back, name)
            if a is None:
                assert b is None
                continue
            assert (a.dtype, a.shape, a.flags.c_contiguous, a.tobytes("A")) == (
                b.dtype, b.shape, b.flags.c_contiguous, b.tobytes("A")), (part.name, name)
        assert (back.kind, back.name, back.json_path, back.known, back.visible) == (
            part.kind, part.name, part.json_path, part.known, part.visible)


def test_a_part_whose_fields_are_not_arrays_pickles_as_it_is():
    """A value of another type where an array is expected (a tuple of numbers, say) comes back as it was given, never
    read as an array's rows."""
    import pickle

    from toosicubix.model import Part

    part = Part("keypoint", "odd", np.zeros((1, 2)), "$", at=(0.1, 0.2, 0.3), spread=([1.0], (2,)))
    back = pickle.loads(pickle.dumps(part))
    assert back.at == (0.1, 0.2, 0.3) and back.spread == ([1.0], (2,))

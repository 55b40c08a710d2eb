"""The part vocabulary (:mod:`toosicubix.vocabulary`) is complete and consistent."""

import typing

import numpy as np
import pytest

from toosicubix import vocabulary
from toosicubix.annotations import schema
from toosicubix.model import Part
from toosicubix.parts.linear import LINEAR_FORMS, build_parts_model


def test_every_kind_has_its_linear_form_and_no_form_lacks_a_kind():
    assert set(LINEAR_FORMS) == set(vocabulary.KINDS)


def test_the_schema_admits_exactly_the_vocabulary_s_names():
    admitted = {kind: typing.get_args(cls.model_fields[vocabulary.KINDS[kind].name_field].annotation)
                for kind, cls in schema.PART_ANNOTATIONS.items() if not vocabulary.KINDS[kind].open_names}
    assert admitted["point"] == vocabulary.POINT_PARTS == vocabulary.names("point")
    assert admitted["symmetry"] == vocabulary.SYMMETRY_FACES == ("front", "rear", "roof")
    assert admitted["direction"] == vocabulary.DIRECTION_AXES == vocabulary.names("direction")
    assert admitted["length"] == tuple(vocabulary.LENGTH_FEATURES) == vocabulary.names("length")
    assert all(isinstance(d, str) and d for d in vocabulary.LENGTH_FEATURES.values())
    assert len(vocabulary.POINT_PARTS) == 23  # with the four wheel hubs
    assert vocabulary.names("keypoint") == () and vocabulary.KINDS["keypoint"].open_names
    assert vocabulary.names("plate") == ("front", "rear")


@pytest.mark.parametrize("kind", list(vocabulary.KINDS))
def test_every_name_builds_its_clicks_with_the_vocabulary_s_labels(kind):
    k = vocabulary.KINDS[kind]
    for name, entry in k.names.items():
        uv = np.zeros((len(k.clicks), 2))
        known = (1.0, 0.1) if k.known else None
        soft = {"at": np.array([0.5, 0.0, 0.4]), "spread": np.full(3, 0.05)} if k.fields_extra else {}
        model = build_parts_model([Part(kind, name, uv, "$", known, **soft)])
        assert model.click_labels == vocabulary.click_labels(kind, name)
        for index, label in enumerate(model.click_labels):
            assert vocabulary.click(label) == vocabulary.Click(kind, name, index, label)
        assert entry.faces is None or (entry.faces and set(entry.faces) <= set(vocabulary.FACES))
        assert entry.suits == "all" or entry.suits in vocabulary.PROTOTYPE_GROUPS


def test_typical_positions_have_a_point_per_click_and_known_terms():
    for k in vocabulary.KINDS.values():
        for entry in k.names.values():
            if entry.typical is None:
                continue
            assert len(entry.typical) == len(k.clicks)
            for point in entry.typical:
                assert len(point) == 3
                assert all(term in vocabulary.TYPICAL_TERMS for form in point for term in form)


def test_typical_positions_lie_on_the_faces_they_name():
    """A part's typical points, on a 4 x 2 x 1.5 m cuboid, lie on (one of) the faces the vocabulary names."""
    d = np.array([4.0, 2.0, 1.5])
    values = {"dx": 4.0, "dy": 2.0, "dz": 1.5, "Xwf": 1.3, "Xwr": -1.2, "side": 1.0, "side*dy": 2.0, "one": 1.0}
    on_face = {"front": lambda X: np.isclose(X[0], d[0] / 2), "rear": lambda X: np.isclose(X[0], -d[0] / 2),
               "left": lambda X: np.isclose(X[1], d[1] / 2), "right": lambda X: np.isclose(X[1], -d[1] / 2),
               "top": lambda X: np.isclose(X[2], d[2])}
    checked = 0
    for k in vocabulary.KINDS.values():
        for entry in k.names.values():
            if entry.typical is None or entry.faces is None or entry.get("shape") == "wheel":
                continue  # wheels touch the ground under their face, not on it
            for X in vocabulary.typical_points(entry, values):
                assert any(on_face[f](X) for f in entry.faces), (entry.kind, entry.name, X)
                checked += 1
    assert checked > 20


def test_arrows_are_off_the_body_and_wheels_on_it():
    assert not vocabulary.on_body("direction-forward/tail")
    assert vocabulary.on_body("wheel-front-left")
    assert vocabulary.faces_of_click("corner-bottom-rear-left") == ("rear", "left")
    assert vocabulary.faces_of_click("length-wheelbase-right/b") == ("right", "front", "rear")
    with pytest.raises(KeyError):
        vocabulary.click("wheel-middle-left")


def test_corners_suit_box_shaped_prototypes_only():
    corner = vocabulary.entry("point", "corner-top-front-left")
    assert vocabulary.suits(corner, ("Van",)) and vocabulary.suits(corner, ("Mid Size Car", "Truck"))
    assert not vocabulary.suits(corner, ("Car",))
    assert vocabulary.suits(vocabulary.entry("point", "wheel-rear-right"), ("Car",))


def test_the_schema_has_a_class_per_kind_with_the_vocabulary_s_file_keys():
    assert set(schema.PART_ANNOTATIONS) == set(vocabulary.KINDS)
    for kind, cls in schema.PART_ANNOTATIONS.items():
        k = vocabulary.KINDS[kind]
        assert cls.__name__ == k.schema["class"]
        assert list(cls.model_fields) == ["kind", k.name_field, *k.clicks, *k.known, *(f for f, _ in k.fields_extra)]


def test_an_open_kind_takes_any_name_and_its_labels_read_back():
    assert vocabulary.click("keypoint-top_left_c_rear_glass") == vocabulary.Click(
        "keypoint", "top_left_c_rear_glass", 0, "keypoint-top_left_c_rear_glass")
    assert vocabulary.faces_of_click("keypoint-x") is None and vocabulary.soft("keypoint-x")
    assert vocabulary.soft("plate-rear/a") and not vocabulary.soft("wheel-front-left")
    with pytest.raises(KeyError):
        vocabulary.click("keypoint-")
    model = build_parts_model([Part("keypoint", "lamp", np.zeros((1, 2)), "$", None, np.array([-0.45, 0.4, 0.6]),
                                    np.full(3, 0.05))])
    assert model.click_faces == (("rear", "left"),)


def test_faces_seen_from_answers_as_the_array_form_did():
    """faces_seen_from sums in numpy einsum's order in plain floats; its answers must be the array form's for
    cameras anywhere, on a face's plane too, and for every grazing angle the solver and the page use."""
    from toosicubix.vocabulary import _FACE_CENTRES, _FACE_NORMALS

    def array_form(camera_vehicle, dimensions, grazing_deg):
        to_camera = camera_vehicle - _FACE_CENTRES * dimensions
        along = np.einsum("fi,fi->f", _FACE_NORMALS, to_camera)
        distance = np.sqrt(np.einsum("fi,fi->f", to_camera, to_camera))
        return dict(zip(vocabulary.FACES, (along > -np.sin(np.deg2rad(grazing_deg)) * distance).tolist(), strict=True))

    rng = np.random.default_rng(11)
    for i in range(20000):
        camera = rng.normal(size=3) * 10.0 ** rng.integers(-2, 3, size=3)
        dimensions = np.abs(rng.normal(size=3)) * 3.0
        if i % 10 == 0:  # on the plane of a face
            camera[i % 3] = 0.5 * dimensions[i % 3]
        grazing = (0.0, 15.0, -5.0, 2.0)[i % 4]
        assert vocabulary.faces_seen_from(camera, dimensions, grazing) == array_form(camera, dimensions, grazing)


def test_click_faces_are_the_first_forms_on_real_keypoints_and_every_part():
    # click_faces keeps each (label, position)'s answer (issue 37); it must give what the per-click reading gave, on
    # ApolloCar3D's 66 keypoints at their typical positions, keypoints anywhere, and every part of the vocabulary.
    from toosicubix.annotations.mapping import load_mapping
    from toosicubix.parts.linear import KINDS as kinds
    from toosicubix.parts.linear import class_keypoint_faces, keypoint_faces

    def first_form(model):
        out = []
        for i, label in enumerate(model.click_labels):
            c = vocabulary.click(label)
            if not kinds[c.kind].open_names:
                out.append(vocabulary.faces_of_click(label))
                continue
            named, faces = class_keypoint_faces(c.name)
            out.append(faces if named else keypoint_faces((model.A[i, 0, 0], model.A[i, 1, 1], model.A[i, 2, 2])))
        return tuple(out)

    rng = np.random.default_rng(5)
    typical = load_mapping("apollocar3d-66")[0].keypoint_candidates("Car")
    parts = [Part("keypoint", name, rng.normal(300.0, 50.0, (1, 2)), "$", None, np.asarray(k.at), np.asarray(k.spread))
             for name, k in typical.items()]
    parts += [Part("keypoint", f"anywhere{i}", rng.normal(300.0, 50.0, (1, 2)), "$", None,
                   rng.uniform(-0.6, 1.1, 3), np.full(3, 0.05)) for i in range(40)]
    model = build_parts_model(parts)
    assert model.click_faces == first_form(model) and len(model.click_faces) == len(parts)
    assert any(f is None for f in model.click_faces) and any(f for f in model.click_faces)
    from tests.scenes import VIEW_YAW, random_scene

    for view in sorted(VIEW_YAW):  # the paper's parts, arrows included
        model = random_scene(rng, view).model
        assert model.click_faces == first_form(model)

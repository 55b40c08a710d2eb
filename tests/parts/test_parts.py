import numpy as np
import pytest

from toosicubix.model import Part
from toosicubix.parts.linear import build_parts_model
from toosicubix.parts.synthesis import PartSpec, true_parameters
from toosicubix.vocabulary import POINT_PARTS

D = np.array([4.0, 1.8, 1.5])  # dx, dy, dz
WHEELS = (1.3, -1.2)  # Xwf, Xwr


def point(name: str) -> Part:
    return Part("point", name, np.zeros((1, 2)), "$")


def pair(kind: str, name: str) -> Part:
    return Part(kind, name, np.zeros((2, 2)), "$")


def points_of(specs: list[PartSpec]) -> np.ndarray:
    parts, p = true_parameters(specs, D, WHEELS)
    return build_parts_model(parts).points_vehicle(p)


# The table of DESIGN section 3 ("Parts and their 3D points"), with dx, dy, dz = 4.0, 1.8, 1.5.
@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        (PartSpec("point", "wheel-front-left"), [[1.3, 0.9, 0.0]]),
        (PartSpec("point", "wheel-front-right"), [[1.3, -0.9, 0.0]]),
        (PartSpec("point", "wheel-rear-left"), [[-1.2, 0.9, 0.0]]),
        (PartSpec("point", "wheel-rear-right"), [[-1.2, -0.9, 0.0]]),
        (PartSpec("point", "front-center", {"Z": 0.4}), [[2.0, 0.0, 0.4]]),
        (PartSpec("point", "rear-center", {"Z": 0.5}), [[-2.0, 0.0, 0.5]]),
        (PartSpec("point", "top-center", {"X": -0.3}), [[-0.3, 0.0, 1.5]]),
        (PartSpec("point", "edge-front-left", {"Z": 0.7}), [[2.0, 0.9, 0.7]]),
        (PartSpec("point", "edge-front-right", {"Z": 0.7}), [[2.0, -0.9, 0.7]]),
        (PartSpec("point", "edge-rear-left", {"Z": 0.7}), [[-2.0, 0.9, 0.7]]),
        (PartSpec("point", "edge-rear-right", {"Z": 0.7}), [[-2.0, -0.9, 0.7]]),
        (PartSpec("point", "corner-top-front-left"), [[2.0, 0.9, 1.5]]),
        (PartSpec("point", "corner-top-rear-right"), [[-2.0, -0.9, 1.5]]),
        (PartSpec("point", "corner-bottom-front-right"), [[2.0, -0.9, 0.0]]),
        (PartSpec("point", "corner-bottom-rear-left"), [[-2.0, 0.9, 0.0]]),
        (PartSpec("symmetry", "front", {"Y": 0.6, "Z": 0.8}), [[2.0, 0.6, 0.8], [2.0, -0.6, 0.8]]),
        (PartSpec("symmetry", "rear", {"Y": 0.6, "Z": 0.8}), [[-2.0, 0.6, 0.8], [-2.0, -0.6, 0.8]]),
        (PartSpec("symmetry", "roof", {"X": 0.2, "Y": 0.5}), [[0.2, 0.5, 1.5], [0.2, -0.5, 1.5]]),
        (PartSpec("direction", "forward", {"X": 0.1, "Y": 1.0, "Z": 0.0}), [[0.1, 1.0, 0.0], [4.1, 1.0, 0.0]]),
        (PartSpec("direction", "backward", {"X": 0.1, "Y": 1.0, "Z": 0.0}), [[0.1, 1.0, 0.0], [-3.9, 1.0, 0.0]]),
        (PartSpec("direction", "leftward", {"X": 0.1, "Y": 1.0, "Z": 0.3}), [[0.1, 1.0, 0.3], [0.1, 2.8, 0.3]]),
        (PartSpec("direction", "rightward", {"X": 0.1, "Y": 1.0, "Z": 0.3}), [[0.1, 1.0, 0.3], [0.1, -0.8, 0.3]]),
        (PartSpec("direction", "upward", {"X": 0.1, "Y": 1.0, "Z": 0.3}), [[0.1, 1.0, 0.3], [0.1, 1.0, 1.8]]),
        (PartSpec("direction", "downward", {"X": 0.1, "Y": 1.0, "Z": 0.3}), [[0.1, 1.0, 0.3], [0.1, 1.0, -1.2]]),
        (PartSpec("length", "plate-rear", {"Y": 0.26, "Z": 0.5}, known=(0.52, 0.01)),
         [[-2.0, 0.26, 0.5], [-2.0, -0.26, 0.5]]),
        (PartSpec("length", "plate-front", {"Y": 0.26, "Z": 0.4}, known=(0.52, 0.01)),
         [[2.0, 0.26, 0.4], [2.0, -0.26, 0.4]]),
        (PartSpec("length", "wheelbase-left", known=(2.55, 0.01)), [[1.3, 0.9, 0.0], [-1.2, 0.9, 0.0]]),
        (PartSpec("length", "tyre-front-right", {"Zt": 0.65}, known=(0.65, 0.01)),
         [[1.3, -0.9, 0.0], [1.3, -0.9, 0.65]]),
    ],
)
def test_points_follow_the_design_table(spec, expected):
    np.testing.assert_allclose(points_of([spec]), expected, atol=1e-12)


def test_all_corners_are_cuboid_corners():
    from toosicubix.geometry import cuboid_corners_vehicle

    corners = points_of([PartSpec("point", n) for n in POINT_PARTS if n.startswith("corner-")])
    expected = {tuple(np.round(c, 9)) for c in cuboid_corners_vehicle(D)}
    assert {tuple(np.round(c, 9)) for c in corners} == expected


def test_wheel_unknowns_are_shared():
    model = build_parts_model([point("wheel-front-left"), point("wheel-front-right"), point("wheel-rear-left")])
    assert model.param_names == ("dx", "dy", "dz", "Xwf", "Xwr")
    assert model.n_aux == 2


def test_no_wheel_unknown_without_wheels():
    model = build_parts_model([point("corner-top-front-left")])
    assert model.param_names == ("dx", "dy", "dz")


# Constraint counts from the paper (sections "The wheels" to "Directions").
@pytest.mark.parametrize(
    ("parts", "constraints"),
    [
        ([point("wheel-front-left")], 1),  # one wheel: 2 equations, 1 for Xwf
        ([point("wheel-front-left"), point("wheel-front-right")], 3),  # both front wheels: 3
        ([point("front-center")], 1),
        ([point("top-center")], 1),
        ([point("edge-rear-left")], 1),
        ([point("corner-top-rear-left")], 2),  # no auxiliary unknown
        ([pair("symmetry", "rear")], 2),  # two auxiliaries for four equations
        ([pair("symmetry", "roof")], 2),
        ([pair("direction", "forward")], 1),  # three auxiliaries for four equations
        ([pair("direction", "upward")], 1),
    ],
)
def test_constraint_counts(parts, constraints):
    assert build_parts_model(parts).constraints == constraints


def test_lines_for_yaw_initialisation():
    parts = [point("wheel-front-left"), point("wheel-rear-left"), point("wheel-rear-right"),
             pair("symmetry", "rear"), pair("direction", "forward"), pair("direction", "upward"),
             point("corner-top-front-left"), point("corner-top-rear-left"), point("corner-top-front-right")]
    model = build_parts_model(parts)
    axes = sorted((line.axis, model.click_labels[line.i], model.click_labels[line.j]) for line in model.lines)
    assert axes == sorted([
        (0, "wheel-front-left", "wheel-rear-left"),
        (1, "wheel-rear-left", "wheel-rear-right"),
        (1, "symmetry-rear/left", "symmetry-rear/right"),
        (0, "direction-forward/tail", "direction-forward/head"),
        (0, "corner-top-front-left", "corner-top-rear-left"),
        (1, "corner-top-front-left", "corner-top-front-right"),
    ])  # an upward arrow gives no yaw line


def test_click_labels_follow_annotation_order():
    model = build_parts_model([pair("symmetry", "front"), point("top-center")])
    assert model.click_labels == ("symmetry-front/left", "symmetry-front/right", "top-center")
    np.testing.assert_array_equal(model.click_part, [0, 0, 1])


@pytest.mark.parametrize(("spec", "value"), [
    (PartSpec("length", "plate-rear", {"Y": 0.26, "Z": 0.5}, known=(0.52, 0.01)), 0.52),  # 2 Y
    (PartSpec("length", "wheelbase-right", known=(2.5, 0.01)), 2.5),  # Xwf - Xwr
    (PartSpec("length", "tyre-rear-left", {"Zt": 0.64}, known=(0.64, 0.01)), 0.64),  # Zt
])
def test_length_annotations_give_a_measurement(spec, value):
    parts, p = true_parameters([spec], D, WHEELS)
    (m,) = build_parts_model(parts).measurements
    assert m.metres == value and m.sigma == 0.01 and m.label == f"length {spec.name}"
    assert m.coefficients @ p == pytest.approx(value if spec.name != "wheelbase-right" else WHEELS[0] - WHEELS[1])


def test_known_dimensions_are_measurements():
    model = build_parts_model([point("corner-top-front-left")], {"dx": (4.5, 0.02), "dz": (1.4, 0.03)})
    got = [(m.label, m.metres, m.sigma) for m in model.measurements]
    assert got == [("known dx", 4.5, 0.02), ("known dz", 1.4, 0.03)]
    np.testing.assert_array_equal(model.measurements[0].coefficients, [1.0, 0.0, 0.0])

"""The descent's shape step keeps one start's design matrix at a time, not every start's at once."""

import json
import tracemalloc

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.annotations.convert import images_from_schema
from toosicubix.annotations.priors_file import load_priors
from toosicubix.annotations.schema import parse_annotations
from toosicubix.parts.linear import build_parts_model
from toosicubix.solver import descent
from toosicubix.solver.descent import solve_shapes
from toosicubix.solver.problem import Problem


def many_click_problem(pairs: int) -> Problem:
    doc = json.loads((REPO / "samples" / "annotations.json").read_text())
    vehicle = doc["images"][0]["vehicles"][0]
    rng = np.random.default_rng(0)
    pair = next(p for p in vehicle["parts"] if p["kind"] == "symmetry")
    vehicle["parts"] = [{**pair, "left": (np.array(pair["left"]) + rng.normal(0, 1, 2)).tolist(),
                         "right": (np.array(pair["right"]) + rng.normal(0, 1, 2)).tolist()} for _ in range(pairs)]
    image = images_from_schema(parse_annotations(doc))[0]
    v = image.vehicles[0]
    return Problem.build(build_parts_model(v.parts), image.camera, load_priors()[v.prototype], 0.1, 10.0)


def _rotations(n: int) -> np.ndarray:
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    R = np.zeros((n, 3, 3))
    R[:, 0, 0] = R[:, 2, 2] = np.cos(angles)
    R[:, 0, 2], R[:, 2, 0] = np.sin(angles), -np.sin(angles)
    R[:, 1, 1] = 1.0
    return R


def test_shape_step_memory_does_not_grow_with_the_starts():
    problem = many_click_problem(32)  # 64 clicks, the limit
    N, _, P = problem.A.shape
    one_design = 2 * N * (P + 3) * 8  # bytes of one start's design matrix

    def peak(starts: int) -> int:
        R = _rotations(starts)
        tracemalloc.start()
        solve_shapes(problem, R)
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    # 48 starts (the 36-angle sweep plus 12) once needed 48 design matrices at once (and R A_i for each);
    # now a few of one start's, whatever the number of starts.
    assert peak(48) < 4 * one_design
    assert peak(48) < 1.5 * peak(4)


def test_shape_step_one_start_at_a_time_equals_each_start_alone():
    problem = many_click_problem(5)
    R = _rotations(6)
    p, t = solve_shapes(problem, R)
    for k in range(len(R)):
        p1, t1 = solve_shapes(problem, R[k:k + 1])
        np.testing.assert_allclose(p[k], p1[0], rtol=1e-12, atol=1e-12)  # the same arithmetic: algebra tier
        np.testing.assert_allclose(t[k], t1[0], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("pairs", [2, 8])
def test_shape_step_chunks_of_starts_give_the_same_bits_as_one_start_at_a_time(monkeypatch, pairs):
    problem = many_click_problem(pairs)
    R = _rotations(48)
    p, t = solve_shapes(problem, R)  # 2 pairs: the 48 starts in one chunk; 8 pairs: in chunks of 14
    monkeypatch.setattr(descent, "_SHAPE_CHUNK_BYTES", 1)  # one start per chunk
    p1, t1 = solve_shapes(problem, R)
    np.testing.assert_array_equal(p, p1)
    np.testing.assert_array_equal(t, t1)

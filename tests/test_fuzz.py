"""Property-based fuzzing of every input reader (issue 13, item 7): mutated annotation files through fit and
validate, mutated ground-truth lines and calibration files through the KITTI readers and eval.

Properties: never a traceback; exit code 0, 1 or 2 (2 with an ``Error:`` message and nothing written); no
NaN or infinity in any file written; nothing written outside the output folder. Bounded for CI: a few
seconds per test (``max_examples``); ``benchmarks/fuzz.py`` runs 10,000 files.
"""

from __future__ import annotations

import copy
import json
import math
import shutil
import tempfile
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.errors import FormatError
from toosicubix.formats.kitti import MAX_FRAME, MAX_SIZE_M, parse_label_line, read_calib

SAMPLE = REPO / "samples" / "annotations.json"
SAMPLE_GT = REPO / "samples" / "ground_truth"
#: One image with one vehicle keeps an example near 0.2 s.
SMALL = {**json.loads(SAMPLE.read_text()), "images": [json.loads(SAMPLE.read_text())["images"][2]]}
LABEL = "Car 0.00 0 0.187878 399.61 186.27 685.93 301.16 1.5000 1.6500 3.9000 -1.0600 1.6000 10.5000 0.087266"
P2 = "720 0 620 43.2 0 720 180 0 0 0 1 0"
FUZZ = settings(max_examples=40, deadline=None, database=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _paths(doc: Any, path: tuple = ()) -> list[tuple]:
    out = [path]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*path, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*path, i))
    return out


def _get(doc: Any, path: tuple) -> Any:
    for key in path:
        doc = doc[key]
    return doc


PATHS = _paths(SMALL)
NUMBER_PATHS = [p for p in PATHS if isinstance(_get(SMALL, p), int | float) and not isinstance(_get(SMALL, p), bool)]
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(min_value=-(10**400), max_value=10**400),
    st.sampled_from([0, -1, 1e-308, 1e308, -1e308, 1e6, 1e6 + 1, 100.0001, 1e-4]),
)
VALUES = st.one_of(NUMBERS, st.none(), st.booleans(), st.text(max_size=300), st.just([]), st.just({}),
                   st.lists(NUMBERS, max_size=4))


@st.composite
def mutated_files(draw) -> bytes:
    """An annotation file after one structural, numeric or text mutation of the small sample."""
    doc = copy.deepcopy(SMALL)
    family = draw(st.sampled_from(["structure", "numeric", "text"]))
    if family == "numeric":
        path = draw(st.sampled_from(NUMBER_PATHS))
        _get(doc, path[:-1])[path[-1]] = draw(NUMBERS)
    elif family == "structure":
        path = draw(st.sampled_from(PATHS[1:]))
        parent, key = _get(doc, path[:-1]), path[-1]
        action = draw(st.sampled_from(["drop", "replace", "nest", "duplicate"]))
        if action == "drop":
            del parent[key]
        elif action == "replace":
            parent[key] = draw(VALUES)
        elif action == "nest":
            value = parent[key]
            for _ in range(draw(st.integers(min_value=1, max_value=2000))):
                value = [value]
            parent[key] = value
        elif isinstance(parent, list):
            parent.extend([copy.deepcopy(parent[key])] * draw(st.integers(min_value=1, max_value=20)))
    try:
        data = json.dumps(doc).encode()
    except (ValueError, RecursionError):  # a 2,000-deep document: its text is what matters
        data = b"[" * 2000 + b"]" * 2000
    if family == "text":
        i = draw(st.integers(min_value=0, max_value=len(data)))
        cut = draw(st.integers(min_value=0, max_value=32))
        data = data[:i] + draw(st.binary(max_size=8)) + data[i + cut:]
    return data


def _non_finite(path: Path) -> bool:
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".json":
        def reject(name):
            raise ValueError(name)
        try:
            json.loads(text, parse_constant=reject)
        except ValueError:
            return True
        return False
    return any(not math.isfinite(float(t)) for t in text.replace(",", " ").split() if _is_number(t))


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _check(result, out: Path | None = None) -> None:
    assert result.exc_info is None or isinstance(result.exc_info[1], SystemExit), result.exc_info
    assert result.exit_code in (0, 1, 2), result.output
    if result.exit_code == 2:
        assert "Error" in result.output
        assert out is None or not out.exists()  # nothing written
    if out is not None and out.exists():
        for written in out.rglob("*"):
            if written.is_file():
                assert not _non_finite(written), written.read_text()[:500]


@FUZZ
@given(data=mutated_files())
def test_fit_and_validate_survive_mutated_annotation_files(data):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        ann = folder / "annotations.json"
        ann.write_bytes(data)
        out = folder / "out"
        fit = CliRunner().invoke(main, ["fit", str(ann), "-o", str(out), "-q"])
        _check(fit, out)
        validate = CliRunner().invoke(main, ["validate", str(ann), "-q", "--json"])
        _check(validate)
        if validate.exit_code in (0, 1):
            json.loads(validate.stdout, parse_constant=lambda name: pytest.fail(f"{name} in validate --json"))
        assert {p.relative_to(folder).parts[0] for p in folder.rglob("*")} <= {"annotations.json", "out"}


TOKENS = st.one_of(NUMBERS.map(str), st.sampled_from(["nan", "inf", "-inf", "1e308", "1e999", "", "Car", "\ufeff"]),
                   st.text(max_size=6))


@st.composite
def mutated_label_lines(draw) -> tuple[str, bool]:
    tracking = draw(st.booleans())
    tokens = (["0", "1"] if tracking else []) + LABEL.split()
    for _ in range(draw(st.integers(min_value=1, max_value=3))):
        action = draw(st.sampled_from(["replace", "drop", "insert"]))
        k = draw(st.integers(min_value=0, max_value=len(tokens) - 1))
        if action == "replace":
            tokens[k] = draw(TOKENS)
        elif action == "drop" and len(tokens) > 1:
            del tokens[k]
        else:
            tokens.insert(k, draw(TOKENS))
    return " ".join(tokens), tracking


@settings(max_examples=100, deadline=None, database=None, derandomize=True)
@given(case=mutated_label_lines())
def test_label_lines_parse_to_bounded_finite_objects_or_a_format_error(case):
    line, tracking = case
    try:
        obj = parse_label_line(line, "gt.txt", 7, tracking=tracking)
    except FormatError as exc:
        assert str(exc).startswith("gt.txt:7: ")
        return
    numbers = [obj.truncated, obj.alpha, obj.rotation_y, *obj.box2d, *obj.dimensions, *obj.location_rect]
    assert all(math.isfinite(v) for v in numbers)
    if obj.type != "DontCare":
        assert 0 < obj.dimensions.min() and obj.dimensions.max() <= MAX_SIZE_M
    if tracking:
        assert 0 <= obj.frame <= MAX_FRAME


@settings(max_examples=50, deadline=None, database=None, derandomize=True)
@given(data=st.binary(max_size=8), where=st.integers(min_value=0, max_value=400), cut=st.integers(0, 40))
def test_calib_files_read_as_cameras_or_a_format_error(data, where, cut):
    text = "\n".join(f"P{k}: {P2}" for k in range(4)).encode() + b"\nR0_rect: 1 0 0 0 1 0 0 0 1\n"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "calib.txt"
        path.write_bytes(text[:where] + data + text[where + cut:])
        try:
            calib = read_calib(path)
        except FormatError as exc:
            assert str(exc).startswith(str(path))
            return
        camera = calib.camera(2)
        assert all(math.isfinite(v) for v in [*camera.K.ravel(), *camera.t_cam_rect])


@FUZZ
@given(case=mutated_label_lines(), calib_noise=st.binary(max_size=6), where=st.integers(0, 300))
def test_eval_survives_mutated_ground_truth(fitted_sample, case, calib_noise, where):
    line, tracking = case
    with tempfile.TemporaryDirectory() as tmp:
        gt = Path(tmp) / "gt"
        shutil.copytree(SAMPLE_GT, gt)
        label = gt / "label_2" / "000003.txt"
        label.write_text(line if not tracking else line.split(" ", 2)[-1], encoding="utf-8")
        calib = gt / "calib" / "000003.txt"
        data = calib.read_bytes()
        calib.write_bytes(data[:where] + calib_noise + data[where:])
        report = Path(tmp) / "eval"
        result = CliRunner().invoke(main, ["eval", str(fitted_sample), "--kitti", str(gt), "-q",
                                           "--json", str(report / "e.json"), "--csv", str(report / "e.csv")])
        _check(result, report)
        assert "nan" not in result.stdout.lower().split()


@pytest.fixture(scope="module")
def fitted_sample(tmp_path_factory):
    out = tmp_path_factory.mktemp("fitted") / "out"
    result = CliRunner().invoke(main, ["fit", str(SAMPLE), "-o", str(out), "-q"])
    assert result.exit_code == 0, result.output
    return out

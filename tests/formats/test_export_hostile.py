"""export openlabel and export cvat on results.json files fit did not write (issue 34, item 4): a reflection, an
all-zero rotation, a NaN sigma, a confidence that is an object, a translation of 1e308 are refused naming
results.json and the JSON path (exit 2, nothing written); nothing non-finite is ever written."""

from __future__ import annotations

import copy
import json
import math
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.formats.tool_fixtures import SAMPLE
from toosicubix.cli import main
from toosicubix.fields import shown

KINDS = (("openlabel", "labels.json"), ("cvat", "review.xml"))


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fitted")
    annotations = folder / "annotations.json"
    shutil.copy(SAMPLE, annotations)
    result = CliRunner().invoke(main, ["fit", str(annotations), "-o", str(folder / "out"), "-q"])
    assert result.exit_code == 0, result.output
    return folder / "out"


def _variant(fitted: Path, tmp_path: Path, change) -> Path:
    out = tmp_path / "out"
    shutil.copytree(fitted, out)
    doc = json.loads((out / "results.json").read_text())
    change(doc["images"][0]["vehicles"][0])
    (out / "results.json").write_text(json.dumps(doc))  # NaN written as NaN, as Python's JSON writer allows
    return out


def _reflect(v):
    v["R_cam_vehicle"] = [[-x for x in row] for row in v["R_cam_vehicle"]]


WHERE = "$.images[0].vehicles[0]"


@pytest.mark.parametrize(("change", "message"), [
    (_reflect, f"{WHERE}.R_cam_vehicle: expected a rotation matrix (orthonormal to 1e-06, determinant +1), got "
               "determinant -1"),
    (lambda v: v.__setitem__("R_cam_vehicle", [[0, 0, 0]] * 3), f"{WHERE}.R_cam_vehicle: expected a rotation matrix"),
    (lambda v: v["sigma"].__setitem__("yaw_deg", math.nan), f"{WHERE}.sigma.yaw_deg: expected a sigma (or null for "
                                                            "infinite): a number at least 0, got nan"),
    (lambda v: v["sigma"]["dimensions"].__setitem__(1, -1.0), f"{WHERE}.sigma.dimensions[1]: expected a sigma"),
    (lambda v: v.__setitem__("confidence", {"a": 1}), f"{WHERE}.confidence: expected a finite number or null, got "
                                                      "{'a': 1}"),
    (lambda v: v.__setitem__("t_cam_vehicle", [1e308, 1e308, 1e308]), f"{WHERE}.t_cam_vehicle: expected a position "
                                                                      "within 1e+06 m of the camera"),
    (lambda v: v.__setitem__("t_cam_vehicle", [10**400, 1, 1]), f"{WHERE}.t_cam_vehicle: expected finite numbers of "
                                                                 "shape (3,), got [an integer of 401 digits, 1, 1]"),
    (lambda v: v.__setitem__("dimensions", [0, 1, 1]), f"{WHERE}.dimensions: expected three sizes greater than 0"),
    (lambda v: v.__setitem__("prototype", 10**400), f"{WHERE}.prototype: expected a string (of text UTF-8 can write) "
                                                    "or null, got an integer of 401 digits"),
    (lambda v: v.__setitem__("id", "\ud800"), f"{WHERE}.id: expected a vehicle id: a string of 1 to 128 characters (no "
                                              "control characters)"),
    (lambda v: v.__setitem__("error", "\udc00"), f"{WHERE}.error: expected a string (of text UTF-8 can write)"),
    (lambda v: v.__setitem__("warnings", [1]), f"{WHERE}.warnings: expected a list of strings"),
    (lambda v: v.__setitem__("rms_px", math.inf), f"{WHERE}.rms_px: expected a finite number or null, got inf"),
])
@pytest.mark.parametrize(("kind", "name"), KINDS)
def test_results_fit_did_not_write_are_refused_naming_the_path(fitted, tmp_path, change, message, kind, name):
    out = _variant(fitted, tmp_path, change)
    target = tmp_path / name
    result = CliRunner().invoke(main, ["export", kind, str(out), "-o", str(target)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"Error: {out / 'results.json'}: {message}")
    assert not target.exists()


def test_a_far_cuboid_is_left_out_of_the_cvat_review_not_written_as_inf(fitted, tmp_path):
    out = _variant(fitted, tmp_path, lambda v: v.__setitem__("t_cam_vehicle", [9e5, 0.0, 20.0]))
    target = tmp_path / "review.xml"
    result = CliRunner().invoke(main, ["export", "cvat", str(out), "-o", str(target)])
    assert result.exit_code == 0, result.output
    assert "the cuboid projects beyond +-1000000 pixels" in result.output
    assert "inf" not in target.read_text() and "nan" not in target.read_text()


def _paths(doc, path=()):
    out = [path]
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        out += _paths(value, (*path, key))
    return out


VALUES = st.one_of(st.none(), st.booleans(), st.floats(), st.integers(min_value=-(10**400), max_value=10**400),
                   st.text(max_size=8), st.just([]), st.just({}), st.lists(st.floats(), min_size=3, max_size=3),
                   st.just([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))


@settings(max_examples=60, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_any_value_of_results_json_exports_finite_or_is_named(fitted, tmp_path, data):
    doc = json.loads((fitted / "results.json").read_text())
    vehicle = doc["images"][0]["vehicles"][0]
    path = data.draw(st.sampled_from(_paths(vehicle)[1:]))
    changed = copy.deepcopy(doc)
    target = changed["images"][0]["vehicles"][0]
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = data.draw(VALUES)
    out = tmp_path / f"out-{shown(path, 40)}"
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(fitted, out)
    (out / "results.json").write_text(json.dumps(changed))
    for kind, name in KINDS:
        written = out / name
        result = CliRunner().invoke(main, ["export", kind, str(out), "-o", str(written)])
        assert result.exc_info is None or isinstance(result.exc_info[1], SystemExit), result.exc_info
        assert result.exit_code in (0, 2), result.output
        if result.exit_code == 2:
            assert result.output.startswith(f"Error: {out / 'results.json'}: $") and not written.exists()
        else:
            text = written.read_text()
            if kind == "openlabel":
                json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} written"))
            else:
                assert "inf" not in text.lower() and "nan" not in text.lower()

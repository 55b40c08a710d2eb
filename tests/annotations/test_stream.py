"""Reading an annotation file one image at a time gives what reading it whole gives, errors included."""

import copy
import io
import json

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.annotations.convert import image_from_schema, load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.annotations.schema import load_annotations
from toosicubix.annotations.stream import index_annotations, iter_image_annotations
from toosicubix.errors import InputFileError
from toosicubix.formats.results import dumps, results_to_json, write_results_stream
from toosicubix.pipeline.fitting import fit_images
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.solver.fit import SolverOptions

SAMPLE = REPO / "samples" / "annotations.json"


def test_streamed_images_equal_the_whole_file():
    index = index_annotations(SAMPLE)
    whole = load_images(SAMPLE)
    streamed = [image_from_schema(im, i) for i, im in iter_image_annotations(index)]
    assert index.vehicles == sum(len(im.vehicles) for im in whole)
    assert index.clicked == sum(bool(v.parts) for im in whole for v in im.vehicles) > 0
    assert [im.id for im in streamed] == [im.id for im in whole]
    for a, b in zip(streamed, whole, strict=True):
        assert a.json_path == b.json_path
        np.testing.assert_array_equal(a.camera.K, b.camera.K)  # same numbers parsed: exact
        assert [v.json_path for v in a.vehicles] == [v.json_path for v in b.vehicles]
        assert repr(a.vehicles) == repr(b.vehicles)


def _mutations():
    doc = json.loads(SAMPLE.read_text())

    def m(fn):
        d = copy.deepcopy(doc)
        fn(d)
        return json.dumps(d)

    yield m(lambda d: d["images"][1]["vehicles"][0]["parts"][0].update(part="wheel-middle"))
    yield m(lambda d: d["images"][2].update(id=d["images"][0]["id"]))
    yield m(lambda d: d.update(toosicubix=2))
    yield m(lambda d: d.update(extra=1))
    yield m(lambda d: d.pop("images"))
    yield m(lambda d: d.update(images={}))
    yield m(lambda d: d["images"][0]["camera"].pop("P"))
    yield '{"toosicubix": 1, "images": [{"id": "a",}]}'
    yield '{"toosicubix": 1, "images": []} trailing'
    yield '[1, 2]'


@pytest.mark.parametrize("text", list(_mutations()))
def test_errors_are_those_of_the_whole_file_reader(tmp_path, text):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InputFileError) as whole:
        load_annotations(path)
    with pytest.raises(InputFileError) as streamed:
        index_annotations(path)
    assert str(path) in str(streamed.value)
    if text.startswith("{") and not text.endswith("trailing") and ",}" not in text:
        # The same messages; a duplicate image id is located more precisely ($.images[2].id, not $.images).
        assert sorted(m for _, m in streamed.value.problems) == sorted(m for _, m in whole.value.problems)
        assert {p.split("[")[0] for p, _ in streamed.value.problems} == {
            p.split("[")[0] for p, _ in whole.value.problems}
    else:  # JSON syntax: both name the line and column
        assert "line 1 column" in str(streamed.value) or "expected a JSON object" in str(streamed.value)


def test_streamed_results_json_is_byte_identical():
    results = fit_images(load_images(SAMPLE), BatchSettings(priors=load_priors(), options=SolverOptions()))
    for header in ({}, {"generator": "x", "settings": {"a": [1, 2]}}):
        for images in (results, results[:1], []):
            handle = io.StringIO()
            summary = write_results_stream(handle, images, header)
            assert handle.getvalue() == dumps(results_to_json(images, header))
            assert summary == results_to_json(images, header)["summary"]

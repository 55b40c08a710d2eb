"""A batch keeps a bounded amount per vehicle: input read lazily, results handed on image by image."""

import json

import pytest

from tests.conftest import REPO
from toosicubix.annotations.convert import load_images
from toosicubix.pipeline import batch
from toosicubix.pipeline.batch import fit_file, fit_images, iter_fit_images
from toosicubix.priors.table import load_priors
from toosicubix.solver import SolverOptions

SAMPLE = REPO / "samples" / "annotations.json"


@pytest.mark.parametrize("jobs", [1, 2])
def test_images_are_read_lazily_and_results_come_in_order(jobs):
    images = load_images(SAMPLE) * 4  # 12 images, 24 vehicles
    read = []

    def source():
        for k, im in enumerate(images):
            read.append(k)
            yield im

    n = sum(len(im.vehicles) for im in images)
    stream = iter_fit_images(source(), n, load_priors(), SolverOptions(), jobs=jobs)
    first = next(stream)
    assert first.id == images[0].id
    # jobs 1: nothing read beyond the first image's; jobs 2: at most the chunks in flight (8 chunks of 3).
    assert len(read) <= (1 if jobs == 1 else 12)
    rest = list(stream)
    assert [im.id for im in [first, *rest]] == [im.id for im in images]
    assert [v.id for v in first.vehicles] == [v.id for v in images[0].vehicles]


def test_streamed_results_equal_the_listed_ones():
    images = load_images(SAMPLE)
    listed = fit_images(images, load_priors(), SolverOptions())
    streamed = list(iter_fit_images(iter(images), 6, load_priors(), SolverOptions(), jobs=2))
    assert [[(v.id, v.status, v.cost) for v in im.vehicles] for im in streamed] == [
        [(v.id, v.status, v.cost) for v in im.vehicles] for im in listed]


def test_the_summary_lists_a_bounded_number_of_failures(tmp_path, monkeypatch):
    doc = json.loads(SAMPLE.read_text())
    for im in doc["images"]:
        for v in im["vehicles"]:
            v["parts"] = v["parts"][:1]  # too few constraints: every vehicle fails
    path = tmp_path / "few.json"
    path.write_text(json.dumps(doc))
    monkeypatch.setattr(batch, "FAILED_KEPT", 2)
    summary = fit_file(path, tmp_path / "out")
    assert (summary.vehicles, summary.ok, summary.n_failed, len(summary.failed)) == (6, 0, 6, 2)
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    assert results["summary"]["failed"] == 6  # every failure is in results.json

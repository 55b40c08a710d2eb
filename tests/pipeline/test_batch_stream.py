"""A batch keeps a bounded amount per vehicle: input read lazily, results handed on image by image."""

import json

import pytest

from tests.conftest import REPO
from toosicubix.annotations.convert import load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.pipeline import batch, fitting, vehicle
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.fitting import fit_images, iter_fit_images
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.solver.fit import SolverOptions

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
    stream = iter_fit_images(source(), n, BatchSettings(priors=load_priors(), options=SolverOptions(), jobs=jobs))
    first = next(stream)
    assert first.id == images[0].id
    # jobs 1: nothing read beyond the first image's; jobs 2: at most the chunks in flight (8 chunks of 3).
    assert len(read) <= (1 if jobs == 1 else 12)
    rest = list(stream)
    assert [im.id for im in [first, *rest]] == [im.id for im in images]
    assert [v.id for v in first.vehicles] == [v.id for v in images[0].vehicles]


def test_streamed_results_equal_the_listed_ones():
    images = load_images(SAMPLE)
    listed = fit_images(images, BatchSettings())
    streamed = list(iter_fit_images(iter(images), 6, BatchSettings(jobs=2)))
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


def _counting_fits(monkeypatch) -> list[str]:
    calls: list[str] = []
    fit_one = fitting.fit_one  # as the batch calls it

    def counted(vehicle, *args):
        calls.append(vehicle.id)
        return fit_one(vehicle, *args)

    monkeypatch.setattr(fitting, "fit_one", counted)
    return calls


def test_a_small_batch_with_nothing_to_estimate_is_fitted_once(tmp_path, monkeypatch):
    # The sample: 6 vehicles of parts on the cuboid (no click noise to estimate) under one camera (too few for a
    # road normal). The pilot fits all 6 with the batch's settings, and its fits are written.
    once = tmp_path / "once"
    calls = _counting_fits(monkeypatch)
    summary = fit_file(SAMPLE, once, BatchSettings(estimate_click_sigma=True, estimate_road_normal=True))
    assert summary.ok == 6 and len(calls) == 6
    assert summary.pilot.results is not None and len(summary.pilot.results) == 3  # the sample's three images
    # The same as fitting without a pilot, byte for byte but for the header's estimates.
    plain = tmp_path / "plain"
    fit_file(SAMPLE, plain)
    assert len(calls) == 12
    assert (once / "label_2" / "000001.txt").read_bytes() == (plain / "label_2" / "000001.txt").read_bytes()
    a, b = (json.loads((d / "results.json").read_text()) for d in (once, plain))
    assert a["images"] == b["images"]


def test_a_batch_the_pilot_changes_is_fitted_again(tmp_path, monkeypatch):
    calls = _counting_fits(monkeypatch)
    # A robust loss: the pilot fits without it, so its fits are not the batch's.
    fit_file(SAMPLE, tmp_path / "robust",
             BatchSettings(options=SolverOptions(robust_loss="cauchy"), estimate_road_normal=True))
    assert len(calls) == 12


def test_next_clicks_are_suggested_by_a_pilot_that_fits_every_vehicle(tmp_path, monkeypatch):
    """fit --next-clicks and validate (which always asks for next clicks) fit a small batch once, and write what
    a batch without a pilot writes."""
    from toosicubix.pipeline.validation import validate_file

    calls = _counting_fits(monkeypatch)
    once = tmp_path / "once"
    fit_file(SAMPLE, once, BatchSettings(estimate_click_sigma=True, estimate_road_normal=True, next_clicks=2))
    assert len(calls) == 6
    fit_file(SAMPLE, tmp_path / "plain", BatchSettings(next_clicks=2))
    assert len(calls) == 12
    a, b = (json.loads((d / "results.json").read_text()) for d in (once, tmp_path / "plain"))
    assert a["images"] == b["images"] and all(len(v["next_clicks"]) == 2 for im in a["images"] for v in im["vehicles"])
    report = validate_file(SAMPLE, BatchSettings(next_clicks=3, estimate_click_sigma=True, estimate_road_normal=True))
    assert len(calls) == 18 and len(report.vehicles) == 6
    plain = validate_file(SAMPLE, BatchSettings(next_clicks=3))
    assert [c.result.next_clicks for c in report.vehicles] == [c.result.next_clicks for c in plain.vehicles]


def test_a_pilot_whose_fits_are_not_reused_suggests_nothing(tmp_path, monkeypatch):
    """Guidance costs about a fit: the pilot asks for it only for fits it hands on. A robust loss makes the
    pilot's fits not the batch's; the sample's 6 vehicles are then fitted twice and given suggestions once.
    When the pilot's fits are reused (several processes too), each vehicle is given suggestions once."""
    suggested: list[int] = []
    suggest = vehicle.guide

    def counted(*args, **kwargs):
        suggested.append(1)
        return suggest(*args, **kwargs)

    monkeypatch.setattr(vehicle, "guide", counted)
    calls = _counting_fits(monkeypatch)
    fit_file(SAMPLE, tmp_path / "robust",
             BatchSettings(options=SolverOptions(robust_loss="cauchy"), estimate_road_normal=True, next_clicks=2))
    assert len(calls) == 12 and len(suggested) == 6
    summary = fit_file(SAMPLE, tmp_path / "reused", BatchSettings(estimate_road_normal=True, next_clicks=2))
    assert summary.pilot.results is not None and len(calls) == 18 and len(suggested) == 12
    fit_file(SAMPLE, tmp_path / "two",
             BatchSettings(estimate_road_normal=True, next_clicks=2, jobs=2))  # counted in workers
    a, b = (json.loads((d / "results.json").read_text()) for d in (tmp_path / "reused", tmp_path / "two"))
    assert a["images"] == b["images"] and all(len(v["next_clicks"]) == 2 for im in a["images"] for v in im["vehicles"])

"""The fuzz harness of issue 34 (benchmarks/fuzz.py, benchmarks/fuzz_targets.py): cases made and run in forked
children, with tracebacks, hangs and peak memory measured; a few cases of the quick targets end cleanly."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click
import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def harness(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import fuzz
    import fuzz_targets

    yield fuzz, fuzz_targets
    for name in ("fuzz", "fuzz_targets"):
        sys.modules.pop(name, None)


def test_run_isolated_measures_each_case_in_its_own_process(harness, monkeypatch, tmp_path):
    fuzz, targets = harness

    @click.command()
    @click.argument("what")
    def fake(what):
        if what == "sleep":
            time.sleep(30)
        if what == "raise":
            raise KeyError("P")
        if what == "allocate":
            block = np.ones(300 * 2**20 // 8)  # 300 MB, touched
            click.echo(f"{block.sum():.0f}")
        if what == "write":
            (tmp_path / "out.json").write_text('{"a": NaN}')
            raise click.exceptions.Exit(2)

    monkeypatch.setattr(fuzz, "main", fake)
    hang = fuzz.run_isolated(targets.Command("sleep", ["sleep"]), 0.5, tmp_path)
    assert hang["hang"] and hang["seconds"] < 5
    failed = fuzz.run_isolated(targets.Command("raise", ["raise"]), 20, tmp_path)
    assert failed["exit"] == 1 and failed["traceback"].startswith("KeyError at test_fuzz_targets.py")
    small = fuzz.run_isolated(targets.Command("nothing", ["nothing"]), 20, tmp_path)
    large = fuzz.run_isolated(targets.Command("allocate", ["allocate"]), 20, tmp_path)
    assert small["exit"] == 0 and "traceback" not in small
    assert large["max_rss_mb"] - small["max_rss_mb"] > 250  # the child's own peak, not the worker's
    written = fuzz.run_isolated(targets.Command("write", ["write"], tmp_path / "out.json"), 20, tmp_path)
    assert written["exit"] == 2 and written["written_on_error"] and written["non_finite"].startswith("out.json")


@pytest.mark.parametrize("name", ["coco", "cvat", "label-studio"])
def test_quick_targets_make_cases_that_end_cleanly(harness, tmp_path, name):
    fuzz, targets = harness
    target = targets.TARGETS[name]()
    (tmp_path / "base").mkdir()
    target.prepare(tmp_path / "base")
    target._bomb_zip = b"PK\x05\x06" + bytes(18)  # the 600 MB bomb takes seconds to make: an empty zip stands in
    kinds = set()
    for index in range(4):
        folder = tmp_path / f"c{index}"
        folder.mkdir()
        for record in target.run_case(index, 0, folder, 60, fuzz.run_isolated):
            kinds.add(record["kind"])
            assert record["exit"] in (0, 2) and not record["hang"], record
            assert "traceback" not in record and "non_finite" not in record, record
            assert record["exit"] == 0 or record["output"].startswith("Error: "), record
    assert len(kinds) >= 2  # different mutations


def test_tracks_target_fits_its_sequence_and_its_cases_end_cleanly(harness, tmp_path):
    """The sequence the tracks target mutates is one ``fit`` places whole (3 tracks over 16 frames, each track one
    size), so that a mutation's effect is the mutation's; a few of its cases end with exit 0, 1 or 2 and no
    traceback, the fit cases and the results cases both."""
    fuzz, targets = harness
    target = targets.TARGETS["tracks"]()
    (tmp_path / "base").mkdir()
    target.prepare(tmp_path / "base")
    vehicles = [v for image in target.results["images"] for v in image["vehicles"]]
    assert len(target.results["images"]) == 16 and len(vehicles) == 44
    assert all(v["status"] == "ok" for v in vehicles)
    sizes = {}
    for v in vehicles:
        sizes.setdefault(v["track"], set()).add(tuple(v["dimensions"]))
    assert len(sizes) == 3 and all(len(s) == 1 for s in sizes.values())
    labels = {}
    for index in range(6):
        folder = tmp_path / f"c{index}"
        folder.mkdir()
        for record in target.run_case(index, 0, folder, 60, fuzz.run_isolated):
            labels.setdefault(record["command"], set()).add(record["exit"])
            assert record["exit"] in (0, 1, 2) and not record["hang"], record
            assert "traceback" not in record and "non_finite" not in record, record
            assert record["exit"] != 2 or record["output"].startswith("Error: "), record
    assert {"fit", "render --video"} <= set(labels) and {"export openlabel", "export cvat"} & set(labels)

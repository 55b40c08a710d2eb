"""With several processes, ``fit`` has its workers read the images they fit (iter_fit_file): the same results, byte
for byte, as the images read in the main process and fitted one by one."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import REPO
from toosicubix.annotations import stream
from toosicubix.annotations.stream import index_annotations
from toosicubix.formats.results import RenderedImage, image_text, image_to_json
from toosicubix.model import GroundOverride
from toosicubix.pipeline import fitting
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.fitting import (
    iter_fit_file,
    iter_fit_images,
    on_road,
    ordered_map,
    shared_workers,
    stream_images,
)
from toosicubix.pipeline.labels import kitti_lines
from toosicubix.pipeline.road_normal import camera_key
from toosicubix.pipeline.settings import BatchSettings

SAMPLE = REPO / "samples" / "annotations.json"


def _file(tmp_path: Path) -> Path:
    """The sample's images three times over with new ids, an image without vehicles among them, and one image with a
    ground block of its own."""
    doc = json.loads(SAMPLE.read_text())
    images = []
    for copy in range(3):
        for im in doc["images"]:
            images.append({**im, "id": f"{im['id']}-{copy}"})
    images.insert(4, {**doc["images"][0], "id": "empty", "vehicles": []})
    images[1] = {**images[1], "ground": {"camera_height": 1.65}}
    path = tmp_path / "annotations.json"
    path.write_text(json.dumps({**doc, "images": images}))
    return path


@pytest.mark.parametrize("ground", [None, GroundOverride(camera_height=1.7)])
def test_workers_reading_their_images_give_the_same_results(tmp_path: Path, ground):
    path = _file(tmp_path)
    index = index_annotations(path)
    first = next(stream_images(index, None))
    blocks = {camera_key(first.camera): GroundOverride(normal=(0.0, -0.9995, 0.0316), normal_sigma_deg=2.0,
                                                       upright_sigma_deg=2.0)}
    settings = BatchSettings(ground=ground, jobs=2)
    counted: list[int] = []
    by_workers = list(iter_fit_file(index, settings, blocks, counted.append))
    in_main = list(iter_fit_images((on_road(im, blocks) for im in stream_images(index, ground)), index.vehicles,
                                   BatchSettings(ground=ground, jobs=1)))
    # Each entry written by its worker, as the main process would write it (json's own indented text), and each
    # image's KITTI label lines; the vehicles come back as their summaries.
    assert all(isinstance(r, RenderedImage) for r in by_workers) and not any(isinstance(r, RenderedImage)
                                                                             for r in in_main)
    assert [r.text for r in by_workers] == [json.dumps(image_to_json(r), indent=1, allow_nan=False) for r in in_main]
    assert [image_text(r) for r in by_workers] == [image_text(r) for r in in_main]
    assert [list(r.label_lines) for r in by_workers] == [kitti_lines(r) for r in in_main]
    assert sum(len(r.label_lines) for r in by_workers) > 0
    assert [[v.summary() for v in r.vehicles] for r in by_workers] == [[v.summary() for v in r.vehicles]
                                                                       for r in in_main]
    assert [(r.id, r.sequence, r.frame, r.image_size) for r in by_workers] == [
        (r.id, r.sequence, r.frame, r.image_size) for r in in_main]
    assert all(v.R_cam_vehicle is None and v.residuals_px is None and v.sigma is None
               for r in by_workers for v in r.vehicles)
    assert [r.id for r in by_workers][4] == "empty" and not by_workers[4].vehicles
    assert sum(counted) == index.vehicles == sum(len(r.vehicles) for r in by_workers)
    on_estimated_road = [r for r in by_workers if r.ground is not None and r.ground.estimated]
    if ground is None:  # with an override every image has a block of its own, and keeps it
        assert on_estimated_road and np.allclose(on_estimated_road[0].ground.normal, (0.0, -0.9995, 0.0316),
                                                 atol=1e-3)


@pytest.mark.parametrize("estimate", [True, False])
def test_fit_writes_the_same_folder_with_one_process_or_two(tmp_path: Path, monkeypatch, estimate: bool):
    path = _file(tmp_path)
    read_in_main: list[str] = []
    parse = stream.image_annotation

    def counted(text: str):
        read_in_main.append(text)
        return parse(text)

    monkeypatch.setattr(stream, "image_annotation", counted)  # the main process's reads (the workers' are their own)
    settings = BatchSettings(estimate_click_sigma=estimate, estimate_road_normal=estimate)
    one = fit_file(path, tmp_path / "one", replace(settings, jobs=1))
    read_one = len(read_in_main)
    read_in_main.clear()
    two = fit_file(path, tmp_path / "two", replace(settings, jobs=2))
    assert (one.vehicles, one.ok) == (two.vehicles, two.ok)
    if not estimate:  # no pilot: every image read once by the main process with one process, by none with two
        assert (read_one, len(read_in_main)) == (len(index_annotations(path).spans), 0)
    for name in ["results.json", *sorted(p.name for p in (tmp_path / "one" / "label_2").iterdir())]:
        where = "" if name == "results.json" else "label_2"
        a = (tmp_path / "one" / where / name).read_bytes()
        b = (tmp_path / "two" / where / name).read_bytes()
        assert a == b, name


def test_workers_started_by_spawn_read_and_fit_the_same(tmp_path: Path):
    """macOS and Windows start workers by spawn, not fork: nothing of the main process is inherited, so what a worker
    needs to read and fit its images (the settings, the estimated roads) must travel with its tasks."""
    import subprocess
    import sys

    path = _file(tmp_path)
    script = tmp_path / "spawned.py"
    script.write_text(
        "import multiprocessing, sys\n"
        "if __name__ == '__main__':\n"
        "    multiprocessing.set_start_method('spawn', force=True)\n"
        "    from toosicubix.pipeline.batch import fit_file\n"
        "    from toosicubix.pipeline.settings import BatchSettings\n"
        "    settings = BatchSettings(jobs=int(sys.argv[3]))  # with a pilot: its workers fit the batch too\n"
        "    fit_file(sys.argv[1], sys.argv[2], settings)\n")
    for jobs in (1, 2):
        subprocess.run([sys.executable, str(script), str(path), str(tmp_path / f"out{jobs}"), str(jobs)], check=True,
                       timeout=300)
    assert (tmp_path / "out1" / "results.json").read_bytes() == (tmp_path / "out2" / "results.json").read_bytes()
    labels = sorted(p.name for p in (tmp_path / "out1" / "label_2").iterdir())
    assert labels and all((tmp_path / "out1" / "label_2" / n).read_bytes() ==
                          (tmp_path / "out2" / "label_2" / n).read_bytes() for n in labels)


def _pids(tasks: list) -> list:
    """A chunk's tasks, each with the worker that took it."""
    import os

    return [(task, os.getpid()) for task in tasks]


def test_one_pool_serves_every_map_of_a_shared_workers_block():
    """A batch's pilot, fits and next clicks start their workers once (spawned workers each load the package and the
    compiled solver again): within ``shared_workers`` every map of the same number of processes takes one pool, shut
    down when the block ends; outside it each map has its own."""
    tasks = [(k,) for k in range(40)]
    with shared_workers():
        first = list(ordered_map(iter(tasks), 2, 3, _pids))
        second = list(ordered_map(iter(tasks), 2, 3, _pids))
        (pool,) = fitting._shared_pools.values()
        left_early = ordered_map(iter(tasks), 2, 1, _pids)
        assert next(left_early)[0] == (0,)
        left_early.close()  # the reader stops: the map's queued chunks are cancelled, the pool stays
        third = list(ordered_map(iter(tasks), 2, 5, _pids))
    assert [t for t, _ in first] == [t for t, _ in second] == [t for t, _ in third] == tasks  # in order
    workers = {pid for _, pid in first + second + third}
    assert 1 <= len(workers) <= 2
    assert fitting._shared_pools is None
    with pytest.raises(RuntimeError):  # shut down with the block
        pool.submit(_pids, [(0,)])
    alone = {pid for _, pid in ordered_map(iter(tasks), 2, 3, _pids)}
    assert not alone & workers


_SMALL_OR_LARGE = """
import sys
from toosicubix.pipeline import fitting
from toosicubix.pipeline.batch import fit_file
from toosicubix.pipeline.settings import BatchSettings
if sys.argv[3] == "compiled":
    fitting.COMPILED_FROM_VEHICLES = 0  # the sample counts as a large batch
said = []
fit_file(sys.argv[1], sys.argv[2], BatchSettings(jobs=int(sys.argv[4])), say=said.append)
print("numba" in sys.modules)
"""


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_small_batch_takes_the_numpy_path_with_the_same_bytes(tmp_path: Path, jobs: int):
    """A batch below COMPILED_FROM_VEHICLES does not load the compiled solver (numba is not even imported: half a
    second, twenty the first time after installing); its folder is byte for byte the compiled path's."""
    import subprocess
    import sys

    from toosicubix.pipeline.fitting import COMPILED_FROM_VEHICLES

    path = _file(tmp_path)
    assert index_annotations(path).vehicles < COMPILED_FROM_VEHICLES
    script = tmp_path / "small_or_large.py"
    script.write_text(_SMALL_OR_LARGE)
    loaded = {}
    for mode in ("numpy", "compiled"):
        run = subprocess.run([sys.executable, str(script), str(path), str(tmp_path / mode), mode, str(jobs)],
                             check=True, capture_output=True, text=True, timeout=300)
        loaded[mode] = run.stdout.strip().splitlines()[-1]
    assert loaded == {"numpy": "False", "compiled": "True"}
    assert (tmp_path / "numpy" / "results.json").read_bytes() == (tmp_path / "compiled" / "results.json").read_bytes()
    for label in (tmp_path / "numpy" / "label_2").iterdir():
        assert label.read_bytes() == (tmp_path / "compiled" / "label_2" / label.name).read_bytes()


def test_fit_says_it_compiles_only_for_a_batch_that_loads_the_compiled_solver(tmp_path: Path, monkeypatch):
    from toosicubix.pipeline import fitting
    from toosicubix.solver import compiled

    if not compiled.available():
        pytest.skip("no compiled path here (numba absent or switched off)")
    monkeypatch.setattr(compiled, "_cached", lambda dispatcher: False)  # as on the first run after installing
    path = _file(tmp_path)
    said: list[str] = []
    fit_file(path, tmp_path / "small", BatchSettings(), say=said.append)
    assert said == []  # 18 vehicles: the numpy path, nothing to compile
    monkeypatch.setattr(fitting, "COMPILED_FROM_VEHICLES", 10)
    fit_file(path, tmp_path / "large", BatchSettings(), say=said.append)
    assert said == [compiled.COMPILING]


def test_a_file_of_few_crowded_images_is_read_in_the_main_process(tmp_path: Path):
    """The workers get whole images: one image of 45 vehicles would keep one worker busy while the other waits,
    where the main process's reading hands out its vehicles a few at a time. Such a file keeps that path."""
    from toosicubix.pipeline.fitting import _chunk, _image_groups, reads_in_workers

    doc = json.loads(SAMPLE.read_text())
    first = doc["images"][0]
    crowded = {**first, "vehicles": [{**v, "id": f"{k}-{v['id']}"} for k in range(15) for v in first["vehicles"]]}
    path = tmp_path / "crowded.json"
    path.write_text(json.dumps({**doc, "images": [crowded]}))
    index = index_annotations(path)
    n = len(crowded["vehicles"])
    assert index.image_vehicles == (n,) and not reads_in_workers(index, 2)
    spread = index_annotations(_file(tmp_path))
    assert reads_in_workers(spread, 2) and not reads_in_workers(spread, 1)
    groups = list(_image_groups(spread, _chunk(spread.vehicles, 2)))
    assert len(groups) > 1
    assert [i for group in groups for i, _ in group] == list(range(len(spread.spans)))  # every image once, in order
    chunk = _chunk(spread.vehicles, 2)
    assert all(sum(spread.image_vehicles[i] for i, _ in group) >= chunk for group in groups[:-1])
    two = fit_file(path, tmp_path / "two", BatchSettings(jobs=2, estimate_click_sigma=False,
                                                        estimate_road_normal=False))
    one = fit_file(path, tmp_path / "one", BatchSettings(jobs=1, estimate_click_sigma=False,
                                                        estimate_road_normal=False))
    assert (one.ok, one.vehicles) == (two.ok, two.vehicles) == (n, n)
    assert (tmp_path / "one" / "results.json").read_bytes() == (tmp_path / "two" / "results.json").read_bytes()

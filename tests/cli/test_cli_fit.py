import copy
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.formats.kitti import read_label_file
from toosicubix.formats.results import read_results
from toosicubix.geometry import geodesic_angle
from toosicubix.pipeline.batch import fit_file

SAMPLE = REPO / "samples" / "annotations.json"


def run(*args: str):
    return CliRunner().invoke(main, list(args))


def sample_doc() -> dict:
    return json.loads(SAMPLE.read_text())


def write_doc(tmp_path: Path, doc: dict, name: str = "ann.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def test_fit_sample_writes_kitti_and_results(tmp_path):
    out = tmp_path / "out"
    result = run("fit", str(SAMPLE), "-o", str(out))
    assert result.exit_code == 0, result.output
    labels = sorted(p.name for p in (out / "label_2").glob("*.txt"))
    assert labels == ["000001.txt", "000002.txt", "000003.txt"]
    for path in (out / "label_2").glob("*.txt"):
        for line in path.read_text().splitlines():
            assert len(line.split(" ")) == 16
    doc = json.loads((out / "results.json").read_text())
    vehicle = doc["images"][0]["vehicles"][0]
    for key in ("id", "status", "error", "prototype", "R_cam_vehicle", "t_cam_vehicle", "dimensions", "box2d",
                "rms_px", "residuals_px", "cost", "constraints"):
        assert key in vehicle
    assert "fitted 6 of 6 vehicles" in result.output
    assert "pitch and roll dropped" in result.output


def test_sample_fit_matches_its_ground_truth(tmp_path):
    """The sample's clicks are exact up to 0.1 px rounding: every rotation within 2 degrees of the truth, the KITTI
    boxes where the sample's generator put them. But one: car 3 of image 000001, seen broadside with no road, whose
    clicks leave its yaw and roll to the cues (yaw sigma 27 degrees, 32 with free axles); its axles, where the sample's
    generator put them (0.32 and 0.30 of its length from the middle), are half a sigma from where the axle prior puts a
    car's (rule 29), which turns it 9.2 degrees along that valley: within its own sigma."""
    out = tmp_path / "out"
    assert run("fit", str(SAMPLE), "-o", str(out)).exit_code == 0
    truth_dir = REPO / "samples" / "ground_truth" / "label_2"
    for image in read_results(out / "results.json"):
        truth = read_label_file(truth_dir / f"{image.id}.txt")
        for fitted, gt in zip(image.vehicles, truth, strict=True):
            angle = np.rad2deg(geodesic_angle(fitted.R_cam_vehicle, gt.R_cam_vehicle))
            if (image.id, fitted.id) == ("000001", "3"):
                assert fitted.sigma.yaw_deg > 20.0 and angle < fitted.sigma.yaw_deg
                continue
            assert angle < 2.0, (image.id, fitted.id, angle)
            np.testing.assert_allclose(fitted.box2d, gt.box2d, atol=0.1)


def test_default_output_folder_is_what_eval_reads(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = run("fit", str(SAMPLE))
    assert result.exit_code == 0, result.output
    assert (tmp_path / "toosicubix-out" / "results.json").is_file()
    assert (tmp_path / "toosicubix-out" / "label_2" / "000001.txt").is_file()


def test_one_unsolvable_vehicle_does_not_stop_the_batch(tmp_path):
    doc = sample_doc()
    vehicles = doc["images"][0]["vehicles"]
    vehicles.insert(1, {"id": "lonely", "prototype": "Car", "parts": [vehicles[0]["parts"][0]]})
    out = tmp_path / "out"
    result = run("fit", str(write_doc(tmp_path, doc)), "-o", str(out))
    assert result.exit_code == 1
    assert ("failed: image 000001 vehicle lonely: too few clicks: 1 clicked point cannot place a cuboid; click at "
            "least 2 more") in result.output  # a wheel: its axle is held by a car's axle prior (rule 31)
    images = read_results(out / "results.json")
    statuses = [(v.id, v.status) for v in images[0].vehicles]
    assert statuses == [("1", "ok"), ("lonely", "failed"), ("2", "ok"), ("3", "ok")]
    assert images[0].vehicles[1].error_detail.startswith("too few constraints")
    assert len((out / "label_2" / "000001.txt").read_text().splitlines()) == 3
    assert sum(v.ok for im in images for v in im.vehicles) == 6


def test_internal_error_in_one_vehicle_is_contained(tmp_path, monkeypatch):
    import toosicubix.pipeline.vehicle as one

    real = one.fit_vehicle
    calls = {"n": 0}

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("boom")
        return real(*args, **kwargs)

    monkeypatch.setattr(one, "fit_vehicle", flaky)
    summary = fit_file(SAMPLE, tmp_path / "out")
    assert summary.ok == 5 and len(summary.failed) == 1
    assert summary.failed[0][2].startswith("internal error: RuntimeError: boom")


@pytest.mark.parametrize(
    ("mutate", "fragment"),
    [
        (lambda d: d["images"][0]["vehicles"][0]["parts"][0].update(part="wheel"),
         "$.images[0].vehicles[0].parts[0].part"),
        (lambda d: d["images"][0]["vehicles"][0]["parts"][0]["xy"].__setitem__(0, float("nan")),
         "$.images[0].vehicles[0].parts[0].xy[0]: Input should be a finite number"),
        (lambda d: d["images"][0]["vehicles"][1].update(id="1"),
         "$.images[0].vehicles: expected unique vehicle ids, got '1'"),
        (lambda d: d["images"][1].update(camera={"K": [[0, 0, 0], [0, 0, 0], [0, 0, 1]]}),
         "$.images[1].camera.K: expected an invertible K"),
        (lambda d: d["images"][0]["vehicles"][0].update(wheels=4),
         "$.images[0].vehicles[0].wheels: unknown field"),
        (lambda d: d["images"][0]["vehicles"][0].pop("parts") and d["images"][0]["vehicles"][0].pop("prototype"),
         "$.images[0].vehicles[0].prototype: missing required field"),
        (lambda d: d["images"][0]["vehicles"][2].update(prototype="Limousine"),
         "$.images[0].vehicles[2].prototype: unknown prototype 'Limousine'; known: Barrier, Bicycle, Box Wagon"),
    ],
)
def test_bad_input_exits_2_names_file_and_path_and_writes_nothing(tmp_path, mutate, fragment):
    doc = sample_doc()
    mutate(doc)
    path = write_doc(tmp_path, doc)
    out = tmp_path / "out"
    result = run("fit", str(path), "-o", str(out))
    assert result.exit_code == 2
    assert f"{path}: {fragment}" in result.output
    assert not out.exists()


def test_missing_annotation_file_exits_2(tmp_path):
    result = run("fit", str(tmp_path / "nope.json"), "-o", str(tmp_path / "out"))
    assert result.exit_code == 2
    assert "nope.json: $: cannot read the file" in result.output


def test_custom_priors_and_unknown_prototype_in_them(tmp_path):
    priors = {"toosicubix_priors": 1, "prototypes": {"Sedan": {
        "mean": [4.8, 1.8, 1.45], "cov": [[0.04, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], "kitti_type": "Car",
        "source": "test"}}}
    priors_path = tmp_path / "priors.json"
    priors_path.write_text(json.dumps(priors))
    doc = sample_doc()
    for image in doc["images"]:
        for v in image["vehicles"]:
            v["prototype"] = "Sedan"
    result = run("fit", str(write_doc(tmp_path, doc)), "-o", str(tmp_path / "out"), "--priors", str(priors_path))
    assert result.exit_code == 0, result.output
    result = run("fit", str(SAMPLE), "-o", str(tmp_path / "out2"), "--priors", str(priors_path))
    assert result.exit_code == 2
    assert "unknown prototype 'Car'; known: Sedan" in result.output


def test_bad_priors_file_exits_2(tmp_path):
    priors_path = tmp_path / "priors.json"
    priors_path.write_text(json.dumps({"toosicubix_priors": 1, "prototypes": {"Car": {"mean": [4, 1.7, -1]}}}))
    result = run("fit", str(SAMPLE), "-o", str(tmp_path / "out"), "--priors", str(priors_path))
    assert result.exit_code == 2
    assert f"{priors_path}: $.prototypes.Car.mean: expected positive dimensions" in result.output
    assert f"{priors_path}: $.prototypes.Car.cov: missing required field" in result.output


def test_lambda_options_are_validated_and_recorded(tmp_path):
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "o"), "--lambda-p", "-1").exit_code == 2
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "o"), "--lambda", "0.5", "--lambda-p", "0.25").exit_code == 0
    settings = json.loads((tmp_path / "o" / "results.json").read_text())["settings"]
    assert (settings["lambda_3d"], settings["lambda_px"]) == (0.5, 0.25)


def test_upright_weight_is_validated_and_recorded(tmp_path):
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "o"), "--upright-weight", "prior").exit_code == 2
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "o")).exit_code == 0
    assert "upright_weight" not in json.loads((tmp_path / "o" / "results.json").read_text())["settings"]  # default
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "o"), "--upright-weight", "clicks").exit_code == 0
    assert json.loads((tmp_path / "o" / "results.json").read_text())["settings"]["upright_weight"] == "clicks"


def test_foreign_label_files_are_never_overwritten(tmp_path):
    label_dir = tmp_path / "kitti" / "label_2"
    label_dir.mkdir(parents=True)
    (label_dir / "000001.txt").write_text("Car 0 0 0 1 2 3 4 1.5 1.6 4 1 2 10 0.1\n")
    result = run("fit", str(SAMPLE), "-o", str(tmp_path / "kitti"))
    assert result.exit_code == 2
    assert "that toosicubix did not write" in result.output
    assert (label_dir / "000001.txt").read_text() == "Car 0 0 0 1 2 3 4 1.5 1.6 4 1 2 10 0.1\n"


def test_rerun_replaces_outputs_and_removes_stale_labels(tmp_path):
    out = tmp_path / "out"
    assert run("fit", str(SAMPLE), "-o", str(out)).exit_code == 0
    doc = sample_doc()
    doc["images"] = doc["images"][:1]
    assert run("fit", str(write_doc(tmp_path, doc)), "-o", str(out)).exit_code == 0
    assert sorted(p.name for p in (out / "label_2").glob("*.txt")) == ["000001.txt"]
    assert [im.id for im in read_results(out / "results.json")] == ["000001"]
    assert not list(out.rglob("*.tmp"))  # no temporary files left behind


def test_results_are_deterministic(tmp_path):
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "a")).exit_code == 0
    assert run("fit", str(SAMPLE), "-o", str(tmp_path / "b")).exit_code == 0
    a = json.loads((tmp_path / "a" / "results.json").read_text())
    b = json.loads((tmp_path / "b" / "results.json").read_text())
    assert a["images"] == b["images"]


def test_image_without_vehicles_gets_an_empty_label_file(tmp_path):
    doc = sample_doc()
    doc["images"].append({**copy.deepcopy(doc["images"][0]), "id": "000099", "vehicles": []})
    out = tmp_path / "out"
    assert run("fit", str(write_doc(tmp_path, doc)), "-o", str(out)).exit_code == 0
    assert (out / "label_2" / "000099.txt").read_text() == ""


def test_help_texts_have_examples():
    for command in ("fit", "schema"):
        result = run(command, "--help")
        assert result.exit_code == 0
        assert "Example:" in result.output
    assert "toosicubix eval --kitti" in run("--help").output


def test_help_shows_no_empty_range():
    """A number option without bounds shows none: click's range text would read ``[x<=None]``."""
    from toosicubix.cli import main

    commands = [[name] for name in main.commands]
    commands += [[name, sub] for name, group in main.commands.items() for sub in getattr(group, "commands", {})]
    for command in commands:
        result = run(*command, "--help")
        assert result.exit_code == 0, command
        assert "None]" not in result.output and "=None" not in result.output, command


def test_schema_command_prints_the_schema():
    result = run("schema")
    assert result.exit_code == 0
    assert json.loads(result.output)["title"] == "ToosiCubix annotation file v1"

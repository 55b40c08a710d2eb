"""`toosicubix validate`, `fit --next-clicks`, and the confidence in the KITTI score field."""

import json
import math

from tests.cli.test_cli_fit import SAMPLE, run, sample_doc, write_doc
from toosicubix.formats.kitti import read_label_file
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.validation import Thresholds, validate_file

LOOSE = ("--max-yaw-sigma", "1000", "--max-depth-sigma", "100", "--allow-ambiguous")


def _files(folder):
    return sorted(p.relative_to(folder) for p in folder.rglob("*"))


def test_validate_writes_nothing_and_exits_0_when_every_vehicle_passes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    before = _files(tmp_path)
    result = run("validate", str(SAMPLE), *LOOSE)
    assert result.exit_code == 0, result.output
    assert _files(tmp_path) == before
    assert "6 vehicles: 6 well determined, 0 not, 0 failed" in result.output
    assert "for clicks off by 1.5 px on parts 9 cm off the cuboid model)" in result.output  # no keypoints here


def test_validate_exits_1_and_explains_the_vehicles_that_need_clicks(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = run("validate", str(SAMPLE), "--max-yaw-sigma", "1")
    assert result.exit_code == 1
    out = result.output
    assert "NOT well determined: yaw sigma" in out
    assert "constraints " in out and "auxiliary unknowns" in out
    assert "sigma: yaw " in out and "confidence " in out
    assert "set by the size prior" in out  # an observability sentence
    assert "click next:" in out and "    1. " in out and "yaw sigma" in out
    assert _files(tmp_path) == []


def test_validate_json_report_matches_the_thresholds(tmp_path):
    result = run("validate", str(SAMPLE), "--json", "--max-yaw-sigma", "5", "--next-clicks", "2")
    report = json.loads(result.output)
    assert report["thresholds"]["max_yaw_sigma_deg"] == 5.0
    assert len(report["vehicles"]) == 6
    for v in report["vehicles"]:
        assert v["json_path"].startswith("$.images[")
        assert len(v["next_clicks"]) == 2
        reach = v["reachable_sigma"]  # rule 20: the limits rise to 1.25 x what every visible part would give
        max_yaw, max_depth = max(5.0, 1.25 * reach["yaw_deg"]), max(0.10, 1.25 * reach["depth_rel"])
        too_uncertain = v["sigma"]["yaw_deg"] > max_yaw or v["sigma"]["depth_rel"] > max_depth or v["ambiguous"]
        assert v["well_determined"] is (not too_uncertain)
        assert v["well_determined"] is (not v["problems"])
    assert report["ok"] is all(v["well_determined"] for v in report["vehicles"])
    assert result.exit_code == (0 if report["ok"] else 1)


def test_validate_reports_schema_errors_with_json_paths_and_exit_2(tmp_path):
    doc = sample_doc()
    doc["images"][0]["vehicles"][0]["parts"][0]["part"] = "wheel"
    doc["images"][1]["vehicles"][0]["parts"][0]["xy"] = [1.0]
    path = write_doc(tmp_path, doc)
    result = run("validate", str(path))
    assert result.exit_code == 2
    assert f"{path}: $.images[0].vehicles[0].parts[0].part" in result.output
    assert "$.images[1].vehicles[0].parts[0].xy" in result.output


def test_validate_counts_a_vehicle_with_too_few_clicks_as_failed(tmp_path):
    doc = sample_doc()
    vehicles = doc["images"][0]["vehicles"]
    vehicles.append({"id": "lonely", "prototype": "Car", "parts": [vehicles[0]["parts"][0]]})
    result = run("validate", str(write_doc(tmp_path, doc)), *LOOSE)
    assert result.exit_code == 1
    assert "vehicle lonely (Car, $.images[0].vehicles[3]): NOT well determined: failed: too few clicks" in (
        result.output)
    assert "7 vehicles: 6 well determined, 0 not, 1 failed" in result.output


def test_validate_and_fit_agree(tmp_path):
    """validate fits exactly as fit does: same sigmas, same suggestions."""
    out = tmp_path / "out"
    assert run("fit", str(SAMPLE), "-o", str(out), "--next-clicks", "3").exit_code == 0
    fitted = json.loads((out / "results.json").read_text())
    report = validate_file(SAMPLE, BatchSettings(next_clicks=3), thresholds=Thresholds())
    by_id = {(c.image_id, c.result.id): c.result.to_json() for c in report.vehicles}
    for image in fitted["images"]:
        for v in image["vehicles"]:
            details = by_id[(image["id"], v["id"])]
            assert v["sigma"] == json.loads(json.dumps(details["sigma"]))
            assert [s["name"] for s in v["next_clicks"]] == [s["name"] for s in details["next_clicks"]]


def test_fit_adds_next_clicks_only_when_asked(tmp_path):
    plain, guided = tmp_path / "plain", tmp_path / "guided"
    assert run("fit", str(SAMPLE), "-o", str(plain)).exit_code == 0
    assert run("fit", str(SAMPLE), "-o", str(guided), "--next-clicks", "2").exit_code == 0
    for image in json.loads((plain / "results.json").read_text())["images"]:
        assert all("next_clicks" not in v for v in image["vehicles"])
    for image in json.loads((guided / "results.json").read_text())["images"]:
        for v in image["vehicles"]:
            assert len(v["next_clicks"]) == 2
            s = v["next_clicks"][0]
            assert {"kind", "name", "label", "uv", "visible", "inside_image", "yaw_sigma_deg", "depth_sigma_rel",
                    "yaw_gain_deg", "depth_gain_rel", "score"} <= set(s)
            assert s["yaw_gain_deg"] == v["sigma"]["yaw_deg"] - s["yaw_sigma_deg"]


def test_kitti_score_is_the_confidence_from_the_uncertainty(tmp_path):
    out = tmp_path / "out"
    assert run("fit", str(SAMPLE), "-o", str(out)).exit_code == 0
    doc = json.loads((out / "results.json").read_text())
    for image in doc["images"]:
        labels = read_label_file(out / "label_2" / f"{image['id']}.txt")
        for v, label in zip(image["vehicles"], labels, strict=True):
            sigma = v["sigma"]
            expected = (math.erf(10.0 / (math.sqrt(2) * sigma["yaw_deg"]))
                        * math.erf(0.1 / (math.sqrt(2) * sigma["depth_rel"])))
            assert v["confidence"] == expected
            assert label.score == round(expected, 4)
    assert len({round(v["confidence"], 4) for im in doc["images"] for v in im["vehicles"]}) > 1


def test_validate_help_explains_the_exit_codes():
    result = run("validate", "--help")
    assert result.exit_code == 0
    assert "Exit code 0 when every vehicle is well determined" in result.output
    assert "Example:" in result.output

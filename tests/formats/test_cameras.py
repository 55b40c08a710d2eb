"""Cameras files: the first glob that fits wins; bad entries name the JSON path."""

import json

import pytest

from tests.conftest import shared_data_dir
from toosicubix.errors import FormatError
from toosicubix.formats.cameras import load_cameras

K = [[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]]


def test_first_match_wins(tmp_path):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*Camera_5*", "K": K, "distortion": [0.1, 0, 0, 0, 0]},
                                            {"match": "*.png", "K": [[500, 0, 1], [0, 500, 2], [0, 0, 1]]}]}))
    table = load_cameras(path)
    assert table.camera_for("road/Camera_5/a.png") == {"K": K, "distortion": [0.1, 0, 0, 0, 0]}
    assert table.camera_for("b.png")["K"][0][0] == 500
    assert table.camera_for("b.jpg") is None


@pytest.mark.parametrize(("entry", "message"), [
    ({"K": K}, r"\$.cameras\[0\].match: missing"),
    ({"match": "*"}, r"\$.cameras\[0\].K: missing"),
    ({"match": "*", "K": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}, r"\$.cameras\[0\].K: expected the last row of K"),
    ({"match": "*", "K": K, "distortion": [1, 2]}, r"\$.cameras\[0\].distortion: expected 4, 5, 8, 12 or 14"),
    ({"match": "*", "K": K, "P": K}, r"unknown field 'P'"),
])
def test_bad_entries_name_the_file_and_path(tmp_path, entry, message):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [entry]}))
    with pytest.raises(FormatError, match=message) as info:
        load_cameras(path)
    assert str(path) in str(info.value)


def test_reads_the_apollocar3d_cameras_file():
    path = shared_data_dir() / "apollocar3d" / "cameras.json"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    table = load_cameras(path)
    camera = table.camera_for("171206_034625454_Camera_5.jpg")
    assert camera is not None and camera["K"][0][0] > 1000

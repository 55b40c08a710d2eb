"""Hostile Cityscapes 3D ground truth (issue 13, item 6): no camera, absurd sizes, bad bytes: a FormatError
naming the file and the JSON path, never a traceback."""

from __future__ import annotations

import json

import pytest

from tests.eval_scenes import CITYSCAPES_SCENE, cs_document
from toosicubix.errors import FormatError
from toosicubix.formats.cityscapes import read_gtbbox3d
from toosicubix.jsonfile import MAX_JSON_DEPTH

BOXES = CITYSCAPES_SCENE["aachen_000000_000019"]


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["sensor"].update(fx=0.0), r"\$\.sensor: fx, fy, u0, v0 are not a camera"),
    (lambda d: d["sensor"].update(fy=1e308), r"\$\.sensor: fx, fy, u0, v0 are not a camera"),
    (lambda d: d["sensor"].update(sensor_T_ISO_8855=[[0, 0, 0, 1.7], [0, 0, 0, 0.1], [0, 0, 0, 1.2]]),
     r"\$\.sensor\.sensor_T_ISO_8855: expected \[R \| t\] with R a rotation"),
    (lambda d: d["objects"][0]["3d"].update(dimensions=[4.0, 1.7, 1e308]), r"\.3d\.dimensions: expected at most 100"),
    (lambda d: d["objects"][0]["3d"].update(center=[1e308, 0.0, 0.0]), r"\.3d\.center: expected within 10000"),
    (lambda d: d["objects"][0]["2d"].update(amodal=[0, 0, 1e308, 10]), r"\.2d\.amodal: expected pixels within"),
    (lambda d: d.update(imgWidth=1e308), r"\$\.imgWidth: expected a size from 1 to"),
])
def test_hostile_cityscapes_files_name_file_and_json_path(tmp_path, edit, message):
    doc = cs_document(BOXES[:1])
    edit(doc)
    path = tmp_path / "x_gtBbox3d.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=message) as info:
        read_gtbbox3d(path)
    assert str(info.value).startswith(str(path))


def test_bytes_bom_and_nesting(tmp_path):
    path = tmp_path / "x_gtBbox3d.json"
    text = json.dumps(cs_document(BOXES[:1]))
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert len(read_gtbbox3d(path).objects) == 1  # a BOM is skipped
    path.write_bytes(text.encode().replace(b'"car"', b'"c\xe4r"', 1))
    with pytest.raises(FormatError, match=r"expected UTF-8 JSON text: invalid continuation byte at byte \d+"):
        read_gtbbox3d(path)
    path.write_text("[" * 5000 + "]" * 5000)
    with pytest.raises(FormatError, match=f"x_gtBbox3d.json:1: arrays and objects nested 5000 deep "
                                          f"\\(first at line 1\\); at most {MAX_JSON_DEPTH}"):
        read_gtbbox3d(path)

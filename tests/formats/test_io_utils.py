"""Atomic writes (toosicubix.io_utils)."""

import json
import math

import pytest

from toosicubix.formats.atomic import atomic_write_json, atomic_write_text
from toosicubix.formats.results import dumps


def test_streamed_json_is_byte_identical_to_dumps(tmp_path):
    doc = {"a": [1, 2.5, {"b": None, "c": "é"}], "d": {"e": [[1.0, 2.0], [3.0, 4.0]]}, "f": True}
    atomic_write_json(tmp_path / "x.json", doc)
    assert (tmp_path / "x.json").read_text(encoding="utf-8") == dumps(doc)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_a_failed_write_leaves_the_old_file_and_no_temporary_file(tmp_path, bad):
    path = tmp_path / "results.json"
    atomic_write_text(path, "old\n")
    with pytest.raises(ValueError):
        atomic_write_json(path, {"ok": [1.0] * 10_000, "bad": bad})
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]
    json.loads(dumps({"fine": 1}))

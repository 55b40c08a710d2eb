"""Atomic writes (toosicubix.io_utils)."""

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toosicubix.errors import FormatError
from toosicubix.formats.atomic import atomic_write_json, atomic_write_json_items, atomic_write_text
from toosicubix.formats.results import dumps
from toosicubix.jsonfile import scan_object


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


# --- issue 34: a large array read one element at a time, written one item at a time -------------------------------

JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
                    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner,
                                                                                max_size=3), max_leaves=8)


@settings(max_examples=150, deadline=None, database=None, derandomize=True)
@given(doc=st.dictionaries(st.sampled_from(["a", "images", "annotations", "b"]), JSON, max_size=4),
       indent=st.sampled_from([None, 1, 3]))
def test_scan_object_reads_what_json_loads_reads(doc, indent):
    text = json.dumps(doc, indent=indent)
    members, spans = scan_object(text, "f.json", spans_of=("annotations",))
    decoder = json.JSONDecoder()
    rebuilt = {**members, **{k: [decoder.raw_decode(text, start)[0] for start, _ in v] for k, v in spans.items()}}
    assert rebuilt == doc
    assert set(spans) == ({"annotations"} if isinstance(doc.get("annotations"), list) else set())


@settings(max_examples=100, deadline=None, database=None, derandomize=True)
@given(text=st.text(max_size=40), where=st.integers(0, 40))
def test_scan_object_names_a_line_or_leaves_other_text_to_the_caller(text, where):
    source = '{"annotations": [1, 2], "images": []}'
    broken = source[:where] + text + source[where:]
    try:
        scanned = scan_object(broken, "f.json", spans_of=("annotations",))
    except FormatError as exc:
        assert str(exc).startswith("f.json:") and "not valid JSON" in str(exc)
        return
    if scanned is not None:
        assert json.loads(broken).keys() == {**scanned[0], **scanned[1]}.keys()


@pytest.mark.parametrize("items", [[], [{"a": [1, 2]}, {"b": "x\ny"}, []]])
def test_items_written_one_at_a_time_as_dumps_writes_them(tmp_path, items):
    path = tmp_path / "x.json"
    assert atomic_write_json_items(path, {"toosicubix": 1}, "images", iter(items)) == len(items)
    assert path.read_text() == json.dumps({"toosicubix": 1, "images": items}, indent=1) + "\n"

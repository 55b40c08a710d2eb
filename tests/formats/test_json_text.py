"""toosicubix.formats.json_text writes what json.dumps(indent=1, allow_nan=False) writes, byte for byte."""

from __future__ import annotations

import enum
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toosicubix.formats.json_text import dumps_indented


def _json(value):
    return json.dumps(value, indent=1, allow_nan=False)


class _Level(enum.IntEnum):
    LOW = 1


class _Name(str, enum.Enum):
    A = "a\u00e9"


_scalars = (st.none() | st.booleans() | st.integers(min_value=-(2 ** 70), max_value=2 ** 70)
            | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=6))
_values = st.recursive(
    _scalars,
    lambda inner: (st.lists(inner, max_size=5) | st.lists(inner, max_size=3).map(tuple)
                   | st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=4)
                   | st.lists(st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=3), max_size=3)
                   | st.dictionaries(st.text(max_size=4), inner, max_size=4)),
    max_leaves=30,
)


@settings(max_examples=400, deadline=None)
@given(_values)
def test_same_text_as_json_for_any_plain_document(value):
    assert dumps_indented(value) == _json(value)


@pytest.mark.parametrize("value", [
    {}, [], (), "", 0, -0.0, 1e308, 5e-324, 2 ** 64, True, None, "\n\t\"\\\u2603\U0001f600",
    [[], [[]], {}], [[1.0, 2.0], [3.0]], [[1.0, 2.0], []], [[1.0], [1]], [1.0, 1], ["a", 1.0], [1.0, True],
    {"k": {"": [0.1, 0.2, 0.30000000000000004]}},
])
def test_same_text_as_json_at_the_edges(value):
    assert dumps_indented(value) == _json(value)


@pytest.mark.parametrize("value", [
    {1: "int key", 2.5: "float key", None: "null key", False: "bool key"},  # json turns the keys into strings
    [np.float64(0.1), _Level.LOW, _Name.A],  # subclasses json accepts (float64 is a float)
    {"nested": [{"a": [np.float64(1.5)]}]},
])
def test_what_json_converts_itself_is_json_s_own_text(value):
    assert dumps_indented(value) == _json(value)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", [
    lambda x: x, lambda x: [x], lambda x: [1.0, x], lambda x: {"a": x}, lambda x: [[0.5, x]], lambda x: [["a"], [x]],
])
def test_nan_and_infinities_are_refused_with_json_s_message(bad, where):
    with pytest.raises(ValueError) as ours:
        dumps_indented(where(bad))
    with pytest.raises(ValueError) as theirs:
        _json(where(bad))
    assert str(ours.value) == str(theirs.value)


def test_a_list_whose_sum_overflows_is_written_number_by_number():
    value = [1e308, 1e308, -1e308]  # finite numbers whose sum is infinite
    assert dumps_indented(value) == _json(value)
    assert dumps_indented([value]) == _json([value])


def test_objects_json_refuses_raise_json_s_error():
    with pytest.raises(TypeError, match="not JSON serializable"):
        dumps_indented({"a": [object()]})
    with pytest.raises(TypeError, match="not JSON serializable"):
        dumps_indented(np.array([1.0]))

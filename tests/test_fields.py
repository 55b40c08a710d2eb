"""The field rules (toosicubix.fields): hostile values give a FieldError naming file and place, never another
exception; sane values pass as they were."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toosicubix import fields
from toosicubix.errors import InputError
from toosicubix.fields import (
    MAX_ID_LENGTH,
    MAX_PIXEL,
    DistinctKeys,
    FieldError,
    identifier,
    image_side,
    integer,
    metres,
    number,
    numeric_key,
    pixel,
    shown,
    text_integer,
    text_number,
)

HUGE = 10**400
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers(min_value=-(10**5000), max_value=10**5000) | st.text(),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=4), children, max_size=4),
    max_leaves=10)


def test_numbers_pass_finite_values_within_bounds():
    assert number(3, "f.json", "$.a") == 3.0
    assert pixel(-1e6, "f.json", "$.a") == -1e6
    assert metres(4.5, "f.json", "$.a") == 4.5
    assert image_side(1242.0, "f.json", "$.a") == 1242
    assert integer(7, "f.json", "$.a", low=0, high=10) == 7


@pytest.mark.parametrize("value", [HUGE, -HUGE, 10**5000, math.nan, math.inf, True, "1", None, [1], {"a": 1},
                                   MAX_PIXEL + 1], ids=lambda value: shown(value, 20))
def test_pixels_refuse_hostile_values_naming_file_and_path(value):
    with pytest.raises(FieldError) as info:
        pixel(value, "f.json", "$.annotations[3].bbox[0]")
    text = str(info.value)
    assert text.startswith("f.json: $.annotations[3].bbox[0]: expected a pixel coordinate from -1000000 to 1000000, "
                           "got ")
    assert isinstance(info.value, InputError)  # the CLI's exit 2
    assert len(text) < 200  # a 5,000-digit integer is not spelled out


def test_huge_integers_are_named_by_their_digits():
    assert shown(10**400) == "an integer of 401 digits"
    assert shown(-(10**5000 - 1)) == "an integer of 5000 digits"
    assert shown([1, 10**5000]) == "[1, an integer of 5001 digits]"
    assert len(shown(list(range(1000)))) <= 60


def test_metres_refuse_sizes_no_vehicle_has():
    for value in (0, -1, 1e-300, 100.5, HUGE):
        with pytest.raises(FieldError, match="expected a size in metres"):
            metres(value, "m.json", "$.35.length", low=0.1)


def test_image_sides_are_positive_integers():
    for value in (0, -3, 12.5, 1e7, HUGE, "1242"):
        with pytest.raises(FieldError, match="expected an image side in pixels from 1 to 1000000"):
            image_side(value, "c.json", "$.images[0].width")


def test_identifiers_are_strings_or_integers_of_sane_length():
    assert identifier("000123", "c.json", "$.images[0].id") == "000123"
    assert identifier(171206034625454, "c.json", "$.images[0].id") == 171206034625454
    for value in ([1], {"a": 1}, 1.5, True, None, "", "a" * (MAX_ID_LENGTH + 1), "a\x00b", "\ud800", 10**18,
                  10**5000):
        with pytest.raises(FieldError, match=r"expected an id: a string of 1 to 128 characters"):
            identifier(value, "c.json", "$.images[0].id")


def test_numeric_keys_read_decimal_digits_of_any_script():
    assert numeric_key("35", "m.json", "$.35") == 35
    assert numeric_key("035", "m.json", "$.035") == 35
    assert numeric_key("\u0663\u0665", "m.json", "$.x") == 35  # Arabic-Indic 3, 5
    assert numeric_key(35, "m.json", "$.x") == 35
    for value in ("\u00b2", "9" * 5000, "-1", " 35", "3_5", "", -1, 1.0, [35], "3.5"):
        with pytest.raises(FieldError, match="expected a car model: an integer from 0, or 1 to 18 decimal digits"):
            numeric_key(value, "m.json", "$.x", what="a car model")


def test_distinct_keys_name_both_keys_that_mean_one_number():
    keys = DistinctKeys("car_models.json", "car model")
    keys.add(35, "35", "$.35")
    keys.add(36, "36", "$.36")
    with pytest.raises(FieldError) as info:
        keys.add(35, "\u0663\u0665", "$.\u0663\u0665")
    assert str(info.value) == ("car_models.json: $.\u0663\u0665: car model keys '35' (at $.35) and '\u0663\u0665' "
                               "both mean car model 35: expected each once; keep one")


@pytest.mark.parametrize("text", ["4_01.2", " 1", "1 ", "nan", "inf", "-Infinity", "1e999", "\u0663", "0x10", "",
                                  "1" * 65, None, "1,5"])
def test_text_numbers_are_plain_decimals(text):
    with pytest.raises(FieldError, match=r"expected a coordinate written in decimals"):
        text_number(text, "a.xml", 12, what="a coordinate", label="<points> 'wheel-front-left'")


def test_text_numbers_read_decimal_notation():
    assert text_number("401.20", "a.xml", 3) == 401.2
    assert text_number("-1e3", "a.xml", 3) == -1000.0
    assert text_number(".5", "a.xml", 3) == 0.5
    assert text_integer("0012", "a.xml", 3, low=0, high=100) == 12
    for text in ("\u00b2", "9" * 5000, "1.0", "4_01", "+", None):
        with pytest.raises(FieldError, match=r"a\.xml:3: <image> width: expected an integer written in digits"):
            text_integer(text, "a.xml", 3, low=0, high=10**6, label="<image> width")


@settings(max_examples=300, deadline=None, database=None, derandomize=True)
@given(value=JSON_VALUES)
def test_every_rule_answers_any_json_value_with_its_type_or_a_field_error(value):
    rules = [lambda v: pixel(v, "f", "$"), lambda v: number(v, "f", "$"), lambda v: image_side(v, "f", "$"),
             lambda v: metres(v, "f", "$"), lambda v: identifier(v, "f", "$"), lambda v: numeric_key(v, "f", "$"),
             lambda v: text_number(v if isinstance(v, str) else None, "f", 1),
             lambda v: text_integer(v if isinstance(v, str) else None, "f", 1, low=-5, high=5)]
    for rule in rules:
        try:
            result = rule(value)
        except FieldError as exc:
            assert str(exc).startswith(("f: $: ", "f:1: ")) and len(str(exc)) < 400
            continue
        assert isinstance(result, int | float | str) and not isinstance(result, bool)
        if isinstance(result, float):
            assert math.isfinite(result)


def test_passes_tells_a_value_s_form_by_a_rule_and_sigma_metres_has_the_schema_s_bounds():
    assert fields.passes(fields.number, 1.5) and fields.passes(fields.pixel, -3)
    assert not fields.passes(fields.number, 10**400) and not fields.passes(fields.number, True)
    assert not fields.passes(fields.pixel, 2 * fields.MAX_PIXEL)
    assert fields.passes(fields.identifier, "35") and not fields.passes(fields.identifier, "")
    assert fields.sigma_metres(0.05, "f.json", "$.known[1]") == 0.05
    for refused in (fields.MIN_SIGMA_METRES / 2, 2 * fields.MAX_METRES, float("nan")):
        with pytest.raises(fields.FieldError, match=r"f\.json: \$\.known\[1\]: expected a sigma in metres"):
            fields.sigma_metres(refused, "f.json", "$.known[1]")

"""Annotation files no camera or click can produce are refused with the file and JSON path (issue 13)."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.annotations.schema import MAX_ID_LENGTH, MAX_PIXEL, check_intrinsics, load_annotations
from toosicubix.annotations.stream import index_annotations
from toosicubix.cli import main
from toosicubix.errors import InputFileError
from toosicubix.jsonfile import MAX_JSON_DEPTH, json_nesting

SAMPLE = REPO / "samples" / "annotations.json"


def sample() -> dict:
    return json.loads(SAMPLE.read_text())


def problems_of(tmp_path, doc) -> list[tuple[str, str]]:
    path = tmp_path / "a.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputFileError) as info:
        load_annotations(path)
    assert info.value.file == str(path)
    return info.value.problems


def set_P(i, j, value):
    def mutate(d):
        d["images"][0]["camera"]["P"][i][j] = value
    return mutate


@pytest.mark.parametrize(("mutate", "path", "fragment"), [
    # The cases of issue 13: each passed validation and wrote nan or inf into label files.
    (set_P(2, 3, 1e308), "$.images[0].camera.P", "P[:, 3] = K t within"),
    (set_P(1, 0, -1e308), "$.images[0].camera.P", "entries of K within"),
    (set_P(1, 0, -3.0), "$.images[0].camera.P", "K[1][0] = 0"),
    (set_P(0, 0, 1e308), "$.images[0].camera.P", "entries of K within"),
    (set_P(0, 0, 0.5), "$.images[0].camera.P", "focal length K[0][0] between 1 and"),
    (set_P(0, 3, 1e12), "$.images[0].camera.P", "P[:, 3] = K t within"),
    (set_P(2, 3, 500.0), "$.images[0].camera.P", "at most 100 m"),
    (set_P(1, 1, 1e-3 * 720), "$.images[0].camera.P", "focal length K[1][1]"),
    (lambda d: d["images"][0].update(id="a" * (MAX_ID_LENGTH + 1)), "$.images[0].id", "at most 128 characters"),
    (lambda d: d["images"][0].update(id="../x"), "$.images[0].id", "String should match pattern"),
    (lambda d: d["images"][0]["vehicles"][0].update(id="a\nb"), "$.images[0].vehicles[0].id", "pattern"),
    (lambda d: d["images"][0]["vehicles"][0]["parts"][0].update(xy=[1e308, 3.0]),
     "$.images[0].vehicles[0].parts[0].xy[0]", "no camera image is that large"),
    (lambda d: d["images"][0]["vehicles"][0].update(box2d=[0, 0, 1e7, 10]),
     "$.images[0].vehicles[0].box2d[2]", "pixel coordinate within"),
    (lambda d: d["images"][0].update(size=[10**30, 375]), "$.images[0].size[0]", "less than or equal to 1000000"),
    (lambda d: d["images"][0]["vehicles"][0]["parts"].append(
        {"kind": "length", "feature": "plate-rear", "a": [1, 2], "b": [30, 4], "metres": 1e308, "sigma": 0.01}),
     "$.images[0].vehicles[0].parts[6].metres", "no road vehicle"),
    (lambda d: d["images"][0]["vehicles"][0]["parts"].append(
        {"kind": "length", "feature": "plate-rear", "a": [1, 2], "b": [30, 4], "metres": 0.5, "sigma": 1e-308}),
     "$.images[0].vehicles[0].parts[6].sigma", "swamps every click"),
    (lambda d: d["images"][0].update(ground={"camera_height": 1e308}), "$.images[0].ground.camera_height",
     "at most 100"),
])
def test_what_no_camera_or_click_can_be_is_refused(tmp_path, mutate, path, fragment):
    doc = sample()
    mutate(doc)
    problems = problems_of(tmp_path, doc)
    assert any(p == path and fragment in m for p, m in problems), problems


@pytest.mark.parametrize(("mutate", "path"), [
    # pydantic's lax mode read these as 1.0, 12.0 and 3: no labelling tool means a boolean or a string as a number.
    (lambda d: d["images"][0]["vehicles"][0]["parts"][0].update(xy=[True, 3.0]),
     "$.images[0].vehicles[0].parts[0].xy[0]"),
    (lambda d: d["images"][0]["vehicles"][0].update(box2d=[0, 0, "12", 10]), "$.images[0].vehicles[0].box2d[2]"),
    (lambda d: d["images"][0].update(sequence="s", frame="3"), "$.images[0].frame"),
    (lambda d: d["images"][0].update(ground={"camera_height": "1.65"}), "$.images[0].ground.camera_height"),
    (lambda d: d["images"][0].update(size=[True, 375]), "$.images[0].size[0]"),
])
def test_booleans_and_strings_are_not_numbers(tmp_path, mutate, path):
    doc = sample()
    mutate(doc)
    problems = problems_of(tmp_path, doc)
    assert any(p == path and "valid" in m for p, m in problems), problems


def load_annotations_ok(tmp_path, doc):
    path = tmp_path / "ok.json"
    path.write_text(json.dumps(doc))
    load_annotations(path)


def test_badly_conditioned_K_is_refused():
    # Tolerance: the condition number in focal-length units of a real camera is about (c / f)^2 < 10; 1e8 is refused.
    check_intrinsics(np.array([[720.0, 0, 620], [0, 720, 180], [0, 0, 1]]))
    with pytest.raises(ValueError, match="well-conditioned K"):
        check_intrinsics(np.array([[1.0, 0, 9e5], [0, 1.0, 9e5], [0, 0, 1]]))


def test_the_bounds_leave_real_files_alone(tmp_path):
    # The sample and every plausible camera pass: the bounds only catch what no camera or click can be.
    load_annotations(SAMPLE)
    doc = sample()
    doc["images"][0]["camera"] = {"K": [[2.0e4, 0, 4000], [0, 2.0e4, 3000], [0, 0, 1]], "distortion": [0.1, 0, 0, 0]}
    doc["images"][0]["id"] = "a" * MAX_ID_LENGTH
    load_annotations_ok(tmp_path, doc)
    doc["images"][0]["camera"] = {"K": [[720, 0, 620], [0, 1, 180], [0, 0, 1]]}  # odd, but a camera
    load_annotations_ok(tmp_path, doc)
    assert MAX_PIXEL >= 1e5


@pytest.mark.parametrize("depth", [MAX_JSON_DEPTH + 1, 1000, 100_000])
def test_deep_nesting_is_an_input_error_not_a_recursion_error(tmp_path, depth):
    path = tmp_path / "deep.json"
    path.write_text('{"toosicubix": 1, "images": ' + "[" * depth + "]" * depth + "}")
    with pytest.raises(InputFileError, match=f"nested {depth + 1} deep .*at most {MAX_JSON_DEPTH}") as info:
        load_annotations(path)
    assert info.value.problems[0][0] == "$"


def test_json_nesting_ignores_brackets_in_strings():
    assert json_nesting('{"a": "[[[[{{{", "b": [1, {"c": "\\"]]"}]}') == (3, 1)
    assert json_nesting('[\n[\n[1]]]') == (3, 3)
    assert json_nesting("7") == (0, 1)


def test_byte_order_mark_is_skipped(tmp_path):
    path = tmp_path / "bom.json"
    path.write_bytes(b"\xef\xbb\xbf" + SAMPLE.read_bytes())
    assert len(load_annotations(path).images) == len(sample()["images"])


def test_not_utf8_names_the_byte(tmp_path):
    path = tmp_path / "latin1.json"
    path.write_bytes(SAMPLE.read_bytes().replace(b'"Car"', b'"C\xe4r"', 1))
    with pytest.raises(InputFileError, match=r"expected UTF-8 JSON text: invalid continuation byte at byte \d+"):
        load_annotations(path)


@pytest.mark.parametrize("command", ["fit", "validate"])
def test_cli_exits_2_and_writes_nothing(tmp_path, command):
    doc = sample()
    doc["images"][0]["id"] = "x" * 300  # once: OSError 'File name too long' and a refused folder
    path = tmp_path / "a.json"
    path.write_text(json.dumps(doc))
    out = tmp_path / "out"
    args = [command, str(path), "-q"] + (["-o", str(out)] if command == "fit" else [])
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert f"{path}: $.images[0].id: String should have at most {MAX_ID_LENGTH} characters" in result.output
    assert not out.exists()
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 1000 + "]" * 1000)
    result = CliRunner().invoke(main, [command, str(deep), "-q"] + (["-o", str(out)] if command == "fit" else []))
    assert result.exit_code == 2 and "nested 1000 deep" in result.output, result.output
    assert not out.exists()


def test_image_ids_differing_only_in_case_are_refused(tmp_path):
    doc = sample()
    doc["images"][1]["id"] = doc["images"][0]["id"] + "a"
    doc["images"][2]["id"] = doc["images"][0]["id"] + "A"  # one label file on a case-insensitive disk
    problems = problems_of(tmp_path, doc)
    assert problems == [("$.images", "expected unique image (ignoring case: they name files) ids, got '000001a' "
                                     "at [1] and [2]")]


def _nesting_by_hand(text: str) -> tuple[int, int]:
    """The nesting check's definition, one character at a time: a quote opens or closes a string unless an odd
    number of backslashes precedes it; brackets and braces outside strings count."""
    deepest, line, depth, lines, inside, backslashes = None, 1, 0, 0, False, 0
    for char in text:
        if char == '"' and backslashes % 2 == 0:
            inside = not inside
        elif not inside and char in "[{":
            depth += 1
        elif not inside and char in "]}":
            depth -= 1
        if deepest is None or depth > deepest:
            deepest, line = depth, lines + 1
        lines += char == "\n"
        backslashes = backslashes + 1 if char == "\\" else 0
    return (0, 1) if deepest is None else (deepest, line)


def test_nesting_is_the_same_scanned_in_blocks(monkeypatch):
    """The nesting check scans its text in blocks (its memory stays small for any file): any block size gives
    the depth and the line of its definition, checked character by character, on valid and broken texts; on
    valid JSON that is also what the check gave before, from the text with its strings cut out."""
    import random
    import re

    import toosicubix.jsonfile as formats

    rng = random.Random(0)
    texts = ['{"a": [[1, {"b": "[[[["}], 2]]}', '[\n[\n[\n]]]', "[]" * 50 + "[[[[]]]]", "7", "]]]", "",
             '"a\\\\"[[', '"\\"[["', '"é[[" [[ü]', "[\\\\\\]"]
    texts += ["".join(rng.choice('[]{}"\\\n ab,é') for _ in range(rng.randint(1, 80))) for _ in range(400)]

    def nested(level: int):
        if level == 0 or rng.random() < 0.3:
            return rng.choice(['[{"\\', "a\nb", "\"]]", 1.5, None, "ü[", ""])
        if rng.random() < 0.5:
            return [nested(level - 1) for _ in range(rng.randint(0, 3))]
        return {rng.choice(["[", "}", "k\\"]) + str(i): nested(level - 1) for i in range(rng.randint(0, 3))}

    valid = [json.dumps(nested(8), indent=rng.choice([None, 1]), ensure_ascii=rng.random() < 0.5) for _ in range(200)]

    def skeleton_pass(text: str) -> tuple[int, int]:  # the check before this one (valid JSON only)
        skeleton = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text)  # the old check's cut of the strings
        depth, deepest, line, lines = 0, None, 1, 0
        for char in skeleton:
            depth += (char in "[{") - (char in "]}")
            if deepest is None or depth > deepest:
                deepest, line = depth, lines + 1
            lines += char == "\n"
        return (0, 1) if deepest is None else (deepest, line)

    for block in (1, 3, 7, 1 << 18):
        monkeypatch.setattr(formats, "_NESTING_BLOCK", block)
        for text in texts + valid:
            assert formats.json_nesting(text) == _nesting_by_hand(text), (block, text)
        for text in valid:
            assert formats.json_nesting(text) == skeleton_pass(text), (block, text)


def test_broken_strings_before_deep_nesting_are_still_input_errors(tmp_path):
    """Brackets the check takes for a string's (after an unterminated one) never reach the JSON reader as
    structure: it stops at the broken string first."""
    for text in ['{"toosicubix": 1, "images": "abc' + "[" * 100_000, '{"images": "a\n' + "[" * 100_000 + '"}',
                 '{"images": ["\\' + "[" * 100_000]:
        path = tmp_path / "broken.json"
        path.write_text(text)
        with pytest.raises(InputFileError, match="not valid JSON"):
            load_annotations(path)
        with pytest.raises(InputFileError, match="not valid JSON"):
            index_annotations(path)

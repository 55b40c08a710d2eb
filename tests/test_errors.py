"""The one input-error base: every input exception derives from it and formats its message the same way."""

from __future__ import annotations

import pickle

import pytest

from toosicubix.errors import EvaluationInputError, FormatError, InputError, InputFileError, locate
from toosicubix.pipeline.output_folder import OutputFolderError
from toosicubix.priors.estimation import PriorEstimationError
from toosicubix.size_priors import UnknownPrototypeError


def test_message_names_file_and_place():
    assert locate("a.json", "$.images[0]") == "a.json: $.images[0]"
    assert locate("a.txt", 3) == "a.txt:3"
    assert locate("a.txt") == "a.txt"
    assert locate(None) == ""
    error = InputError("a.json", [("$.images[0].id", "missing required field"), (None, "and more")])
    assert str(error) == "a.json: $.images[0].id: missing required field\na.json: and more"
    assert str(InputError(None, [(None, "no file")])) == "no file"


@pytest.mark.parametrize("error, text", [
    (InputFileError("a.json", [("$.x", "unknown field")]), "a.json: $.x: unknown field"),
    (FormatError("000001.txt", "expected numbers", 2), "000001.txt:2: expected numbers"),
    (FormatError("calib.txt", "expected a line 'P1:'"), "calib.txt: expected a line 'P1:'"),
    (EvaluationInputError("ground-truth folder not found (kitti)", "gt"), "gt: ground-truth folder not found (kitti)"),
    (EvaluationInputError("min_iou: expected [0, 1], got 2"), "min_iou: expected [0, 1], got 2"),
    (PriorEstimationError("no label file"), "no label file"),
    (OutputFolderError("holds label files", "out"), "out: holds label files"),
    (UnknownPrototypeError("Cra", ["Car", "Van"]),
     "unknown prototype 'Cra'. Did you mean 'Car'? Known prototypes: Car, Van"),
])
def test_every_input_exception_is_an_input_error(error, text):
    assert isinstance(error, InputError) and isinstance(error, ValueError)
    assert str(error) == text
    with pytest.raises(InputError) as info:
        raise error
    assert info.value is error
    # Raised in a worker process, it reaches the caller as itself (pickled with its attributes).
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error) and str(copy) == text and copy.problems == error.problems
    assert copy.file == error.file


def test_unknown_prototype_is_still_a_key_error():
    with pytest.raises(KeyError):
        raise UnknownPrototypeError("Cra", ["Car"])

"""The README's picture exists, is a small valid PNG, and the README says how it is made."""

from __future__ import annotations

import cv2
import numpy as np

from tests.conftest import REPO

PICTURE = REPO / "docs" / "sample-overlay.png"


def test_readme_shows_the_sample_overlay_and_the_command_that_makes_it():
    text = (REPO / "README.md").read_text()
    assert "![" in text and "](docs/sample-overlay.png)" in text
    assert text.index("docs/sample-overlay.png") < text.index("## Use")  # near the top
    assert ("toosicubix fit samples/annotations.json && toosicubix render --png-compression 9 && "
            "cp toosicubix-out-render/000002.png docs/sample-overlay.png") in text
    data = PICTURE.read_bytes()
    assert len(data) < 200_000
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape == (720, 1280 + 720, 3)  # the 1280 x 720 image and its top view

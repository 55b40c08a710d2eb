"""Shared fixtures. Real KITTI data is read from ../shared/data (or $TOOSICUBIX_SHARED_DATA) when present."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """The shared ground-truth folder: $TOOSICUBIX_SHARED_DATA, else ../shared/data beside the repo."""
    env = os.environ.get("TOOSICUBIX_SHARED_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """The shared data folder; the test is skipped when it is absent."""
    path = shared_data_dir()
    if not (path / "kitti").is_dir():
        pytest.skip(f"real KITTI data not found at {path}")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture(scope="session", autouse=True)
def compiled_refinement():
    """The compiled refinement loaded (compiled once on a fresh checkout) before any test runs, so that no command a
    test runs says "compiling ..." on stderr or waits for it."""
    from toosicubix.solver.compiled import warm_up

    warm_up()

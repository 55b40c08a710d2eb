"""The ApolloCar3D benchmark's data diagnostic of the ground truth's up axes (issue 36, item 1): how far each car's
up axis lies from the camera's road normal, from its image's other cars and from all of them."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def apollocar3d(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    module = importlib.import_module("apollocar3d")
    yield module
    monkeypatch.delitem(sys.modules, "apollocar3d")


def _car(car_id: str, tilt_deg: float) -> SimpleNamespace:
    """A car whose up axis (R_cam_vehicle's third column) leans ``tilt_deg`` from (0, -1, 0) about the camera's x."""
    a = np.radians(tilt_deg)
    R = np.eye(3)
    R[:, 2] = (0.0, -np.cos(a), np.sin(a))
    return SimpleNamespace(id=car_id, R_cam_vehicle=R)


def test_up_axis_scatter_by_image(apollocar3d):
    images = [SimpleNamespace(cars=[_car("a", 2.0), _car("b", 4.0), _car("c", 6.0)]),
              SimpleNamespace(cars=[_car("d", -3.0)]),  # alone in its image: the camera's normal stands for the rest
              SimpleNamespace(cars=[_car("e", 1.0), _car("x", 9.0)])]  # x is not scored but is another car of e's
    found = apollocar3d.up_axis_scatter(images, (0.0, -1.0, 0.0), {"a", "b", "c", "d", "e"})
    assert found["cars"] == 5
    # All tilts lie in one plane, so the angles are differences of tilts (the mean of two unit vectors in that plane
    # points along their mean tilt); 1e-9 deg is far above the rounding of arccos near these angles.
    assert found["mean_deg"] == pytest.approx(np.mean([2, 4, 6, 3, 1]), abs=1e-9)
    assert found["median_deg"] == pytest.approx(3.0, abs=1e-9)
    others = [abs(2 - 5), abs(4 - 4), abs(6 - 3), 3.0, abs(1 - 9)]
    assert found["image_others_mean_deg"] == pytest.approx(np.mean(others), abs=1e-9)
    everyone = [abs(2 - 4), 0.0, abs(6 - 4), 0.0, abs(1 - 5)]
    assert found["image_all_mean_deg"] == pytest.approx(np.mean(everyone), abs=1e-9)

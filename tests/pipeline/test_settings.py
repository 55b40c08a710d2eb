"""Solver settings: defaults, then a settings file, then explicit values; the ground overrides."""

from __future__ import annotations

import json

import pytest

from toosicubix.errors import InputFileError
from toosicubix.model import KITTI_GROUND
from toosicubix.pipeline.settings import ground_overrides, settings_document, solver_options, write_settings_file
from toosicubix.solver.fit import SolverOptions


def test_file_over_defaults_and_explicit_over_file(tmp_path):
    path = tmp_path / "settings.json"
    write_settings_file(path, settings_document(0.5, 20.0, {"annotations": "a.json"}))
    assert json.loads(path.read_text())["toosicubix_settings"] == 1
    assert solver_options() == SolverOptions()
    from_file = solver_options(path)
    assert (from_file.lambda_3d, from_file.lambda_px) == (0.5, 20.0)
    assert from_file.click_sigma == SolverOptions().click_sigma
    explicit = solver_options(path, lambda_px=3.0)
    assert (explicit.lambda_3d, explicit.lambda_px) == (0.5, 3.0)


def test_a_bad_settings_file_names_file_and_path(tmp_path):
    path = tmp_path / "settings.json"
    path.write_text('{"toosicubix_settings": 1, "lambda_3d": -1}')
    with pytest.raises(InputFileError, match=r"settings\.json: \$\.lambda_3d: "):
        solver_options(path)


def test_ground_overrides():
    assert ground_overrides() is None
    assert ground_overrides(kitti_ground=True) == KITTI_GROUND
    fields = ground_overrides(True, (0.0, -0.99, 0.1), camera_height=1.5, normal_sigma_deg=None)
    assert fields.normal == (0.0, -0.99, 0.1) and fields.camera_height == 1.5
    assert fields.normal_sigma_deg == KITTI_GROUND.normal_sigma_deg
    # A camera pitch replaces the normal, KITTI's included.
    pitched = ground_overrides(True, camera_pitch_deg=1.0)
    assert pitched.normal is None and pitched.camera_pitch_deg == 1.0
    assert list(pitched.to_json()) == ["camera_height", "camera_height_sigma", "camera_pitch_deg", "normal_sigma_deg",
                                       "upright_sigma_deg"]

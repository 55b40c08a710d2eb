"""`toosicubix eval --plots`: valid PNG files for a small evaluation, identical on a re-run."""

from __future__ import annotations

import math

import cv2
import numpy as np
from click.testing import CliRunner

from tests.conftest import REPO
from toosicubix.cli import main
from toosicubix.evaluation import evaluate_folder
from toosicubix.pipeline.batch import fit_file
from toosicubix.render.plots import PLOT_FILES, normalized_errors, sigmas_from_results

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_eval_plots_are_valid_pngs_and_reproducible(tmp_path):
    out = tmp_path / "out"
    fit_file(REPO / "samples" / "annotations.json", out)
    gt = REPO / "samples" / "ground_truth"
    runner = CliRunner()
    for name in ("p1", "p2"):
        result = runner.invoke(main, ["eval", str(out), "--kitti", str(gt), "--plots", str(tmp_path / name)])
        assert result.exit_code == 0, result.output
    assert f"wrote {tmp_path / 'p2'}" in result.stderr
    for name in PLOT_FILES:
        data = (tmp_path / "p1" / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE)
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        assert image is not None and image.shape[0] >= 400 and image.shape[1] >= 900
        assert image.std() > 10  # not a blank page
        assert data == (tmp_path / "p2" / name).read_bytes(), name
    assert sorted(p.name for p in (tmp_path / "p1").iterdir()) == sorted(PLOT_FILES)  # no temporary files


def test_normalized_errors_use_the_fits_sigmas(tmp_path):
    out = tmp_path / "out"
    fit_file(REPO / "samples" / "annotations.json", out)
    result = evaluate_folder(out, "kitti", REPO / "samples" / "ground_truth")
    sigmas = sigmas_from_results(out / "results.json")
    yaw, depth = normalized_errors(result, sigmas)
    assert len(yaw) == len(depth) == len(result.matched) == 6
    m = result.matched[0]
    s = sigmas[(m.image_id, m.pred_id)]
    expected = (math.degrees(m.pred.yaw - m.gt.yaw) + 180.0) % 360.0 - 180.0
    assert math.isclose(yaw[0], expected / s["yaw_deg"], rel_tol=1e-12)
    assert math.isclose(depth[0], (m.pred.t_cam_vehicle[2] - m.gt.t_cam_vehicle[2]) / s["depth_m"], rel_tol=1e-12)
    assert normalized_errors(result, {})[0].size == 0

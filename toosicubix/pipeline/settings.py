"""Solver settings as the commands assemble them: defaults, a settings file, explicit values; ground overrides.

``toosicubix tune`` writes a settings file (:func:`write_settings_file`); ``fit --config`` and ``validate
--config`` read it back (:func:`solver_options`), and options given on the command line win over it.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

from toosicubix.formats.atomic import atomic_write_text
from toosicubix.solver.fit import SolverOptions

#: The settings a file may set (the rest of :class:`SolverOptions` keeps its defaults).
SETTINGS_FIELDS = ("lambda_3d", "lambda_px")


def solver_options(config_path: str | Path | None = None, **explicit: Any) -> SolverOptions:
    """The defaults, then the settings file's values, then ``explicit`` (any :class:`SolverOptions` field).

    Raises
    ------
    toosicubix.errors.InputFileError
        The settings file cannot be read or is not a settings file v1 (file and JSON path).
    """
    options = SolverOptions()
    if config_path is not None:
        from toosicubix.annotations.settings_file import load_settings_file

        settings = load_settings_file(config_path)
        from_file = {k: getattr(settings, k) for k in SETTINGS_FIELDS if getattr(settings, k) is not None}
        options = replace(options, **from_file)
    return replace(options, **explicit)


def ground_overrides(kitti_ground: bool = False, normal: tuple[float, float, float] | None = None,
                     **fields: float | None) -> dict[str, object]:
    """The ground-block fields (schema names) to set on every image.

    Parameters
    ----------
    kitti_ground : start from KITTI's nominal block (:data:`toosicubix.model.KITTI_GROUND`)
    normal : (3,) road normal in camera coordinates, or None
    fields : ``camera_height``, ``camera_height_sigma``, ``camera_pitch_deg``, ``camera_roll_deg``,
        ``normal_sigma_deg``, ``upright_sigma_deg``; None leaves a field as it is

    Returns
    -------
    dict
        A camera pitch or roll replaces the normal (the caller refuses both being given).
    """
    from toosicubix.model import KITTI_GROUND

    out: dict[str, object] = dict(KITTI_GROUND) if kitti_ground else {}
    if normal is not None:
        out["normal"] = tuple(normal)
    out.update({k: v for k, v in fields.items() if v is not None})
    if "camera_pitch_deg" in out or "camera_roll_deg" in out:
        out.pop("normal", None)
    return out


def settings_document(lambda_3d: float, lambda_px: float, tuned: dict[str, Any]) -> dict[str, Any]:
    """A settings file v1 (``toosicubix_settings: 1``) with the chosen weights and how they were chosen."""
    return {"toosicubix_settings": 1, "lambda_3d": lambda_3d, "lambda_px": lambda_px, "tuned": tuned}


def write_settings_file(path: str | Path, document: dict[str, Any]) -> None:
    """Write a settings file atomically (JSON, one-space indent).

    Raises
    ------
    OSError
        The folder does not exist or is not writable.
    """
    atomic_write_text(path, json.dumps(document, indent=1) + "\n")


__all__ = ["SETTINGS_FIELDS", "ground_overrides", "settings_document", "solver_options", "write_settings_file"]

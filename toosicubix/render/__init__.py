"""Pictures of fits: overlays with OpenCV (:mod:`.overlay`, :mod:`.folder`) and evaluation plots with
matplotlib on its Agg backend (:mod:`.plots`, imported only when asked for).

Example
-------
>>> from toosicubix.render.folder import render_folder
>>> summary = render_folder("toosicubix-out")  # doctest: +SKIP  (writes toosicubix-out-render/<image id>.png)
"""

from __future__ import annotations

from toosicubix.render.folder import (
    RenderInputError,
    RenderOptions,
    RenderSummary,
    render_folder,
    render_image,
)
from toosicubix.render.overlay import OverlayOptions

__all__ = ["OverlayOptions", "RenderInputError", "RenderOptions", "RenderSummary", "render_folder", "render_image"]

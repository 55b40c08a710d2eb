"""Keypoint mapping files: which keypoints of another schema (COCO categories, ApolloCar3D's 66, a labelling tool's)
make which ToosiCubix parts, at which typical positions per prototype; JSON Schema in ``schemas/mapping.schema.json``.

Its parts are tried in file order by an importer (:mod:`toosicubix.formats.coco`): a part is made when every keypoint
it names is labelled and none was taken by an earlier part. Parts with an ``option`` are used only when the import
asks for it. Bundled mappings (:data:`BUNDLED_MAPPINGS`) are read by name; the ``toosicubix`` one is not a file but
:func:`toosicubix.parts.keypoints.mapping_document`, the labelling tools' flat keypoint names.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field

from toosicubix import vocabulary
from toosicubix.annotations.schema import PositiveRow3, _Model, _validate
from toosicubix.errors import InputFileError
from toosicubix.jsonfile import read_json
from toosicubix.parts.linear import TypicalKeypoint
from toosicubix.parts.road_users import ROAD_USER_MAPPINGS
from toosicubix.parts.road_users import mapping_document as road_user_mapping

Row3 = tuple[float, float, float]

#: The mappings shipped with the package, by name (``coco-person`` and ``two-wheeler`` are built from the
#: vocabulary's road-user classes, :func:`toosicubix.parts.road_users.mapping_document`).
BUNDLED_MAPPINGS = ("apollocar3d-66", "apollocar3d-66-paper", "toosicubix", "coco-person", "two-wheeler")


class _MappingPart(_Model):
    option: str | None = Field(default=None, description="Used only when the import asks for this option.")


class MappingPoint(_MappingPart):
    """One keypoint as a ``point`` part (e.g. a wheel hub); ``xy`` names the keypoint that fills its click."""

    kind: Literal["point"]
    part: Literal[vocabulary.POINT_PARTS]  # type: ignore[valid-type]
    xy: str = Field(min_length=1, description="The keypoint that is this point.")


class MappingSymmetry(_MappingPart):
    """Two mirror keypoints as a ``symmetry`` pair."""

    kind: Literal["symmetry"]
    face: Literal[vocabulary.SYMMETRY_FACES]  # type: ignore[valid-type]
    left: str = Field(min_length=1, description="The keypoint on the vehicle's own left side.")
    right: str = Field(min_length=1)


class MappingDirection(_MappingPart):
    """Two keypoints as a ``direction`` arrow."""

    kind: Literal["direction"]
    axis: Literal[vocabulary.DIRECTION_AXES]  # type: ignore[valid-type]
    tail: str = Field(min_length=1)
    head: str = Field(min_length=1)


class MappingLength(_MappingPart):
    """Two keypoints on a feature of known size (e.g. a licence plate's left and right ends)."""

    kind: Literal["length"]
    feature: Literal[tuple(vocabulary.LENGTH_FEATURES)]  # type: ignore[valid-type]
    a: str = Field(min_length=1)
    b: str = Field(min_length=1)
    metres: float | None = Field(default=None, gt=0, description="Its size; none: the part is not made.")
    sigma: float | None = Field(default=None, gt=0)


class KeypointPosition(_Model):
    """A keypoint's typical position, fractions of ``(dx, dy, dz)``, and its spread over vehicles."""

    at: Row3
    spread: PositiveRow3
    n: int | None = Field(default=None, ge=0, description="How many labelled keypoints it was learned from.")
    seen_from: list[Literal["front", "rear", "left", "right", "top"]] | None = Field(
        default=None, min_length=1,
        description="The faces it is seen from: it counts as visible when one of them is turned to the camera "
                    "(learned: one of them was, on at least 95 % of the vehicles it was labelled on). None: the "
                    "faces its position sits near.")
    clicked_share: float | None = Field(
        default=None, gt=0, le=1,
        description="How often it was clicked where it could be seen (learned: of the vehicles on which one of "
                    "its seen_from faces was turned to the camera, the share on which it was labelled); the "
                    "suggested next clicks weigh their gain by it. None: 1.")


class _PositionFor:
    """What a part with a typical position (``position``, ``by_prototype``) gives a vehicle."""

    def position_for(self, prototype: str) -> KeypointPosition:
        """Its position on a vehicle of ``prototype``: that prototype's own, else the one for all."""
        return self.by_prototype.get(prototype, self.position)  # type: ignore[attr-defined]

    def seen_from_for(self, prototype: str) -> tuple[str, ...]:
        """The faces it is seen from on a vehicle of ``prototype``: that prototype's own, else the one for all
        (learned pooled over prototypes), else none (empty: the faces its position sits near)."""
        own = self.position_for(prototype).seen_from
        return tuple(own or self.position.seen_from or ())  # type: ignore[attr-defined]

    def clicked_share_for(self, prototype: str) -> float:
        """How often it was clicked where it could be seen, on a vehicle of ``prototype``: that prototype's own,
        else the one for all, else 1."""
        own = self.position_for(prototype).clicked_share
        return float(own or self.position.clicked_share or 1.0)  # type: ignore[attr-defined]


class MappingKeypoint(_MappingPart, _PositionFor):
    """One keypoint at a typical place on the vehicle (``keypoint`` part), per prototype or for all."""

    kind: Literal["keypoint"]
    keypoint: str = Field(min_length=1)
    position: KeypointPosition
    by_prototype: dict[str, KeypointPosition] = Field(default_factory=dict)


class MappingPlate(_MappingPart, _PositionFor):
    """A licence plate's two ends as a ``plate`` part: a centreline point and its known width."""

    kind: Literal["plate"]
    face: Literal["front", "rear"]
    a: str = Field(min_length=1, description="The keypoint at the plate's end on the vehicle's own left.")
    b: str = Field(min_length=1)
    metres: float = Field(gt=0, description="The plate's width, metres (China 0.44, EU 0.52).")
    sigma: float = Field(gt=0)
    position: KeypointPosition
    by_prototype: dict[str, KeypointPosition] = Field(default_factory=dict)


MappingPart = Annotated[
    MappingPoint | MappingSymmetry | MappingDirection | MappingLength | MappingKeypoint | MappingPlate,
    Field(discriminator="kind")]


class MappingFile(_Model):
    """Which keypoints of another schema make which ToosiCubix parts."""

    model_config = ConfigDict(title="ToosiCubix keypoint mapping v1")

    toosicubix_mapping: Literal[1]
    name: str = Field(min_length=1)
    description: str = ""
    keypoints: list[str] | None = Field(
        default=None, description="Keypoint names by index, for COCO files whose categories do not name them.")
    unused: list[str] = Field(default_factory=list, description="Known keypoints no part uses (counted on import).")
    prototype: str = Field(default="Car", min_length=1, description="Prototype of a category not listed below.")
    prototypes: dict[str, str] = Field(
        default_factory=dict, description="Prototype per COCO category id (as a string) or category name.")
    parts: list[MappingPart]

    def keypoint_positions(self, prototype: str) -> dict[str, KeypointPosition]:
        """The keypoint parts made without an option, by keypoint name, at their positions on a vehicle of
        ``prototype`` (what the annotate page offers)."""
        return {p.keypoint: p.position_for(prototype) for p in self._plain_keypoints()}

    def _plain_keypoints(self) -> list[MappingKeypoint]:
        """The keypoint parts made without an option."""
        return [p for p in self.parts if isinstance(p, MappingKeypoint) and p.option is None]

    def keypoint_candidates(self, prototype: str) -> dict[str, TypicalKeypoint]:
        """The keypoint parts made without an option, as the solver's guidance and the page's naming take them:
        name -> where it typically is on a vehicle of ``prototype``, the faces it is seen from and how often it is
        clicked where it can be seen."""
        return {p.keypoint: TypicalKeypoint(np.asarray(p.position_for(prototype).at, dtype=float),
                                            np.asarray(p.position_for(prototype).spread, dtype=float),
                                            p.seen_from_for(prototype), p.clicked_share_for(prototype))
                for p in self._plain_keypoints()}

    def known_keypoints(self) -> set[str]:
        names = set(self.unused) | set(self.keypoints or ())
        for part in self.parts:
            names |= set(keypoints_of(part))
        return names


def keypoints_of(part: Any) -> tuple[str, ...]:
    if isinstance(part, MappingPoint):
        return (part.xy,)
    if isinstance(part, MappingKeypoint):
        return (part.keypoint,)
    if isinstance(part, MappingSymmetry):
        return (part.left, part.right)
    if isinstance(part, MappingDirection):
        return (part.tail, part.head)
    return (part.a, part.b)


def mapping_json_schema() -> dict[str, Any]:
    """The JSON Schema of a mapping file, as committed in ``schemas/mapping.schema.json``."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **MappingFile.model_json_schema()}


def load_mapping(name_or_path: str | Path) -> tuple[MappingFile, str]:
    """A bundled mapping by name, or a mapping file; returns it and where it was read.

    Raises
    ------
    InputFileError
    """
    if str(name_or_path) == "toosicubix":
        from toosicubix.parts.keypoints import mapping_document

        source = "bundled mapping toosicubix"
        return _validate(MappingFile, mapping_document(), source), source
    if str(name_or_path) in ROAD_USER_MAPPINGS:
        source = f"bundled mapping {name_or_path}"
        return _validate(MappingFile, road_user_mapping(str(name_or_path)), source), source
    if str(name_or_path) in BUNDLED_MAPPINGS:
        source = f"bundled mapping {name_or_path}"
        text = resources.files("toosicubix.parts").joinpath("mappings", f"{name_or_path}.json").read_text("utf-8")
        return _validate(MappingFile, json.loads(text), source), source
    path = Path(name_or_path)
    if not path.is_file():
        raise InputFileError(path, [("$", f"no such mapping file, and not a bundled mapping "
                                          f"({', '.join(BUNDLED_MAPPINGS)})")])
    return _validate(MappingFile, read_json(path, at_root=True), path), str(path)

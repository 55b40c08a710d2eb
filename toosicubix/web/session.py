"""The state behind ``toosicubix annotate``: the images being annotated, their vehicles and clicks, undo, the
fits, auto-naming, and the annotation file (v1) written atomically after every change.

Concurrency (two pages on one file): **refuse, never merge.** Every change carries the ``revision`` the page
last saw; a change made on an older revision is refused (:class:`Conflict`, HTTP 409) and the page gets the
current state, re-applies a click it was adding and tells the person. A change is also refused when the file
on disk was changed by another program since this session read or wrote it (a second ``toosicubix annotate``
on the same file, an editor): the content hashes of both files it writes (the annotation file and its extras file,
below) are checked under a lock file beside them before each write, and the person is told to reload. So no click
is ever silently overwritten: the one that would be lost is refused and said so.

What the file cannot hold: the annotation file v1 names every part, so a click not named yet (waiting for
the cuboid to be fixed, see below) and the *done* mark of a vehicle go to a second file beside it,
``<file>.annotate.json`` (:attr:`Session.extras_path`), written atomically right after it and read back on start
(unnamed clicks come back after their vehicle's named ones; the entries of images not served are kept as read); it
is removed when there is nothing in it.

Naming (:mod:`toosicubix.web.placement`, :mod:`toosicubix.web.naming`): a click made without a name takes the most
probable name when the page is sure enough of it, else it waits with the few names that fit there for the person to
choose from. Before the vehicle's named clicks fit a cuboid, the prototype's prior cuboid placed by its box and
named clicks ranks the names; after, the same placement with the fit's dimensions (with a keypoint mapping: its
keypoints at their places on the fit). The response names the choice, its probability and the runner-up. The
requests' fields are checked by :mod:`toosicubix.web.request_fields`.

Sequences (``annotate --sequence``, or a file's images that are frames): a vehicle of a frame carries a track (a new
vehicle a new one, :func:`toosicubix.web.sequence.new_track_name`) and is fitted with its track's nearby frames as
``fit`` fits tracks (:meth:`Session._track_fit`); a track with a vehicle near a frame but none on it is shown there as
a prediction, the track's fit with that frame added empty, which the person confirms (a vehicle of the track without
clicks), boxes, clicks or dismisses (kept in the extras file).

A keypoint mapping (``--mapping``, :class:`toosicubix.annotations.mapping.MappingFile`) adds its keypoints to what the
page makes: a click named one is a ``keypoint`` part with the mapping's position for the vehicle's prototype,
unnamed clicks are named among the mapping's keypoints instead of the point parts, and the next clicks suggested
are its keypoints.
"""

from __future__ import annotations

import contextlib
import copy
import fcntl
import hashlib
import json
import math
import os
import re
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from http import HTTPStatus
from pathlib import Path
from typing import Any

import numpy as np

from toosicubix import vocabulary
from toosicubix.annotations.convert import (
    camera_from_schema,
    ground_with,
    image_json,
    images_from_schema,
    load_images,
)
from toosicubix.annotations.mapping import MappingFile
from toosicubix.annotations.schema import MAX_CLICKS_PER_VEHICLE, MAX_ID_LENGTH, parse_annotations
from toosicubix.camera import Camera
from toosicubix.errors import FormatError, InputFileError
from toosicubix.fields import FILE_NAME_PATTERN, file_name, passes, shown
from toosicubix.formats.atomic import atomic_write_texts
from toosicubix.formats.cameras import load_cameras as load_camera_table
from toosicubix.formats.results import VehicleResult
from toosicubix.geometry import FRONT_FACE, cuboid_corners_cam
from toosicubix.jsonfile import read_json
from toosicubix.model import GroundBlock, GroundOverride, GroundPlane, Image, Part, Vehicle
from toosicubix.parts.linear import TypicalKeypoint
from toosicubix.parts.mirror import mirrored
from toosicubix.parts.road_users import class_keypoints, keypoint_class
from toosicubix.pipeline.click_noise import PILOT_VEHICLES
from toosicubix.pipeline.fitting import check_prototypes
from toosicubix.pipeline.road_normal import MIN_VEHICLES, camera_key
from toosicubix.pipeline.tracks import results_of_track
from toosicubix.pipeline.validation import Thresholds, judge
from toosicubix.pipeline.vehicle import SWAPPED, fit_one, with_next_clicks
from toosicubix.render.palette import class_colours_hex
from toosicubix.size_priors import Priors, SizePrior
from toosicubix.solver.fit import SolverOptions
from toosicubix.solver.plausibility import AXLES_MARK
from toosicubix.solver.track import TrackOptions
from toosicubix.web.images import image_size
from toosicubix.web.naming import naming_candidates, nearest_parts
from toosicubix.web.placement import NAMING_SETTINGS, NamingSettings, propose
from toosicubix.web.request_fields import (
    ApiError,
    Conflict,
    check_on_image,
    checked_box2d,
    checked_kind_name,
    checked_known,
    checked_pixel,
    checked_pixels,
)
from toosicubix.web.sequence import TRACK_WINDOW, frame_numbers, frames_to_fit, new_track_name, track_sort_key
from toosicubix.web.worker import DeadlineWorker, OutOfTime, WorkerDied

#: How many changes per image ``undo`` can take back.
UNDO_DEPTH = 500
#: How many parts to suggest as targets on the image.
TARGETS = 5
#: How many names the page offers for a click it did not name (or instead of the name it gave).
CHOICES = 5
#: How far (fractions of the dimensions) a mapping's keypoint may lie from another's mirror place to be its mirror
#: partner: apollocar3d-66's partners lie within 0.046 of each other's mirror places (median 0.023).
MIRROR_TOLERANCE = 0.1
#: The most vehicles the page adds to one image (a file may have more; the page's answers and undo grow with them).
MAX_VEHICLES_PER_IMAGE = 500
#: A vehicle id the page numbers from: ASCII digits, few enough for any integer conversion.
_VEHICLE_NUMBER = re.compile(r"^[0-9]{1,18}$")
#: How many suggestions a fit on the page computes (the targets shown and the candidates of auto-naming).
NEXT_CLICKS = 1000
#: Seconds the fits of one request may take in all, from the moment the session takes the request (issue 34: an
#: answer or an error within a second; the rest of the second is for reading the request, writing the files and the
#: answer). A fit already on the page (cached) takes none of it.
FIT_SECONDS = 0.75
#: What the fitting process imports, and then calls, before its first fit (so that the first one does not pay for it):
#: the compiled solver's loading alone takes most of :data:`FIT_SECONDS`.
FIT_MODULES = ("toosicubix.web.session", "toosicubix.solver.compiled:warm_up")


class OutOfFitTime(ApiError):
    """A request whose fits did not finish within the session's bound (:data:`FIT_SECONDS`): 422, nothing changed."""

    def __init__(self, message: str):
        super().__init__(message, HTTPStatus.UNPROCESSABLE_ENTITY)


@dataclass
class ClickedPart:
    """One annotation as the page edits it.

    Attributes
    ----------
    kind, name : as in the annotation file; both None for a click waiting for a name
    uv : (k, 2) pixels as clicked
    known : ``(metres, sigma)`` of a length annotation
    auto : how the session named it: ``{"name", "runner_up", "distance_px", "runner_up_distance_px"}``
    extra : a keypoint's or plate's further fields as the file has them (``at``, ``spread``, ``visible``: its
        typical position, from a mapping); kept through every edit but a rename, never made by the page
    """

    kind: str | None
    name: str | None
    uv: list[list[float]]
    known: tuple[float, float] | None = None
    auto: dict[str, Any] | None = None
    extra: dict[str, Any] | None = None
    choices: list[dict[str, Any]] | None = None

    @property
    def named(self) -> bool:
        return self.name is not None

    @classmethod
    def of(cls, part: Part) -> ClickedPart:
        """The part of an annotation file (or request) as the page edits it, with its further fields."""
        fields = vocabulary.KINDS[part.kind].fields_extra
        extra = {key: (value.tolist() if isinstance(value, np.ndarray) else value)
                 for key, _ in fields if (value := getattr(part, key)) is not None}
        return cls(part.kind, part.name, part.uv.tolist(), part.known, extra=extra or None)

    def model_fields(self) -> dict[str, Any]:
        """``extra`` as :class:`toosicubix.model.Part` takes it (arrays for the rows)."""
        return {key: (np.asarray(value, dtype=float) if isinstance(value, list) else value)
                for key, value in (self.extra or {}).items()}


@dataclass
class VehicleState:
    """One vehicle as the page edits it; ``track`` names the physical vehicle across a sequence's frames."""

    id: str
    prototype: str
    box2d: list[float] | None = None
    done: bool = False
    parts: list[ClickedPart] = field(default_factory=list)
    known_dimensions: dict[str, tuple[float, float]] = field(default_factory=dict)
    track: str | None = None


@dataclass
class ImageState:
    """One image given on the command line; ``path`` is never sent to or taken from a page.

    ``sequence`` and ``frame``: the sequence it is a frame of and its number there, or None; ``dismissed``: the
    tracks whose prediction the person dismissed on this frame (kept in the extras file, not the annotation file);
    ``undo``: the vehicles and dismissed tracks before each change."""

    index: int
    id: str
    path: Path
    file: str
    camera: Camera
    ground_block: GroundBlock | None
    ground: GroundPlane | None
    vehicles: list[VehicleState] = field(default_factory=list)
    undo: list[tuple[list[VehicleState], list[str]]] = field(default_factory=list)
    sequence: str | None = None
    frame: int | None = None
    dismissed: list[str] = field(default_factory=list)

    def snapshot(self) -> tuple[list[VehicleState], list[str]]:
        """What a change may alter, copied (for undo, and to restore after a refused change)."""
        return copy.deepcopy(self.vehicles), list(self.dismissed)

    def restore(self, snapshot: tuple[list[VehicleState], list[str]]) -> None:
        self.vehicles, self.dismissed = copy.deepcopy(snapshot[0]), list(snapshot[1])


@dataclass(frozen=True)
class _TrackedOn:
    """A track's vehicle on one frame: its image (served, or one of the file's others) and the vehicle there (as the
    page edits it, the ``j``-th of a served image, or as the file has it)."""

    image: ImageState | Image
    vehicle: VehicleState | Vehicle
    j: int | None = None

    @property
    def clicked(self) -> bool:
        """Whether it has named clicks (what a track needs on some frame to be placed)."""
        if isinstance(self.vehicle, VehicleState):
            return any(p.named for p in self.vehicle.parts)
        return bool(self.vehicle.parts)

    def model(self, session: Session) -> Vehicle:
        if isinstance(self.vehicle, VehicleState):
            return session._model_vehicle(self.image, self.j, self.vehicle)
        return self.vehicle


def load_cameras(path: Path, image_ids: list[str], file_names: list[str] | None = None) -> dict[str, Camera]:
    """Cameras per image id from ``--cameras``, in any form the importers take
    (:func:`toosicubix.formats.cameras.load_cameras`: the cameras JSON file ``{"cameras": [{"match": GLOB, "K": ...}]}``
    matched on each image's file name, a KITTI calibration file for every image, a folder of them matched by image
    file stem, an OpenCV or ROS camera YAML for every image), or the page's own JSON forms: one camera block as the
    annotation file has it (``{"K": ...}`` or ``{"P": ...}``, optional ``distortion``) for every image, or
    ``{"<image id or file name>": block, ...}``. ``file_names``: each image's file name (by default its id).

    Raises
    ------
    InputFileError
        Naming the file and the JSON path or line of each problem, or the images without a camera.
    """
    path = Path(path)
    names = file_names if file_names is not None else image_ids
    data: Any = None
    if path.is_file() and _looks_like_json(path):
        data = read_json(path, at_root=True)
        if not isinstance(data, dict):
            raise InputFileError(path, [("$", "expected an object: a camera block, image id -> camera block, or "
                                              '{"cameras": [...]}')])
    if data is None or "cameras" in data:  # the importers' reader: one for every command's --cameras
        try:
            table = load_camera_table(path)
        except FormatError as exc:
            where = "$" if exc.line is None else f"line {exc.line}"
            raise InputFileError(path, [(where, exc.message)]) from None
        blocks = {image_id: ("$.cameras" if table.by_stem is None else "$", camera)
                  for image_id, name in zip(image_ids, names, strict=True)
                  if (camera := table.camera_for(name)) is not None}
        missing = [(i, n) for i, n in zip(image_ids, names, strict=True) if i not in blocks]
        if missing:
            raise InputFileError(path, [("$", f"no camera for image {i!r}: {table.why_none(n)}") for i, n in missing])
    elif "K" in data or "P" in data:
        blocks = {image_id: ("$", data) for image_id in image_ids}
    else:
        blocks = {key.rsplit(".", 1)[0] if key not in image_ids else key: (f"$[{json.dumps(key)}]", block)
                  for key, block in data.items()}
    missing = [i for i in image_ids if i not in blocks]
    if missing:
        raise InputFileError(path, [("$", f"no camera for image {m!r} (keys: image ids or file names)")
                                    for m in missing])
    cameras = {}
    for image_id in image_ids:
        where, block = blocks[image_id]
        try:
            doc = parse_annotations({"toosicubix": 1, "images": [{"id": "x", "camera": block}]}, path)
        except InputFileError as exc:
            prefix = "$.images[0].camera"
            raise InputFileError(path, [(where + p.removeprefix(prefix) if p.startswith(prefix) else where, m)
                                        for p, m in exc.problems]) from None
        cameras[image_id] = camera_from_schema(doc.images[0].camera, None)
    return cameras


def _looks_like_json(path: Path) -> bool:
    """Whether a file starts (after white space) as a JSON object or array does."""
    with open(path, "rb") as handle:
        head = handle.read(256).decode("utf-8-sig", errors="replace").lstrip()
    return head[:1] in ("{", "[")


def _digest(data: bytes | None) -> str | None:
    return None if data is None else hashlib.sha256(data).hexdigest()


def _read_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None


class Session:
    """The annotation state of one ``toosicubix annotate`` run; every public method is thread-safe.

    Parameters
    ----------
    image_paths : the images to serve, in order (their file stems are the image ids)
    out : the annotation file; read when it exists, written after every change
    cameras : camera per image id, for images the file does not have
    priors : size priors (the prototypes a vehicle may take)
    prototype : the prototype of a new vehicle
    ground : the ground block's fields (e.g. :data:`toosicubix.model.KITTI_GROUND`) given to images the file does
        not have yet; the file's own blocks are kept
    road_grounds : per camera (:func:`toosicubix.pipeline.road_normal.camera_key`), the ground-block fields of the
        road normal ``fit`` estimates for it (:func:`toosicubix.pipeline.pilot.file_estimates`): the page fits that
        camera's images without a ground block of their own on it, as ``fit`` does; never written to the file
    estimate : what ``fit`` would estimate from an annotation file (its path), ``(options, road_grounds)``, or
        None when nothing is estimated (a given click noise, no road normal). ``options`` and ``road_grounds`` are
        taken to be its answer for the file as it was read; as the file grows, the page estimates again from a
        snapshot of its state, in the background (:meth:`estimate_again_if_grown`)
    mapping : a keypoint mapping (:func:`toosicubix.annotations.mapping.load_mapping`) whose keypoints the page offers
        besides the vocabulary: a click named one takes its typical position for the vehicle's prototype (and
        again when the prototype changes), unnamed clicks are named among its keypoints, and the parts to click
        next are its keypoints. None, or a mapping without keypoint parts: the vocabulary alone
    sequence : the name of the sequence whose frames ``image_paths`` are, in frame order (``annotate --sequence``):
        the images the file does not have yet become its frames, numbered by :func:`.sequence.frame_numbers`
        (:attr:`frames_from_names` says how); the file's images keep their own sequence and frame. Whatever it is,
        the served images that are frames of a sequence show its tracks: a tracked vehicle is fitted with its
        track's nearby frames, and a track with a vehicle near this frame but none in it is shown as predicted
    track_options : the tracks' motion model and box cue, as ``fit`` takes them (its ``--frame-rate``)
    naming : how unnamed clicks are named (:class:`toosicubix.web.placement.NamingSettings`)
    fitter : the process the fits are computed in, each request's within ``fit_seconds`` (``annotate`` gives one):
        an edit or a preview whose fits would take longer is refused (:class:`OutOfFitTime`, 422) and nothing
        changes; an image's view shows a vehicle not fitted in time as such. None: fits are computed in this
        process, unbounded (a thread cannot be stopped)
    """

    def __init__(self, image_paths: list[Path], out: Path, cameras: dict[str, Camera], priors: Priors,
                 prototype: str = "Car", options: SolverOptions | None = None,
                 thresholds: Thresholds | None = None, ground: GroundOverride | None = None,
                 road_grounds: dict[tuple, GroundOverride] | None = None,
                 estimate: Callable[[Path], tuple[SolverOptions, dict[tuple, GroundOverride] | None]] | None = None,
                 mapping: MappingFile | None = None, sequence: str | None = None,
                 track_options: TrackOptions | None = None, naming: NamingSettings = NAMING_SETTINGS,
                 fitter: DeadlineWorker | None = None, fit_seconds: float = FIT_SECONDS):
        self.out = Path(out)
        self._fitter, self.fit_seconds = fitter, fit_seconds
        #: When the fits of the request being answered must be done (:meth:`_bounded`); None between requests.
        self._deadline: float | None = None
        #: Whether a fit not done in time refuses the request being answered (an edit, a preview) or shows as such.
        self._strict = False
        self.naming = naming
        self.mapping = mapping if mapping is not None and mapping.keypoint_positions(prototype) else None
        self._ground_block, self._ground = (None, None) if not ground else ground_with(None, ground, "ground")
        self._road_grounds = _road_grounds(road_grounds)
        self._estimate = estimate
        self._estimating: threading.Thread | None = None
        self.priors = priors
        if prototype not in priors:
            raise ApiError(f"unknown prototype {prototype!r}; known: {', '.join(sorted(priors))}")
        self.prototype = prototype
        self.options = options or SolverOptions()
        self.thresholds = thresholds or Thresholds()
        self._lock = threading.RLock()
        self._fits: dict[str, dict[str, Any]] = {}
        ids = [Path(p).stem for p in image_paths]
        bad = [str(p) for p in image_paths if not re.fullmatch(FILE_NAME_PATTERN, Path(p).stem)]
        if bad:
            raise ApiError(f"image file names must make valid image ids (letters, digits, '_', '.', '-', the first a "
                           f"letter or digit; the id is the file stem): {', '.join(bad)}")
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ApiError(f"images with the same file stem (the image id): {', '.join(duplicates)}")
        self._paths = [Path(p) for p in image_paths]
        self._cameras = cameras
        self.track_options = track_options or TrackOptions()
        self.sequence = sequence
        self.frames_from_names: bool | None = None
        self._new_frames: dict[str, int] = {}
        if sequence is not None:
            if not passes(file_name, sequence):
                raise ApiError(f"sequence: expected a name of letters, digits, '_', '.', '-' (the first a letter or "
                               f"digit, at most {MAX_ID_LENGTH} characters: it names a file), got {shown(sequence)}")
            numbers, self.frames_from_names = frame_numbers([p.name for p in self._paths])
            self._new_frames = dict(zip(ids, numbers, strict=True))
        self.revision = 0
        self._load()
        self._estimated_from = self._vehicle_count()  # the vehicles the given options were estimated from

    # -- loading and saving ------------------------------------------------------------------------------------

    def _load(self) -> None:
        """(Re)read the annotation file and its extras file, if any, and build the state of every given image.

        Both files are read under the lock file's shared lock (a second session writes them under its exclusive
        lock), so the pair read is one that session wrote together. Nothing of this session's state changes until
        everything is read: a file that cannot be read (an error naming it) leaves the session as it was."""
        with self._file_lock(exclusive=False):
            data, extras = _read_bytes(self.out), _read_bytes(self.extras_path)
            loaded: list[Image] = load_images(self.out) if data is not None else []
            extras_doc = read_json(self.extras_path, at_root=True) if extras is not None else None
        check_prototypes(loaded, self.priors, self.out)
        by_id = {im.id: im for im in loaded}
        served_ids = {p.stem for p in self._paths}
        taken = {(im.sequence, im.frame): im.id for im in loaded if im.sequence is not None}
        images: list[ImageState] = []
        for index, path in enumerate(self._paths):
            image_id = path.stem
            size = image_size(path)
            known = by_id.get(image_id)
            if known is not None:
                camera = Camera(K=known.camera.K, distortion=known.camera.distortion,
                                t_cam_rect=known.camera.t_cam_rect, image_size=size)
                vehicles = [self._vehicle_state(v) for v in known.vehicles]
                file, block, ground = known.file or self._relative(path), known.ground_block, known.ground
                sequence, frame = known.sequence, known.frame
            else:
                if image_id not in self._cameras:
                    raise InputFileError(path, [("$", "no camera for this image: give --cameras")])
                c = self._cameras[image_id]
                camera = Camera(K=c.K, distortion=c.distortion, t_cam_rect=c.t_cam_rect, image_size=size)
                vehicles, file, block, ground = [], self._relative(path), self._ground_block, self._ground
                sequence, frame = (self.sequence, self._new_frames[image_id]) if self.sequence is not None else (None,
                                                                                                                  None)
                if sequence is not None and (sequence, frame) in taken:
                    raise ApiError(f"--sequence {sequence}: {path.name} would be frame {frame}, which is image "
                                   f"{taken[(sequence, frame)]!r}'s in {self.out} already (the file's images keep "
                                   "their frames): give the sequence another name, or files numbered as the file's")
            images.append(ImageState(index, image_id, path, file, camera, block, ground, vehicles,
                                     sequence=sequence, frame=frame))
        other_extras = self._restore_extras(images, extras_doc)
        # Read: now the session's state.
        self._disk_digest, self._extras_digest = _digest(data), _digest(extras)
        self._others = [image_json(im) for im in loaded if im.id not in served_ids]
        # The file's frames that are not served: their tracked vehicles are fitted with the served frames' (never
        # changed here, so kept as read).
        self._other_frames = [im for im in loaded if im.id not in served_ids and im.sequence is not None]
        self._order = [im.id for im in loaded] + [i for i in (p.stem for p in self._paths) if i not in by_id]
        #: The served images the file did not have when it was read.
        self.new_ids = served_ids - set(by_id)
        self.images = images
        self._other_extras = other_extras
        #: Every track name this session has seen or given: a new track never takes one of them, so an undo that
        #: brings a deleted track back (or a dismissal kept for it) cannot meet another vehicle under its name.
        self._track_names = set(self._all_tracks()) | {t for im in images for t in im.dismissed}

    @property
    def order(self) -> list[int]:
        """The served images' indices in the order the page steps through them: the frames of a sequence together
        (where its first one was given) and in frame order; other images where they were given."""
        first: dict[Any, int] = {}
        for im in self.images:
            first.setdefault(im.sequence if im.sequence is not None else ("", im.index), im.index)
        return [im.index for im in sorted(self.images, key=lambda im: (
            first[im.sequence if im.sequence is not None else ("", im.index)],
            im.frame if im.frame is not None else im.index))]

    def _vehicle_count(self) -> int:
        """The vehicles of the file as this session has it (served images and the others)."""
        return (sum(len(im.vehicles) for im in self.images)
                + sum(len(d.get("vehicles") or []) for d in self._others))

    def _keypoints(self, prototype: str) -> dict[str, TypicalKeypoint] | None:
        """The keypoints a vehicle of ``prototype`` is clicked on (name -> place, faces and clicked share): its
        class's own (a pedestrian's COCO keypoints, :func:`~toosicubix.parts.road_users.class_keypoints`), else the
        mapping's; None for a prototype of the cuboid vocabulary without a mapping."""
        own = class_keypoints(prototype)
        if own:
            return own
        return None if self.mapping is None else self.mapping.keypoint_candidates(prototype)

    def _keypoint_extra(self, prototype: str, name: str, visible: Any = None) -> dict[str, Any] | None:
        """A keypoint's fields (``at``, ``spread``; ``visible`` kept when given) on a vehicle of ``prototype``: its
        class's keypoint, else the mapping's; None when neither has it (a class with keypoints of its own takes no
        mapping's)."""
        keypoints = self._keypoints(prototype) if isinstance(name, str) else None
        position = None if keypoints is None else keypoints.get(name)
        if position is None:
            return None
        extra: dict[str, Any] = {"at": [float(x) for x in position.at], "spread": [float(x) for x in position.spread]}
        if visible is not None:
            extra["visible"] = visible
        return extra

    # -- estimating again as the file grows ---------------------------------------------------------------------

    def estimate_again_if_grown(self) -> bool:
        """Start estimating the click noise and road normals again from the file as this session has it, in a
        background thread, when its vehicles have doubled since the last estimate and number at least
        :data:`MIN_VEHICLES` (what a camera's road normal needs), until an estimate has had as many as ``fit``'s
        pilot takes (:data:`PILOT_VEHICLES`). When it is done, the page fits with the new estimates (each fit says
        which it was made for). Called after every saved change; True when it started one."""
        with self._lock:
            if self._estimate is None or (self._estimating is not None and self._estimating.is_alive()):
                return False
            n = self._vehicle_count()
            if self._estimated_from >= PILOT_VEHICLES or n < max(MIN_VEHICLES, 2 * self._estimated_from):
                return False
            # A snapshot of the file as the session has it: the estimate reads a consistent file, whatever
            # another program does to the real one meanwhile.
            with tempfile.NamedTemporaryFile("w", suffix=".json", prefix="toosicubix-annotate-",
                                             delete=False) as snapshot:
                json.dump(self.document(), snapshot, allow_nan=False)
            self._estimating = threading.Thread(target=self._estimate_again, name="estimates", daemon=True,
                                                args=(self._estimate, Path(snapshot.name), n))
            self._estimating.start()
            return True

    def _estimate_again(self, estimate: Callable, snapshot: Path, vehicles: int) -> None:
        try:
            options, road_grounds = estimate(snapshot)
            grounds = _road_grounds(road_grounds)
        except InputFileError:  # e.g. a prototype another program wrote into the file: keep the estimates there are
            with self._lock:
                self._estimated_from = vehicles
            return
        finally:
            snapshot.unlink(missing_ok=True)
        with self._lock:
            self.options, self._road_grounds, self._estimated_from = options, grounds, vehicles
            self._fits.clear()

    def wait_for_estimates(self, timeout: float | None = None) -> None:
        """Wait until an estimate started by :meth:`estimate_again_if_grown` is done (tests, shutting down)."""
        thread = self._estimating
        if thread is not None:
            thread.join(timeout)

    def _relative(self, path: Path) -> str:
        return Path(os.path.relpath(path.resolve(), self.out.resolve().parent)).as_posix()

    @staticmethod
    def _vehicle_state(v: Vehicle) -> VehicleState:
        return VehicleState(
            id=v.id, prototype=v.prototype, box2d=None if v.box2d is None else [float(x) for x in v.box2d],
            parts=[ClickedPart.of(p) for p in v.parts],
            known_dimensions=dict(v.known_dimensions), track=v.track)

    def document(self) -> dict[str, Any]:
        """The annotation file (v1) of the current state: named clicks only, images in the file's order."""
        served = {im.id: im for im in self.images}
        others = {d["id"]: d for d in self._others}
        images = []
        for image_id in self._order:
            if image_id in served:
                im = served[image_id]
                model = Image(im.id, im.file, im.camera, tuple(self._model_vehicle(im, j, v)
                                                               for j, v in enumerate(im.vehicles)),
                              f"$.images[{len(images)}]", ground_block=im.ground_block, sequence=im.sequence,
                              frame=im.frame)
                images.append(image_json(model))
            else:
                images.append(others[image_id])
        return {"toosicubix": 1, "images": images}

    @contextlib.contextmanager
    def _file_lock(self, exclusive: bool = True) -> Iterator[None]:
        """The lock file beside the annotation file (``.<name>.lock``), held exclusively to write the annotation
        file and its extras file, shared to read them (every session on the file takes it)."""
        lock_path = self.out.with_name(f".{self.out.name}.lock")
        with open(lock_path, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            try:
                yield
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def _save(self) -> None:
        """Write the annotation file and its extras file atomically, unless someone else changed either since this
        session read or wrote them (Conflict: nothing is written).

        Both are checked by content hash under the lock file (:meth:`_file_lock`) before either is written: a
        second ``annotate`` on the file writes them under the same lock, so what it wrote is never overwritten."""
        text = json.dumps(self.document(), indent=1, allow_nan=False) + "\n"
        extras = self._extras_document()
        extras_text = None if extras is None else json.dumps(extras, indent=1, allow_nan=False) + "\n"
        try:
            with self._file_lock():
                for path, digest in ((self.out, self._disk_digest), (self.extras_path, self._extras_digest)):
                    if _digest(_read_bytes(path)) != digest:
                        raise Conflict(f"{path} was changed on disk by another program (a second annotate page on "
                                       "this file, an editor) since this session read or wrote it; the change was "
                                       "not saved. Reload (the page's reload button, or POST /api/reload) to "
                                       "continue from the files as they are now.")
                # Both files written before either is renamed: a full disk leaves both as they were.
                atomic_write_texts([(self.out, text), (self.extras_path, extras_text)])
                self._disk_digest = _digest(text.encode("utf-8"))
                self._extras_digest = None if extras_text is None else _digest(extras_text.encode("utf-8"))
        except OSError as exc:
            raise ApiError(f"cannot write {exc.filename or self.out}: {exc.strerror or exc}; the change was not "
                           "saved", HTTPStatus.SERVICE_UNAVAILABLE) from None

    @property
    def extras_path(self) -> Path:
        """The file beside the annotation file that keeps what v1 cannot: unnamed clicks, done marks, and the
        tracks whose prediction was dismissed on a frame."""
        return self.out.with_name(f"{self.out.name}.annotate.json")

    def _extras_document(self) -> dict[str, Any] | None:
        """The extras file of the current state (the served images', and the other images' entries as read), or
        None when there is nothing in it."""
        images = dict(self._other_extras["images"])
        for im in self.images:
            vehicles = {v.id: {"done": v.done, "unnamed": [p.uv[0] for p in v.parts if not p.named]}
                        for v in im.vehicles if v.done or any(not p.named for p in v.parts)}
            if vehicles:
                images[im.id] = vehicles
        dismissed = {**self._other_extras["dismissed"],
                     **{im.id: list(im.dismissed) for im in self.images if im.dismissed}}
        if not images and not dismissed:
            return None
        extras: dict[str, Any] = {"toosicubix_annotate": 1, "images": images}
        if dismissed:
            extras["dismissed"] = dismissed
        return extras

    def _restore_extras(self, images: list[ImageState], data: Any) -> dict[str, dict[str, Any]]:
        """Put the extras file's unnamed clicks (appended to their vehicle) and done marks of vehicles that still
        exist, and its dismissed tracks, on ``images``. The entries of images not served, kept as read (written
        back with the served ones')."""
        others: dict[str, dict[str, Any]] = {"images": {}, "dismissed": {}}
        if data is None:
            return others
        if not isinstance(data, dict) or data.get("toosicubix_annotate") != 1:
            raise InputFileError(self.extras_path, [("$.toosicubix_annotate", "expected 1 (an annotate session file)")])
        try:
            by_id = {im.id: im for im in images}
            for image_id, vehicles in data["images"].items():
                # Checked as an edit's clicks are (the entries of images not served are written back as read).
                entries = {vehicle_id: {"done": bool(extra["done"]),
                                        "unnamed": [checked_pixels([uv], 1, "uv")[0] for uv in extra["unnamed"]]}
                           for vehicle_id, extra in vehicles.items()}
                if image_id not in by_id:
                    others["images"][image_id] = entries
                for v in by_id[image_id].vehicles if image_id in by_id else []:
                    extra = entries.get(v.id)
                    if extra is not None:
                        v.done = extra["done"]
                        v.parts.extend(ClickedPart(None, None, [uv]) for uv in extra["unnamed"])
            for image_id, tracks in data.get("dismissed", {}).items():
                if not isinstance(tracks, list) or not all(isinstance(t, str) for t in tracks):
                    raise TypeError("dismissed tracks that are not a list of strings")
                if image_id in by_id:
                    by_id[image_id].dismissed = list(tracks)
                else:
                    others["dismissed"][image_id] = tracks
        except (KeyError, TypeError, AttributeError, ApiError) as exc:
            raise InputFileError(self.extras_path, [("$", f"not a toosicubix annotate session file ({exc})")]) from None
        return others

    # -- the model and the fit --------------------------------------------------------------------------------

    def use_fitter(self, fitter: DeadlineWorker | None) -> None:
        """Compute the fits in ``fitter`` from now on, each request's within :attr:`fit_seconds` (None: here)."""
        with self._lock:
            self._fitter = fitter

    @contextlib.contextmanager
    def _bounded(self, started: float) -> Iterator[None]:
        """The fits computed in the block (:meth:`_compute`) must be done :attr:`fit_seconds` after ``started`` (a
        :func:`time.monotonic`; the request's, taken before waiting for the lock). Called under the lock; a block
        within another's keeps the outer deadline."""
        outer = self._deadline
        if outer is None:
            self._deadline = started + self.fit_seconds
        try:
            yield
        finally:
            self._deadline = outer

    def _compute(self, function: Callable[..., Any], *args: Any) -> Any:
        """``function(*args)``: in the fitting process within the request's deadline (:meth:`_bounded`) when the
        session has one, else here.

        Raises
        ------
        OutOfFitTime
            Not done by the deadline (the fitting process computing it was ended), or that process died.
        """
        if self._fitter is None:
            return function(*args)
        deadline = self._deadline if self._deadline is not None else time.monotonic() + self.fit_seconds
        try:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise OutOfTime("no time left for it")
            return self._fitter.call(function, args, remaining)
        except (OutOfTime, WorkerDied) as exc:
            raise OutOfFitTime(f"the fits of this request did not finish within {self.fit_seconds:g} s ({exc}); "
                               "nothing was changed. A vehicle with fewer clicks, or on a frame with fewer tracked "
                               "frames near it, fits faster") from None

    def _model_vehicle(self, image: ImageState, j: int, v: VehicleState) -> Vehicle:
        """The vehicle with its named clicks, as :mod:`toosicubix.model` has it."""
        parts = tuple(Part(p.kind, p.name, np.asarray(p.uv, dtype=float), f"{image.id}.vehicles[{j}].parts[{k}]",
                           p.known, **p.model_fields()) for k, p in enumerate(v.parts) if p.named)
        box = None if v.box2d is None else np.asarray(v.box2d, dtype=float)
        return Vehicle(v.id, v.prototype, box, parts, f"vehicles[{j}]", dict(v.known_dimensions), v.track)

    def _fit(self, image: ImageState, j: int, v: VehicleState) -> VehicleResult:
        """The vehicle fitted as ``toosicubix fit`` fits it, with every suggestion (cached by its clicks): alone, or
        on a frame of a sequence, with its track (:meth:`_track_fit`)."""
        if v.track is not None and image.sequence is not None:
            return self._track_fit(image, v.track, self._model_vehicle(image, j, v))["result"]
        vehicle = self._model_vehicle(image, j, v)
        key = json.dumps(["alone", image.index, _vehicle_key(vehicle)])  # every field a fit depends on
        cached = self._fits.get(key)
        if cached is None:
            cached = self._cache(key, {"result": self._compute(_fit_one, vehicle, image.camera,
                                                               self.priors[v.prototype], self.options,
                                                               self._ground_of(image),
                                                               self._keypoints(v.prototype))})
        return cached["result"]

    def _cache(self, key: str, entry: dict[str, Any]) -> dict[str, Any]:
        self._fits[key] = entry
        if len(self._fits) > 2000:
            self._fits.pop(next(iter(self._fits)))
        return entry

    def _ground_of(self, image: ImageState | Image) -> GroundPlane | None:
        """The image's own ground, else its camera's estimated road (as ``fit`` fits it), else None."""
        if image.ground is not None or not self._road_grounds:
            return image.ground
        return self._road_grounds.get(camera_key(image.camera))

    # -- tracks -----------------------------------------------------------------------------------------------

    def _tracks(self, sequence: str) -> dict[str, dict[int, _TrackedOn]]:
        """Per track of ``sequence``, its frames in the file as this session has it: frame number -> where it is
        (its image, a served one or one of the file's others, and its vehicle there)."""
        out: dict[str, dict[int, _TrackedOn]] = {}
        for im in self.images:
            if im.sequence == sequence:
                for j, v in enumerate(im.vehicles):
                    if v.track is not None:
                        out.setdefault(v.track, {})[im.frame] = _TrackedOn(im, v, j)
        for other in self._other_frames:
            if other.sequence == sequence:
                for v in other.vehicles:
                    if v.track is not None:
                        out.setdefault(v.track, {})[other.frame] = _TrackedOn(other, v)
        return out

    def _frame_image(self, image: ImageState | Image) -> Image:
        """A frame as the track fit reads it: its camera, the ground it is fitted on, its sequence and frame."""
        return Image(image.id, image.file, image.camera, (), image.id, ground=self._ground_of(image),
                     sequence=image.sequence, frame=image.frame)

    def _track_fit(self, image: ImageState, track: str, vehicle: Vehicle | None,
                   tracks: dict[str, dict[int, _TrackedOn]] | None = None) -> dict[str, Any]:
        """Frame ``image`` of ``track`` fitted with the track's frames near it (:func:`.sequence.frames_to_fit`), as
        ``fit`` fits a track (:func:`toosicubix.pipeline.tracks.results_of_track`), with every suggestion; cached by
        what those frames hold. ``vehicle``: the track's vehicle on this frame, or None for its prediction here
        (the frame added with nothing on it: its pose interpolated, or held beyond the track's ends).

        Returns ``{"result": VehicleResult, "frames": [frame numbers fitted together], "seconds": the fit's}``."""
        if tracks is None:
            tracks = self._tracks(image.sequence)
        frames = tracks.get(track, {})
        chosen = frames_to_fit(image.frame, {f: on.clicked for f, on in frames.items() if f != image.frame})
        if vehicle is None:
            vehicle = Vehicle("predicted", next(iter(frames.values())).vehicle.prototype, None, (), "predicted",
                              track=track)
        pairs = [(self._frame_image(frames[f].image), frames[f].model(self)) for f in chosen]
        pairs.append((self._frame_image(image), vehicle))
        key = json.dumps(["track", track, image.index, [[im.id, im.frame, _vehicle_key(v)] for im, v in pairs]])
        cached = self._fits.get(key)
        if cached is None:
            started = time.perf_counter()
            result = self._compute(_track_result, track, pairs, self.priors[vehicle.prototype], self.options,
                                   self.track_options, image.camera, self._ground_of(image),
                                   self._keypoints(vehicle.prototype))
            cached = self._cache(key, {"result": result, "frames": sorted(im.frame for im, _ in pairs),
                                       "seconds": time.perf_counter() - started})
        return cached

    def _carried(self, image: ImageState, tracks: dict[str, dict[int, _TrackedOn]]) -> list[str]:
        """The tracks shown as predicted on ``image``: those with a vehicle within :data:`TRACK_WINDOW` frames of it
        and none on it, in natural order (dismissed ones included)."""
        return sorted((t for t, frames in tracks.items() if image.frame not in frames
                       and any(abs(f - image.frame) <= TRACK_WINDOW for f in frames)), key=track_sort_key)

    def _all_tracks(self) -> dict[str, str]:
        """Every track of the file as this session has it, with its sequence."""
        out = {}
        for im in [*self.images, *self._other_frames]:
            for v in im.vehicles:
                if v.track is not None:
                    out.setdefault(v.track, im.sequence)
        return out

    def _auto_name(self, image: ImageState, j: int, v: VehicleState) -> list[dict[str, Any]]:
        """Name the vehicle's unnamed clicks, oldest first: each takes the most probable name when the page is sure
        enough of it (:meth:`_choices`), else it waits with the few names that fit there (``choices``, for the
        person to choose from). What was named."""
        named = []
        for part in v.parts:
            if part.named:
                continue
            choices, sure, how = self._choices(image, j, v, part)
            part.choices = choices[:CHOICES] or None
            if not choices or not sure:
                continue
            best = choices[0]
            runner = choices[1] if len(choices) > 1 else None
            part.kind, part.name = best["kind"], best["name"]
            part.extra = self._keypoint_extra(v.prototype, best["name"]) if best["kind"] == "keypoint" else None
            part.choices = choices[1:CHOICES + 1] or None
            part.auto = {"kind": best["kind"], "name": best["name"], "how": how,
                         "distance_px": best.get("distance_px"), "probability": best.get("probability"),
                         "runner_up_kind": None if runner is None else runner["kind"],
                         "runner_up": None if runner is None else runner["name"],
                         "runner_up_distance_px": None if runner is None else runner.get("distance_px")}
            named.append({"vehicle": v.id, "part": v.parts.index(part), **part.auto})
        return named

    def _choices(self, image: ImageState, j: int, v: VehicleState, part: ClickedPart
                 ) -> tuple[list[dict[str, Any]], bool, str]:
        """The names an unnamed click of ``v`` may take, the most probable first (``kind``, ``name``, and its
        ``probability`` or ``distance_px``), whether the page is sure enough to give it the first, and how they were
        found: 'prior' (no fit yet: the prototype's prior cuboid placed by the box and the named clicks,
        :mod:`.placement`) or 'fit' (the vehicle's named clicks fit a cuboid: the same placement with its dimensions,
        or, by :attr:`~.placement.NamingSettings.after_fit`, the parts not clicked yet at their places on the fit,
        :mod:`.naming`; always so with a keypoint mapping)."""
        result = self._fit(image, j, v)
        keypoints = self._keypoints(v.prototype)
        named = [(p.kind, p.name, np.asarray(p.uv, dtype=float)) for p in v.parts if p.named]
        # A track's vehicle fitted from its other frames, with no named click here: its fit places it.
        placed_by_fit = result.ok and not named
        if result.ok and (keypoints is not None or self.naming.after_fit == "fit" or placed_by_fit):
            if keypoints is None:
                candidates = naming_candidates(result, image.camera)
            else:  # the mapping's vocabulary: its keypoints not clicked yet
                clicked = {p.name for p in v.parts if p.kind == "keypoint"}
                candidates = naming_candidates(result, image.camera, {n: k for n, k in keypoints.items()
                                                                      if n not in clicked}, points=set(),
                                               click_sigma=self.options.click_sigma)
            choices = nearest_parts(part.uv[0], candidates)
            return ([{"kind": c["kind"], "name": c["name"], "distance_px": c["distance_px"]} for c in choices],
                    True, "fit")
        if keypoints is not None:
            return [], False, "prior"
        fitted = np.round(result.dimensions, 4).tolist() if result.ok else None
        key = json.dumps(["prior", fitted, image.index, v.prototype, v.box2d,
                          [[k, n, uv.tolist()] for k, n, uv in named], part.uv[0], self.options.click_sigma,
                          self.naming.to_json()])
        cached = self._fits.get(key)
        if cached is None:
            prior = self.priors[v.prototype]
            dims = None
            if result.ok:  # the fit's dimensions, within their sigmas (at most the prior's)
                sd = np.sqrt(np.diag(prior.cov))
                if result.sigma is not None:
                    sd = np.fmin(np.nan_to_num(np.asarray(result.sigma.dimensions, dtype=float), nan=np.inf), sd)
                dims = (np.asarray(result.dimensions, dtype=float), np.diag(sd**2))
            proposal = self._compute(propose, image.camera, prior, named, np.asarray(part.uv[0], dtype=float),
                               None if v.box2d is None else np.asarray(v.box2d, dtype=float), self._ground_of(image),
                               self.options.click_sigma, self.naming, dims)
            cached = self._cache(key, {"proposal": proposal})
        proposal = cached["proposal"]
        far = proposal.placed and proposal.outlier  # farther from every part's place than a click of it would be
        choices = [{"kind": kind, "name": name, "probability": round(p, 4), **({"far": True} if far else {})}
                   for kind, name, p in proposal.choices]
        sure = (proposal.placed and not proposal.outlier and bool(choices)
                and choices[0]["probability"] >= self.naming.confidence)
        return choices, sure, "fit" if result.ok else "prior"

    # -- views ------------------------------------------------------------------------------------------------

    def summary(self) -> dict[str, Any]:
        """What the page needs first: the images (no paths), the prototypes, the vocabulary, the thresholds."""
        with self._lock:
            return {
                "revision": self.revision, "file": self.out.name, "prototype": self.prototype,
                "prototypes": sorted(self.priors),
                "images": [{"index": im.index, "id": im.id, "size": list(im.camera.image_size),
                            "vehicles": len(im.vehicles),
                            "done": sum(v.done for v in im.vehicles),
                            **({} if im.sequence is None else {"sequence": im.sequence, "frame": im.frame})}
                           for im in self.images],
                "order": self.order,
                "vocabulary": {k.kind: {"clicks": list(k.clicks), "names": list(k.names)}
                               for k in vocabulary.KINDS.values() if not k.known},
                "mapping": None if self.mapping is None else self.mapping.name,
                "keypoints": [] if self.mapping is None else list(self.mapping.keypoint_positions(self.prototype)),
                # The prototypes clicked on keypoints of their own class (a pedestrian's), with those keypoints.
                "class_keypoints": {name: list(c.keypoints) for name in sorted(self.priors)
                                    if (c := keypoint_class(name)) is not None},
                "thresholds": self.thresholds.to_json(),
            }

    def image_view(self, index: int, strict: bool = False) -> dict[str, Any]:
        """One image: its vehicles, each with its clicks, fit, cuboid, sigmas and targets; on a frame of a sequence
        also the predictions of the tracks carried to it and how each track's pose here is determined.

        The fits it computes are bounded (:meth:`_bounded`): one not done in time shows as not fitted (status
        'failed', error 'out_of_time') and is tried again on the next view; ``strict``: raises
        :class:`OutOfFitTime` instead (an edit's view)."""
        started = time.monotonic()
        with self._lock, self._bounded(started):
            self._strict = strict
            image = self.image(index)
            view: dict[str, Any] = {"revision": self.revision, "index": index, "id": image.id,
                                    "size": list(image.camera.image_size), "sequence": image.sequence,
                                    "frame": image.frame}
            if image.sequence is None:
                view["vehicles"] = _coloured([self._vehicle_view(image, j, v) for j, v in enumerate(image.vehicles)])
                return {**view, "predictions": [], "dismissed": [], "tracks": []}
            tracks = self._tracks(image.sequence)
            view["vehicles"] = _coloured([self._vehicle_view(image, j, v, tracks)
                                          for j, v in enumerate(image.vehicles)])
            carried = self._carried(image, tracks)
            view["predictions"] = [self._prediction_view(image, t, tracks) for t in carried
                                   if t not in image.dismissed]
            view["dismissed"] = [t for t in carried if t in image.dismissed]
            states = [{"track": v["track"], "vehicle": v["id"], "pose_from": v["fit"].get("pose_from") or "not fitted"}
                      for v in view["vehicles"] if v["track"] is not None]
            states += [{"track": p["track"], "vehicle": None, "pose_from": "predicted"} for p in view["predictions"]]
            states += [{"track": t, "vehicle": None, "pose_from": "dismissed"} for t in view["dismissed"]]
            view["tracks"] = sorted(states, key=lambda s: track_sort_key(s["track"]))
            return view

    def _out_of_time(self, exc: OutOfFitTime) -> dict[str, Any]:
        """A fit not done in time, as the view shows it; raised again in an edit's view."""
        if self._strict:
            raise exc
        return {"status": "failed", "error": "out_of_time", "error_detail": str(exc)}

    def _vehicle_view(self, image: ImageState, j: int, v: VehicleState,
                      tracks: dict[str, dict[int, _TrackedOn]] | None = None) -> dict[str, Any]:
        tracked = v.track is not None and image.sequence is not None
        parts = [{"index": k, "kind": p.kind, "name": p.name, "uv": p.uv, "auto": p.auto, "residuals_px": None,
                  "choices": p.choices} for k, p in enumerate(v.parts)]
        base = {"id": v.id, "prototype": v.prototype, "track": v.track, "box2d": v.box2d, "done": v.done,
                "parts": parts, "unnamed": sum(not p.named for p in v.parts), "targets": []}
        try:
            entry = self._track_fit(image, v.track, self._model_vehicle(image, j, v), tracks) if tracked else None
            result = entry["result"] if entry is not None else self._fit(image, j, v)
            for view_part, part in zip(parts, v.parts, strict=True):
                if not part.named and part.choices is None:  # a click read back unnamed from the extras file
                    part.choices = self._choices(image, j, v, part)[0][:CHOICES] or None
                    view_part["choices"] = part.choices
        except OutOfFitTime as exc:
            return {**base, "fit": self._out_of_time(exc)}
        fit = self._fit_view(image, result)
        if result.ok and len(result.residuals_px) == sum(len(p.uv) for p in v.parts if p.named):
            # (a track's frame whose clicks it left out has none)
            residuals = np.asarray(result.residuals_px).tolist()
            row = 0
            for view, p in zip(parts, v.parts, strict=True):
                if p.named:
                    view["residuals_px"] = residuals[row:row + len(p.uv)]
                    row += len(p.uv)
        if entry is not None:
            fit.update({"pose_from": result.pose_from, "track_frames": entry["frames"]})
        targets = [s for s in (result.next_clicks or []) if s["visible"] and s["inside_image"]][:TARGETS]
        return {**base, "fit": fit, "targets": targets}

    def _prediction_view(self, image: ImageState, track: str, tracks: dict[str, dict[int, _TrackedOn]]
                         ) -> dict[str, Any]:
        """A track carried to ``image``: its pose here from its other frames (interpolated between them, or held
        beyond its ends), the cuboid and sigmas, and the frames it comes from."""
        own = [f for f in tracks[track] if f != image.frame]
        before = max((f for f in own if f < image.frame), default=None)
        after = min((f for f in own if f > image.frame), default=None)
        view = {"track": track, "prototype": next(iter(tracks[track].values())).vehicle.prototype,
                "source": "interpolated" if before is not None and after is not None else "held",
                "from_frames": [before, after]}
        try:
            entry = self._track_fit(image, track, None, tracks)
        except OutOfFitTime as exc:
            return {**view, "fit": {**self._out_of_time(exc), "pose_from": "predicted"}}
        result = entry["result"]
        return {**view, "prototype": result.prototype,
                "fit": {**self._fit_view(image, result), "pose_from": "predicted", "track_frames": entry["frames"]}}

    def _fit_view(self, image: ImageState, result: VehicleResult) -> dict[str, Any]:
        """A fit as the page draws it: the cuboid's corners in pixels, the pose, size and sigmas, the verdict."""
        fit: dict[str, Any] = {"status": result.status, "error": result.error, "error_detail": result.error_detail}
        if not result.ok:
            return fit
        corners_cam = cuboid_corners_cam(result.R_cam_vehicle, result.t_cam_vehicle, result.dimensions)
        sigma = result.sigma
        problems = judge(result, self.thresholds)
        fit.update({
            "corners_uv": (image.camera.project(corners_cam).round(2).tolist()
                           if np.all(corners_cam[:, 2] > 0.1) else None),
            "front_face": list(FRONT_FACE),
            "yaw_pitch_roll_deg": [round(a, 2) for a in result.yaw_pitch_roll_deg],
            "depth_m": round(float(result.t_cam_vehicle[2]), 3),
            "dimensions": [round(float(x), 3) for x in result.dimensions],
            "rms_px": result.rms_px,
            "sigma": {"yaw_deg": _finite(sigma.yaw_deg), "depth_rel": _finite(sigma.depth_rel),
                      "depth_m": _finite(sigma.depth_m)} if sigma is not None else None,
            "confidence": result.confidence, "ambiguous": result.ambiguous,
            "well_determined": not problems, "problems": list(problems),
            "implausible": result.implausible, "warnings": list(result.warnings),
            "likely_cause": None if result.implausible is None else (
                "swapped" if SWAPPED in result.warnings else "axles" if AXLES_MARK in result.implausible
                else "names"),
            "R_cam_vehicle": np.asarray(result.R_cam_vehicle).tolist(),
            "t_cam_vehicle": np.asarray(result.t_cam_vehicle).tolist(),
            "click_sigma_px": self.options.click_sigma,
            "road": _road_kind(self._ground_of(image)),
        })
        return fit

    # -- changes ----------------------------------------------------------------------------------------------

    def image(self, index: int) -> ImageState:
        """The image with that index on the command line (ApiError 404 otherwise)."""
        if not 0 <= index < len(self.images):
            raise ApiError(f"no image {index}: there are {len(self.images)} (0 to {len(self.images) - 1})", 404)
        return self.images[index]

    def edit(self, index: int, request: Any) -> dict[str, Any]:
        """Apply one change to an image and save; the image view with what the change did.

        ``request``: ``{"revision": int, "op": str, ...}`` with ``op`` one of ``add_vehicle`` (``prototype``,
        ``box2d``, ``track``: on a frame of a sequence, a track of it not on this frame yet, else a new track),
        ``set_vehicle`` (``vehicle``; ``prototype``, ``box2d``, ``done``, ``track``), ``delete_vehicle``
        (``vehicle``), ``add_click`` (``vehicle``, ``uv`` [[x, y], ...]; ``kind`` and ``name``, or neither for a
        point to be auto-named), ``move_click`` (``vehicle``, ``part``, ``click``, ``uv`` [x, y]), ``rename``
        (``vehicle``, ``part``, ``kind``, ``name``; ``swap``: true to give a name another click holds, that click
        taking this one's, :meth:`_swap_names`), ``delete_click`` (``vehicle``, ``part``), ``swap_sides``
        (``vehicle``: its left and right swapped in every named click),
        ``confirm_prediction`` (``track``: a vehicle of that track without clicks, its pose interpolated),
        ``dismiss_prediction`` and ``restore_prediction`` (``track``: not shown on this frame, or again), ``undo``.

        Raises
        ------
        ApiError
            A bad request (400; 404 for an unknown image), the message naming the field.
        Conflict
            ``revision`` is not the current one, or the file changed on disk (409); nothing changed.
        """
        started = time.monotonic()
        if not isinstance(request, dict):
            raise ApiError("expected a JSON object {\"revision\": ..., \"op\": ...}")
        with self._lock, self._bounded(started):
            image = self.image(index)
            revision = request.get("revision")
            if not isinstance(revision, int) or isinstance(revision, bool):
                raise ApiError(f"revision: expected the integer revision the page last saw, got {shown(revision)}")
            if revision != self.revision:
                raise Conflict(f"stale revision {revision}: the annotations are at revision {self.revision} "
                               "(another page changed them); nothing was changed, reload and apply it again")
            op = request.get("op")
            handler = _OPS.get(op) if isinstance(op, str) else None
            if handler is None:
                raise ApiError(f"op: expected one of {', '.join(sorted(_OPS))}, got {shown(op)}")
            before = image.snapshot()
            try:
                outcome = handler(self, image, request) or {}
                auto = [a for j, v in enumerate(image.vehicles) for a in self._auto_name(image, j, v)]
                # Every fit the answer shows, before anything is written: one not done in time refuses the change.
                view = self.image_view(index, strict=True)
                self._save()
            except BaseException:
                image.restore(before)
                raise
            if op == "undo":
                image.undo.pop()
            else:
                image.undo.append(before)
                del image.undo[:-UNDO_DEPTH]
            self.revision += 1
            self.estimate_again_if_grown()
            return {**view, "revision": self.revision, "op": op, **outcome, "auto_named": auto}

    def save(self, request: Any) -> dict[str, Any]:
        """Write the file now (it is written after every change anyway)."""
        with self._lock:
            revision = request.get("revision") if isinstance(request, dict) else None
            if revision is not None and (not isinstance(revision, int) or isinstance(revision, bool)):
                raise ApiError(f"revision: expected the integer revision the page last saw, got {shown(revision)}")
            if revision is not None and revision != self.revision:
                raise Conflict(f"stale revision {revision}: the annotations are at revision {self.revision}")
            self._save()
            return {"revision": self.revision, "file": self.out.name, "saved": True}

    def preview(self, body: Any) -> dict[str, Any]:
        """``POST /api/fit``: the view of a vehicle given in the request, ``{"image": index, "vehicle": {...}}``
        (a vehicle of the annotation file v1), fitted on that image's camera; nothing is stored."""
        started = time.monotonic()
        if not isinstance(body, dict) or set(body) != {"image", "vehicle"}:
            raise ApiError('expected {"image": index, "vehicle": {...a vehicle of the annotation file v1...}}')
        index = body["image"]
        if not isinstance(index, int) or isinstance(index, bool):
            raise ApiError(f"image: expected an index, got {shown(index)}")
        doc = {"toosicubix": 1, "images": [{"id": "request", "camera": {"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
                                            "vehicles": [body["vehicle"]]}]}
        try:
            v = images_from_schema(parse_annotations(doc, "request body"))[0].vehicles[0]
        except InputFileError as exc:
            prefix = "$.images[0].vehicles[0]"
            # A problem of the vehicle names its field; one the vehicle causes above it (a track on an image of
            # no sequence) names the vehicle.
            raise ApiError("; ".join(f"{'vehicle' + p.removeprefix(prefix) if p.startswith(prefix) else 'vehicle'}: "
                                     f"{m}" for p, m in exc.problems)) from None
        image = self.image(index)
        size = image.camera.image_size
        try:
            self._check_prototype(v.prototype)
            for k, part in enumerate(v.parts):  # on the image, as an edit's clicks
                for name, xy in zip(vocabulary.KINDS[part.kind].clicks, part.uv, strict=True):
                    check_on_image((float(xy[0]), float(xy[1])), size, f"parts[{k}].{name}")
            if v.box2d is not None:
                checked_box2d([float(x) for x in v.box2d], size)
        except ApiError as exc:
            raise ApiError(f"vehicle.{exc}", exc.status) from None
        state = replace(self._vehicle_state(v), track=None)  # fitted alone: a preview is of no frame
        with self._lock, self._bounded(started):
            self._strict = True
            return {"revision": self.revision, **_coloured([self._vehicle_view(image, 0, state)])[0]}

    def reload(self) -> dict[str, Any]:
        """Read the file again (after another program changed it); undo history is dropped."""
        with self._lock:
            self._load()
            self._fits.clear()
            self.revision += 1
            self.estimate_again_if_grown()
            return self.summary()

    # -- the operations (under the lock; they may raise ApiError before changing anything) ----------------------

    def _op_add_vehicle(self, image: ImageState, r: dict) -> dict[str, Any]:
        track = r.get("track")
        if track is not None:
            prototype = self._check_carried(image, track)
            if r.get("prototype", prototype) != prototype:
                raise ApiError(f"prototype: track {track!r} is a {prototype} (one prototype per track), got "
                               f"{shown(r['prototype'])}")
        else:
            prototype = r.get("prototype", self.prototype)
            self._check_prototype(prototype)
            if image.sequence is not None:
                track = new_track_name(image.sequence, self._track_names)  # every name the file has had too
                self._track_names.add(track)
        box = checked_box2d(r.get("box2d"), image.camera.image_size)
        vehicle_id = self._new_vehicle_id(image)
        image.vehicles.append(VehicleState(vehicle_id, prototype, box, track=track))
        if track in image.dismissed:
            image.dismissed.remove(track)
        return {"vehicle": vehicle_id, "track": track}

    @staticmethod
    def _new_vehicle_id(image: ImageState) -> str:
        """One more than the largest id of ASCII digits on the image (ids of other characters, e.g. '²', which
        ``int`` refuses though ``str.isdigit`` passes them, or '007', are left alone), never one it has.

        Raises
        ------
        ApiError
            The image has :data:`MAX_VEHICLES_PER_IMAGE` vehicles already.
        """
        if len(image.vehicles) >= MAX_VEHICLES_PER_IMAGE:
            raise ApiError(f"image {image.id} has {len(image.vehicles)} vehicles, as many as the page adds to one "
                           f"image (MAX_VEHICLES_PER_IMAGE)")
        taken = {v.id for v in image.vehicles}
        k = max((int(v.id) for v in image.vehicles if _VEHICLE_NUMBER.match(v.id)), default=0) + 1
        while str(k) in taken:
            k += 1
        return str(k)

    def _op_set_vehicle(self, image: ImageState, r: dict) -> None:
        v = self._vehicle(image, r)
        if "track" in r and r["track"] != v.track:  # another track of the sequence: its prototype too
            prototype = self._check_carried(image, r["track"])
            if r.get("prototype", prototype) != prototype:
                raise ApiError(f"prototype: track {r['track']!r} is a {prototype} (one prototype per track), got "
                               f"{shown(r['prototype'])}")
            v.track = r["track"]
            self._set_prototype(v, prototype)
            if v.track in image.dismissed:  # a vehicle of it is here now, as add_vehicle and confirm have it
                image.dismissed.remove(v.track)
        elif "prototype" in r:
            self._check_prototype(r["prototype"])
            if v.track is not None and r["prototype"] != v.prototype:
                elsewhere = [f for f in self._tracks(image.sequence).get(v.track, {}) if f != image.frame]
                if elsewhere:
                    raise ApiError(f"prototype: vehicle {v.id} is track {v.track!r}, a {v.prototype} on "
                                   f"{len(elsewhere)} other frame(s) too (one prototype per track): change it where "
                                   "the track has no other frame, or delete those")
            self._set_prototype(v, r["prototype"])
        if "box2d" in r:
            v.box2d = checked_box2d(r["box2d"], image.camera.image_size)
        if "done" in r:
            if not isinstance(r["done"], bool):
                raise ApiError(f"done: expected true or false, got {shown(r['done'])}")
            v.done = r["done"]

    def _set_prototype(self, v: VehicleState, prototype: str) -> None:
        v.prototype = prototype
        for part in v.parts:  # the mapping's keypoints sit where they sit on that prototype
            if part.kind == "keypoint":
                extra = self._keypoint_extra(v.prototype, part.name, (part.extra or {}).get("visible"))
                part.extra = extra or part.extra

    def _op_delete_vehicle(self, image: ImageState, r: dict) -> None:
        image.vehicles.remove(self._vehicle(image, r))

    def _op_add_click(self, image: ImageState, r: dict) -> dict[str, Any]:
        v = self._vehicle(image, r)
        kind, name = r.get("kind"), r.get("name")
        size = image.camera.image_size
        if kind is None and name is None:
            uv = checked_pixels(r.get("uv"), 1, "uv", size)
            self._check_room(v, 1)
            v.parts.append(ClickedPart(None, None, uv))
        elif kind == "keypoint" and (extra := self._keypoint_extra(v.prototype, name)) is not None:
            uv = checked_pixels(r.get("uv"), 1, "uv", size)
            self._check_room(v, 1)
            self._check_not_clicked(v, kind, name)
            v.parts.append(ClickedPart(kind, name, uv, extra=extra))
        else:
            self._check_page_made(kind, name, v.prototype)
            kind, name = checked_kind_name(kind, name)
            uv = checked_pixels(r.get("uv"), len(vocabulary.KINDS[kind].clicks), "uv", size)
            self._check_room(v, len(uv))
            self._check_not_clicked(v, kind, name)
            known = None
            if vocabulary.KINDS[kind].known:
                known = checked_known(r.get("known"))
            v.parts.append(ClickedPart(kind, name, uv, known))
        return {"part": len(v.parts) - 1}

    def _op_move_click(self, image: ImageState, r: dict) -> None:
        v = self._vehicle(image, r)
        part = self._part(v, r)
        click = r.get("click", 0)
        if not isinstance(click, int) or isinstance(click, bool) or not 0 <= click < len(part.uv):
            raise ApiError(f"click: expected 0 to {len(part.uv) - 1}, got {shown(click)}")
        part.uv[click] = checked_pixel(r.get("uv"), "uv", image.camera.image_size)

    def _op_rename(self, image: ImageState, r: dict) -> dict[str, Any] | None:
        v = self._vehicle(image, r)
        part = self._part(v, r)
        swap = r.get("swap", False)
        if not isinstance(swap, bool):
            raise ApiError(f"swap: expected true or false, got {shown(swap)}")
        if (r.get("kind"), r.get("name")) == (part.kind, part.name):  # the same name: now the user's, not auto
            part.auto = part.choices = None
            return None
        holder = next((p for p in v.parts if p is not part and p.named
                       and (p.kind, p.name) == (r.get("kind"), r.get("name"))), None)
        if swap and holder is not None:
            return self._swap_names(v, part, holder)
        if r.get("kind") == "keypoint" and len(part.uv) == 1:
            extra = self._keypoint_extra(v.prototype, r.get("name"), (part.extra or {}).get("visible"))
            if extra is not None:
                self._check_not_clicked(v, "keypoint", r["name"], part, swap_hint=True)
                part.kind, part.name, part.auto, part.extra, part.choices = "keypoint", r["name"], None, extra, None
                return None
        if part.extra is not None and r.get("kind") == part.kind:
            other = "" if self.mapping is None else f", or name it a keypoint of {self.mapping.name}"
            raise ApiError(f"name: this {part.kind}'s typical position is its name's ({part.name!r}); delete it and "
                           f"import the clicks again to rename it{other}")
        self._check_page_made(r.get("kind"), r.get("name"), v.prototype)
        kind, name = checked_kind_name(r.get("kind"), r.get("name"))
        if len(vocabulary.KINDS[kind].clicks) != len(part.uv):
            raise ApiError(f"kind: a {kind} annotation has {len(vocabulary.KINDS[kind].clicks)} clicks, this one "
                           f"{len(part.uv)}")
        known = part.known
        if vocabulary.KINDS[kind].known:
            if r.get("known") is not None:
                known = checked_known(r.get("known"))
            elif part.known is None:
                raise ApiError(f"known: a {kind} annotation needs its known size [metres, sigma]")
            elif (kind, name) != (part.kind, part.name):  # another feature: the old one's size is not its own
                raise ApiError(f"known: {part.name!r} measured {part.known[0]:g} m; renamed to {name!r} it needs that "
                               "feature's own known size [metres, sigma]")
        self._check_not_clicked(v, kind, name, part, swap_hint=True)
        part.kind, part.name, part.auto, part.extra, part.choices = kind, name, None, None, None
        part.known = known if vocabulary.KINDS[kind].known else None
        return None

    @staticmethod
    def _swap_names(v: VehicleState, part: ClickedPart, holder: ClickedPart) -> dict[str, Any]:
        """``rename`` with ``swap``: ``part`` takes the name ``holder`` has and ``holder`` the one ``part`` had (none,
        when ``part`` waits for a name: ``holder`` then waits too), each as the person's own. A name goes with what
        belongs to it (a keypoint's typical position, a length's known size); whether a click is ``visible`` stays
        with the click. Both must have as many clicks (a pair's name fits a pair). Answers ``swapped_with``, the
        holder's part index."""
        if len(part.uv) != len(holder.uv):
            raise ApiError(f"swap: {holder.name!r} is a {holder.kind} of {len(holder.uv)} click(s) and this one has "
                           f"{len(part.uv)}: names are swapped between clicks of as many points")

        def name_of(p: ClickedPart) -> tuple[Any, ...]:
            extra = {k: x for k, x in (p.extra or {}).items() if k != "visible"}
            return p.kind, p.name, p.known, extra

        def give(p: ClickedPart, to: tuple[Any, ...]) -> None:
            visible = (p.extra or {}).get("visible")
            p.kind, p.name, p.known, extra = to
            if p.named and visible is not None:
                extra = {**extra, "visible": visible}
            p.extra, p.auto, p.choices = extra or None, None, None

        mine, theirs = name_of(part), name_of(holder)
        give(part, theirs)
        give(holder, mine)
        return {"swapped_with": v.parts.index(holder)}

    def _op_delete_click(self, image: ImageState, r: dict) -> None:
        v = self._vehicle(image, r)
        v.parts.remove(self._part(v, r))

    def _op_swap_sides(self, image: ImageState, r: dict) -> dict[str, Any]:
        """Swap the vehicle's left and right in its named clicks (:func:`toosicubix.parts.mirror.mirrored`: the
        ``-left`` and ``-right`` parts, the two clicks of a pair, ``leftward`` and ``rightward``; a keypoint of the
        vehicle's class or of the mapping becomes the keypoint at its mirror place, :func:`_mirror_keypoint`), as
        the person's own names. Unnamed clicks stay, and so does a keypoint with none at its mirror place. How many
        clicks changed, and those keypoints."""
        v = self._vehicle(image, r)
        named = [(k, p) for k, p in enumerate(v.parts) if p.named]
        if not named:
            raise ApiError(f"vehicle {v.id} has no named click to swap")
        model = tuple(Part(p.kind, p.name, np.asarray(p.uv, dtype=float), f"parts[{k}]", p.known,
                           **p.model_fields()) for k, p in named)
        changed, unpaired = 0, []
        keypoints = self._keypoints(v.prototype)
        for (_, part), swapped in zip(named, mirrored(model), strict=True):
            name, uv, extra = swapped.name, swapped.uv.tolist(), part.extra
            if part.kind == "keypoint" and keypoints is not None:
                name = _mirror_keypoint(keypoints, part.name)
                if name is None:  # no keypoint of its class or mapping there: left as it is, and said
                    unpaired.append(part.name)
                    name = part.name
                elif name != part.name:
                    extra = self._keypoint_extra(v.prototype, name, (part.extra or {}).get("visible"))
            elif swapped.at is not None:  # a keypoint or plate of the file: its typical place mirrored
                extra = {**(part.extra or {}), "at": swapped.at.tolist()}
            changed += (name, uv, extra) != (part.name, part.uv, part.extra)
            part.name, part.uv, part.extra, part.auto, part.choices = name, uv, extra, None, None
        names = [(p.kind, p.name) for p in v.parts if p.named]
        twice = sorted({f"{k} {n}" for k, n in names if names.count((k, n)) > 1})
        if twice:
            raise ApiError(f"swapping left and right would name two clicks {', '.join(twice)}; rename them one by "
                           "one instead")
        return {"swapped": changed, "unpaired": unpaired}

    def _op_confirm_prediction(self, image: ImageState, r: dict) -> dict[str, Any]:
        track = r.get("track")
        prototype = self._check_carried(image, track)
        vehicle_id = self._new_vehicle_id(image)
        image.vehicles.append(VehicleState(vehicle_id, prototype, track=track))
        if track in image.dismissed:
            image.dismissed.remove(track)
        return {"vehicle": vehicle_id, "track": track}

    def _op_dismiss_prediction(self, image: ImageState, r: dict) -> None:
        track = r.get("track")
        self._check_carried(image, track)
        if track not in image.dismissed:
            image.dismissed.append(track)

    def _op_restore_prediction(self, image: ImageState, r: dict) -> None:
        track = r.get("track")
        if track not in image.dismissed:
            raise ApiError(f"track: {shown(track)} is not dismissed on image {image.id} (dismissed: "
                           f"{', '.join(image.dismissed) or 'none'})")
        image.dismissed.remove(track)

    def _op_undo(self, image: ImageState, r: dict) -> dict[str, Any]:
        if not image.undo:
            raise ApiError("nothing to undo on this image")
        image.restore(image.undo[-1])  # popped once the change is saved
        self._check_tracks_agree(image)
        return {}

    # -- checks -----------------------------------------------------------------------------------------------

    def _check_tracks_agree(self, image: ImageState) -> None:
        """ApiError unless ``image``'s tracked vehicles agree with their tracks' other frames, as the file's reader
        requires: one prototype per track, one vehicle of a track per frame. The other ops keep that by themselves;
        an undo brings back a frame as it was, while another frame of its track may have changed since."""
        if image.sequence is None:
            return
        tracks = self._tracks(image.sequence)
        seen: set[str] = set()
        for v in image.vehicles:
            if v.track is None:
                continue
            if v.track in seen:
                raise ApiError(f"track {v.track!r} would have two vehicles on image {image.id}; delete one first")
            seen.add(v.track)
            for frame, on in tracks.get(v.track, {}).items():
                if frame != image.frame and on.vehicle.prototype != v.prototype:
                    raise ApiError(f"track {v.track!r} would be a {v.prototype} here and a {on.vehicle.prototype} "
                                   f"on frame {frame} (one prototype per track): change that frame back first")

    def _check_prototype(self, prototype: Any) -> None:
        if not isinstance(prototype, str) or prototype not in self.priors:
            raise ApiError(f"prototype: unknown {shown(prototype)}; known: {', '.join(sorted(self.priors))}")

    def _check_carried(self, image: ImageState, track: Any) -> str:
        """``track`` may get a vehicle on ``image`` (ApiError otherwise): a frame of a sequence, a track of that
        sequence, none of whose vehicles is on it yet. Its prototype."""
        if image.sequence is None:
            raise ApiError(f"track: image {image.id} is not a frame of a sequence (start the page with --sequence, or "
                           "give the file's image a sequence and frame)")
        if not isinstance(track, str):
            raise ApiError(f"track: expected the name of a track of sequence {image.sequence}, got {shown(track)}")
        frames = self._tracks(image.sequence).get(track)
        if not frames:
            names = sorted(self._tracks(image.sequence), key=track_sort_key)
            raise ApiError(f"track: no track {shown(track)} in sequence {image.sequence} (its tracks: "
                           f"{', '.join(names) or 'none yet'})")
        if image.frame in frames:
            here = next(v.id for v in image.vehicles if v.track == track)
            raise ApiError(f"track: {track} is on this frame already (vehicle {here}): one vehicle per track in a "
                           "frame")
        return next(iter(frames.values())).vehicle.prototype

    @staticmethod
    def _vehicle(image: ImageState, r: dict) -> VehicleState:
        vehicle_id = r.get("vehicle")
        for v in image.vehicles:
            if v.id == vehicle_id:
                return v
        raise ApiError(f"vehicle: no vehicle {shown(vehicle_id)} on image {image.id} "
                       f"(it has {', '.join(v.id for v in image.vehicles) or 'none'})")

    @staticmethod
    def _part(v: VehicleState, r: dict) -> ClickedPart:
        k = r.get("part")
        if not isinstance(k, int) or isinstance(k, bool) or not 0 <= k < len(v.parts):
            raise ApiError(f"part: expected an index 0 to {len(v.parts) - 1} of vehicle {v.id}'s parts, got {shown(k)}")
        return v.parts[k]

    def _check_page_made(self, kind: Any, name: Any, prototype: str) -> None:
        """A kind whose annotations need a typical position (keypoints, plates: from a class or a mapping) is made
        on the page only for the keypoints of the vehicle's class or of the given mapping (the caller's case):
        anything else of such a kind is refused (ApiError); other kinds, known or not, pass
        (:func:`~toosicubix.web.request_fields.checked_kind_name` checks them)."""
        entry = vocabulary.KINDS.get(kind) if isinstance(kind, str) else None
        if entry is None or not any(key == "at" for key, _ in entry.fields_extra):
            return
        own = keypoint_class(prototype)
        if own is not None:
            raise ApiError(f"name: {kind} {shown(name)} is not a keypoint of a {prototype} (its keypoints: "
                           f"{', '.join(own.keypoints)})")
        if self.mapping is None:
            raise ApiError(f"kind: a {kind} annotation needs its typical position on the vehicle, which comes from a "
                           "keypoint mapping: start the page with --mapping (e.g. apollocar3d-66) to click keypoints")
        raise ApiError(f"name: {kind} {shown(name)} is not a keypoint of the mapping {self.mapping.name} (its "
                       f"keypoints are in the palette; plates are not made on the page)")

    @staticmethod
    def _check_room(v: VehicleState, clicks: int) -> None:
        """Room on ``v`` for ``clicks`` more clicked points, named or not: a file with more than the schema's
        :data:`MAX_CLICKS_PER_VEHICLE` on a vehicle is one ``fit`` refuses (ApiError otherwise)."""
        have = sum(len(p.uv) for p in v.parts)
        if have + clicks > MAX_CLICKS_PER_VEHICLE:
            raise ApiError(f"uv: vehicle {v.id} has {have} clicked points; a file may hold at most "
                           f"{MAX_CLICKS_PER_VEHICLE} on one vehicle (MAX_CLICKS_PER_VEHICLE), so this click would "
                           "make one that fit refuses")

    @staticmethod
    def _check_not_clicked(v: VehicleState, kind: str, name: str, this: ClickedPart | None = None,
                           swap_hint: bool = False) -> None:
        for k, p in enumerate(v.parts):
            if p is not this and p.kind == kind and p.name == name:
                how = ("move or delete that one, or rename with \"swap\": true to swap the two names" if swap_hint
                       else "move or delete that one")
                raise ApiError(f"name: vehicle {v.id} has a {kind} {name!r} already (part {k}: {how})")


_OPS = {name.removeprefix("_op_"): fn for name, fn in vars(Session).items() if name.startswith("_op_")}


def _mirror_keypoint(keypoints: dict[str, TypicalKeypoint], name: str) -> str | None:
    """The keypoint of ``keypoints`` (a vehicle's class's, else the mapping's: :meth:`Session._keypoints`) at the
    mirror place of keypoint ``name`` (its typical place with Y negated: the nearest keypoint, within
    :data:`MIRROR_TOLERANCE`), or None when there is none there."""
    if name not in keypoints:
        return None
    at = np.asarray(keypoints[name].at, dtype=float) * np.array([1.0, -1.0, 1.0])
    distance, nearest = min((float(np.linalg.norm(np.asarray(k.at, dtype=float) - at)), n)
                            for n, k in keypoints.items())
    return nearest if distance <= MIRROR_TOLERANCE else None


def _road_grounds(blocks: dict[tuple, GroundOverride] | None) -> dict[tuple, GroundPlane]:
    """Per camera, the ground plane of an estimated road normal's block (the batch's, never the file's)."""
    return {key: replace(ground_with(None, block, "estimated road normal")[1], from_batch=True)
            for key, block in (blocks or {}).items()}


def _road_kind(ground: GroundPlane | None) -> str | None:
    """What the fit stood on: 'estimated' (the camera's road normal from the file's vehicles), 'given' (the
    image's ground block), or None."""
    if ground is None:
        return None
    return "estimated" if ground.from_batch else "given"


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _vehicle_key(v: Vehicle) -> list[Any]:
    """What a fit of ``v`` depends on, as JSON: its prototype, box, clicks (with a keypoint's position) and known
    sizes."""
    return [v.prototype, None if v.box2d is None else [float(x) for x in v.box2d],
            [[p.kind, p.name, p.uv.tolist(), p.known, None if p.at is None else p.at.tolist(),
              None if p.spread is None else p.spread.tolist(), p.visible] for p in v.parts],
            sorted(v.known_dimensions.items())]


def _fit_one(vehicle: Vehicle, camera: Camera, prior: SizePrior, options: SolverOptions, ground: GroundPlane | None,
             keypoints: dict[str, TypicalKeypoint] | None) -> VehicleResult:
    """One vehicle fitted as ``fit`` fits it, with the page's suggestions (computed in the fitting process)."""
    return fit_one(vehicle, camera, prior, options, ground, next_clicks=NEXT_CLICKS, keypoints=keypoints)


def _track_result(track: str, pairs: list[tuple[Image, Vehicle]], prior: SizePrior, options: SolverOptions,
                  track_options: TrackOptions, camera: Camera, ground: GroundPlane | None,
                  keypoints: dict[str, TypicalKeypoint] | None) -> VehicleResult:
    """The last of ``pairs`` (a frame and the track's vehicle there) fitted with the others as ``fit`` fits a track,
    with the page's suggestions (computed in the fitting process)."""
    result = results_of_track(track, pairs, prior, options, track_options)[-1]
    return with_next_clicks(pairs[-1][1], camera, prior, result, options, ground, NEXT_CLICKS, keypoints)


def _coloured(vehicles: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """An image's vehicle views, each with the ``colour`` its cuboid is drawn in: a road user of a class with a palette
    of its own (a pedestrian, a cyclist, ...) its class's, as ``render`` draws it (:mod:`toosicubix.render.palette`);
    None for a vehicle of the cuboid vocabulary (the page draws it in its track's colour)."""
    for vehicle, colour in zip(vehicles, class_colours_hex([v["prototype"] for v in vehicles]), strict=True):
        vehicle["colour"] = colour
    return vehicles


"""One folder walker per dataset: KITTI object, KITTI tracking, Cityscapes 3D.

Simulation (:mod:`toosicubix.simulate.annotator`), evaluation (:mod:`toosicubix.formats.ground_truth`)
and size-prior estimation (:mod:`toosicubix.priors.estimation`) find their files here; the files themselves
are read by :mod:`toosicubix.formats.kitti` and :mod:`toosicubix.formats.cityscapes`.

Layouts:

- KITTI object: ``DIR/label_2/<id>.txt`` (or ``DIR/training/label_2/``) with ``calib/<id>.txt`` beside
  ``label_2``, or a bare folder of label files ``DIR/<id>.txt`` with the calibration at ``DIR/../calib``.
- KITTI tracking: the same with ``label_02/<seq>.txt`` and ``calib/<seq>.txt``; the image id of a frame is
  ``<seq>_<frame as 6 digits>`` (:func:`tracking_image_id`).
- Cityscapes 3D: ``*_gtBbox3d.json`` anywhere under ``DIR`` (other ``*.json`` files count too, a
  ``_gtBbox3d`` file wins over another of the same stem); image id = file stem without ``_gtBbox3d``.

Every walker raises :class:`toosicubix.errors.FormatError` (an :class:`toosicubix.errors.InputError`)
naming the folder when it is missing or holds none of the expected files.
"""

from __future__ import annotations

import re
from pathlib import Path

from toosicubix.camera import Camera
from toosicubix.errors import FormatError
from toosicubix.formats import kitti

#: KITTI's vehicle types: the classes simulated, scored and given priors unless others are asked for.
KITTI_VEHICLE_CLASSES = ("Car", "Van", "Truck")
#: KITTI image sizes (width, height) by the focal length of P2 (one per recording date).
KITTI_IMAGE_SIZES = {721.5: (1242, 375), 707.0: (1224, 370), 707.1: (1226, 370), 718.3: (1238, 374),
                     718.9: (1241, 376)}
#: The most common KITTI image size, for any other focal length.
DEFAULT_IMAGE_SIZE = (1242, 375)

_TRACKING_ID = re.compile(r"^(\d+)_(\d+)$")
GTBBOX3D_SUFFIX = "_gtBbox3d"


def tracking_image_id(sequence: str, frame: int) -> str:
    """The image id of a tracking frame: ``<sequence>_<frame as 6 digits>``, e.g. ``0010_000123``."""
    return f"{sequence}_{frame:06d}"


def parse_tracking_image_id(image_id: str) -> tuple[str, int] | None:
    """``(sequence, frame)`` of a tracking image id such as ``0010_000123``, or None if it is not one."""
    m = _TRACKING_ID.match(image_id)
    return None if m is None else (m.group(1), int(m.group(2)))


def parse_sequences(value: str | None) -> tuple[str, ...] | None:
    """Tracking sequence names from ranges: ``'0010-0012,0015'`` -> ``('0010', '0011', '0012', '0015')``.

    The width of each range's first number is kept (``'7-9'`` -> ``('7', '8', '9')``); None stays None.

    Raises
    ------
    ValueError
        An item that is not a number or a range of numbers.
    """
    if value is None:
        return None
    names: list[str] = []
    for item in value.split(","):
        item = item.strip()
        first, dash, last = item.partition("-")
        if not (first.isdigit() and (not dash or last.isdigit())):
            raise ValueError(f"expected sequence numbers like 0010-0020 or 0001,0005, got {item!r}")
        width = len(first)
        names += [f"{n:0{width}d}" for n in range(int(first), int(last if dash else first) + 1)]
    return tuple(names)


def kitti_image_size(camera: Camera) -> tuple[int, int]:
    """The KITTI image size (width, height) for a P2 focal length, else the most common one."""
    return KITTI_IMAGE_SIZES.get(round(float(camera.K[0, 0]), 1), DEFAULT_IMAGE_SIZE)


def _require_folder(root: Path, dataset: str) -> None:
    if not root.is_dir():
        raise FormatError(root, f"ground-truth folder not found ({dataset})")


class KittiFolder:
    """A KITTI label folder and the calibration folder beside it.

    Parameters
    ----------
    root : a KITTI root (``labels/`` or ``training/labels/``) or a bare folder of label files
    strict : the root must hold both ``labels/`` and ``calib/`` (as the simulator wants)

    Attributes
    ----------
    root : the folder given
    label_dir : the folder of label files
    calib_dir : ``calib/`` beside ``label_dir``, or None when there is none

    Raises
    ------
    FormatError
        A missing folder, or one without label files (strict: without ``labels/`` or ``calib/``).
    """

    labels: str = ""
    kind: str = ""
    dataset: str = ""

    def __init__(self, root: str | Path, strict: bool = False):
        self.root = Path(root)
        if strict:
            self.label_dir, self.calib_dir = self.root / self.labels, self.root / "calib"
            for folder in (self.label_dir, self.calib_dir):
                if not folder.is_dir():
                    raise FormatError(folder, f"expected a KITTI {self.kind} folder with {self.labels}/ and calib/"
                                              f"{self._other_layout()}")
            return
        _require_folder(self.root, self.dataset)
        self.label_dir, self.calib_dir = self._find()

    def _find(self) -> tuple[Path, Path | None]:
        for candidate in (self.root / self.labels, self.root / "training" / self.labels):
            if candidate.is_dir():
                calib = candidate.parent / "calib"
                return candidate, calib if calib.is_dir() else None
        if any(self.root.glob("*.txt")):
            calib = self.root.parent / "calib"
            return self.root, calib if calib.is_dir() else None
        raise FormatError(self.root, f"expected a KITTI {self.kind} root with {self.labels}/ (and calib/), or a "
                                     f"folder of .txt label files; found neither{self._other_layout()}")

    def _other_layout(self) -> str:
        """' (ROOT holds label_02/, ...)' when the root holds the other KITTI layout's labels (tracking for object, and
        the reverse), with the option that reads them; else ''."""
        other = {"label_2": ("label_02", "tracking", "kitti-tracking"),
                 "label_02": ("label_2", "object", "kitti")}.get(self.labels)
        if other is None or not any((self.root / sub / other[0]).is_dir() for sub in (".", "training")):
            return ""
        return f" ({self.root} holds {other[0]}/, KITTI {other[1]} ground truth: --{other[2]} reads it)"

    def label_files(self) -> list[Path]:
        """Every label file, sorted by name."""
        return sorted(self.label_dir.glob("*.txt"))

    def label_file(self, stem: str) -> Path:
        """``label_dir/<stem>.txt`` (it may not exist)."""
        return self.label_dir / f"{stem}.txt"

    def calib_file(self, stem: str) -> Path | None:
        """``calib/<stem>.txt``, or None when there is no calibration folder (the file may not exist)."""
        return self.calib_dir / f"{stem}.txt" if self.calib_dir is not None else None

    def require_calib_dir(self) -> Path:
        """The calibration folder, which must exist.

        Raises
        ------
        FormatError
            Naming where it was expected.
        """
        if self.calib_dir is None:
            raise FormatError(self.label_dir.parent / "calib",
                              f"expected a KITTI {self.kind} folder with {self.labels}/ and calib/")
        return self.calib_dir

    def require_calib(self, stem: str) -> Path:
        """``calib/<stem>.txt``, which must exist.

        Raises
        ------
        FormatError
            No calibration folder (naming where it was expected), or no file for ``stem`` (naming the label file).
        """
        calib_dir = self.require_calib_dir()
        path = calib_dir / f"{stem}.txt"
        if not path.is_file():
            raise FormatError(self.label_file(stem), f"no calibration file {path}")
        return path

    def camera(self, stem: str) -> Camera:
        """The camera of image 2 (``P2``) from ``calib/<stem>.txt``, with the KITTI image size of its focal length.

        Raises
        ------
        FormatError
            No calibration file (see :meth:`require_calib`) or a malformed one.
        """
        camera = kitti.read_calib(self.require_calib(stem)).camera(2)
        return Camera(K=camera.K, t_cam_rect=camera.t_cam_rect, image_size=kitti_image_size(camera))


class KittiObjectFolder(KittiFolder):
    """KITTI object-benchmark labels, one file per image: ``label_2/<id>.txt``."""

    labels = "label_2"
    kind = "object"
    dataset = "kitti"

    def image_ids(self) -> list[str]:
        """Every image id with a label file, sorted."""
        return [p.stem for p in self.label_files()]


class KittiTrackingFolder(KittiFolder):
    """KITTI tracking labels, one file per sequence: ``label_02/<seq>.txt``."""

    labels = "label_02"
    kind = "tracking"
    dataset = "kitti-tracking"

    def sequences(self) -> list[str]:
        """Every sequence with a label file, sorted."""
        return [p.stem for p in self.label_files()]

    def last_frame(self, sequence: str) -> int:
        """The last frame with a label row (-1 for none), from a cheap scan of the frame column.

        Raises FormatError for a frame number past ``kitti.MAX_FRAME``, before any caller allocates an id per frame.
        """
        from toosicubix.errors import FormatError
        from toosicubix.formats import kitti

        last = -1
        path = self.label_file(sequence)
        for number, line in enumerate(kitti.read_text(path).splitlines(), 1):
            first = line.split(maxsplit=1)[:1]
            if first and first[0].isascii() and first[0].isdigit():
                if int(first[0]) > kitti.MAX_FRAME:
                    raise FormatError(path, f"expected a frame number from 0 to {kitti.MAX_FRAME}, got {first[0]}",
                                      number)
                last = max(last, int(first[0]))
        return last

    def image_ids(self) -> list[str]:
        """Frames 0 to the last labelled frame of every sequence (a frame without rows has no objects)."""
        return [tracking_image_id(seq, f) for seq in self.sequences() for f in range(self.last_frame(seq) + 1)]


class CityscapesFolder:
    """Cityscapes 3D ground-truth files anywhere under a folder.

    Attributes
    ----------
    root : the folder given
    files : image id -> its file
    clashes : image id -> the files of the same rank that claim it (such an id cannot be read)
    """

    dataset = "cityscapes"

    def __init__(self, root: str | Path):
        self.root = Path(root)
        _require_folder(self.root, self.dataset)
        self.files: dict[str, Path] = {}
        self.clashes: dict[str, list[Path]] = {}
        for path in sorted(self.root.rglob("*.json")):
            stem = path.stem
            preferred = stem.endswith(GTBBOX3D_SUFFIX)
            image_id = stem[: -len(GTBBOX3D_SUFFIX)] if preferred else stem
            known = self.files.get(image_id)
            if known is None:
                self.files[image_id] = path
            elif preferred and not known.stem.endswith(GTBBOX3D_SUFFIX):
                self.files[image_id] = path
            elif preferred == known.stem.endswith(GTBBOX3D_SUFFIX):
                self.clashes.setdefault(image_id, [known]).append(path)
        if not self.files:
            raise FormatError(self.root, "no Cityscapes 3D *_gtBbox3d.json files found (searched recursively)")

    def image_ids(self) -> list[str]:
        """Every image id, sorted."""
        return sorted(self.files)

    def resolve_id(self, image_id: str) -> str:
        """The id of the file an image id names: itself, or without a ``_leftImg8bit`` / ``_gtBbox3d`` suffix."""
        if image_id in self.files:
            return image_id
        for suffix in ("_leftImg8bit", GTBBOX3D_SUFFIX):
            if image_id.endswith(suffix) and image_id[: -len(suffix)] in self.files:
                return image_id[: -len(suffix)]
        return image_id

    def clash(self, image_id: str) -> str | None:
        """Why ``image_id`` cannot be read (several files claim it), or None."""
        if image_id not in self.clashes:
            return None
        files = ", ".join(str(p) for p in self.clashes[image_id])
        return f"image {image_id!r}: several ground-truth files have that name: {files}"


__all__ = [
    "DEFAULT_IMAGE_SIZE", "GTBBOX3D_SUFFIX", "KITTI_IMAGE_SIZES", "KITTI_VEHICLE_CLASSES", "CityscapesFolder",
    "KittiFolder", "KittiObjectFolder", "KittiTrackingFolder", "kitti_image_size", "parse_sequences",
    "parse_tracking_image_id", "tracking_image_id",
]

"""Fit every vehicle of an annotation file and write the outputs: the job behind ``toosicubix fit``.

Outputs in the output folder:

- ``label_2/<image id>.txt``: KITTI labels (camera-0 frame when the camera is a KITTI ``P``), one file per
  image, vehicles that failed left out. KITTI stores yaw only: pitch and roll are dropped there.
- ``results.json``: every vehicle, with its full rotation, or its status "failed" and the reason.

The folder is written as a whole (:mod:`toosicubix.pipeline.output_folder`): a staging folder beside it
takes every file, with a marker that makes it ours, and then replaces it in one rename; a killed run
leaves the previous output. The annotation file is read one image at a time and each image's results
are written as soon as it is done, so memory does not grow with the batch. One vehicle that fails, even
by an unexpected error, never stops the batch.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from toosicubix import __version__
from toosicubix.annotations.stream import AnnotationIndex, index_annotations
from toosicubix.formats import kitti
from toosicubix.formats.results import (
    RESULTS_FILENAME,
    ImageResult,
    RenderedImage,
    VehicleResult,
    write_results_stream,
)
from toosicubix.model import Image
from toosicubix.pipeline.fitting import (
    batch_run,
    iter_fit_file,
    iter_fit_images,
    reads_in_workers,
    stream_images,
)
from toosicubix.pipeline.labels import kitti_lines
from toosicubix.pipeline.output_folder import (
    LABEL_DIR,
    TRACKING_LABEL_DIR,
    OutputFolderError,
    check_output_dir,
    pause_after_file,
    staged_output,
)
from toosicubix.pipeline.pilot import PilotFindings, estimated_grounds, on_estimated_roads, run_pilot
from toosicubix.pipeline.settings import BatchSettings
from toosicubix.pipeline.tracks import fit_tracks

__all__ = ["LABEL_DIR", "BatchSummary", "FailedTrack", "OutputFolderError", "fit_file", "fitted_batch", "kitti_lines",
           "pilot_and_fits", "write_outputs"]


#: How many failed vehicles a :class:`BatchSummary` lists (a batch's memory must not grow with its size).
FAILED_KEPT = 1000
#: How many distinct reasons of one failed track's frames are told apart (:class:`FailedTrack`).
REASONS_KEPT = 100


@dataclass
class FailedTrack:
    """A track's failed frames, for the summary (the reason of each frame is in results.json)."""

    track: str
    frames: int  # how many of its frames failed
    first_image: str  # the image of its first failed frame (file order) and of its last
    last_image: str
    reasons: list[str]  # its frames' distinct reasons, the first frame's first; at most REASONS_KEPT

    @property
    def reason(self) -> str:
        """Its first failed frame's reason."""
        return self.reasons[0]

    @property
    def other_reasons(self) -> int:
        """How many other reasons its other failed frames give (counted up to :data:`REASONS_KEPT` in all)."""
        return len(self.reasons) - 1

    def add(self, image_id: str, reason: str) -> None:
        """Count another failed frame, in image ``image_id``, for ``reason``."""
        self.frames, self.last_image = self.frames + 1, image_id
        if reason not in self.reasons and len(self.reasons) < REASONS_KEPT:
            self.reasons.append(reason)

    def describe(self) -> str:
        """``track T (N frames, images A to B): reason``, as ``fit`` says it."""
        where = (f"image {self.first_image}" if self.frames == 1 else
                 f"{self.frames} frames, images {self.first_image} to {self.last_image}")
        others = (f" (and {self.other_reasons} other reason{'s' if self.other_reasons > 1 else ''} on other frames: "
                  "results.json)" if self.other_reasons else "")
        return f"track {self.track} ({where}): {self.reason}{others}"


@dataclass(frozen=True)
class BatchSummary:
    """What a batch did."""

    images: int
    vehicles: int
    ok: int
    # (image id, vehicle id, reason) of failed vehicles without a track, the first FAILED_KEPT in file order
    failed: list[tuple[str, str, str]]
    out_dir: Path
    scale_from: dict[str, int] = field(default_factory=dict)  # cue -> vehicles whose scale it set
    pilot: PilotFindings | None = None  # the click noise and road normals the batch was fitted with, and whence
    misfits: int | None = None  # fitted vehicles whose residuals failed the chi-square test; None: not tested
    implausible: list[tuple[str, str, str]] = field(default_factory=list)  # (image, vehicle, why), first FAILED_KEPT
    tracks: int = 0  # tracks fitted as tracks
    pose_from: dict[str, int] = field(default_factory=dict)  # tracked frames fitted, by what their pose came from
    jobs: int = 1  # the processes it was fitted in (``--jobs auto`` resolved)
    failed_tracks: list[FailedTrack] = field(default_factory=list)  # tracks with failed frames, the first FAILED_KEPT

    @property
    def n_failed(self) -> int:
        """How many vehicles failed (``failed`` lists only the first :data:`FAILED_KEPT`; all are in
        results.json)."""
        return self.vehicles - self.ok


def prepare_output_dir(out_dir: Path) -> None:
    """Check that ``out_dir`` may be replaced by this run's output; write nothing.

    Raises
    ------
    OutputFolderError
        See :func:`toosicubix.pipeline.output_folder.check_output_dir`: a dataset, ground truth, any folder
        with files toosicubix did not write (the marker file decides, not ``results.json``).
    """
    check_output_dir(out_dir)


def write_outputs(out_dir: Path, results: Iterable[ImageResult], header: dict[str, Any],
                  on_image: Callable[[ImageResult], None] | None = None) -> dict[str, int]:
    """Write the KITTI label files and results.json into a staging folder, one image at a time as the
    results come, then swap it in for ``out_dir`` as a whole (:mod:`.output_folder`); return the summary.

    Frames of sequences also give KITTI tracking labels, ``label_02/<sequence>.txt``, of their tracked vehicles
    (sorted by frame): each track gets an integer id per sequence in the order the file first names it, and
    results.json's ``track_ids`` maps the tracks' names to them."""

    def write_label(path: Path, text: str) -> None:  # made durable with the whole folder (staged_output)
        with open(path, "w", encoding="utf-8", newline="\n") as handle:
            handle.write(text)
        pause_after_file()

    try:
        with staged_output(out_dir, {"generator": header.get("generator")}) as staging:
            label_dir = staging / LABEL_DIR
            label_dir.mkdir()
            track_ids: dict[str, dict[str, int]] = {}  # per sequence, track -> its KITTI tracking id
            tracking: dict[str, list[tuple[int, int, str]]] = {}  # per sequence, (frame, id, line)

            def labelled() -> Iterator[ImageResult]:
                for res in results:
                    # A worker's image comes with its lines (iter_fit_file); the others' are made here.
                    lines = res.label_lines if isinstance(res, RenderedImage) and res.label_lines is not None \
                        else kitti_lines(res)
                    write_label(label_dir / f"{res.id}.txt", "".join(f"{line}\n" for line in lines))
                    if res.sequence is not None:
                        ids, frame = track_ids.setdefault(res.sequence, {}), int(res.frame or 0)
                        for v, line in zip((v for v in res.vehicles if v.ok), lines, strict=True):
                            if v.track is not None:
                                number = ids.setdefault(v.track, len(ids))
                                tracking.setdefault(res.sequence, []).append(
                                    (frame, number, kitti.tracking_line(frame, number, line)))
                    yield res

            def trailer() -> dict[str, Any]:
                named = {sequence: ids for sequence, ids in track_ids.items() if ids}
                return {"track_ids": named} if named else {}

            with open(staging / RESULTS_FILENAME, "w", encoding="utf-8", newline="\n") as handle:
                summary = write_results_stream(handle, labelled(), header, on_image, trailer)
            pause_after_file()
            if tracking:
                tracking_dir = staging / TRACKING_LABEL_DIR
                tracking_dir.mkdir()
                for sequence, rows in tracking.items():
                    write_label(tracking_dir / f"{sequence}.txt", "".join(f"{line}\n" for *_, line in sorted(rows)))
    except OSError as exc:  # a full disk, a name the file system refuses: nothing of this run is left
        where = Path(exc.filename).name if exc.filename else out_dir
        raise OutputFolderError(f"{out_dir}: cannot write {where}: {exc.strerror or exc}; the folder is "
                                f"unchanged") from None
    return summary


def fitted_batch(images: Iterable[Image], n_vehicles: int, settings: BatchSettings, pilot: PilotFindings,
                 progress: Callable[[int], None] | None = None,
                 tracked: Iterator[tuple[Image, list[VehicleResult]]] | None = None,
                 index: AnnotationIndex | None = None) -> Iterator[ImageResult]:
    """The batch's results, image by image in file order
    (:func:`~toosicubix.pipeline.fitting.iter_fit_images` with the pilot's solver settings; ``tracked`` the
    tracked vehicles' results, :func:`~toosicubix.pipeline.tracks.fit_tracks`), reusing the pilot's own fits when
    they are the batch's (:attr:`~toosicubix.pipeline.pilot.PilotFindings.results`) and the batch asks nothing the
    pilot did not do (no joint ground, as many next clicks, no tracks): a small batch is then fitted once.

    ``index``: the file ``images`` are read from, when nothing else reads them: with several processes, no tracks,
    no joint ground and no image crowded enough to keep a worker alone busy
    (:func:`~toosicubix.pipeline.fitting.reads_in_workers`), the workers then read the images themselves
    (:func:`~toosicubix.pipeline.fitting.iter_fit_file`, the same results)."""
    settings = replace(settings, options=pilot.options)
    if (pilot.results is None or settings.joint_ground or settings.next_clicks != pilot.next_clicks
            or tracked is not None or settings.box_cue):
        if index is not None and tracked is None and not settings.joint_ground and reads_in_workers(index,
                                                                                                   settings.jobs):
            yield from iter_fit_file(index, settings, estimated_grounds(pilot.road_normals), progress)
        else:
            yield from iter_fit_images(images, n_vehicles, settings, progress, tracked)
        return
    done = iter(pilot.results)  # the images with vehicles, in file order
    for im in images:
        if not im.vehicles:  # the pilot skipped it: nothing to fit
            yield from iter_fit_images([im], 0, settings)
            continue
        result = next(done)
        assert result.id == im.id and len(result.vehicles) == len(im.vehicles)
        if progress is not None:
            progress(len(result.vehicles))
        yield result


def pilot_and_fits(index: AnnotationIndex, settings: BatchSettings, progress: Callable[[int], None] | None = None,
                   on_start: Callable[[int], None] | None = None, with_images: bool = True
                   ) -> tuple[PilotFindings, Iterator[Image] | None, Iterator[ImageResult]]:
    """A batch as ``fit`` fits it (``fit`` and ``validate``): the pilot
    (:func:`~toosicubix.pipeline.pilot.run_pilot`), then, lazily, every image of the file on its camera's
    estimated road (a second reader of the stream, for the checks; None without ``with_images``) and its fit
    (:func:`fitted_batch`), in file order."""
    pilot = run_pilot(index, settings, progress, on_start)

    def on_roads() -> Iterator[Image]:
        return on_estimated_roads(stream_images(index, settings.ground), pilot.road_normals)

    images, second = itertools.tee(on_roads()) if with_images else (on_roads(), None)
    tracked = None
    if settings.tracks and index.tracked:  # another reader: the tracks, fitted a sequence at a time
        last_of_sequence = {where[0]: i for i, where in enumerate(index.sequences) if where is not None}
        tracked = fit_tracks(on_roads(), last_of_sequence, replace(settings, options=pilot.options), progress)
    return pilot, second, fitted_batch(images, index.vehicles, settings, pilot, progress, tracked,
                                       None if with_images else index)


def fit_file(annotations: str | Path, out_dir: str | Path, settings: BatchSettings | None = None,
             progress: Callable[[int], None] | None = None,
             on_start: Callable[[int], None] | None = None,
             say: Callable[[str], None] | None = None) -> BatchSummary:
    """Read an annotation file, fit every vehicle, write ``label_2/`` and ``results.json``.

    Parameters
    ----------
    annotations : the annotation file (v1)
    out_dir : output folder, created when missing
    settings : how the batch is fitted (:class:`~toosicubix.pipeline.settings.BatchSettings`: priors, solver
        settings, ground override, joint ground, jobs, next clicks, whether to estimate the click noise and the road
        normals first); its defaults when None
    progress : called with the number of vehicles just finished
    on_start : called once with the number of vehicles to fit
    say : told, before the first fit, when the compiled solver is being compiled (the first large batch after
        installing; a small batch takes the numpy path: :func:`~toosicubix.pipeline.fitting.batch_solver`)

    Raises
    ------
    InputFileError
        Bad annotation file, unknown prototype: nothing is written.
    OutputFolderError
        The output folder holds label files toosicubix did not write.
    """
    annotations, out_dir = Path(annotations), Path(out_dir)
    settings = settings or BatchSettings()
    index = index_annotations(annotations, known_prototypes=list(settings.priors))
    prepare_output_dir(out_dir)  # fail before the work, not after
    with batch_run(index.vehicles, settings, say) as settings:
        return _fit_indexed(annotations, index, out_dir, settings, progress, on_start)


def _fit_indexed(annotations: Path, index: AnnotationIndex, out_dir: Path, settings: BatchSettings,
                 progress: Callable[[int], None] | None, on_start: Callable[[int], None] | None) -> BatchSummary:
    """:func:`fit_file` once the file is indexed and the output folder checked."""
    # One reader of the images: the fitter (the label writer takes each camera's offset from the results).
    pilot, _, results = pilot_and_fits(index, settings, progress, on_start, with_images=False)
    options = pilot.options
    ground = settings.ground
    header = {
        "generator": f"toosicubix {__version__}",
        "annotations": str(annotations),
        "annotations_sha256": _sha256(annotations),
        "priors": "bundled" if settings.priors.bundled else settings.priors.source,
        "settings": {"lambda_3d": options.lambda_3d, "lambda_px": options.lambda_px, "click_sigma": options.click_sigma,
                     "part_sigma": options.part_sigma,
                     **({"misfit_level": options.misfit_level} if options.misfit_level is not None else {}),
                     **({"upright_weight": options.upright_weight} if options.upright_weight != "lambda" else {}),
                     **({"ground": ground.to_json()} if ground else {}),
                     **({"joint_ground": True} if settings.joint_ground else {})},
        **pilot.header(),
        "notes": "t_cam_vehicle is in the frame where the image's K applies (camera 2 for KITTI P2); "
                 "X_rect = X_cam - t_cam_rect. KITTI label files drop pitch and roll; R_cam_vehicle keeps them.",
    }
    failed: list[tuple[str, str, str]] = []
    scale_from: dict[str, int] = {}
    misfits = [0]
    tracks: set[str] = set()
    pose_from: dict[str, int] = {}
    implausible: list[tuple[str, str, str]] = []
    failed_tracks: dict[str, FailedTrack] = {}

    def tally(im: ImageResult) -> None:
        for v in im.vehicles:
            if v.track is not None and v.pose_from is not None:
                tracks.add(v.track)
                if v.ok:
                    pose_from[v.pose_from] = pose_from.get(v.pose_from, 0) + 1
            if v.ok and v.implausible is not None and len(implausible) < FAILED_KEPT:
                swapped = any(w.startswith("left and right look swapped") for w in v.warnings)
                implausible.append((im.id, v.id, "left and right look swapped" if swapped else v.implausible))
            if not v.ok and v.track is not None:  # a track's frames fail alike: one entry for the track
                if v.track in failed_tracks:
                    failed_tracks[v.track].add(im.id, v.error or "")
                elif len(failed_tracks) < FAILED_KEPT:
                    failed_tracks[v.track] = FailedTrack(v.track, 1, im.id, im.id, [v.error or ""])
            elif not v.ok:
                if len(failed) < FAILED_KEPT:
                    failed.append((im.id, v.id, v.error or ""))
            else:
                if v.scale_from:
                    scale_from[v.scale_from] = scale_from.get(v.scale_from, 0) + 1
                misfits[0] += bool(v.residual_test is not None and v.residual_test.misfit)

    summary = write_outputs(out_dir, results, header, tally)
    return BatchSummary(images=summary["images"], vehicles=summary["vehicles"], ok=summary["ok"], failed=failed,
                        out_dir=out_dir, scale_from=scale_from, pilot=pilot,
                        misfits=misfits[0] if options.misfit_level is not None else None, tracks=len(tracks),
                        pose_from=pose_from, implausible=implausible, jobs=settings.jobs,
                        failed_tracks=list(failed_tracks.values()))


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
